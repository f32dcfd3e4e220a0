"""Dynamic Window Approach (Fox, Burgard, Thrun 1997) for a differential-drive robot, with recovery.

Each control step samples ``(v, w)`` in the dynamic window (velocity limits intersected with what the
acceleration limits reach in one control period), rolls each sample out as a constant-velocity arc,
rejects samples that come closer to an obstacle than the safety distance within their check horizon
(``predict_time``, stretched to cover one period at the sample plus the braking distance at ``a_max`` and,
for slow samples, a minimum path length), and picks the lowest cost over ``predict_time``:

    cost = k_goal * |end - goal| + k_heading * |bearing(goal) - yaw_end| / pi
           + k_speed * (v_max - v) / v_max + k_clear * (c_cap - min(clearance, c_cap)) / c_cap

Obstacles come from a bool occupied grid (clearance = Euclidean distance transform, in metres, measured at
least up to the safety distance: :attr:`DWAConfig.clearance_range`). When no sample faster than
``forward_speed`` (which follows ``a_max * dt`` and ``v_max``) is admissible the planner enters *recovery*:
it backs off slowly when backing increases clearance, else brakes and turns in place toward the goal.

Why the clearance holds for any limits: a chosen sample's arc is clear for one period plus its braking
distance, so after that period braking along the same arc stays clear (the window always holds the braking
speed ``v - a_max * dt``). A robot with :attr:`DWAConfig.slow_dynamics` (more than one period to reach the
back-off speed; not the Jackal nor the TurtleBot, whose plans are unchanged) also aims at the nearest free
heading when the way toward the goal is blocked within its stopping distance, and recovers along checked
paths (:meth:`DWAPlanner.recover_slowly`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np


@dataclass(frozen=True)
class DWAConfig:
    """DWA parameters (SI units). Defaults suit the Jackal spec (v 1.0 m/s, w 1.5 rad/s, a 2, alpha 4)."""

    v_max: float = 1.0
    w_max: float = 1.5
    a_max: float = 2.0
    alpha_max: float = 4.0
    dt: float = 0.2
    """Control period (one env step)."""
    predict_time: float = 1.6
    rollout_dt: float = 0.2
    """Longest step (s) of the rollouts; never longer than ``dt`` (:attr:`rollout_step`)."""
    n_v: int = 7
    n_w: int = 15
    robot_radius: float = 0.30
    safety_margin: float = 0.12
    """Clearance margin beyond the radius; covers the 0.1 m grid's quantisation of wall positions."""
    k_goal: float = 1.0
    k_heading: float = 0.6
    k_speed: float = 0.3
    k_clear: float = 0.4
    clearance_cap: float = 0.9
    backoff_speed: float = 0.2
    creep_speed: float = 0.05
    """Slowest speed (m/s) that counts as forward motion for a robot that reaches it within one period."""

    @property
    def forward_speed(self) -> float:
        """Speed (m/s) a sample must exceed to count as forward motion: ``creep_speed``, lowered to half of
        one period's speed change ``a_max * dt`` (the window's top from rest) and to half of ``v_max``."""
        return min(self.creep_speed, 0.5 * self.a_max * self.dt, 0.5 * self.v_max)

    @property
    def check_distance(self) -> float:
        """Shortest path (m) a forward sample is checked along: what ``creep_speed`` covers in
        ``predict_time``."""
        return self.creep_speed * self.predict_time

    @property
    def safety_horizon(self) -> float:
        """Seconds a sample is checked for at least: ``predict_time``, longer when one period at the sample
        plus its braking distance ``v**2 / (2 a_max)`` exceeds what ``v <= v_max`` covers in ``predict_time``
        (the Jackal and the TurtleBot stop well within ``predict_time``)."""
        return max(self.predict_time, self.dt + self.v_max / (2.0 * self.a_max))

    @property
    def rollout_step(self) -> float:
        """Step (s) of the rollouts: ``rollout_dt``, or ``dt`` when shorter, so that a rollout's first pose is
        where one period of the command takes the robot."""
        return min(self.rollout_dt, self.dt)

    @property
    def slow_dynamics(self) -> bool:
        """Whether the robot needs more than one period to reach ``backoff_speed`` (``a_max * dt <
        backoff_speed``; the Jackal and the TurtleBot reach it within one). Such a robot looks
        :attr:`lookahead` metres ahead for the way toward the goal and recovers along checked paths
        (:meth:`DWAPlanner.recover_slowly`)."""
        return self.a_max * self.dt < self.backoff_speed

    @property
    def lookahead(self) -> float:
        """With :attr:`slow_dynamics`: how far (m) ahead the way toward the goal must be free for the heading
        cost to aim at the goal, the safety distance plus the braking distance from ``v_max`` (a slow robot
        cannot swerve late); 0 otherwise."""
        return self.safe_distance + self.v_max**2 / (2.0 * self.a_max) if self.slow_dynamics else 0.0

    @property
    def backoff_periods(self) -> int:
        """Periods a back-off is checked for: two for each period the robot takes to reach ``backoff_speed``,
        so that a slowly accelerating robot's back-off is checked along enough path to show a gain."""
        return 2 * max(1, math.ceil(self.backoff_speed / (self.a_max * self.dt) - 1e-9))

    @property
    def safe_distance(self) -> float:
        """Closest (m) a checked sample may come to an obstacle: ``robot_radius + safety_margin``."""
        return self.robot_radius + self.safety_margin

    @property
    def clearance_range(self) -> float:
        """Cap (m) of the :class:`ClearanceMap` the planner reads: ``clearance_cap``, raised to the safety
        distance for a robot whose radius and margin exceed it (a capped map could not tell a safe sample from
        one inside the safety distance)."""
        return max(self.clearance_cap, self.safe_distance)

    @property
    def map_half_size(self) -> float:
        """Half side (m) of the :class:`ClearanceMap` window around the robot: every checked rollout
        (:attr:`reach`) or look-ahead (:attr:`lookahead`) and the obstacles within :attr:`clearance_range` of
        it, plus the robot's radius."""
        return max(self.reach, self.lookahead) + self.clearance_range + self.robot_radius

    def check_horizon(self, v: np.ndarray) -> np.ndarray:
        """Seconds (float64 ``[N]``) each sample speed ``v`` ``[N]`` is checked for obstacles: the
        ``safety_horizon``, longer for slow samples so each covers ``check_distance``."""
        return np.maximum(self.safety_horizon, self.check_distance / np.maximum(v, self.forward_speed))

    @property
    def reach(self) -> float:
        """Farthest (m) a checked rollout ends from the robot
        (size a :class:`ClearanceMap` window with it)."""
        return max(self.v_max * self.safety_horizon, self.check_distance)


