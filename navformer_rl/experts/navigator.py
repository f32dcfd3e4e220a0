"""Per-robot global navigation on a robot's own lidar map: frontier goals, A* paths, carrots, stuck handling.

A :class:`FrontierNavigator` owns one robot's :class:`LogOddsGrid`. Each step it integrates a scan, then
returns a *carrot* (a point about ``lookahead`` metres ahead on the current A* path) for a local planner
(DWA for the exploration expert, NH-ORCA for FCA). Goals: the nearest frontier (Yamauchi, by path length),
or the target once it is known (seen by the camera, or given to the privileged FCA).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from navformer_rl.experts.astar import astar
from navformer_rl.experts.frontier import select_frontier
from navformer_rl.experts.grid import distance_field, nearest_true_cell
from navformer_rl.experts.mapping import FREE, UNKNOWN, LogOddsGrid, inflate

LIDAR_SOURCES = ("analytic", "pybullet")


@dataclass(frozen=True)
class LidarConfig:
    """Simulated 360-degree planar lidar: 180 rays (2 degrees), 6 m range.

    ``source``: ``"analytic"`` (:class:`~navformer_rl.experts.lidar.StaticLidar`, closed-form rays on the
    world's static geometry, the default for speed) or ``"pybullet"`` (``Simulator.ray_scan_all``, which also
    sees robots; same distances on the static scene).
    """

    n_rays: int = 180
    max_range: float = 6.0
    source: str = "analytic"

    def __post_init__(self) -> None:
        if self.source not in LIDAR_SOURCES:
            raise ValueError(f"unknown lidar source {self.source!r}; expected one of {LIDAR_SOURCES}")
        if self.n_rays < 1 or not self.max_range > 0:
            raise ValueError(f"need n_rays >= 1 and max_range > 0, got {self.n_rays}, {self.max_range}")

    @property
    def angles(self) -> np.ndarray:
        """float64 ``[n_rays]`` ray angles relative to the heading (the simulator's convention)."""
        return np.linspace(-math.pi, math.pi, self.n_rays, endpoint=False)


@dataclass(frozen=True)
class NavigatorConfig:
    """Global-planning parameters (metres, steps of 0.2 s)."""

    resolution: float = 0.1
    robot_radius: float = 0.30
    inflation_margin: float = 0.05
    """Extra clearance added to the robot radius when inflating obstacles for A*."""
    min_frontier_cells: int = 5
    """Frontier groups smaller than this (0.5 m at 0.1 m cells) are ignored."""
    replan_every: int = 8
    lookahead: float = 2.0
    """Pursuit point: the farthest path point within this distance in straight line of sight."""
    goal_reached: float = 0.4
    min_goal_distance: float = 1.0
    """Frontier goals are chosen at least this far (by path) from the robot when any such goal exists."""
    """A frontier goal closer than this is considered visited (the frontier is replanned)."""
    progress_window: int = 30
    progress_min: float = 0.3
    """No ``progress_min`` metres of progress toward the goal within ``progress_window`` steps -> stuck."""
    blacklist_radius: float = 0.8
    target_approach: float = 1.1
    """In target mode the A* goal is the free cell nearest to the target within this radius (if that cell is
    cut off, the reachable cell within it nearest to the robot by path); inside the 1.2 m stop radius."""
    fallback_inflation: tuple[float, ...] = ()
    """Target mode only: inflation radii in metres (decreasing, each below the full robot radius + margin +
    half a cell) to retry A* with when the full inflation leaves no path to the target - e.g. a parked
    robot's disc narrowing a gap that the local collision avoidance still lets the robot through. Empty (the
    default, the exploration expert's): no retry."""

    def __post_init__(self) -> None:
        full = self.robot_radius + self.inflation_margin + 0.5 * self.resolution
        radii = (full, *self.fallback_inflation)
        if any(not (0 <= b < a) for a, b in zip(radii, radii[1:])):
            raise ValueError(
                f"fallback_inflation={self.fallback_inflation!r}: expected decreasing radii >= 0 m, each "
                f"below the full inflation {full:.3f} m (robot_radius + inflation_margin + resolution / 2)"
            )


class FrontierNavigator:
    """Map, goal and path of one robot.

    Args:
        extent: world size in metres (square ``[0, extent]^2``).
        config: :class:`NavigatorConfig`.
        target: float ``[2]`` target centre (used only once :meth:`set_target_known` was called, or from the
            start when ``target_known`` is True - the privileged FCA).
        frontier_bias: weight of the straight-line frontier-to-target distance in frontier ranking (FCA only).
        camera: ``(fov, range)`` of the camera looking for the target. When given, frontiers bound the area
            the *camera* has viewed (free cells the lidar mapped but the camera never looked at count as
            unexplored): exploring lidar frontiers alone ends with unseen corners, as the camera sees 90
            degrees and the lidar 360.
    """

    def __init__(
        self,
        extent: float,
        config: NavigatorConfig,
        target: np.ndarray,
        target_known: bool = False,
        frontier_bias: float = 0.0,
        camera: tuple[float, float] | None = None,
    ) -> None:
        self.config = config
        self.map = LogOddsGrid((extent, extent), resolution=config.resolution)
        self.target = np.asarray(target, dtype=np.float64)
        self.target_known = target_known
        self.target_mode = False
        self.frontier_bias = frontier_bias
        self.camera = camera
        self.viewed = np.zeros(self.map.shape, dtype=bool)
        self.discs = np.zeros((0, 3))
        self.planning_blocked = np.zeros(self.map.shape, dtype=bool)
        self.goal: np.ndarray | None = None
        self.goal_cell: tuple[int, int] | None = None
        self.path: np.ndarray = np.zeros((0, 2))
        self.blacklist: list[tuple[int, int]] = []
        self.exhausted = False
        self.stuck_events = 0
        self.no_path_plans = 0
        """Plans in target mode that found no path to the target at any inflation (the robot then explores,
        or waits when nothing is left to explore)."""
        self.steps_since_plan = 0
        self.best_remaining = math.inf
        self.last_progress_step = 0
        self.step_count = 0

    # ------------------------------------------------------------------ sensing
    def observe(
        self, pose: np.ndarray, ranges: np.ndarray, lidar: LidarConfig, keep: np.ndarray | None = None
    ) -> None:
        """Integrate one scan (float ``[n_rays]``) taken at ``pose``; ``keep``
        (bool ``[n_rays]``) drops rays."""
        angles = lidar.angles
        if keep is not None:
            ranges, angles = ranges[keep], angles[keep]
        self.map.update(pose, ranges, angles, lidar.max_range)
        if self.camera is not None:
            fov, view_range = self.camera
            in_view = np.abs(angles) <= fov / 2
            self.map.mark_viewed(self.viewed, pose, ranges[in_view], angles[in_view], view_range)

    def exploration_map(self) -> np.ndarray:
        """int8 ``[H, W]`` ternary map whose frontiers are explored: the lidar map, where free cells the
        camera never viewed are unknown (with a camera), else the lidar map itself."""
        t = self.map.ternary()
        if self.camera is not None:
            # Grown by 0.2 m: the thin strips along walls that rays only graze hide no target (targets
            # stand >= 0.9 m from walls) and would otherwise stay frontiers forever.
            viewed = cv2.dilate(self.viewed.astype(np.uint8), np.ones((5, 5), np.uint8)) > 0
            t[(t == FREE) & ~viewed] = UNKNOWN
        return t

    def set_target_seen(self) -> None:
        """The target became visible: drive to it from now on (forces a replan)."""
        if not self.target_mode:
            self.target_mode = True
            self.target_known = True
            self._reset_goal()

    # ------------------------------------------------------------------ planning
    def _reset_goal(self) -> None:
        self.goal, self.goal_cell, self.path = None, None, np.zeros((0, 2))
        self.best_remaining = math.inf
        self.last_progress_step = self.step_count

    def set_static_discs(self, discs: np.ndarray) -> None:
        """Obstacles known from outside the map, float ``[K, 3] = (x, y, r)`` (e.g. parked robots for the
        privileged FCA); they block planning like occupied cells. A change that cuts the path forces a
        re-plan."""
        discs = np.asarray(discs, dtype=np.float64).reshape(-1, 3)
        changed = discs.shape != self.discs.shape or not np.array_equal(discs, self.discs)
        self.discs = discs
        if changed and len(self.path) and len(discs):
            gap = (
                np.hypot(self.path[:, None, 0] - discs[None, :, 0], self.path[:, None, 1] - discs[None, :, 1])
                - discs[None, :, 2]
            )
            if gap.min() < self.config.robot_radius + self.config.inflation_margin:
                self.steps_since_plan = self.config.replan_every

    def _blocked(self, radius: float | None = None) -> np.ndarray:
        """bool map grid: cells within ``radius`` (default robot radius + margin + half a cell) of an occupied
        cell or a static disc."""
        c = self.config
        occupied = self.map.occupied()
        if len(self.discs):
            h, w = occupied.shape
            centres = self.map.cell_to_world(np.stack(np.mgrid[0:h, 0:w], axis=-1))
            for x, y, r in self.discs:
                occupied |= (centres[..., 0] - x) ** 2 + (centres[..., 1] - y) ** 2 <= r * r
        if radius is None:
            radius = c.robot_radius + c.inflation_margin + 0.5 * c.resolution
        return inflate(occupied, radius, c.resolution)

    def _start_cell(self, pose: np.ndarray, traversable: np.ndarray) -> tuple[int, int] | None:
        r, c = (int(v) for v in self.map.world_to_cell(pose[:2]))
        r = min(max(r, 0), self.map.shape[0] - 1)
        c = min(max(c, 0), self.map.shape[1] - 1)
        if traversable[r, c]:
            return r, c
        return nearest_true_cell(traversable, (r, c), max_radius=int(round(0.6 / self.config.resolution)))

    def _plan(self, pose: np.ndarray) -> None:
        """Choose the goal (target or frontier) and an A* path to it."""
        c = self.config
        blocked = self._blocked()
        self.planning_blocked = blocked
        self.steps_since_plan = 0
        if self.target_mode:
            # Optimistic about unknown cells: the target was seen, the way to it is mostly mapped.
            tcell = tuple(int(v) for v in self.map.world_to_cell(self.target))
            approach = int(round(c.target_approach / c.resolution))
            for radius in (None, *c.fallback_inflation):
                passable = ~(blocked if radius is None else self._blocked(radius))
                start = self._start_cell(pose, passable)
                goal = nearest_true_cell(passable, tcell, max_radius=approach)
                path = None if start is None or goal is None else astar(~passable, start, goal)
                # the cell nearest the target is cut off: try the others
                if path is None and start is not None:
                    goal = self._approach_goal(passable, start)
                    path = None if goal is None else astar(~passable, start, goal)
                if path is not None:
                    self.planning_blocked = ~passable  # the pursuit point keeps line of sight on this map
                    self._set_path(pose, path, goal)
                    return
            self.no_path_plans += 1
            # fall through: explore until the target can be reached
        traversable = self.map.free() & ~blocked
        start = self._start_cell(pose, traversable)
        if start is None:
            self._reset_goal()
            return
        if self.target_known and not self.target_mode:
            # Privileged (FCA): once the mapped free space reaches the known target, go there.
            goal = self._approach_goal(traversable, start)
            path = None if goal is None else astar(~traversable, start, goal)
            if path is not None:
                self.target_mode = True
                self._set_path(pose, path, goal)
                return
        bias_cell = None
        if self.target_known and self.frontier_bias > 0:
            bias_cell = tuple(int(v) for v in self.map.world_to_cell(self.target))
        explore = self.exploration_map()
        frontier = None
        for min_path in (c.min_goal_distance / c.resolution, 0.0):
            frontier = select_frontier(
                explore,
                traversable,
                start,
                min_cells=c.min_frontier_cells,
                blacklist=self.blacklist,
                blacklist_radius=c.blacklist_radius / c.resolution,
                bias_cell=bias_cell,
                bias_weight=self.frontier_bias,
                min_path=min_path,
            )
            if frontier is not None:
                break
        goal = None if frontier is None else frontier.goal
        if goal is None and self.camera is not None:
            goal = self._unviewed_goal(traversable, start)
        if goal is None:
            if self.target_known and not self.target_mode:
                self.target_mode = True  # nothing left to explore: head for the known target optimistically
            else:
                self.exhausted = not self.target_mode
            self._reset_goal()
            return
        path = astar(~traversable, start, goal)
        if path is None:  # cannot happen (the goal was chosen by path length); blacklist defensively
            self.blacklist.append(goal)
            self._reset_goal()
            return
        self._set_path(pose, path, goal)

    def _approach_goal(self, passable: np.ndarray, start: tuple[int, int]) -> tuple[int, int] | None:
        """The passable cell within ``target_approach`` of the target nearest to ``start`` by path,
        or None."""
        c = self.config
        grid = np.stack(np.mgrid[0 : passable.shape[0], 0 : passable.shape[1]], -1)
        near = ((self.map.cell_to_world(grid) - self.target) ** 2).sum(-1) <= c.target_approach**2
        candidates = near & passable
        if not candidates.any():
            return None
        dist = np.where(candidates, distance_field(passable, [start]), np.inf)
        k = int(np.argmin(dist))
        return divmod(k, dist.shape[1]) if np.isfinite(dist.flat[k]) else None

    def _explored_around(self, cell: tuple[int, int]) -> bool:
        """Whether ``cell`` and its 4-neighbours are all explored
        (the goal no longer borders unexplored space)."""
        r, c = cell
        h, w = self.map.shape
        r0, r1, c0, c1 = max(0, r - 1), min(h, r + 2), max(0, c - 1), min(w, c + 2)
        lo = self.map.logodds[r0:r1, c0:c1]
        known = (lo < self.map.free_below) | (lo > self.map.occupied_above)
        if self.camera is not None:
            known &= (lo > self.map.occupied_above) | self.viewed[r0:r1, c0:c1]
        cross = np.zeros_like(known)
        cross[r - r0, :] = True
        cross[:, c - c0] = True
        return bool(known[cross].all())

    def _unviewed_goal(self, traversable: np.ndarray, start: tuple[int, int]) -> tuple[int, int] | None:
        """No camera frontier is reachable: the nearest (by path) reachable free cell the camera has not
        viewed yet, outside blacklisted areas, else None."""
        dist = distance_field(traversable, [start])
        candidates = np.isfinite(dist) & ~self.viewed & traversable
        far = candidates & (dist >= self.config.min_goal_distance / self.config.resolution)
        candidates = far if far.any() else candidates
        for r, c in self.blacklist:
            rr, cc = np.ogrid[: dist.shape[0], : dist.shape[1]]
            candidates &= (rr - r) ** 2 + (cc - c) ** 2 > (
                self.config.blacklist_radius / self.config.resolution
            ) ** 2
        if not candidates.any():
            return None
        k = int(np.argmin(np.where(candidates, dist, np.inf)))
        return divmod(k, dist.shape[1])

    def _set_path(self, pose: np.ndarray, cells: list[tuple[int, int]], goal_cell: tuple[int, int]) -> None:
        new_goal = (
            self.goal_cell is None
            or np.hypot(*np.subtract(goal_cell, self.goal_cell)) * self.config.resolution > 0.5
        )
        self.goal_cell = goal_cell
        self.goal = self.map.cell_to_world(np.array(goal_cell))
        self.path = self.map.cell_to_world(np.array(cells))
        if new_goal:
            self.best_remaining = math.inf
            self.last_progress_step = self.step_count

    def _path_blocked(self, pose: np.ndarray, horizon: float = 3.0) -> bool:
        """Whether an occupied cell now lies within the robot radius of the next ``horizon`` metres of
        path."""
        if len(self.path) == 0:
            return False
        c = self.config
        k = int(np.argmin(np.hypot(*(self.path - pose[:2]).T)))
        pts = self.path[k : k + int(horizon / c.resolution) + 1]
        lo = self.map.world_to_cell(pts.min(axis=0) - c.robot_radius)
        hi = self.map.world_to_cell(pts.max(axis=0) + c.robot_radius)
        r0, c0 = max(0, lo[0]), max(0, lo[1])
        window = self.map.occupied()[r0 : hi[0] + 1, c0 : hi[1] + 1]
        occ = np.argwhere(window)
        if len(occ) == 0:
            return False
        centres = self.map.cell_to_world(occ + np.array([r0, c0]))
        d2 = ((pts[:, None, :] - centres[None, :, :]) ** 2).sum(-1)
        return bool(d2.min() < (c.robot_radius + 0.5 * c.resolution) ** 2)

    def _remaining(self, pose: np.ndarray) -> float:
        if len(self.path) == 0:
            return math.inf
        d = np.hypot(*(self.path - pose[:2]).T)
        k = int(np.argmin(d))
        seg = np.hypot(*np.diff(self.path[k:], axis=0).T).sum() if k + 1 < len(self.path) else 0.0
        return float(d[k] + seg)

    def carrot(self, pose: np.ndarray) -> np.ndarray | None:
        """The point to drive toward now (float64 ``[2]``), or None when there is nothing left to do."""
        c = self.config
        self.step_count += 1
        self.steps_since_plan += 1
        pose = np.asarray(pose, dtype=np.float64)
        need = self.goal is None or self.steps_since_plan >= c.replan_every or self._path_blocked(pose)
        if not need and not self.target_mode and np.hypot(*(self.goal - pose[:2])) < c.goal_reached:
            # Visited: whatever can be seen from here has been; never come back for this goal.
            self.blacklist.append(self.goal_cell)
            need = True
        if not need and not self.target_mode and self.goal_cell is not None and self.steps_since_plan >= 4:
            need = self._explored_around(self.goal_cell)
        if need:
            self._plan(pose)
        if self.goal is None:
            return None
        remaining = self._remaining(pose)
        if remaining < self.best_remaining - c.progress_min:
            self.best_remaining = remaining
            self.last_progress_step = self.step_count
        elif self.step_count - self.last_progress_step > c.progress_window:
            self.stuck_events += 1
            if not self.target_mode and self.goal_cell is not None:
                self.blacklist.append(self.goal_cell)
            self._plan(pose)
            self.best_remaining = math.inf
            self.last_progress_step = self.step_count
            if self.goal is None:
                return None
        return self._pursuit_point(pose)

    def _pursuit_point(self, pose: np.ndarray) -> np.ndarray:
        """The farthest path point within ``lookahead`` of the robot whose straight segment from the robot
        stays outside the inflated obstacles of the last plan (the nearest path point at worst)."""
        c = self.config
        d = np.hypot(*(self.path - pose[:2]).T)
        k = int(np.argmin(d))
        reach = np.flatnonzero(d[k:] <= c.lookahead)
        last = k + int(reach[-1]) if len(reach) else k
        candidates = self.path[k : last + 1]
        # Sample every candidate's segment at half-cell steps, skipping the first robot radius.
        t = np.arange(c.robot_radius, c.lookahead + c.resolution, 0.5 * c.resolution)
        delta = candidates - pose[:2]
        length = np.hypot(delta[:, 0], delta[:, 1])
        frac = np.clip(t[None, :] / np.maximum(length[:, None], 1e-9), 0.0, 1.0)  # [K, S]
        pts = pose[:2] + frac[..., None] * delta[:, None, :]
        cells = self.map.world_to_cell(pts)
        h, w = self.planning_blocked.shape
        rows, cols = np.clip(cells[..., 0], 0, h - 1), np.clip(cells[..., 1], 0, w - 1)
        hit = (self.planning_blocked[rows, cols] & (t[None, :] <= length[:, None])).any(axis=1)
        clear = np.flatnonzero(~hit)
        return candidates[int(clear[-1])] if len(clear) else candidates[0]
