"""Damaged dataset folders: resuming a collection or opening a dataset gives a ValueError naming the file,
the problem and what to do (never a raw JSONDecodeError / KeyError / AttributeError); provably uncommitted
temp files are deleted silently.

Collections here run with a synthetic ``unit_fn`` (no simulator), so each takes well under a second.
"""

import hashlib
import json
import re
import shutil
import warnings
from pathlib import Path

import numpy as np
import pytest
import torch

from navformer_rl.data import collect as collect_module
from navformer_rl.data import open_dataset
from navformer_rl.data import synthetic as syn
from navformer_rl.data import writer as writer_module
from navformer_rl.data.cli import main as cli_main
from navformer_rl.data.collect import collect, settings_for
from navformer_rl.data.schema import DatasetKind
from navformer_rl.data.versions import VERSIONS_KEY, data_versions

# 5 trajectories, 2 per unit: units 0, 1 and the first trajectory of unit 2 (a cut shard)
SETTINGS = settings_for("e", "small", seed=7, n_trajectories=5, episodes_per_unit=2)
REMEDY = r"delete \S*unit-{unit:06d} and run the same collection again"


class _Crash(Exception):
    pass


def _synthetic_unit(root, kind, settings, unit):
    """A ``collect`` unit function writing a small synthetic shard (deterministic in seed and unit)."""
    n = settings.episodes_per_unit
    rows, targets = syn._trajectory_unit(DatasetKind.EXPLORATION, syn._unit_rng(settings.seed, unit), n, 2, 5)
    writer_module.write_shard(root, kind, unit, rows, targets, {"attempted": n})
    return {"items": n, "rows": int(rows.shape[0])}


def _crash_at_unit(stop):
    def unit_fn(root, kind, settings, unit):
        if unit == stop:
            raise _Crash
        return _synthetic_unit(root, kind, settings, unit)

    return unit_fn


def _collect(out, unit_fn=_synthetic_unit, settings=SETTINGS):
    return collect("e", out, settings, workers=1, progress=False, unit_fn=unit_fn)


@pytest.fixture(scope="module")
def reference(tmp_path_factory) -> Path:
    """The uninterrupted collection."""
    return _collect(tmp_path_factory.mktemp("damaged") / "ref")


@pytest.fixture(scope="module")
def interrupted(tmp_path_factory) -> Path:
    """A collection stopped after its units 0, 1 and 2 were committed, before consolidation."""
    out = tmp_path_factory.mktemp("damaged") / "interrupted"

    def crash(self, **kwargs):
        raise _Crash

    with pytest.MonkeyPatch.context() as patch, pytest.raises(_Crash):
        patch.setattr(writer_module.DatasetWriter, "finalize", crash)
        _collect(out)
    assert sorted(p.name for p in (out / "shards").iterdir()) == [f"unit-{u:06d}" for u in range(3)]
    return out


@pytest.fixture
def resumable(interrupted, tmp_path) -> Path:
    out = tmp_path / "resumable"
    shutil.copytree(interrupted, out)
    return out


def _stats_path(root: Path, unit: int) -> Path:
    return writer_module.shard_dir(root, unit) / "stats.json"


def _edit_stats(**changes):
    def damage(path: Path) -> None:
        stats = json.loads(path.read_text())
        stats.update(changes)
        path.write_text(json.dumps(stats))

    return damage


def _remove_and_mkdir(path: Path) -> None:
    path.unlink()
    path.mkdir()


def _drop_stats_key(key):
    def damage(path: Path) -> None:
        stats = json.loads(path.read_text())
        del stats[key]
        path.write_text(json.dumps(stats))

    return damage


def _edit_hashes(edit):
    def damage(path: Path) -> None:
        stats = json.loads(path.read_text())
        edit(stats["content_hashes"])
        path.write_text(json.dumps(stats))

    return damage


