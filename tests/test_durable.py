"""navformer_rl.utils.durable's JSON writer and leftover finder (the rest is tested through its users:
checkpoints, datasets, evaluation outputs)."""

from __future__ import annotations

import json
import stat

import pytest

from navformer_rl.utils import durable

PAYLOAD = {
    "schema_version": 1,
    "kind": "e",
    "settings": {"seed": 0, "code_sha256": "ab" * 32, "sizes": [1, 2.5, None], "flag": True},
    "statistics": {
        "length_mean": 10.125,
        "collision_rate_per_step": 1e-06,
        "name": "caf\u00e9 \u2192 \u00fc",
    },
    "empty": {},
    "list": [],
}


def test_atomic_write_json_keeps_the_dataset_json_format(tmp_path):
    """The bytes that dataset metadata.json / stats.json have always had: ``json.dump(indent=2,
    sort_keys=True)`` and a newline (equal content must give equal files across versions)."""
    expected = tmp_path / "expected.json"
    with open(expected, "w") as handle:
        json.dump(PAYLOAD, handle, indent=2, sort_keys=True)
        handle.write("\n")
    durable.atomic_write_json(tmp_path / "metadata.json", PAYLOAD)
    written = (tmp_path / "metadata.json").read_bytes()
    assert written == expected.read_bytes()
    assert written.startswith(b'{\n  "empty": {},\n  "kind": "e",') and written.endswith(b"}\n")
    assert stat.S_IMODE((tmp_path / "metadata.json").stat().st_mode) == durable.file_mode()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["expected.json", "metadata.json"]


def test_atomic_write_json_leaves_the_old_file_on_error(tmp_path):
    target = tmp_path / "stats.json"
    durable.atomic_write_json(target, {"items": 1})
    with pytest.raises(TypeError):
        durable.atomic_write_json(target, {"items": object()})
    assert json.loads(target.read_text()) == {"items": 1}
    assert durable.atomic_leftovers(target) == []


def test_atomic_leftovers_finds_only_the_temporaries_of_that_path(tmp_path):
    target = tmp_path / "metadata.json"
    killed = durable.atomic_path(target)
    leftover = killed.__enter__()  # the writer is killed before the rename: its temporary file stays
    others = [
        "metadata.json",
        ".metadata.json",
        ".metadata.short.tmp.json",  # not mkstemp's 8 random characters
        ".stats.abcd1234.tmp.json",  # another file's temporary
        ".metadata.abcd1234.tmp.txt",
    ]
    for name in others:
        (tmp_path / name).write_text("{}")
    (tmp_path / ".metadata.dir12345.tmp.json").mkdir()  # not a file
    assert durable.atomic_leftovers(target) == [leftover]
    assert durable.atomic_leftovers(tmp_path / "stats.json") == [tmp_path / ".stats.abcd1234.tmp.json"]
    error = RuntimeError("writer failed")
    assert killed.__exit__(RuntimeError, error, None) is False  # an error (not a kill) removes it at once
    assert durable.atomic_leftovers(target) == [] and not leftover.exists()
