"""Writer + loader: round trip, refusals with clear messages, crash/resume == uninterrupted
(byte for byte)."""

import json
import os
import shutil
import subprocess
import sys

import numpy as np
import pytest
import torch

from navformer_rl.data import open_dataset
from navformer_rl.data import synthetic as syn
from navformer_rl.data import writer as writer_module
from navformer_rl.data.schema import SCHEMA_VERSION
from navformer_rl.utils import durable


def test_round_trip_matches_generated_trajectories(e_dataset):
    ds = open_dataset(e_dataset, kind="e")
    meta = ds.metadata
    assert meta["schema_version"] == SCHEMA_VERSION and meta["kind"] == "e" and meta["status"] == "complete"
    assert meta["counts"]["items"] == ds.num_trajectories == 12
    assert meta["statistics"]["steps"] == len(ds)
    assert not (e_dataset / "shards").exists()
    # regenerate unit 0 (4 trajectories) from its seed and compare with the stored rows
    rows, targets = syn._trajectory_unit(ds.kind, syn._unit_rng(3, 0), 4, 5, 30)
    n = rows.shape[0]
    stored = ds.rows[:n]
    for key in ("pixels", "action", "return_to_go", "step", ("next", "collision"), ("privileged", "pose")):
        assert torch.equal(stored[key], rows[key]), key
    assert torch.equal(ds.targets[:4], targets)
    # global ids: episodes numbered 0..11, target_id == episode, steps restart at 0
    ep = ds.rows["episode"]
    assert ep.unique().tolist() == list(range(12))
    assert torch.equal(ds.rows["target_id"], ep)
    assert (ds.rows["step"][ds.episodes.start] == 0).all()
    # the learnable structure: action[1] is a function of the target image colour only
    for traj in range(12):
        colour = ds.targets[traj, 42, 42].numpy()
        c = int(np.flatnonzero((syn.PALETTE == colour).all(1))[0])
        a1 = ds.rows["action"][ep == traj][:, 1]
        assert torch.allclose(a1, torch.full_like(a1, 2 * c / 4 - 1))


def test_ssl_round_trip(ssl_dataset):
    ds = open_dataset(ssl_dataset, kind="ssl")
    assert len(ds) == 40 and ds.targets is None
    differs = (ds.rows["pixels_static"] != ds.rows["pixels_dynamic"]).flatten(1).any(1)
    assert differs.all()  # every dynamic view holds at least one "robot"


def _copy(src, tmp_path):
    dst = tmp_path / "copy"
    shutil.copytree(src, dst)
    return dst


def test_refuses_unknown_schema_version(e_dataset, tmp_path):
    root = _copy(e_dataset, tmp_path)
    meta = json.loads((root / "metadata.json").read_text())
    meta["schema_version"] = 99
    (root / "metadata.json").write_text(json.dumps(meta))
    with pytest.raises(ValueError, match="schema_version 99 is not supported"):
        open_dataset(root)


def test_refuses_wrong_kind_and_missing_folder(e_dataset, tmp_path):
    with pytest.raises(ValueError, match="holds a 'e' dataset, expected 'ca'"):
        open_dataset(e_dataset, kind="ca")
    with pytest.raises(FileNotFoundError, match="metadata.json is missing"):
        open_dataset(tmp_path / "nothing")


def test_refuses_truncated_memmap(e_dataset, tmp_path):
    root = _copy(e_dataset, tmp_path)
    pixels = root / "consolidated" / "rows" / "pixels.memmap"
    with open(pixels, "r+b") as f:
        f.truncate(pixels.stat().st_size - 100)
    with pytest.raises(ValueError, match=r"pixels.memmap has \d+ bytes, expected \d+.*truncated"):
        open_dataset(root)


def test_refuses_missing_targets(e_dataset, tmp_path):
    root = _copy(e_dataset, tmp_path)
    (root / "consolidated" / "targets" / "target_pixels.memmap").unlink()
    with pytest.raises(FileNotFoundError, match="target_pixels.memmap is missing"):
        open_dataset(root)


def test_refuses_wrong_shape(e_dataset, tmp_path):
    root = _copy(e_dataset, tmp_path)
    rows = root / "consolidated" / "rows"
    meta = json.loads((rows / "meta.json").read_text())
    n = meta["pixels"]["shape"][0]
    meta["pixels"]["shape"] = [n, 3, 84, 84]  # same bytes, CHW instead of HWC
    (rows / "meta.json").write_text(json.dumps(meta))
    with pytest.raises(ValueError, match=r"'pixels' is torch.uint8 \(\d+, 3, 84, 84\), expected"):
        open_dataset(root)