STATS_DAMAGE = {
    "truncated": (lambda p: p.write_bytes(p.read_bytes()[:20]), r"is not valid JSON \(truncated or corrupt"),
    "empty": (lambda p: p.write_bytes(b""), r"is empty, expected a JSON object"),
    "binary": (lambda p: p.write_bytes(b"\x00\xff\xfe garbage"), r"is not valid JSON \(not UTF-8 text"),
    "array": (lambda p: p.write_text("[1, 2]"), r"holds an array \(\[1, 2\]\), expected a JSON object"),
    "missing": (lambda p: p.unlink(), r"is missing"),
    "a folder": (_remove_and_mkdir, r"cannot be read \(Is a directory\)"),
    "no items": (lambda p: p.write_text('{"rows": 3, "counters": {}}'), r"'items' is missing"),
    "negative rows": (_edit_stats(rows=-1), r"'rows' is -1, expected a non-negative integer"),
    "items as text": (_edit_stats(items="2"), r"'items' is '2', expected a non-negative integer"),
    "counters list": (_edit_stats(counters=[1]), r"'counters' is \[1\], expected an object"),
    "counter float": (_edit_stats(counters={"attempted": 1.5}), r"counters \{'attempted': 1.5\} are not"),
    "items > rows": (_edit_stats(items=99), r"'items' is 99 but 'rows' \d+; every trajectory has"),
    # content hashes (a shard written before they were recorded has none)
    "no hashes": (
        _drop_stats_key("content_hashes"),
        r"'content_hashes' is missing: the shard was written by a navformer_rl version that recorded no",
    ),
    "hash not hex": (
        _edit_hashes(lambda h: h["files"].__setitem__("rows/action.memmap", "xyz")),
        r"'content_hashes' holds 'xyz' for 'rows/action.memmap', expected a sha256 hex digest",
    ),
    "hash of a file missing": (
        _edit_hashes(lambda h: h["files"].pop("targets/target_pixels.memmap")),
        r"'content_hashes' lists no hash of \['targets/target_pixels.memmap'\] and unknown files \[\]",
    ),
    "other algorithm": (
        _edit_hashes(lambda h: h.__setitem__("algorithm", "md5")),
        r"'content_hashes' has algorithm 'md5', expected \{'algorithm': 'sha256'",
    ),
    # per-item counters (what the metadata counts when the dataset ends inside this unit)
    "counters_by_item short": (
        _edit_stats(counters_by_item={"attempted": [1]}),
        r"counters_by_item\['attempted'\] is \[1\], expected 2 non-decreasing non-negative integers",
    ),
    "counters_by_item unknown": (
        _edit_stats(counters_by_item={"failed": [0, 0]}),
        r"'counters_by_item' holds 'failed', which 'counters' lacks",
    ),
}


@pytest.mark.parametrize("case", list(STATS_DAMAGE))
def test_resume_with_damaged_stats_names_the_file_and_the_fix(case, resumable, reference, folder_bytes):
    damage, problem = STATS_DAMAGE[case]
    path = _stats_path(resumable, 1)
    damage(path)
    with pytest.raises(ValueError, match=rf"{re.escape(str(path))}:? {problem}.*{REMEDY.format(unit=1)}"):
        _collect(resumable)
    # following the advice: the unit is collected again and the dataset is the uninterrupted one
    shutil.rmtree(writer_module.shard_dir(resumable, 1))
    _collect(resumable)
    assert folder_bytes(resumable) == folder_bytes(reference)


def test_cli_resume_with_damaged_stats_is_a_one_line_error(tmp_path, capsys):
    """``navformer collect`` itself: the damaged unit is reported before any unit runs (exit status 2)."""
    settings = settings_for("e", "small", seed=0, n_trajectories=6)  # what --n 6 --seed 0 asks for
    out = tmp_path / "e"
    with pytest.raises(_Crash):
        _collect(out, unit_fn=_crash_at_unit(1), settings=settings)
    _stats_path(out, 0).write_text('{"items": 4, "rows": ')
    argv = ["collect", "e", "--out", str(out), "--n", "6", "--workers", "1", "--no-progress"]
    assert cli_main(argv) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"navformer collect: error: {_stats_path(out, 0)} is not valid JSON")
    assert f"delete {writer_module.shard_dir(out, 0)} and run the same collection again" in err
    assert "Traceback" not in err


