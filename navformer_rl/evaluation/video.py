"""Episode visualisation: top-down trajectory maps (PNG) and video frames showing every robot's egocentric
camera beside the top-down map (written as H.264 mp4 by :class:`navformer_rl.utils.mp4.Mp4Writer`)."""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path

import cv2
import numpy as np

from navformer_rl.utils.durable import atomic_path

MAP_PX = 480
"""Side of the top-down map in video frames and map images, in pixels."""
CAMERA_PX = 168
"""Side of each upscaled 84 x 84 camera view in video frames (2x, nearest neighbour)."""
_INSET_PX = 48
_HEADER_PX = 34
_LABEL_PX = 18
_BACKGROUND = (255, 255, 255)
_TEXT = (20, 20, 20)


MAP_PNG_PX = 720
"""Side of the stand-alone top-down map images (PNG), in pixels."""


def topdown_scale(size: float, side: int = MAP_PX) -> float:
    """Pixels per metre so that a ``size`` m world fills ``side`` pixels (12 px margin each side)."""
    return (side - 24) / float(size)


def draw_map(
    world, trajectories: Sequence[np.ndarray], poses: np.ndarray, robot_specs, side: int = MAP_PX
) -> np.ndarray:
    """Top-down map uint8 ``[side, side, 3]`` RGB: walls, targets with their 1.5 m discs, each robot's
    trajectory (float ``[T, 2]``) and current pose (float ``[R, 3]``) in its own colour."""
    from navformer_rl.envs.topdown import draw_topdown

    image = draw_topdown(
        world, trajectories, poses, robot_specs, px_per_m=topdown_scale(world.size, side), margin_px=12
    )
    if image.shape[:2] != (side, side):
        image = cv2.resize(image, (side, side), interpolation=cv2.INTER_AREA)
    return image


def _put(image: np.ndarray, text: str, origin: tuple[int, int], scale: float = 0.5, color=_TEXT) -> None:
    cv2.putText(image, text, origin, cv2.FONT_HERSHEY_SIMPLEX, scale, color, 1, cv2.LINE_AA)


def save_map_png(image: np.ndarray, path: str | os.PathLike, title: str) -> Path:
    """Write a map (uint8 RGB ``[H, W, 3]``) with a title strip as PNG, atomically."""
    canvas = np.full((image.shape[0] + _HEADER_PX, image.shape[1], 3), _BACKGROUND, dtype=np.uint8)
    canvas[_HEADER_PX:] = image
    _put(canvas, title, (8, 22), 0.5)
    path = Path(path)
    with atomic_path(path) as tmp:
        if not cv2.imwrite(str(tmp), cv2.cvtColor(canvas, cv2.COLOR_RGB2BGR)):
            raise OSError(f"OpenCV could not write {path}")
    return path


def compose_frame(
    map_image: np.ndarray,
    cameras: np.ndarray,
    targets: np.ndarray,
    robot_colors: np.ndarray,
    status: Sequence[str],
    title: str,
) -> np.ndarray:
    """One video frame, uint8 RGB ``[H, W, 3]`` with even ``H``, ``W``: the top-down map on the left and
    the robots' 84 x 84 cameras (uint8 ``[R, 84, 84, 3]``) in a two-column grid on the right, each framed
    in its robot's colour (uint8 ``[>=R, 3]``), labelled with ``status[i]`` and showing its target image
    (uint8 ``[R, 84, 84, 3]``) as an inset in the top-right corner."""
    n = cameras.shape[0]
    columns = 1 if n == 1 else 2
    rows = (n + columns - 1) // columns
    cell_h = CAMERA_PX + _LABEL_PX + 6
    grid_w = columns * (CAMERA_PX + 8) + 8
    height = _HEADER_PX + max(MAP_PX, rows * cell_h + 8)
    width = MAP_PX + grid_w
    height += height % 2
    width += width % 2
    frame = np.full((height, width, 3), _BACKGROUND, dtype=np.uint8)
    frame[_HEADER_PX : _HEADER_PX + MAP_PX, :MAP_PX] = map_image
    _put(frame, title, (8, 22), 0.5)
    legend_y = _HEADER_PX + rows * cell_h + 24
    if legend_y + 30 <= height:
        _put(frame, "camera views (84x84, 2x); inset: the target image g", (MAP_PX + 8, legend_y), 0.4)
        _put(frame, "map: dashed circle = 1.5 m success radius", (MAP_PX + 8, legend_y + 18), 0.4)
    for i in range(n):
        r, c = divmod(i, columns)
        x0 = MAP_PX + 8 + c * (CAMERA_PX + 8)
        y0 = _HEADER_PX + 4 + r * cell_h
        color = tuple(int(v) for v in robot_colors[i % len(robot_colors)])
        _put(frame, f"robot {i}: {status[i]}", (x0, y0 + 13), 0.42, color)
        view = cv2.resize(cameras[i], (CAMERA_PX, CAMERA_PX), interpolation=cv2.INTER_NEAREST)
        inset = cv2.resize(targets[i], (_INSET_PX, _INSET_PX), interpolation=cv2.INTER_AREA)
        view[2 : 2 + _INSET_PX, CAMERA_PX - 2 - _INSET_PX : CAMERA_PX - 2] = inset
        cv2.rectangle(
            view, (CAMERA_PX - 3 - _INSET_PX, 1), (CAMERA_PX - 2, 2 + _INSET_PX), (255, 255, 255), 1
        )
        y1 = y0 + _LABEL_PX
        frame[y1 : y1 + CAMERA_PX, x0 : x0 + CAMERA_PX] = view
        cv2.rectangle(frame, (x0 - 2, y1 - 2), (x0 + CAMERA_PX + 1, y1 + CAMERA_PX + 1), color, 2)
    return frame
