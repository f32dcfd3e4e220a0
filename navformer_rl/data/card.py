"""Pictures for the dataset card: sample frames with their target images, and D_ssl pairs.

``sample_sheet(dataset, n=3, frames=6) -> uint8 [H, W, 3]`` and ``save_png(image, path)`` (OpenCV).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from navformer_rl.data.dataset import NavDataset

_GAP = 4


def _row(images: list[np.ndarray]) -> np.ndarray:
    gap = np.full((images[0].shape[0], _GAP, 3), 255, np.uint8)
    parts = []
    for k, img in enumerate(images):
        parts.extend([img] if k == 0 else [gap, img])
    return np.concatenate(parts, axis=1)


def _stack(rows: list[np.ndarray]) -> np.ndarray:
    width = max(r.shape[1] for r in rows)
    padded = [np.pad(r, ((0, _GAP), (0, width - r.shape[1]), (0, 0)), constant_values=255) for r in rows]
    return np.concatenate(padded, axis=0)[:-_GAP]


def sample_sheet(dataset: NavDataset, n: int = 3, frames: int = 6) -> np.ndarray:
    """uint8 ``[H, W, 3]`` RGB sheet of ``n`` samples.

    Trajectory datasets: per row the target image, then ``frames`` frames evenly spaced over the trajectory
    (first to last). D_ssl: per row ``frames // 2`` pairs (o^s, o^d) side by side.
    """
    if n < 1 or frames < 2:
        raise ValueError(f"need n >= 1 and frames >= 2, got n={n}, frames={frames}")
    rows = []
    if dataset.episodes is not None:
        picks = np.linspace(0, len(dataset.episodes) - 1, min(n, len(dataset.episodes))).astype(int)
        for traj in picks:
            start, length = int(dataset.episodes.start[traj]), int(dataset.episodes.length[traj])
            steps = np.linspace(0, length - 1, frames).astype(int)
            target = dataset.targets[int(dataset.episodes.target_id[traj])].numpy()
            rows.append(_row([target] + [dataset.rows["pixels"][start + s].numpy() for s in steps]))
    else:
        moved = (dataset.rows["pixels_static"] != dataset.rows["pixels_dynamic"]).flatten(1).any(1).numpy()
        order = np.concatenate([np.flatnonzero(moved), np.flatnonzero(~moved)])  # pairs showing robots first
        per_row = max(1, frames // 2)
        for r in range(n):
            picks = order[r * per_row : (r + 1) * per_row]
            if len(picks) == 0:
                break
            images = []
            for i in picks:
                images += [
                    dataset.rows["pixels_static"][int(i)].numpy(),
                    dataset.rows["pixels_dynamic"][int(i)].numpy(),
                ]
            rows.append(_row(images))
    return _stack(rows)


def save_png(image: np.ndarray, path: str | Path) -> Path:
    """Write an RGB uint8 image as PNG (atomic: temp file + rename)."""
    import os

    import cv2

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".tmp-{path.name}")
    if not cv2.imwrite(str(tmp) + ".png", np.ascontiguousarray(image[:, :, ::-1])):
        raise ValueError(f"could not write {path}")
    os.replace(str(tmp) + ".png", path)
    return path
