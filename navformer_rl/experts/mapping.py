"""Log-odds occupancy grid built from a robot's own range scans (simulated 2-D lidar).

Sensor: :meth:`navformer_rl.envs.sim.Simulator.ray_scan` casts ``n_rays`` horizontal rays over 360 degrees at
the robot's lidar height; each returns the hit distance, or ``max_range`` when nothing is hit. See
``docs/experts.md`` for the chosen ray count and range. The grid is indexed ``[row, col]`` with row = y,
col = x; cell ``(r, c)`` covers ``[ox + c*res, ox + (c+1)*res) x [oy + r*res, oy + (r+1)*res)``.
"""

from __future__ import annotations

import math

import cv2
import numpy as np

UNKNOWN, FREE, OCCUPIED = -1, 0, 1
"""Ternary cell classes returned by :meth:`LogOddsGrid.ternary`."""


def disk_structure(radius_cells: float) -> np.ndarray:
    """bool ``[2k+1, 2k+1]`` disk of cells whose centres lie within ``radius_cells`` of the centre."""
    k = int(math.ceil(radius_cells))
    yy, xx = np.mgrid[-k : k + 1, -k : k + 1]
    return (xx * xx + yy * yy) <= radius_cells * radius_cells + 1e-9


def inflate(occupied: np.ndarray, radius: float, resolution: float) -> np.ndarray:
    """Cells whose centre is within ``radius`` metres of an occupied cell's centre (bool ``[H, W]``).

    The robot (a disk of ``radius``) centred in any cell outside the result cannot overlap an occupied cell's
    centre; callers add half a cell to ``radius`` to cover whole cells.
    """
    if radius <= 0:
        return occupied.copy()
    kernel = disk_structure(radius / resolution).astype(np.uint8)
    return cv2.dilate(occupied.astype(np.uint8), kernel, borderType=cv2.BORDER_CONSTANT, borderValue=0) > 0


def trace_rays(
    shape: tuple[int, int],
    origin: np.ndarray,
    resolution: float,
    pose: np.ndarray,
    ranges: np.ndarray,
    angles: np.ndarray,
    max_range: float,
) -> tuple[np.ndarray, np.ndarray]:
    """Cells crossed by rays and cells just behind their hits, as flat bool masks ``[H * W]``.

    Each ray from ``pose[:2]`` along ``pose[2] + angles[k]`` is sampled every 0.75 cell up to
    ``ranges[k] - 0.75`` cell (crossed cells); a ray with ``ranges[k] < max_range`` also marks the cell
    0.3 cell behind its hit point (the obstacle's surface cell). Cells outside the grid are dropped.
    """
    x, y, yaw = (float(v) for v in pose)
    h, w = shape
    cos, sin = np.cos(yaw + angles), np.sin(yaw + angles)
    cx, cy = (x - origin[0]) / resolution, (y - origin[1]) / resolution  # robot in cell units
    t = np.arange(0.0, max_range, 0.75 * resolution)  # [S] metres
    ray, sample = np.nonzero(t[None, :] < ranges[:, None] - 0.75 * resolution)
    ts = t[sample] / resolution
    cols = np.floor(cx + cos[ray] * ts).astype(np.int64)
    rows = np.floor(cy + sin[ray] * ts).astype(np.int64)
    ok = (rows >= 0) & (rows < h) & (cols >= 0) & (cols < w)
    crossed = np.zeros(h * w, dtype=bool)
    crossed[rows[ok] * w + cols[ok]] = True
    hit = ranges < max_range - 1e-3
    reach = (ranges[hit] + 0.3 * resolution) / resolution
    cols = np.floor(cx + cos[hit] * reach).astype(np.int64)
    rows = np.floor(cy + sin[hit] * reach).astype(np.int64)
    ok = (rows >= 0) & (rows < h) & (cols >= 0) & (cols < w)
    behind = np.zeros(h * w, dtype=bool)
    behind[rows[ok] * w + cols[ok]] = True
    return crossed, behind


