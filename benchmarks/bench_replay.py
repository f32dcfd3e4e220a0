"""Replay sampling throughput (frames/s): our TrajectoryBatcher vs the numpy memmap floor vs torchrl
SliceSampler.

For each paper batch shape (25 x 98 frames from D_e, 150 x 63 from D_ca) a synthetic dataset with
trajectories of exactly that length is written in the real on-disk format, so the three samplers deliver
the same number of frames per batch:

* ``ours``: ``NavDataset.trajectory_batcher`` (index_select into preallocated buffers + target images);
* ``numpy floor``: ``np.memmap`` fancy indexing ``mm[idx]`` of every stored key for the same row indices;
* ``torchrl SliceSampler``: ``TensorDictReplayBuffer(TensorStorage(rows), SliceSampler(num_slices=N,
  traj_key="episode", strict_length=False))``, reshaped to ``[N, T]``.

Usage: ``OMP_NUM_THREADS=1 python benchmarks/bench_replay.py [--repeats 9] [--workdir /tmp/bench_replay]``.
Prints a markdown table (medians over interleaved repeats, frames/s, ratios).
"""

from __future__ import annotations

import argparse
import shutil
import statistics
import time
from pathlib import Path

import numpy as np
import torch

from navformer_rl.data import make_synthetic_dataset, open_dataset
from navformer_rl.data.schema import TRAJECTORY_FIELDS

SHAPES = {"25 x 98 (D_e)": (25, 98, 240), "150 x 63 (D_ca)": (150, 63, 330)}
"""label -> (trajectories per batch, steps per trajectory, trajectories in the dataset)."""


def _numpy_views(rows) -> dict:
    views = {}
    for key in TRAJECTORY_FIELDS:
        t = rows.get(key)
        views[key] = np.memmap(t.filename, dtype=t.numpy().dtype, mode="r", shape=tuple(t.shape))
    return views


def _median_rates(fns: dict, frames: int, repeats: int) -> dict[str, float]:
    """frames/s (median over ``repeats``) of each function; the functions take turns within every repeat so
    that load from other processes affects them alike."""
    for fn in fns.values():
        fn()  # warm-up (page cache, buffers)
    times: dict[str, list[float]] = {name: [] for name in fns}
    for _ in range(repeats):
        for name, fn in fns.items():
            t0 = time.perf_counter()
            fn()
            times[name].append(time.perf_counter() - t0)
    return {name: frames / statistics.median(ts) for name, ts in times.items()}


def bench_shape(root: Path, n_traj: int, length: int, dataset_traj: int, repeats: int) -> dict[str, float]:
    from torchrl.data import SliceSampler, TensorDictReplayBuffer, TensorStorage

    path = root / f"len{length}"
    if not (path / "metadata.json").exists():
        make_synthetic_dataset(path, "e", dataset_traj, length, length, seed=0, items_per_shard=32)
    ds = open_dataset(path)
    frames = n_traj * length
    batcher = ds.trajectory_batcher(n_traj, context_steps=255, seed=0)
    views = _numpy_views(ds.rows)
    targets = np.memmap(ds.targets.filename, dtype=np.uint8, mode="r", shape=tuple(ds.targets.shape))

    def numpy_floor():
        draw = batcher.sampler.draw()
        idx = draw.index.reshape(-1).numpy()
        out = {key: view[idx] for key, view in views.items()}
        out["target_pixels"] = targets[ds.episodes.target_id[draw.trajectory].numpy()]
        return out

    rb = TensorDictReplayBuffer(
        storage=TensorStorage(ds.rows),
        sampler=SliceSampler(num_slices=n_traj, traj_key="episode", strict_length=False),
        batch_size=frames,
    )

    def torchrl_slice():
        return rb.sample().reshape(n_traj, -1)

    return _median_rates(
        {"ours": batcher.sample, "numpy": numpy_floor, "torchrl": torchrl_slice}, frames, repeats
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=9)
    parser.add_argument("--workdir", type=Path, default=Path("/tmp/bench_replay"))
    parser.add_argument("--keep", action="store_true", help="keep the synthetic datasets")
    args = parser.parse_args()
    torch.set_num_threads(1)
    print(f"torch threads: {torch.get_num_threads()}, repeats: {args.repeats} (median)\n")
    print(
        "| batch | ours (frames/s) | numpy memmap floor | torchrl SliceSampler | "
        "ours / numpy | ours / torchrl |"
    )
    print("|---|---|---|---|---|---|")
    try:
        for label, (n, length, dataset_traj) in SHAPES.items():
            r = bench_shape(args.workdir, n, length, dataset_traj, args.repeats)
            print(
                f"| {label} | {r['ours']:,.0f} | {r['numpy']:,.0f} | {r['torchrl']:,.0f} | "
                f"{r['ours'] / r['numpy']:.2f} | {r['ours'] / r['torchrl']:.1f} |"
            )
    finally:
        if not args.keep:
            shutil.rmtree(args.workdir, ignore_errors=True)


if __name__ == "__main__":
    main()
