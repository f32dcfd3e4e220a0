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
from navformer_rl.utils.checks import check_int, check_number


@runtime_checkable
class ObstaclePolicy(Protocol):
    """Drives non-controlled robots. ``act`` returns float32 ``[len(robot_indices), 2]`` in ``[-1, 1]``."""

    def reset(self, world: WorldSpec, sim: Simulator, rng: np.random.Generator) -> None: ...

    def act(self, sim: Simulator, robot_indices: Sequence[int]) -> np.ndarray: ...


def coarsen(occupancy: OccupancyMap, factor: int, clearance: float = 0.0) -> OccupancyMap:
    """A map ``factor`` times coarser, sampled from ``occupancy.inflate(clearance)``: a coarse cell is
    blocked when the fine cell at its centre is. Plan on it with clearance 0 (the inflation is built in);
    sampling (rather than "any fine cell blocked") keeps narrow but passable corridors open."""
    blocked = occupancy.inflate(clearance)
    h, w = blocked.shape
    rows = np.minimum(np.arange(-(-h // factor)) * factor + factor // 2, h - 1)
    cols = np.minimum(np.arange(-(-w // factor)) * factor + factor // 2, w - 1)
    return OccupancyMap(blocked[np.ix_(rows, cols)], occupancy.resolution * factor, occupancy.origin)


def descent_successors(field: np.ndarray) -> np.ndarray:
    """int64 ``[H * W]``: for every cell (flat index) its 8-neighbour with the lowest value of ``field``
    when lower than its own, else itself (a fixed point at goals and unreachable cells)."""
    h, w = field.shape
    padded = np.pad(field, 1, constant_values=np.inf)
    best = field.copy()
    index = np.arange(h * w).reshape(h, w)
    successor = index.copy()
    for dr in (-1, 0, 1):
        for dc in (-1, 0, 1):
            if dr == dc == 0:
                continue
            candidate = padded[1 + dr : 1 + dr + h, 1 + dc : 1 + dc + w]
            better = candidate < best
            best = np.where(better, candidate, best)
            successor = np.where(better, index + dr * w + dc, successor)
    return successor.reshape(-1)


_TARGET, _DETOUR, _WANDER = "target", "detour", "wander"


class GoalSeekingPolicy:
    """Each robot follows a geodesic distance field toward its own target; once within the success radius
    it wanders to random free goals in turn. When it makes no progress for ``patience`` steps (e.g.
    blocked by a parked robot) it takes a detour to a random free goal, then heads for its target again.

    Planning: on the occupancy map inflated by the robot's radius plus ``margin`` (or by the radius alone
    where the margin closes a gap), sampled ``coarsening`` times coarser. Steering: it walks
    ``lookahead`` metres down the distance field from its cell (steepest descent over the 8 neighbours, so
    the waypoint is always reachable), turns toward that waypoint with a proportional gain, slows down
    for large heading errors, and yields (slows, veers right) when another robot is close ahead. After a
    step in which its motion was blocked (executed speed below 30 % of the command) it backs off while
    turning for ``backing_steps`` steps.

    Args:
        lookahead: metres of steepest descent to the waypoint.
        margin: extra clearance from walls in metres.
        patience: steps without getting 0.1 m closer before a robot changes goal.
        speed: fraction of ``v_max`` used when cruising.
        coarsening: planning cells are ``coarsening`` occupancy cells wide (0.2 m by default: a new goal's
            distance field then costs well under a millisecond).
        backing_steps: steps of reversing after a blocked step.

    ValueError for a non-integer or too small ``coarsening`` (>= 1), ``patience`` or ``backing_steps``
    (>= 0), a non-positive ``lookahead``, a negative ``margin`` or a ``speed`` outside [0, 1].
    """

    def __init__(
        self,
        lookahead: float = 0.4,
        margin: float = 0.15,
        patience: int = 25,
        speed: float = 0.8,
        coarsening: int = 4,
        backing_steps: int = 3,
    ):
        self.coarsening = check_int(coarsening, "coarsening")
        self.backing_steps = check_int(backing_steps, "backing_steps", minimum=0)
        self.lookahead = check_number(lookahead, "lookahead", greater_than=0.0, unit="metres")
        self.margin = check_number(margin, "margin", at_least=0.0, unit="metres")
        self.patience = check_int(patience, "patience", minimum=0)
        self.speed = check_number(speed, "speed", at_least=0.0, at_most=1.0, unit="fraction of v_max")

    def reset(self, world: WorldSpec, sim: Simulator, rng: np.random.Generator) -> None:
        self._rng = rng
        radii = [float(r) for r in sim.radii]
        maps = {c: coarsen(world.occupancy, self.coarsening, c) for r in radii for c in (r + self.margin, r)}
        self._maps = [(maps[r + self.margin], maps[r]) for r in radii]  # (with margin, tight) per robot
        self._free_cells = {id(m): np.argwhere(m.largest_free_component(0.0)) for m in maps.values()}
        self._descent_steps = max(1, int(round(self.lookahead / self._maps[0][0].resolution)))
        n = sim.n_robots
        self._targets = [
            world.targets[i].position.astype(np.float64) if i < len(world.targets) else None for i in range(n)
        ]
        self._goals: list[tuple[np.ndarray, str]] = [(np.zeros(2), _WANDER)] * n
        self._fields: list[dict[int, tuple[np.ndarray, np.ndarray]]] = [{} for _ in range(n)]
        self._best = np.full(n, np.inf)
        self._stalled = np.zeros(n, dtype=np.int64)
        self._commanded = np.zeros(n)  # linear speed (m/s) commanded last step
        self._backing = np.zeros(n, dtype=np.int64)  # steps of reversing left after a blocked step
        for i in range(n):
            if self._targets[i] is None:
                self._set_goal(i, self._random_goal(i), _WANDER)
            else:
                self._set_goal(i, self._targets[i], _TARGET)

    def _random_goal(self, i: int) -> np.ndarray:
        occ = self._maps[i][0]
        free = self._free_cells[id(occ)]
        return occ.cell_to_world(free[int(self._rng.integers(len(free)))])

    def _field(self, i: int, occ: OccupancyMap) -> tuple[np.ndarray, np.ndarray]:
        """Distance field of robot ``i``'s current goal on ``occ`` and its steepest-descent successors
        (computed once per goal and map)."""
        key = id(occ)
        if key not in self._fields[i]:
            field = occ.distance_field(self._goals[i][0], 0.0)
            self._fields[i][key] = (field, descent_successors(field))
        return self._fields[i][key]

    def _set_goal(self, i: int, goal: np.ndarray, kind: str) -> None:
        self._goals[i] = (goal, kind)
        self._fields[i] = {}
        self._best[i] = np.inf
        self._stalled[i] = 0

    def _next_goal(self, i: int, reached: bool) -> None:
        """Target reached: wander from now on. Stuck on the way to the target: a random detour, then back."""
        kind = self._goals[i][1]
        if kind == _TARGET and reached:
            self._targets[i] = None
        if kind == _TARGET and not reached:
            self._set_goal(i, self._random_goal(i), _DETOUR)
        elif kind == _DETOUR and self._targets[i] is not None:
            self._set_goal(i, self._targets[i], _TARGET)
        else:
            self._set_goal(i, self._random_goal(i), _WANDER)

    def act(self, sim: Simulator, robot_indices: Sequence[int]) -> np.ndarray:
        poses = sim.poses.astype(np.float64)
        actions = np.zeros((len(robot_indices), 2), dtype=np.float32)
        for row, i in enumerate(robot_indices):
            actions[row] = self._act_one(sim, int(i), poses)
        return actions

    def _act_one(self, sim: Simulator, i: int, poses: np.ndarray) -> tuple[float, float]:
        x, y, yaw = poses[i]
        goal, kind = self._goals[i]
        if math.hypot(goal[0] - x, goal[1] - y) <= (SUCCESS_RADIUS if kind == _TARGET else 0.5):
            self._next_goal(i, reached=True)
            goal, kind = self._goals[i]
        for occ in self._maps[i]:  # with the wall margin if that connects robot and goal, else tight
            field, successor = self._field(i, occ)
            h, w = field.shape
            cell = (
                min(max(int(y // occ.resolution), 0), h - 1),
                min(max(int(x // occ.resolution), 0), w - 1),
            )
            if not math.isfinite(field[cell]):
                cell = occ.snap_to_free((x, y), 0.0)  # inside the inflated walls: the nearest free cell
            start_value = field[cell]
            if math.isfinite(start_value):
                break
        flat = cell[0] * w + cell[1]
        for _ in range(self._descent_steps):  # walk down the distance field: never across a wall
            flat = int(successor[flat])
        cell = divmod(flat, w)
        waypoint = (
            (cell[1] + 0.5) * occ.resolution + occ.origin[0],
            (cell[0] + 0.5) * occ.resolution + occ.origin[1],
        )
        if math.hypot(waypoint[0] - x, waypoint[1] - y) < 0.05:
            waypoint = goal
        if start_value < self._best[i] - 0.1:
            self._best[i], self._stalled[i] = start_value, 0
        else:
            self._stalled[i] += 1
            if self._stalled[i] > self.patience:  # blocked (or the goal is unreachable): go elsewhere
                self._next_goal(i, reached=False)
        heading_error = wrap_angle(math.atan2(waypoint[1] - y, waypoint[0] - x) - yaw)
        spec = sim.robot_specs[i]
        w_cmd = min(1.0, max(-1.0, 2.0 * heading_error / spec.w_max))
        v_cmd = self.speed * max(0.0, math.cos(heading_error)) ** 2
        v_cmd, w_cmd = self._yield_to_robots(i, poses, spec.radius, v_cmd, w_cmd)
        if self._commanded[i] > 0.1 and sim.velocities[i, 0] < 0.3 * self._commanded[i]:
            self._backing[i] = self.backing_steps  # pushed into something: back off while turning
        if self._backing[i] > 0:
            self._backing[i] -= 1
            v_cmd, w_cmd = -0.3, 1.0 if heading_error >= 0 else -1.0
        self._commanded[i] = max(v_cmd, 0.0) * spec.v_max
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
