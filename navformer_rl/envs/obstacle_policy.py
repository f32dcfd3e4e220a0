"""Policies that drive the robots the learner does not control (the dynamic obstacles of paper §III).

Protocol (:class:`ObstaclePolicy`): ``reset(world, sim, rng)`` once per episode, then
``act(sim, robot_indices) -> float32 [k, 2]`` normalised actions for those robots every step. The
default :class:`GoalSeekingPolicy` uses privileged state (the occupancy map); the NH-ORCA expert of the
experts package plugs in through the same protocol.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Protocol, runtime_checkable

import numpy as np

from navformer_rl.constants import SUCCESS_RADIUS
from navformer_rl.envs.occupancy import OccupancyMap
from navformer_rl.envs.sim import Simulator, wrap_angle
from navformer_rl.envs.world import WorldSpec


@runtime_checkable
class ObstaclePolicy(Protocol):
    """Drives non-controlled robots. ``act`` returns float32 ``[len(robot_indices), 2]`` in ``[-1, 1]``."""

    def reset(self, world: WorldSpec, sim: Simulator, rng: np.random.Generator) -> None: ...

    def act(self, sim: Simulator, robot_indices: Sequence[int]) -> np.ndarray: ...


def coarsen(occupancy: OccupancyMap, factor: int) -> OccupancyMap:
    """A coarser map whose cell is occupied when any of the ``factor x factor`` fine cells it covers is."""
    if factor == 1:
        return occupancy
    h, w = occupancy.shape
    grid = np.zeros((-(-h // factor) * factor, -(-w // factor) * factor), dtype=bool)
    grid[:h, :w] = occupancy.grid
    blocks = grid.reshape(grid.shape[0] // factor, factor, grid.shape[1] // factor, factor)
    return OccupancyMap(blocks.any(axis=(1, 3)), occupancy.resolution * factor, occupancy.origin)


class GoalSeekingPolicy:
    """Each robot follows the geodesic distance field (occupancy map inflated by its radius plus
    ``margin``) toward its own target; once within the success radius, or when it makes no progress for
    ``patience`` steps, it wanders to random free goals in turn.

    Steering: it walks ``lookahead`` metres down the distance field from its cell (steepest descent over
    the 8 neighbours, so the waypoint is always reachable), turns toward that waypoint with a
    proportional gain, slows down for large heading errors, and yields (slows, veers right) when another
    robot is close ahead.

    Args:
        lookahead: metres of steepest descent to the waypoint.
        margin: extra clearance from walls in metres.
        patience: steps without getting 0.1 m closer before a robot picks a new random goal.
        speed: fraction of ``v_max`` used when cruising.
        coarsening: the map is planned on at ``coarsening`` times the occupancy resolution (0.2 m cells
            by default: a new goal's distance field then costs well under a millisecond).
    """

    def __init__(
        self,
        lookahead: float = 0.8,
        margin: float = 0.15,
        patience: int = 25,
        speed: float = 0.8,
        coarsening: int = 4,
    ):
        self.coarsening = coarsening
        self.lookahead = lookahead
        self.margin = margin
        self.patience = patience
        self.speed = speed

    def reset(self, world: WorldSpec, sim: Simulator, rng: np.random.Generator) -> None:
        self._world = world
        self._rng = rng
        self._occupancy = coarsen(world.occupancy, self.coarsening)
        self._clearance = [float(r) + self.margin for r in sim.radii]
        n = sim.n_robots
        self._goals = [
            (world.targets[i].position.astype(np.float64), True) if i < len(world.targets) else None
            for i in range(n)
        ]
        self._best = np.full(n, np.inf)
        self._stalled = np.zeros(n, dtype=np.int64)
        self._descent_steps = max(1, int(round(self.lookahead / self._occupancy.resolution)))
        self._free_cells = {
            c: np.argwhere(self._occupancy.largest_free_component(c)) for c in set(self._clearance)
        }
        for i in range(n):
            if self._goals[i] is None:
                self._new_wander_goal(i)

    def _new_wander_goal(self, i: int) -> None:
        free = self._free_cells[self._clearance[i]]
        cell = free[int(self._rng.integers(len(free)))]
        self._goals[i] = (self._occupancy.cell_to_world(cell), False)
        self._best[i] = np.inf
        self._stalled[i] = 0

    def act(self, sim: Simulator, robot_indices: Sequence[int]) -> np.ndarray:
        poses = sim.poses.astype(np.float64)
        actions = np.zeros((len(robot_indices), 2), dtype=np.float32)
        for row, i in enumerate(robot_indices):
            actions[row] = self._act_one(sim, int(i), poses)
        return actions

    def _act_one(self, sim: Simulator, i: int, poses: np.ndarray) -> tuple[float, float]:
        x, y, yaw = poses[i]
        goal, is_target = self._goals[i]
        reach = SUCCESS_RADIUS if is_target else 0.5
        if math.hypot(goal[0] - x, goal[1] - y) <= reach:
            self._new_wander_goal(i)
            goal, is_target = self._goals[i]
        occ = self._occupancy
        field = occ.distance_field(goal, self._clearance[i])
        cell = occ.snap_to_free((x, y), self._clearance[i])  # its own cell, or the nearest free one
        start_value = field[cell]
        h, w = field.shape
        for _ in range(self._descent_steps):  # walk down the distance field: never across a wall
            r, c = cell
            r0, c0 = max(r - 1, 0), max(c - 1, 0)
            window = field[r0 : r + 2, c0 : c + 2]
            k = int(np.argmin(window))
            nxt = (r0 + k // window.shape[1], c0 + k % window.shape[1])
            if not field[nxt] < field[cell]:
                break
            cell = nxt
        waypoint = occ.cell_to_world(np.array(cell))
        if math.hypot(waypoint[0] - x, waypoint[1] - y) < 0.05:
            waypoint = goal
        if start_value < self._best[i] - 0.1:
            self._best[i], self._stalled[i] = start_value, 0
        else:
            self._stalled[i] += 1
            if self._stalled[i] > self.patience:  # blocked (or the goal is unreachable): go elsewhere
                self._new_wander_goal(i)
        heading_error = wrap_angle(math.atan2(waypoint[1] - y, waypoint[0] - x) - yaw)
        spec = sim.robot_specs[i]
        w_cmd = float(np.clip(2.0 * heading_error / spec.w_max, -1.0, 1.0))
        v_cmd = self.speed * max(0.0, math.cos(heading_error)) ** 2
        v_cmd, w_cmd = self._yield_to_robots(i, poses, spec.radius, v_cmd, w_cmd)
        return v_cmd, w_cmd

    @staticmethod
    def _yield_to_robots(i: int, poses: np.ndarray, radius: float, v: float, w: float) -> tuple[float, float]:
        """Slow down and veer right when another robot is within 1.2 m in the forward 90 deg cone."""
        x, y, yaw = poses[i]
        for j in range(len(poses)):
            if j == i:
                continue
            dx, dy = poses[j, 0] - x, poses[j, 1] - y
            dist = math.hypot(dx, dy)
            if dist < 1.2 + radius and abs(wrap_angle(math.atan2(dy, dx) - yaw)) < math.pi / 4:
                return v * max(0.0, (dist - 2 * radius) / 1.2), max(-1.0, w - 0.5)
        return v, w