class LogOddsGrid:
    """Occupancy grid with log-odds cells (prior 0 = p 0.5), clamped to ``[l_min, l_max]``.

    Args:
        extent: world ``(width, height)`` in metres covered from ``origin``.
        resolution: cell size in metres.
        origin: world ``(x, y)`` of the lower-left corner of cell ``(0, 0)``.
        l_free, l_occ: log-odds added to cells a ray passes through / ends in.
        occupied_above, free_below: log-odds thresholds of the ternary classes.
    """

    def __init__(
        self,
        extent: tuple[float, float],
        resolution: float = 0.1,
        origin: tuple[float, float] = (0.0, 0.0),
        l_free: float = -0.85,
        l_occ: float = 1.2,
        l_min: float = -2.5,
        l_max: float = 3.5,
        occupied_above: float = 0.6,
        free_below: float = -0.6,
    ) -> None:
        if resolution <= 0 or min(extent) <= 0:
            raise ValueError(f"need resolution > 0 and a positive extent, got {resolution}, {extent}")
        self.resolution = float(resolution)
        self.origin = np.asarray(origin, dtype=np.float64)
        self.shape = (int(math.ceil(extent[1] / resolution)), int(math.ceil(extent[0] / resolution)))
        self.logodds = np.zeros(self.shape, dtype=np.float32)
        self.l_free, self.l_occ, self.l_min, self.l_max = l_free, l_occ, l_min, l_max
        self.occupied_above, self.free_below = occupied_above, free_below

    def world_to_cell(self, xy: np.ndarray) -> np.ndarray:
        """int64 ``[..., 2]`` ``(row, col)`` of world points ``[..., 2]`` (not clipped to the grid)."""
        rel = (np.asarray(xy, dtype=np.float64) - self.origin) / self.resolution
        return np.floor(rel[..., ::-1]).astype(np.int64)

    def cell_to_world(self, cells: np.ndarray) -> np.ndarray:
        """float64 ``[..., 2]`` world ``(x, y)`` of the centres of cells ``[..., 2]`` = ``(row, col)``."""
        cells = np.asarray(cells, dtype=np.float64)
        return self.origin + (cells[..., ::-1] + 0.5) * self.resolution

    def update(self, pose: np.ndarray, ranges: np.ndarray, angles: np.ndarray, max_range: float) -> None:
        """Integrate one scan taken at ``pose = (x, y, yaw)``.

        ``ranges``/``angles``: float ``[N]``, angles relative to the heading. Cells sampled along each ray
        (every ``0.75`` cell) before the hit become more free; the cell just behind a hit
        (``range < max_range``) becomes more occupied. Each cell is updated at most once per scan; occupied
        wins over free.
        """
        ranges = np.asarray(ranges, dtype=np.float64)
        angles = np.asarray(angles, dtype=np.float64)
        if ranges.shape != angles.shape or ranges.ndim != 1:
            raise ValueError(f"ranges {ranges.shape} and angles {angles.shape} must be equal 1-D shapes")
        free_flat, occ_flat = trace_rays(
            self.shape, self.origin, self.resolution, pose, ranges, angles, max_range
        )
        free_flat &= ~occ_flat
        flat = self.logodds.reshape(-1)
        flat[free_flat] += self.l_free
        flat[occ_flat] += self.l_occ
        np.clip(self.logodds, self.l_min, self.l_max, out=self.logodds)

    def mark_viewed(
        self, viewed: np.ndarray, pose: np.ndarray, ranges: np.ndarray, angles: np.ndarray, max_range: float
    ) -> None:
        """Set ``viewed`` (bool ``[H, W]``, in place) on the cells seen by rays clipped to ``max_range``
        (e.g. the camera's part of a scan): crossed cells and hit surface cells."""
        clipped = np.minimum(np.asarray(ranges, dtype=np.float64), max_range)
        crossed, behind = trace_rays(
            self.shape, self.origin, self.resolution, pose, clipped, angles, max_range
        )
        flat = viewed.reshape(-1)
        flat |= crossed | behind

    def ternary(self) -> np.ndarray:
        """int8 ``[H, W]``: ``UNKNOWN`` (-1), ``FREE`` (0) or ``OCCUPIED`` (1)."""
        out = np.full(self.shape, UNKNOWN, dtype=np.int8)
        out[self.logodds < self.free_below] = FREE
        out[self.logodds > self.occupied_above] = OCCUPIED
        return out

    def occupied(self) -> np.ndarray:
        """bool ``[H, W]`` of occupied cells."""
        return self.logodds > self.occupied_above

    def free(self) -> np.ndarray:
        """bool ``[H, W]`` of free cells."""
        return self.logodds < self.free_below

    def traversable(self, robot_radius: float) -> np.ndarray:
        """bool ``[H, W]``: free cells farther than ``robot_radius``
        (+ half a cell) from any occupied cell."""
        blocked = inflate(self.occupied(), robot_radius + 0.5 * self.resolution, self.resolution)
        return self.free() & ~blocked