def _memmap_meta(part: str, unit: int = 0):
    def damage(root: Path) -> None:
        (writer_module.shard_dir(root, unit) / part / "meta.json").write_text("{garbage")

    return damage


SHARD_DAMAGE = {
    "rows memmap truncated": (
        0,
        lambda r: (writer_module.shard_dir(r, 0) / "rows" / "action.memmap").write_bytes(b"\0" * 8),
        r"unit-000000/rows/action.memmap has 8 bytes, expected \d+",
    ),
    "targets memmap missing": (
        1,
        lambda r: (writer_module.shard_dir(r, 1) / "targets" / "target_pixels.memmap").unlink(),
        r"unit-000001/targets/target_pixels.memmap is missing",
    ),
    "rows meta.json corrupt": (0, _memmap_meta("rows"), r"unit-000000/rows: cannot read the memmapped"),
    # unit 2 gives only its first trajectory: its rows are read to find where that one ends
    "cut shard's rows corrupt": (2, _memmap_meta("rows", 2), r"unit-000002/rows: cannot read the memmapped"),
}


def _overwrite(part: str, name: str, dtype, value):
    """Damage keeping the file size: set every element of memmap ``part/name`` of a unit to ``value``."""

    def damage(root: Path, unit: int) -> None:
        path = writer_module.shard_dir(root, unit) / part / name
        column = np.fromfile(path, dtype=dtype)
        column[:] = value
        column.tofile(path)

    return damage