def test_refuses_unfinished_collection(tmp_path):
    writer_module.DatasetWriter(tmp_path / "d", "ca", {"a": 1}, target_count=3)
    with pytest.raises(ValueError, match="collection is not finished"):
        open_dataset(tmp_path / "d")


def test_writer_refuses_other_settings_in_same_folder(tmp_path):
    writer_module.DatasetWriter(tmp_path / "d", "e", {"seed": 1}, target_count=3)
    with pytest.raises(
        ValueError,
        match=r"already holds a dataset with settings \{.seed.: 1\}, but this run asks for \{.seed.: 2\}",
    ):
        writer_module.DatasetWriter(tmp_path / "d", "e", {"seed": 2}, target_count=3)


class _Crash(Exception):
    pass


def test_resume_after_crashes_is_byte_identical(tmp_path, monkeypatch, folder_bytes):
    """Crash between shards, inside a shard, and inside consolidation; rerunning gives the same bytes."""
    reference = syn.make_synthetic_dataset(tmp_path / "ref", "e", 10, 3, 9, seed=11, items_per_shard=3)
    target = tmp_path / "resumed"
    real_write_shard = writer_module.write_shard
    calls = {"n": 0}

    def crash_on_third_shard(root, kind, unit, rows, targets, counters, *more):
        calls["n"] += 1
        if calls["n"] == 3:
            # die half-way through a shard: a partial temp folder is left behind
            partial = writer_module.shard_dir(root, unit).with_name(f".tmp-unit-{unit:06d}-999")
            partial.mkdir(parents=True)
            (partial / "garbage").write_bytes(b"x" * 10)
            raise _Crash
        return real_write_shard(root, kind, unit, rows, targets, counters, *more)

    monkeypatch.setattr(writer_module, "write_shard", crash_on_third_shard)
    with pytest.raises(_Crash):
        syn.make_synthetic_dataset(target, "e", 10, 3, 9, seed=11, items_per_shard=3)
    assert sorted(p.name for p in (target / "shards").iterdir()) == [
        ".tmp-unit-000002-999",
        "unit-000000",
        "unit-000001",
    ]
    monkeypatch.setattr(writer_module, "write_shard", real_write_shard)

    # second crash: during consolidation (after part of the flat memmap was written)
    real_rename = writer_module.os.rename

    def crash_on_consolidated_rename(src, dst):
        if str(dst).endswith("consolidated"):
            raise _Crash
        return real_rename(src, dst)

    monkeypatch.setattr(writer_module.os, "rename", crash_on_consolidated_rename)
    with pytest.raises(_Crash):
        syn.make_synthetic_dataset(target, "e", 10, 3, 9, seed=11, items_per_shard=3)
    assert (target / "consolidated.tmp").exists()
    assert json.loads((target / "metadata.json").read_text())["status"] == "collecting"
    monkeypatch.setattr(writer_module.os, "rename", real_rename)

    syn.make_synthetic_dataset(target, "e", 10, 3, 9, seed=11, items_per_shard=3)
    assert folder_bytes(target) == folder_bytes(reference)
    # a finished folder reopened by the same command stays unchanged
    syn.make_synthetic_dataset(target, "e", 10, 3, 9, seed=11, items_per_shard=3)
    assert folder_bytes(target) == folder_bytes(reference)


def test_last_shard_is_cut_to_the_requested_count(tmp_path):
    root = syn.make_synthetic_dataset(tmp_path / "d", "ca", 5, 2, 4, seed=0, items_per_shard=4)
    ds = open_dataset(root)
    assert ds.num_trajectories == 5 and ds.targets.shape == (5, 84, 84, 3)
    assert ds.metadata["counts"]["units"] == 2
    assert ds.rows["task"].unique().tolist() == [1]


def test_truncated_shard_is_refused_at_consolidation(tmp_path, monkeypatch):
    real_finalize = writer_module.DatasetWriter.finalize
    monkeypatch.setattr(writer_module.DatasetWriter, "finalize", lambda self, **kw: self.root)
    root = syn.make_synthetic_dataset(tmp_path / "d", "e", 6, 3, 5, seed=0, items_per_shard=3)
    pixels = writer_module.shard_dir(root, 1) / "rows" / "pixels.memmap"
    with open(pixels, "r+b") as f:
        f.truncate(1000)
    monkeypatch.setattr(writer_module.DatasetWriter, "finalize", real_finalize)
    with pytest.raises(ValueError, match=r"unit-000001/rows/pixels.memmap has 1000 bytes, expected"):
        syn.make_synthetic_dataset(root, "e", 6, 3, 5, seed=0, items_per_shard=3)


def _unit_rows(n_trajectories: int = 3):
    return syn._trajectory_unit(syn.DatasetKind.EXPLORATION, syn._unit_rng(0, 0), n_trajectories, 3, 6)


