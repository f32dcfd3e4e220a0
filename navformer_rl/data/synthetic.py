"""Small synthetic datasets in the real on-disk format, with learnable structure (for tests and smoke runs).

They go through the same writer as collection (shards, consolidation, metadata), so ``open_dataset`` reads
them like real data. The structure lets a model overfit them:

* trajectory kinds: the frame ``o_t`` is grey with a white vertical stripe at column ``x_t``; the target image
  is a coloured disc of palette colour ``c``. The action is ``a_t = (2 x_t / 76 - 1, 2 c / 4 - 1)``: the
  linear part is a function of the frame, the angular part of the target image only. The last step has
  reward 1.
* ``ssl``: ``pixels_static`` are horizontal colour bands fixed per world; ``pixels_dynamic`` is the same image
  with 1-3 dark squares ("robots") drawn on top.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch
from tensordict import TensorDict

from navformer_rl.data.schema import IMAGE_SHAPE, TASK_ID, DatasetKind, ssl_rows, trajectory_rows
from navformer_rl.data.writer import DatasetWriter

PALETTE = np.array([[40, 200, 60], [220, 40, 40], [240, 240, 240], [240, 220, 40], [40, 80, 230]], np.uint8)
"""green, red, white, yellow, blue (``constants.TARGET_COLORS``)."""

STRIPE_WIDTH = 8
MAX_STRIPE_X = IMAGE_SHAPE[1] - STRIPE_WIDTH  # 76


def synthetic_target_image(color_index: int) -> np.ndarray:
    """uint8 ``[84, 84, 3]``: a disc of ``PALETTE[color_index]`` on mid grey."""
    img = np.full(IMAGE_SHAPE, 128, np.uint8)
    yy, xx = np.mgrid[: IMAGE_SHAPE[0], : IMAGE_SHAPE[1]]
    img[(yy - 42) ** 2 + (xx - 42) ** 2 <= 24**2] = PALETTE[color_index]
    return img


def synthetic_frames(stripe_x: np.ndarray) -> np.ndarray:
    """uint8 ``[T, 84, 84, 3]``: dark grey frames with a white stripe starting at column ``stripe_x[t]``."""
    frames = np.full((len(stripe_x), *IMAGE_SHAPE), 60, np.uint8)
    for t, x in enumerate(stripe_x):
        frames[t, :, x : x + STRIPE_WIDTH] = 255
    return frames


def synthetic_action(stripe_x: np.ndarray, color_index: int) -> np.ndarray:
    """float32 ``[T, 2]``: the known answer a model must learn (see module docstring)."""
    linear = 2.0 * stripe_x / MAX_STRIPE_X - 1.0
    angular = np.full_like(linear, 2.0 * color_index / (len(PALETTE) - 1) - 1.0)
    return np.stack([linear, angular], -1).astype(np.float32)


def _unit_rng(seed: int, unit: int) -> np.random.Generator:
    return np.random.default_rng(np.random.SeedSequence(entropy=seed, spawn_key=(unit,)))


def _trajectory_unit(kind: DatasetKind, rng: np.random.Generator, n: int, min_len: int, max_len: int):
    rows, targets = [], []
    for local in range(n):
        T = int(rng.integers(min_len, max_len + 1))
        color = int(rng.integers(len(PALETTE)))
        stripe_x = rng.integers(0, MAX_STRIPE_X + 1, size=T)
        reward = np.zeros(T, np.float32)
        reward[-1] = 1.0
        pose = np.cumsum(rng.normal(0, 0.1, size=(T, 3)), 0).astype(np.float32) + 5.0
        rows.append(
            trajectory_rows(
                pixels=synthetic_frames(stripe_x),
                action=synthetic_action(stripe_x, color),
                reward=reward,
                collision=rng.random(T) < 0.05,
                pose=pose,
                target_position=rng.uniform(0, 10, size=2),
                succeeded=True,
                task=TASK_ID[kind],
                episode=local,
                target_id=local,
            )
        )
        targets.append(synthetic_target_image(color))
    return torch.cat(rows), torch.from_numpy(np.stack(targets))


def _ssl_unit(rng: np.random.Generator, world: int, n: int):
    bands = rng.integers(0, 256, size=(4, 3)).astype(np.uint8)
    static = np.repeat(bands, IMAGE_SHAPE[0] // 4, axis=0)[:, None, :].repeat(IMAGE_SHAPE[1], axis=1)
    statics = np.repeat(static[None], n, axis=0)
    dynamics = statics.copy()
    for p in range(n):
        for _ in range(int(rng.integers(1, 4))):
            r, c = rng.integers(0, IMAGE_SHAPE[0] - 12, size=2)
            dynamics[p, r : r + 12, c : c + 12] = 20
    pose = rng.uniform(0, 10, size=(n, 3)).astype(np.float32)
    return ssl_rows(pixels_static=statics, pixels_dynamic=dynamics, world=world, pose=pose)


def make_synthetic_dataset(
    root: str | Path,
    kind: DatasetKind | str,
    n_trajectories: int,
    min_len: int = 5,
    max_len: int = 30,
    seed: int = 0,
    items_per_shard: int = 4,
) -> Path:
    """Write a finished synthetic dataset folder at ``root`` and return its path.

    ``n_trajectories`` is the number of trajectories (``e``/``ca``) or of image pairs (``ssl``); trajectory
    lengths are uniform in ``[min_len, max_len]``. Deterministic in ``seed``.
    """
    kind = DatasetKind.parse(kind)
    if n_trajectories < 1:
        raise ValueError(f"n_trajectories must be >= 1, got {n_trajectories}")
    if not 1 <= min_len <= max_len:
        raise ValueError(f"expected 1 <= min_len <= max_len, got min_len={min_len}, max_len={max_len}")
    settings = {
        "generator": "synthetic",
        "n": n_trajectories,
        "min_len": min_len,
        "max_len": max_len,
        "seed": seed,
        "items_per_shard": items_per_shard,
    }
    writer = DatasetWriter(root, kind, settings, target_count=n_trajectories)
    unit = 0
    while writer.needs_more():
        if not writer.has_shard(unit):
            writer.write_shard(unit, *synthetic_unit(kind, unit, items_per_shard, min_len, max_len, seed))
        unit += 1
    return writer.finalize(extra_metadata={"seeds": {"base": seed}})


def synthetic_unit(
    kind: DatasetKind | str, unit: int, items_per_shard: int, min_len: int, max_len: int, seed: int
) -> tuple[TensorDict, torch.Tensor | None, dict[str, int], dict[str, list[int]]]:
    """Shard ``unit`` of :func:`make_synthetic_dataset` with the same arguments, as the arguments of
    ``DatasetWriter.write_shard`` after the unit: ``(rows, targets, counts, per-item counts)``. Shards depend
    on ``(seed, unit)`` only, so processes can write them in parallel (``writer.write_shard(root, kind, unit,
    ...)``) before one :func:`make_synthetic_dataset` call consolidates them."""
    kind = DatasetKind.parse(kind)
    rng = _unit_rng(seed, unit)
    if kind.is_trajectory:
        rows, targets = _trajectory_unit(kind, rng, items_per_shard, min_len, max_len)
    else:
        rows, targets = _ssl_unit(rng, unit, items_per_shard), None
    attempted = list(range(1, items_per_shard + 1))  # every synthetic item succeeds
    return rows, targets, {"attempted": items_per_shard}, {"attempted": attempted}