def _flip_byte(part: str, name: str):
    def damage(root: Path, unit: int) -> None:
        path = writer_module.shard_dir(root, unit) / part / name
        data = bytearray(path.read_bytes())
        data[len(data) // 2] ^= 0xFF
        path.write_bytes(bytes(data))

    return damage


CONTENT_DAMAGE = {  # (unit, damage, file): the sizes, meta.json and stats.json stay as they were
    "steps zeroed": (1, _overwrite("rows", "step.memmap", np.int64, 0), "rows/step.memmap"),
    "actions NaN": (0, _overwrite("rows", "action.memmap", np.float32, np.nan), "rows/action.memmap"),
    "one target pixel": (1, _flip_byte("targets", "target_pixels.memmap"), "targets/target_pixels.memmap"),
    "one frame pixel of the cut unit": (2, _flip_byte("rows", "pixels.memmap"), "rows/pixels.memmap"),
}


@pytest.mark.parametrize("case", list(CONTENT_DAMAGE))
def test_resume_with_same_size_content_damage_names_the_file_and_the_fix(
    case, resumable, reference, folder_bytes
):
    unit, damage, name = CONTENT_DAMAGE[case]
    damage(resumable, unit)
    file = writer_module.shard_dir(resumable, unit) / name
    with pytest.raises(
        ValueError,
        match=(
            rf"^{re.escape(str(file))}: "
            r"its content changed after it was written \(its sha256 is [0-9a-f]+\.\.\., "
            rf"\S*unit-{unit:06d}/stats.json recorded [0-9a-f]+\.\.\..*{REMEDY.format(unit=unit)}"
        ),
    ):
        _collect(resumable)
    assert json.loads((resumable / "metadata.json").read_text())["status"] == "collecting"
    shutil.rmtree(writer_module.shard_dir(resumable, unit))
    _collect(resumable)
    assert folder_bytes(resumable) == folder_bytes(reference)


def test_shard_changed_after_the_resume_check_is_refused_at_consolidation(interrupted, tmp_path):
    """The audit's case: shards changed in place between the resume's check and consolidation (or by a
    caller that consolidates without resuming) never reach ``consolidated/``."""
    root = tmp_path / "copy"
    shutil.copytree(interrupted, root)
    writer = writer_module.DatasetWriter(
        root, "e", json.loads((root / "metadata.json").read_text())["settings"], target_count=5
    )
    for unit in writer.completed_units():
        writer.check_shard(unit)
    _overwrite("rows", "step.memmap", np.int64, 0)(root, 1)
    with pytest.raises(ValueError, match=r"unit-000001/rows/step.memmap: its content changed after it was"):
        writer.finalize()
    assert not (root / "consolidated").exists()
    assert json.loads((root / "metadata.json").read_text())["status"] == "collecting"


@pytest.mark.parametrize("case", list(SHARD_DAMAGE))
def test_resume_with_damaged_shard_memmaps_names_the_file_and_the_fix(case, resumable):
    unit, damage, problem = SHARD_DAMAGE[case]
    damage(resumable)
    with pytest.raises(ValueError, match=rf"{problem}.*{REMEDY.format(unit=unit)}"):
        _collect(resumable)
    assert json.loads((resumable / "metadata.json").read_text())["status"] == "collecting"


def test_damaged_shard_memmap_is_reported_before_any_unit_runs(tmp_path):
    out = tmp_path / "e"
    with pytest.raises(_Crash):
        _collect(out, unit_fn=_crash_at_unit(2))  # units 0 and 1 committed, unit 2 still to collect
    with open(writer_module.shard_dir(out, 0) / "rows" / "pixels.memmap", "r+b") as f:
        f.truncate(100)
    # the resume would raise _Crash if it ran unit 2 before noticing (e.g. at consolidation)
    with pytest.raises(
        ValueError, match=rf"unit-000000/rows/pixels.memmap has 100 bytes.*{REMEDY.format(unit=0)}"
    ):
        _collect(out, unit_fn=_crash_at_unit(2))


@pytest.mark.parametrize("name", ["unit-000001 (copy)", "unit-1", "unit-x"])
def test_resume_refuses_foreign_unit_folders(name, resumable):
    (resumable / "shards" / name).mkdir()
    with pytest.raises(ValueError, match=rf"shards/{re.escape(name)} is not a work-unit folder.*move it out"):
        _collect(resumable)


def test_resume_refuses_a_file_in_place_of_a_unit(resumable):
    (resumable / "shards" / "unit-000004").write_text("not a folder")
    with pytest.raises(ValueError, match=r"shards/unit-000004 is not a work-unit folder"):
        _collect(resumable)


@pytest.mark.parametrize(
    ("content", "problem"),
    [
        ('{"schema_version": 1, "ki', r"is not valid JSON \(truncated or corrupt"),
        ("null", r"holds null \(None\), expected a JSON object"),
    ],
    ids=["truncated", "null"],
)
def test_resume_with_damaged_metadata_names_the_file_and_the_fix(content, problem, resumable):
    (resumable / "metadata.json").write_text(content)
    with pytest.raises(ValueError, match=rf"metadata.json {problem}.*restore it from a backup, or delete"):
        _collect(resumable)


def test_uncommitted_metadata_temp_files_are_deleted(resumable, reference, folder_bytes, monkeypatch):
    # a process killed while rewriting metadata.json leaves its temp file (named by durable.atomic_path, or
    # as earlier versions named it): deleted on reopening
    (resumable / ".metadata.k1ll3d_x.tmp.json").write_text('{"status": "comp')
    (resumable / ".tmp-metadata.json.4242").write_text('{"status": "comp')
    # an error while rewriting it removes the temp file at once
    real_replace = writer_module.os.replace

    def failing_replace(src, dst):
        if str(dst).endswith("metadata.json"):
            raise _Crash
        return real_replace(src, dst)

    monkeypatch.setattr(writer_module.os, "replace", failing_replace)
    with pytest.raises(_Crash):
        _collect(resumable)
    assert not [*resumable.glob(".tmp-*"), *resumable.glob(".metadata.*")]
    monkeypatch.setattr(writer_module.os, "replace", real_replace)
    _collect(resumable)
    assert folder_bytes(resumable) == folder_bytes(reference)


# ------------------------------------------------------------------------------------- open_dataset
def _edit_metadata(edit):
    def damage(root: Path) -> None:
        meta = json.loads((root / "metadata.json").read_text())
        edit(meta)
        (root / "metadata.json").write_text(json.dumps(meta))

    return damage


def _edit_memmap_meta(part, edit):
    def damage(root: Path) -> None:
        path = root / "consolidated" / part / "meta.json"
        meta = json.loads(path.read_text())
        edit(meta)
        path.write_text(json.dumps(meta))

    return damage


def _write_column(key, value, dtype=np.int64, rows=slice(-1, None)):
    """Same-size damage: set ``rows`` (default: the last) of consolidated column ``key`` (a path below
    ``consolidated/rows``, e.g. ``next/reward``) to ``value``."""

    def damage(root: Path) -> None:
        path = root / "consolidated" / "rows" / f"{key}.memmap"
        column = np.fromfile(path, dtype=dtype)
        column[rows] = value
        column.tofile(path)

    return damage


def _drop_last_target(root: Path) -> None:
    """A consistent targets table of one image fewer, and counts.items to match: the rows still number
    one trajectory more."""
    path = root / "consolidated" / "targets" / "target_pixels.memmap"
    with open(path, "r+b") as f:
        f.truncate(path.stat().st_size - 84 * 84 * 3)
    _edit_memmap_meta("targets", lambda m: m["target_pixels"]["shape"].__setitem__(0, 11))(root)
    _edit_memmap_meta("targets", lambda m: m.__setitem__("shape", [11]))(root)
    _edit_metadata(lambda m: m["counts"].__setitem__("items", 11))(root)


META = "metadata.json"
OPEN_DAMAGE = {
    "metadata binary": (
        lambda r: (r / META).write_bytes(b"\x89PNG\r\n"),
        rf"{META} is not valid JSON \(not UTF-8 text",
    ),
    "metadata empty": (lambda r: (r / META).write_text(" \n"), rf"{META} is empty, expected a JSON object"),
    "metadata array": (lambda r: (r / META).write_text("[]"), rf"{META} holds an array \(\[\]\), expected"),
    "kind missing": (_edit_metadata(lambda m: m.pop("kind")), rf"{META}: 'kind' is None, expected one of"),
    "kind unknown": (
        _edit_metadata(lambda m: m.__setitem__("kind", ["e"])),
        rf"{META}: 'kind' is \['e'\], expected one of",
    ),
    "counts missing": (
        _edit_metadata(lambda m: m.pop("counts")),
        rf"{META}: 'counts' is None, expected an object with the 'rows' and 'items' counts",
    ),
    "counts.rows text": (
        _edit_metadata(lambda m: m["counts"].__setitem__("rows", "many")),
        rf"{META}: counts.rows is 'many', expected a non-negative integer",
    ),
    "counts.items negative": (
        _edit_metadata(lambda m: m["counts"].__setitem__("items", -1)),
        rf"{META}: counts.items is -1, expected a non-negative integer",
    ),
    "counts.rows off by one": (
        _edit_metadata(lambda m: m["counts"].__setitem__("rows", m["counts"]["rows"] + 1)),
        r"rows/pixels.memmap has \d+ bytes, expected \d+",
    ),
    "rows meta.json lacks a key": (
        _edit_memmap_meta("rows", lambda m: m.pop("action")),
        r"rows/meta.json does not describe key 'action' as a tensor \(expected torch.float32",
    ),
    "rows folder is a file": (
        lambda r: (shutil.rmtree(r / "consolidated" / "rows"), (r / "consolidated" / "rows").write_text("")),
        r"consolidated/rows is not a folder",
    ),
    "memmap is a folder": (
        lambda r: _remove_and_mkdir(r / "consolidated" / "rows" / "step.memmap"),
        r"rows/step.memmap is not a file \(expected the memmap of key 'step'\)",
    ),
    "target_id out of range": (
        _write_column("target_id", 12),
        r"consolidated/rows: 'target_id' ranges over 0..12, expected 0..11",
    ),
    "episode ids broken": (
        _write_column("episode", 40),
        r"consolidated/rows: 'episode' ids must be contiguous",
    ),
    "fewer targets than trajectories": (
        _drop_last_target,
        rf"consolidated/rows: 'episode' numbers 12 trajectories, but \S*{META} records counts.items = 11",
    ),
    "content_hashes of another algorithm": (
        _edit_metadata(lambda m: m["content_hashes"].__setitem__("algorithm", "md5")),
        rf"{META}: 'content_hashes' has algorithm 'md5', expected",
    ),
    "content_hashes lacking a file": (
        _edit_metadata(lambda m: m["content_hashes"]["files"].pop("consolidated/rows/step.memmap")),
        rf"{META}: 'content_hashes' lists no hash of \['consolidated/rows/step.memmap'\]",
    ),
    # content checks of the small columns (same sizes: only their values say the data is wrong)
    "every step 0": (
        _write_column("step", 0, rows=slice(None)),
        r"consolidated/rows/step.memmap: row 1 \(trajectory 0\) has step 0, expected 1: steps count 0, 1, 2",
    ),
    "steps not increasing": (
        _write_column("step", 0, rows=slice(-1, None)),
        r"rows/step.memmap: row \d+ \(trajectory 11\) has step 0, expected \d+",
    ),
    "task of the other dataset": (
        _write_column("task", 1, rows=slice(5, 6)),
        r"rows/task.memmap: row 5 \(trajectory 0, step 5\) has task 1, expected 0 for 'e'",
    ),
    "action NaN": (
        _write_column("action", np.nan, np.float32, rows=slice(None)),
        r"rows/action.memmap: row 0 \(trajectory 0, step 0\) holds action \[nan, nan\], expected finite",
    ),
    "action out of range": (
        _write_column("action", 1.5, np.float32, rows=slice(-1, None)),
        r"rows/action.memmap: row \d+ \(trajectory 11, step \d+\) holds action \[\S+, 1.5\], expected finite "
        r"values in \[-1, 1\]",
    ),
    "reward not 0 or 1": (
        _write_column("next/reward", 0.5, np.float32, rows=slice(3, 4)),
        r"rows/next/reward.memmap: row 3 \(trajectory 0, step 3\) holds reward 0.5, expected 0 or 1",
    ),
    "return_to_go not eq. 3": (
        _write_column("return_to_go", 0.0, np.float32, rows=slice(2, 3)),
        r"rows/return_to_go.memmap: row 2 \(trajectory 0, step 2\) holds return_to_go 0.0, expected 1.0: the",
    ),
    "reward moved": (  # every value in {0, 1}, but the trajectory's return-to-go no longer matches
        _write_column("next/reward", 1.0, np.float32, rows=slice(0, 1)),
        r"rows/return_to_go.memmap: row 0 \(trajectory 0, step 0\) holds return_to_go 1.0, expected 2.0",
    ),
}


@pytest.mark.parametrize("case", list(OPEN_DAMAGE))
def test_open_damaged_dataset_names_the_file_and_the_problem(case, e_dataset, tmp_path):
    damage, problem = OPEN_DAMAGE[case]
    root = tmp_path / "copy"
    shutil.copytree(e_dataset, root)
    damage(root)
    with pytest.raises(ValueError, match=rf"^{re.escape(str(root))}/\S*{problem}"):
        open_dataset(root)


def _sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def test_metadata_records_the_sha256_of_every_consolidated_file(e_dataset):
    hashes = json.loads((e_dataset / "metadata.json").read_text())["content_hashes"]
    files = sorted(p for p in (e_dataset / "consolidated").rglob("*.memmap"))
    assert hashes["algorithm"] == "sha256"
    assert hashes["files"] == {p.relative_to(e_dataset).as_posix(): _sha256(p) for p in files}
    assert len(files) == 15  # 14 row keys and the targets table


@pytest.mark.parametrize("name", ["rows/pixels.memmap", "targets/target_pixels.memmap"])
def test_verify_finds_a_changed_pixel_that_the_cheap_checks_cannot(name, e_dataset, tmp_path):
    root = tmp_path / "copy"
    shutil.copytree(e_dataset, root)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        open_dataset(root, verify=True)  # intact: nothing to report
    file = root / "consolidated" / name
    data = bytearray(file.read_bytes())
    data[1000] ^= 0x01
    file.write_bytes(bytes(data))
    open_dataset(root)  # the pixels are not read by default
    with pytest.raises(
        ValueError,
        match=rf"^{re.escape(str(file))}: its content changed after it was written \(its sha256 is \S+, "
        rf"{re.escape(str(root / META))} recorded \S+ when it was written\); the dataset folder was damaged",
    ):
        open_dataset(root, verify=True)


def test_a_dataset_written_before_hashes_opens_and_verify_has_nothing_to_check(e_dataset, tmp_path):
    root = tmp_path / "old"
    shutil.copytree(e_dataset, root)
    _edit_metadata(lambda m: m.pop("content_hashes"))(root)
    assert open_dataset(root).num_trajectories == 12
    with pytest.warns(UserWarning, match=r"records no content_hashes .* verify=True has nothing to compare"):
        assert open_dataset(root, verify=True).num_trajectories == 12


def _bump_exploration_expert(kind):
    return {**data_versions(kind), "exploration_expert": data_versions(kind)["exploration_expert"] + 1}


def test_a_complete_dataset_from_other_code_is_reused_with_a_warning(tmp_path, monkeypatch):
    out = tmp_path / "e"
    _collect(out)
    before = (out / "metadata.json").read_bytes()
    monkeypatch.setattr(collect_module, "data_versions", _bump_exploration_expert)
    was = data_versions("e")["exploration_expert"]
    change = rf"data versions exploration_expert {was} -> {was + 1}"
    with pytest.warns(UserWarning, match=rf"collected by other code \({change}\); .* used as it is"):
        assert _collect(out) == out
    assert (out / "metadata.json").read_bytes() == before  # the record of what made it stays
    # other settings still differ loudly
    with pytest.raises(ValueError, match="already holds a dataset with settings"):
        _collect(out, settings=settings_for("e", "small", seed=8, n_trajectories=5, episodes_per_unit=2))


def test_an_unfinished_collection_from_other_code_is_refused(tmp_path, monkeypatch):
    out = tmp_path / "e"
    with pytest.raises(_Crash):
        _collect(out, unit_fn=_crash_at_unit(1))
    monkeypatch.setattr(collect_module, "data_versions", _bump_exploration_expert)
    with pytest.raises(
        ValueError,
        match=r"unfinished collection started by other code \(data versions exploration_expert \d -> \d\): "
        "finish it with the code version that started it, or delete the folder",
    ):
        _collect(out)


_SOURCE_HASH = "ab" * 32


def _identified_by_source_hash(meta: dict) -> None:
    """Make ``metadata.json`` of a dataset name its code by a sha256 of its source (no data versions)."""
    del meta["settings"][VERSIONS_KEY]
    meta["settings"]["code_sha256"] = _SOURCE_HASH


def test_a_complete_dataset_identified_by_a_source_hash_opens_and_is_reused(reference, tmp_path):
    root = tmp_path / "e"
    shutil.copytree(reference, root)
    _edit_metadata(_identified_by_source_hash)(root)
    before = (root / "metadata.json").read_bytes()
    fresh = open_dataset(reference, verify=True)
    old = open_dataset(root, verify=True)
    assert old.num_trajectories == fresh.num_trajectories == 5
    assert torch.equal(old.rows["action"], fresh.rows["action"]) and torch.equal(old.targets, fresh.targets)
    with pytest.warns(UserWarning, match=r"code_sha256 abababababab, a hash of its source files; now data"):
        assert _collect(root) == root
    assert (root / "metadata.json").read_bytes() == before


def test_an_unfinished_collection_identified_by_a_source_hash_is_refused_in_one_line(resumable):
    _edit_metadata(_identified_by_source_hash)(resumable)
    with pytest.raises(ValueError) as err:
        _collect(resumable)
    message = str(err.value)
    assert "\n" not in message
    assert re.fullmatch(
        rf"{re.escape(str(resumable))} is an unfinished collection started by other code \(code_sha256 "
        r"abababababab, a hash of its source files; now data versions\): finish it with the code version "
        r"that started it, or delete the folder to collect anew",
        message,
    ), message
    assert sorted(p.name for p in (resumable / "shards").iterdir()) == [f"unit-{u:06d}" for u in range(3)]
