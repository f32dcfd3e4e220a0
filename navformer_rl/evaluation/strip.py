"""A frame strip from an evaluation video: evenly spaced frames side by side in one PNG, each labelled with
its time, for a README, a paper figure or an issue (``navformer evaluate strip``)."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from navformer_rl.constants import CONTROL_DT
from navformer_rl.utils.mp4 import read_mp4_frames

GAP = 6
"""White pixels between two frames."""


def strip_frame_indices(n_frames: int, frames: int) -> list[int]:
    """``frames`` evenly spaced indices of ``n_frames`` frames, the first and the last included (every frame
    when there are fewer)."""
    if n_frames < 1:
        raise ValueError("the video has no frames")
    if frames >= n_frames:
        return list(range(n_frames))
    if frames == 1:
        return [n_frames - 1]
    return [round(i * (n_frames - 1) / (frames - 1)) for i in range(frames)]


def frame_label(index: int, step_seconds: float = CONTROL_DT) -> str:
    """The label of frame ``index`` of a video written one frame per control step (``navformer evaluate``'s
    and ``navformer world-demo``'s): its step and the trial's time at that step, ``step 167, t = 33.4 s``.
    The time is ``index * step_seconds`` (0.2 s per step, ``CONTROL_DT``), not the video's playback time."""
    return f"step {index}, t = {index * step_seconds:.1f} s"


def frame_strip(video: str | os.PathLike, out: str | os.PathLike, frames: int = 5, width: int = 1600) -> Path:
    """Write ``frames`` evenly spaced frames of the mp4 ``video`` side by side to the PNG ``out``, scaled to
    ``width`` pixels in all, each labelled in a corner with its step and its time in the trial
    (:func:`frame_label`: frame i is step i, at 0.2 s per step); returns ``out``.

    Raises:
        ValueError: ``frames`` < 1, ``width`` too small for the frames, or ``out`` not a ``.png`` path.
        FileNotFoundError: ``video`` is missing.
    """
    import cv2

    from navformer_rl.utils.durable import atomic_path

    if isinstance(frames, bool) or not isinstance(frames, int) or frames < 1:
        raise ValueError(f"frames={frames!r}: expected a positive integer")
    if isinstance(width, bool) or not isinstance(width, int) or width < 16 * frames:
        raise ValueError(f"width={width!r}: expected an integer >= {16 * frames} (16 pixels per frame)")
    out = Path(out)
    if out.suffix.lower() != ".png":
        raise ValueError(f"out={str(out)!r}: expected a .png path")
    _, all_frames = read_mp4_frames(video)
    chosen = strip_frame_indices(len(all_frames), frames)
    height, frame_width = all_frames[0].shape[:2]
    tile_width = (width - GAP * (len(chosen) - 1)) // len(chosen)
    tile_height = max(1, round(height * tile_width / frame_width))
    tiles = []
    for index in chosen:
        tile = cv2.resize(all_frames[index], (tile_width, tile_height), interpolation=cv2.INTER_AREA)
        label = frame_label(index)
        scale = max(0.4, tile_width / 600)
        origin = (8, tile_height - 10)
        cv2.putText(tile, label, origin, cv2.FONT_HERSHEY_SIMPLEX, scale, (255, 255, 255), 3, cv2.LINE_AA)
        cv2.putText(tile, label, origin, cv2.FONT_HERSHEY_SIMPLEX, scale, (0, 0, 0), 1, cv2.LINE_AA)
        tiles.append(tile)
    gap = np.full((tile_height, GAP, 3), 255, np.uint8)
    row = [tiles[0]]
    for tile in tiles[1:]:
        row += [gap, tile]
    image = np.concatenate(row, axis=1)
    out.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(out) as tmp:  # the temporary path keeps the .png suffix OpenCV's writer needs
        if not cv2.imwrite(str(tmp), cv2.cvtColor(image, cv2.COLOR_RGB2BGR)):
            raise OSError(f"could not write {out}")
    return out