def test_write_shard_refuses_rows_not_sorted_by_episode_and_step(tmp_path):
    rows, targets = _unit_rows()
    swapped = torch.cat([rows[rows["episode"] == 1], rows[rows["episode"] == 0], rows[rows["episode"] == 2]])
    with pytest.raises(
        ValueError, match=r"shard 0 of .*: rows must be sorted by \(episode, step\).*\(0, 0\) after \(1, "
    ):
        writer_module.write_shard(tmp_path, "e", 0, swapped, targets, {})
    reversed_steps = rows.clone()
    first = rows["episode"] == 0
    reversed_steps["step"][first] = rows["step"][first].flip(0)
    with pytest.raises(ValueError, match=r"row 1 has \(episode, step\) = \(0, \d\) after \(0, \d\)"):
        writer_module.write_shard(tmp_path, "e", 1, reversed_steps, targets, {})
    assert not (tmp_path / "shards").exists()  # refused before anything was written
    writer_module.write_shard(tmp_path, "e", 2, rows, targets, {})
    assert writer_module.shard_dir(tmp_path, 2).is_dir()


@pytest.mark.parametrize(
    ("key", "value", "problem"),
    [
        ("action", float("nan"), r"key 'action': row 4 \(trajectory \d, step \d\) holds action \[nan, nan\]"),
        ("return_to_go", 3.0, r"key 'return_to_go': row 4 \(trajectory \d, step \d\) holds return_to_go 3.0"),
    ],
)
def test_write_shard_refuses_impossible_content(key, value, problem, tmp_path):
    rows, targets = _unit_rows()
    rows[key][4] = value
    with pytest.raises(ValueError, match=rf"shard 0 of \S+: {problem}"):
        writer_module.write_shard(tmp_path, "e", 0, rows, targets, {})
    assert not (tmp_path / "shards").exists()  # refused before anything was written


def _cut_unit_writer(root):
    """Two units of 4 trajectories with per-item counters; the dataset takes unit 0 and 1 item of unit 1."""
    writer = writer_module.DatasetWriter(root, "e", {"test": "counts"}, target_count=5)
    for unit, counters, by_item in (
        (
            0,
            {"attempted": 6, "failed": 2, "episodes": 1},
            {"attempted": [1, 3, 4, 6], "failed": [0, 1, 1, 2]},
        ),
        (
            1,
            {"attempted": 7, "failed": 3, "episodes": 1},
            {"attempted": [2, 3, 5, 5], "failed": [1, 1, 2, 2]},
        ),
    ):
        rows, targets = syn._trajectory_unit(syn.DatasetKind.EXPLORATION, syn._unit_rng(0, unit), 4, 2, 4)
        writer.write_shard(unit, rows, targets, counters, by_item)
    return writer


def test_counts_cover_only_the_items_taken(tmp_path):
    root = _cut_unit_writer(tmp_path / "d").finalize()
    counts = json.loads((root / "metadata.json").read_text())["counts"]
    # the rows of the trajectories taken: all 4 of unit 0 and the first of unit 1 (the same seeded units)
    units = [syn._trajectory_unit(syn.DatasetKind.EXPLORATION, syn._unit_rng(0, u), 4, 2, 4) for u in (0, 1)]
    lengths = [torch.bincount(rows["episode"]) for rows, _ in units]
    assert len(lengths[0]) == len(lengths[1]) == 4
    expected_rows = int(lengths[0].sum() + lengths[1][0])
    assert expected_rows < int(lengths[0].sum() + lengths[1].sum())  # unit 1 is cut
    assert len(open_dataset(root)) == expected_rows
    # unit 1 gives its first trajectory: the attempts up to it (one failure, one success), not its 7
    assert counts == {
        "rows": expected_rows,
        "items": 5,
        "units": 2,
        "attempted": 8,
        "failed": 3,
        "episodes": 2,
    }
    assert counts["attempted"] - counts["failed"] == counts["items"]


def test_write_shard_refuses_inconsistent_item_counters(tmp_path):
    rows, targets = _unit_rows()
    with pytest.raises(
        ValueError, match=r"shard 0 of \S+: counters_by_item\['attempted'\] is \[1, 2\], expected 3"
    ):
        writer_module.write_shard(tmp_path, "e", 0, rows, targets, {"attempted": 3}, {"attempted": [1, 2]})
    with pytest.raises(ValueError, match=r"up to counters\['attempted'\] = 2"):
        writer_module.write_shard(tmp_path, "e", 0, rows, targets, {"attempted": 2}, {"attempted": [1, 2, 3]})
    assert not (tmp_path / "shards").exists()


