"""Top-down map of a world (OpenCV): walls (and a furnished world's furniture), targets, robots and their
trajectories.

World ``(x, y)`` maps to pixel ``(u, v) = (margin + x * px_per_m, margin + (size - y) * px_per_m)``,
so +y points up in the image. Robot ``i`` and its target share colour ``ROBOT_COLORS[i % 10]``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import cv2
import numpy as np

from navformer_rl.constants import SUCCESS_RADIUS
from navformer_rl.envs.robots import JACKAL, RobotSpec
from navformer_rl.envs.world import WorldSpec
from navformer_rl.utils.checks import check_int, check_number

ROBOT_COLORS = np.array(
    [
        (31, 119, 180),
        (255, 127, 14),
        (44, 160, 44),
        (214, 39, 40),
        (148, 103, 189),
        (140, 86, 75),
        (227, 119, 194),
        (127, 127, 127),
        (188, 189, 34),
        (23, 190, 207),
    ],
    dtype=np.uint8,
)
"""RGB colour per robot index (matplotlib's tab10)."""

_FLOOR = (245, 243, 238)
_GRID = (228, 225, 218)
_WALL = (60, 60, 66)


def draw_topdown(
    world: WorldSpec,
    trajectories: Sequence[np.ndarray] | None = None,
    poses: np.ndarray | None = None,
    robot_specs: Sequence[RobotSpec] | None = None,
    px_per_m: float = 48.0,
    margin_px: int = 12,
    show_success_radius: bool = True,
    labels: bool = True,
) -> np.ndarray:
    """Draw the world from above: uint8 ``[H, W, 3]`` RGB with ``H = W = size * px_per_m + 2 * margin_px``.

    Args:
        world: the world (walls, targets).
        trajectories: optional per-robot paths, each float ``[T, 2]`` (x, y), drawn as polylines.
        poses: optional float ``[R, 3]`` current poses, drawn as discs with a heading tick.
        robot_specs: radii for the robot discs (default: Jackal for every robot).
        px_per_m: scale; margin_px: border around the world.
        show_success_radius: draw each robot's target's 1.5 m success circle (dashed look, in its robot's
            colour); a target no robot seeks (``world.distractors``) has none.
        labels: write the robot index next to each robot and its target (``T0``, ...).

    ValueError for a non-positive or non-finite ``px_per_m``, a negative or non-integer ``margin_px``,
    trajectories or poses that are not ``(x, y)`` / ``(x, y, yaw)`` rows, or fewer ``robot_specs`` than poses.
    """
    px_per_m = check_number(px_per_m, "px_per_m", greater_than=0.0, unit="pixels per metre")
    margin_px = check_int(margin_px, "margin_px", minimum=0)
    paths = [_rows(path, 2, f"trajectories[{i}]", "(x, y)") for i, path in enumerate(trajectories or [])]
    if poses is not None:
        poses = _rows(poses, 3, "poses", "(x, y, yaw)")
        if robot_specs is not None and len(robot_specs) < len(poses):
            raise ValueError(
                f"robot_specs has {len(robot_specs)} entries for {len(poses)} poses; expected one per pose"
            )
    side = int(round(world.size * px_per_m)) + 2 * margin_px
    img = np.full((side, side, 3), _FLOOR, dtype=np.uint8)

    def to_px(xy) -> tuple[int, int]:
        return (
            int(round(margin_px + float(xy[0]) * px_per_m)),
            int(round(margin_px + (world.size - float(xy[1])) * px_per_m)),
        )

    for k in range(int(math.floor(world.size)) + 1):  # 1 m grid, like the floor tiles
        cv2.line(img, to_px((k, 0)), to_px((k, world.size)), _GRID, 1)
        cv2.line(img, to_px((0, k)), to_px((world.size, k)), _GRID, 1)
    style = world.style  # a furnished world: furniture in its own colours, outlined
    for k, (cx, cy, hx, hy) in enumerate(world.walls.astype(np.float64)):
        corners = to_px((cx - hx, cy + hy)), to_px((cx + hx, cy - hy))
        if style is None or style.roles[k] == "wall":
            cv2.rectangle(img, *corners, _WALL, -1)
        else:
            cv2.rectangle(img, *corners, tuple(int(round(255 * v)) for v in style.box_rgba[k, :3]), -1)
            cv2.rectangle(img, *corners, _WALL, 1)

    def robot_color(i: int) -> tuple[int, int, int]:
        return tuple(int(v) for v in ROBOT_COLORS[i % len(ROBOT_COLORS)])

    for i, target in enumerate(world.targets):
        centre = to_px(target.position)
        rgb = tuple(int(255 * v) for v in target.rgba[:3])
        half = max(2, int(round(target.half_extent * px_per_m)))
        sought = i < world.n_robots
        if show_success_radius and sought:
            _dashed_circle(img, centre, int(round(SUCCESS_RADIUS * px_per_m)), robot_color(i))
        if target.shape == "sphere":
            cv2.circle(img, centre, half, rgb, -1, cv2.LINE_AA)
            cv2.circle(img, centre, half, (0, 0, 0), 1, cv2.LINE_AA)
        else:
            cv2.rectangle(
                img, (centre[0] - half, centre[1] - half), (centre[0] + half, centre[1] + half), rgb, -1
            )
            cv2.rectangle(
                img, (centre[0] - half, centre[1] - half), (centre[0] + half, centre[1] + half), (0, 0, 0), 1
            )
        if labels and sought:
            cv2.putText(
                img,
                f"T{i}",
                (centre[0] + half + 2, centre[1] - half),
                cv2.FONT_HERSHEY_SIMPLEX,
                0.4,
                robot_color(i),
                1,
                cv2.LINE_AA,
            )

    for i, path in enumerate(paths):
        if len(path) >= 2:
            pts = np.array([to_px(p) for p in path], dtype=np.int32)
            cv2.polylines(img, [pts], False, robot_color(i), 2, cv2.LINE_AA)
        if len(path):
            cv2.circle(img, to_px(path[0]), 3, robot_color(i), -1, cv2.LINE_AA)

    if poses is not None:
        for i, (x, y, yaw) in enumerate(poses):
            radius = (robot_specs[i] if robot_specs is not None else JACKAL).radius
            r_px = max(3, int(round(radius * px_per_m)))
            centre = to_px((x, y))
            cv2.circle(img, centre, r_px, robot_color(i), -1, cv2.LINE_AA)
            cv2.circle(img, centre, r_px, (0, 0, 0), 1, cv2.LINE_AA)
            tip = to_px((x + radius * 1.4 * math.cos(yaw), y + radius * 1.4 * math.sin(yaw)))
            cv2.line(img, centre, tip, (0, 0, 0), 2, cv2.LINE_AA)
            if labels:
                cv2.putText(
                    img,
                    str(i),
                    (centre[0] - 4, centre[1] + 4),
                    cv2.FONT_HERSHEY_SIMPLEX,
                    0.4,
                    (255, 255, 255),
                    1,
                    cv2.LINE_AA,
                )
    return img


def _rows(values, width: int, name: str, what: str) -> np.ndarray:
    """``values`` as float64 ``[N, width]`` (from ``[N, width]``, a flat array of a multiple of ``width``
    numbers, or nothing); ValueError naming ``name`` otherwise."""
    try:
        array = np.asarray(values, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be float rows [N, {width}] {what}, got {values!r}") from None
    if array.size == 0:
        return array.reshape(0, width)
    if (array.ndim == 2 and array.shape[1] == width) or (array.ndim == 1 and array.size % width == 0):
        return array.reshape(-1, width)
    raise ValueError(f"{name} must be float rows [N, {width}] {what}, got shape {array.shape}")


def _dashed_circle(img: np.ndarray, centre: tuple[int, int], radius: int, color, segments: int = 24) -> None:
    """A circle drawn as ``segments`` arcs with gaps (in place)."""
    step = 360.0 / segments
    for k in range(segments):
        cv2.ellipse(
            img, centre, (radius, radius), 0.0, k * step, k * step + step * 0.55, color, 1, cv2.LINE_AA
        )