class ClearanceMap:
    """Distance (m) from points to the nearest occupied cell, from a bool ``[H, W]`` occupied grid.

    Computed in a square window around ``center`` (``half_size`` metres), which must contain every point
    queried farther than ``cap`` from the window border; values are capped at ``cap``.
    """

    def __init__(
        self,
        occupied: np.ndarray,
        resolution: float,
        origin: tuple[float, float],
        center: tuple[float, float],
        half_size: float,
        cap: float,
    ) -> None:
        self.resolution = resolution
        self.cap = cap
        h, w = occupied.shape
        k = int(math.ceil(half_size / resolution))
        cr = int(math.floor((center[1] - origin[1]) / resolution))
        cc = int(math.floor((center[0] - origin[0]) / resolution))
        self.r0, self.c0 = cr - k, cc - k
        size = 2 * k + 1
        window = np.zeros((size, size), dtype=bool)
        rlo, rhi = max(0, self.r0), min(h, self.r0 + size)
        clo, chi = max(0, self.c0), min(w, self.c0 + size)
        if rlo < rhi and clo < chi:
            window[rlo - self.r0 : rhi - self.r0, clo - self.c0 : chi - self.c0] = occupied[rlo:rhi, clo:chi]
        if window.any():
            pixels = cv2.distanceTransform((~window).astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
            edt = pixels.astype(np.float64) * resolution - 0.5 * resolution
            self.field = np.clip(edt, 0.0, cap)
        else:
            self.field = np.full((size, size), cap)
        self.origin = np.asarray(origin, dtype=np.float64)

    def __call__(self, xy: np.ndarray) -> np.ndarray:
        """Clearance (float64 ``[...]``) at world points ``[..., 2]``; ``cap`` outside the window."""
        rel = (np.asarray(xy) - self.origin) / self.resolution
        r = np.floor(rel[..., 1]).astype(np.int64) - self.r0
        c = np.floor(rel[..., 0]).astype(np.int64) - self.c0
        n = self.field.shape[0]
        inside = (r >= 0) & (r < n) & (c >= 0) & (c < n)
        out = np.full(r.shape, self.cap)
        out[inside] = self.field[r[inside], c[inside]]
        return out


def rollout(state: np.ndarray, v: np.ndarray, w: np.ndarray, horizon: float, step: float) -> np.ndarray:
    """Unicycle rollouts at constant ``(v, w)``: float64 ``[N, S, 3]`` poses after each ``step``.

    ``state = (x, y, yaw)``; ``v, w``: ``[N]``. Heading is advanced first, then position (PythonRobotics).
    """
    n_steps = max(1, int(round(horizon / step)))
    k = np.arange(1, n_steps + 1)
    yaw = state[2] + w[:, None] * step * k[None, :]  # [N, S]
    dx = v[:, None] * np.cos(yaw) * step
    dy = v[:, None] * np.sin(yaw) * step
    return np.stack([state[0] + np.cumsum(dx, axis=1), state[1] + np.cumsum(dy, axis=1), yaw], axis=-1)


def wrap_angle(a: np.ndarray | float) -> np.ndarray | float:
    """Wrap angles to ``(-pi, pi]``."""
    return (
        np.pi - np.mod(np.pi - np.asarray(a), 2 * np.pi)
        if isinstance(a, np.ndarray)
        else (math.pi - (math.pi - a) % (2 * math.pi))
    )


@dataclass(frozen=True)
class DWAResult:
    """Chosen command (m/s, rad/s); ``recovering`` when no forward sample was admissible."""

    v: float
    w: float
    recovering: bool


class DWAPlanner:
    """Stateless DWA step: ``plan(pose, velocity, goal_xy, clearance) -> DWAResult``."""

    def __init__(self, config: DWAConfig | None = None) -> None:
        self.config = config or DWAConfig()

    def window(self, velocity: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Sampled ``v`` ``[n_v]`` and ``w`` ``[n_w]`` reachable from ``velocity = (v, w)`` in one period."""
        c = self.config
        v0, w0 = float(velocity[0]), float(velocity[1])
        v_lo, v_hi = max(0.0, v0 - c.a_max * c.dt), min(c.v_max, v0 + c.a_max * c.dt)
        if v_lo > v_hi:  # currently reversing faster than one period can undo: brake as hard as allowed
            v_lo = v_hi = min(c.v_max, v0 + c.a_max * c.dt)
        w_lo, w_hi = max(-c.w_max, w0 - c.alpha_max * c.dt), min(c.w_max, w0 + c.alpha_max * c.dt)
        vs = np.linspace(v_lo, v_hi, c.n_v)
        ws = np.linspace(w_lo, w_hi, c.n_w)
        if w_lo < 0.0 < w_hi:
            ws = np.unique(np.append(ws, 0.0))
        return vs, ws

    def plan(
        self, pose: np.ndarray, velocity: np.ndarray, goal: np.ndarray, clearance: ClearanceMap
    ) -> DWAResult:
        """One DWA decision for ``pose = (x, y, yaw)``, ``velocity = (v, w)``, ``goal = (x, y)``."""
        c = self.config
        if clearance.cap < c.safe_distance:
            raise ValueError(
                f"ClearanceMap cap={clearance.cap}: expected at least the safety distance "
                f"{c.safe_distance} (robot_radius + safety_margin); build it with config.clearance_range"
            )
        pose = np.asarray(pose, dtype=np.float64)
        vs, ws = self.window(velocity)
        v_grid, w_grid = np.meshgrid(vs, ws, indexing="ij")
        v, w = v_grid.ravel(), w_grid.ravel()
        horizon = c.check_horizon(v)  # [N]
        step = c.rollout_step
        n_steps = max(1, math.ceil(float(horizon.max()) / step - 1e-9))
        traj = rollout(pose, v, w, n_steps * step, step)  # [N, S, 3]
        t = step * np.arange(1, n_steps + 1)  # [S]
        along = clearance(traj[..., :2])  # [N, S]
        n_predict = max(1, round(c.predict_time / step))
        here = float(clearance(pose[None, :2])[0])
        safe = c.safe_distance
        # Already inside the safety distance: accept only samples that do not get closer.
        checked = t[None, :] <= horizon[:, None] + 1e-9  # [N, S]
        admissible = np.where(checked, along, np.inf).min(axis=1) >= min(safe, here - 1e-3)
        moving = admissible & (v > c.forward_speed)
        if moving.any():
            clear = along[:, :n_predict].min(axis=1)  # [N]
            end = traj[:, n_predict - 1, :]
            to_goal = goal[None, :] - end[:, :2]
            dist = np.hypot(to_goal[:, 0], to_goal[:, 1])
            aim = np.arctan2(to_goal[:, 1], to_goal[:, 0])
            if c.slow_dynamics:  # aim at the nearest free heading when the way toward the goal is blocked
                bearing = math.atan2(goal[1] - pose[1], goal[0] - pose[0])
                length = min(float(np.hypot(goal[0] - pose[0], goal[1] - pose[1])), c.lookahead)
                free = self.free_heading(pose, bearing, clearance, safe, length)
                if free != bearing:
                    aim = np.full_like(aim, free)
            heading = np.abs(wrap_angle(aim - end[:, 2])) / np.pi
            heading = np.where(dist < 0.2, 0.0, heading)
            cost = (
                c.k_goal * dist
                + c.k_heading * heading
                + c.k_speed * (c.v_max - v) / c.v_max
                + c.k_clear * (c.clearance_cap - np.minimum(clear, c.clearance_cap)) / c.clearance_cap
            )
            cost[~moving] = np.inf
            k = int(np.argmin(cost))
            return DWAResult(float(v[k]), float(w[k]), False)
        return self.recover(pose, velocity, goal, clearance, here)

    def recover(
        self, pose: np.ndarray, velocity: np.ndarray, goal: np.ndarray, clearance: ClearanceMap, here: float
    ) -> DWAResult:
        """No admissible forward motion. A robot that reaches ``backoff_speed`` within one period (the Jackal,
        the TurtleBot) backs off if two periods of it gain clearance, else
        brakes at ``a_max`` while turning toward the goal. A slower one (:meth:`recover_slowly`) checks its
        braking and its back-off along the paths they take."""
        c = self.config
        if c.slow_dynamics:
            return self.recover_slowly(pose, velocity, goal, clearance, here)
        v0, w0 = float(velocity[0]), float(velocity[1])
        dv, dw = c.a_max * c.dt, c.alpha_max * c.dt
        v_back = float(np.clip(-c.backoff_speed, v0 - dv, v0 + dv))
        if v_back < 0.0 and here < c.safe_distance:
            back = rollout(pose, np.array([v_back]), np.array([0.0]), 2 * c.dt, c.rollout_step)[0]
            gained = clearance(back[:, :2])
            if gained.min() >= here - 1e-6 and gained[-1] > here + 1e-3:
                return DWAResult(v_back, 0.0, True)
        bearing = math.atan2(goal[1] - pose[1], goal[0] - pose[0])
        direction = 1.0 if wrap_angle(bearing - pose[2]) >= 0 else -1.0
        v = float(np.clip(0.0, v0 - dv, v0 + dv))
        w = float(np.clip(direction * c.w_max, w0 - dw, w0 + dw))
        return DWAResult(v, w, True)

    def recover_slowly(
        self, pose: np.ndarray, velocity: np.ndarray, goal: np.ndarray, clearance: ClearanceMap, here: float
    ) -> DWAResult:
        """Recovery of a robot that needs several periods to reach ``backoff_speed`` (and to brake).

        - Moving forward: brake at ``a_max`` turning toward the goal when that path (one period, then braking
          on the same arc) keeps the clearance, else brake along the arc last checked (whose braking path the
          admissibility test found clear).
        - Inside the safety distance and not moving forward: back off, turning toward straight, when the
          back-off path of :attr:`DWAConfig.backoff_periods` periods gains clearance.
        - Else turn in place toward the goal or, when a straight move toward it would lose clearance, toward
          the nearest heading along which it would not (:meth:`free_heading`): the robot stops turning there
          instead of swinging about a blocked bearing.
        """
        c = self.config
        v0, w0 = float(velocity[0]), float(velocity[1])
        dv, dw = c.a_max * c.dt, c.alpha_max * c.dt
        floor = min(c.safe_distance, here) - 1e-3
        v_back = float(np.clip(-c.backoff_speed, v0 - dv, v0 + dv))
        w_straight = float(np.clip(0.0, w0 - dw, w0 + dw))
        if v0 <= 0.0 and v_back < 0.0 and here < c.safe_distance:
            horizon = c.backoff_periods * c.dt
            back = rollout(pose, np.array([v_back]), np.array([w_straight]), horizon, c.rollout_step)[0]
            gained = clearance(back[:, :2])
            if gained.min() >= here - 1e-6 and gained[-1] > here + 1e-3:
                return DWAResult(v_back, w_straight, True)
        bearing = math.atan2(goal[1] - pose[1], goal[0] - pose[0])
        v = float(np.clip(0.0, v0 - dv, v0 + dv))
        if v0 <= 0.0:
            bearing = self.free_heading(pose, bearing, clearance, floor)
        direction = 1.0 if wrap_angle(bearing - pose[2]) >= 0 else -1.0
        w = float(np.clip(direction * c.w_max, w0 - dw, w0 + dw))
        if v > 0.0 and self.braking_clearance(pose, v, w, clearance) < floor:
            w = float(np.clip(w0 * v / v0, w0 - dw, w0 + dw))  # brake along the arc last checked
        return DWAResult(v, w, True)

    def braking_clearance(self, pose: np.ndarray, v: float, w: float, clearance: ClearanceMap) -> float:
        """Least clearance (m) along the path of ``(v, w)`` for one period then braking at ``a_max`` on the
        same arc (``v > 0``)."""
        c = self.config
        horizon = c.dt + v / (2.0 * c.a_max)  # the arc's length over v
        n_steps = max(1, math.ceil(horizon / c.rollout_step - 1e-9))
        path = rollout(pose, np.array([v]), np.array([w]), n_steps * c.rollout_step, c.rollout_step)[0]
        return float(clearance(path[:, :2]).min())

    def free_heading(
        self,
        pose: np.ndarray,
        bearing: float,
        clearance: ClearanceMap,
        floor: float,
        length: float | None = None,
    ) -> float:
        """``bearing`` when a straight move of ``length`` (default ``check_distance``) along it keeps the
        clearance at least ``floor``; else the nearest heading that does (5 degree steps, either side);
        ``bearing`` when none does."""
        c = self.config
        offsets = np.radians(np.arange(5.0, 181.0, 5.0))
        headings = bearing + np.concatenate([[0.0], np.stack([offsets, -offsets], axis=1).ravel()])
        length = c.check_distance if length is None else max(length, clearance.resolution)
        steps = max(1, math.ceil(length / (0.5 * clearance.resolution)))
        along = np.linspace(0.0, length, steps + 1)[1:]
        unit = np.stack([np.cos(headings), np.sin(headings)], axis=-1)
        points = pose[None, None, :2] + along[None, :, None] * unit[:, None, :]  # [H, S, 2]
        free = clearance(points).min(axis=1) >= floor
        return float(headings[int(np.argmax(free))]) if free.any() else bearing