def test_second_collection_into_a_locked_folder_is_refused(tmp_path):
    from navformer_rl.data.collect import collect, settings_for

    settings = settings_for("e", "small", n_trajectories=1)
    # another live process (our parent) holds the folder, with a shard in progress
    holder = subprocess.Popen(
        [sys.executable, "-c", _HOLD_LOCK, str(tmp_path / "d")], stdout=subprocess.PIPE, text=True
    )
    try:
        assert holder.stdout.readline().strip() == "locked"
        partial = tmp_path / "d" / "shards" / ".tmp-unit-000000-1"
        partial.mkdir(parents=True)
        with pytest.raises(durable.FolderLockedError, match=rf"pid {holder.pid}, lock .*\.collect\.lock"):
            collect("e", tmp_path / "d", settings, workers=1, progress=False)
        assert partial.is_dir()  # the live collection's shard in progress was left alone
    finally:
        holder.kill()
        holder.wait()
    # its holder died without removing the lock file: the next collection takes it over with a warning
    assert (tmp_path / "d" / writer_module.LOCK_FILE).read_text().strip() == str(holder.pid)
    with pytest.warns(UserWarning, match=rf"taking over the lock left by process {holder.pid}"):
        with writer_module.folder_lock(tmp_path / "d") as lock:
            assert lock.read_text().strip() == str(os.getpid())
    assert not (tmp_path / "d" / writer_module.LOCK_FILE).exists()


_HOLD_LOCK = """
import sys, time
from navformer_rl.data.writer import folder_lock
with folder_lock(sys.argv[1]):
    print("locked", flush=True)
    time.sleep(60)
"""


def test_buffer_dumps_a_reference_and_loads_only_over_the_same_dataset(tmp_path):
    import hashlib

    from navformer_rl.data.synthetic import make_synthetic_dataset

    for name, seed in (("e", 1), ("other", 2)):
        make_synthetic_dataset(tmp_path / name, "e", 12, min_len=8, max_len=40, seed=seed)
    pixels_file = next((tmp_path / "e" / "consolidated").rglob("pixels.memmap"))
    before = hashlib.sha256(pixels_file.read_bytes()).hexdigest()
    buffer = open_dataset(tmp_path / "e").trajectory_buffer(4, seed=0)
    buffer.sample()
    buffer.dumps(tmp_path / "dump")
    # the dump holds the sampler state and a reference, not a copy of the rows
    assert not list((tmp_path / "dump").rglob("*.memmap"))
    following = buffer.sample()
    restored = open_dataset(tmp_path / "e").trajectory_buffer(4, seed=9)
    restored.loads(tmp_path / "dump")
    assert torch.equal(restored.sample()["pixels"], following["pixels"])
    assert hashlib.sha256(pixels_file.read_bytes()).hexdigest() == before  # the dataset is untouched
    with pytest.raises(ValueError, match="was dumped over the dataset .* differs from this buffer's"):
        open_dataset(tmp_path / "other").trajectory_buffer(4).loads(tmp_path / "dump")


def test_head_is_the_prefix_of_the_first_n_items(e_dataset, ssl_dataset):
    full = open_dataset(e_dataset)
    head = full.head(5)
    assert head.num_trajectories == 5
    assert len(head) == int(full.episodes.start[5])
    assert torch.equal(head.episodes.length, full.episodes.length[:5])
    assert torch.equal(head.rows["pixels"][-1], full.rows["pixels"][len(head) - 1])
    assert head.metadata["subset"] == {"first": 5, "of": 12}
    assert full.head(12) is full
    draw = head.trajectory_batcher(5, context_steps=40, seed=0).sampler.draw()
    assert sorted(draw.trajectory.tolist()) == [0, 1, 2, 3, 4]  # one epoch: every trajectory of the head once
    assert int(draw.index.max()) < len(head)
    pairs = open_dataset(ssl_dataset).head(7)
    assert len(pairs) == 7 and pairs.metadata["subset"] == {"first": 7, "of": 40}
    for bad in (0, 13, 2.5, True):
        with pytest.raises(ValueError, match=r"expected 1 <= n <= 12"):
            full.head(bad)


def test_buffer_dumped_over_a_head_loads_only_over_the_same_head(e_dataset, tmp_path):
    full = open_dataset(e_dataset)
    buffer = full.head(6).trajectory_buffer(2, context_steps=8, seed=0)
    buffer.sample()
    buffer.dumps(tmp_path / "dump")
    full.head(6).trajectory_buffer(2, context_steps=8, seed=0).loads(tmp_path / "dump")
    with pytest.raises(ValueError, match="differs from this buffer"):
        full.head(7).trajectory_buffer(2, context_steps=8, seed=0).loads(tmp_path / "dump")
