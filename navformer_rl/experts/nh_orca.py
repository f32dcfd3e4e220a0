"""NH-ORCA for differential-drive robots (Alonso-Mora et al. 2013, "Optimal reciprocal collision avoidance
for multiple non-holonomic robots").

Each robot chooses a holonomic velocity ``u`` with ORCA (radii inflated by the tracking error ``E``), under
the extra hard constraint that ``u`` lies in the allowed-holonomic-velocity polygon P_AHV (``u`` can be
tracked by the unicycle within ``E``), then tracks it with ``(v, w)``:

    theta = wrap(angle(u) - yaw),  w = clip(theta / T, +-w_max),
    v = v*(u, theta) = |u| theta sin(theta) / (2 (1 - cos theta))   (v* = |u| as theta -> 0),
    clipped to v_max.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from navformer_rl.experts.orca import Line, box_lines, linear_program2, orca_lines, solve_velocity

SMALL_ANGLE = 1e-6


def wrap(a: float) -> float:
    """Wrap an angle to ``(-pi, pi]``."""
    return math.pi - (math.pi - a) % (2.0 * math.pi)


def v_star(speed: float, theta: float) -> float:
    """Tracking linear speed ``|u| theta sin(theta) / (2 (1 - cos theta))``; ``|u|`` for ``|theta| -> 0``."""
    if abs(theta) < SMALL_ANGLE:
        return speed
    return speed * theta * math.sin(theta) / (2.0 * (1.0 - math.cos(theta)))


def tracking_command(u: np.ndarray, yaw: float, T: float, v_max: float, w_max: float) -> tuple[float, float]:
    """Unicycle ``(v, w)`` that tracks holonomic velocity ``u = (ux, uy)`` from heading ``yaw``."""
    speed = math.hypot(float(u[0]), float(u[1]))
    if speed < 1e-9:
        return 0.0, 0.0
    theta = wrap(math.atan2(float(u[1]), float(u[0])) - yaw)
    w = max(-w_max, min(w_max, theta / T))
    v = min(v_max, max(0.0, v_star(speed, theta)))
    return v, w


def max_holonomic_speed(theta: float, T: float, E: float, v_max: float, w_max: float) -> float:
    """Largest ``|u|`` at relative angle ``theta`` trackable within error ``E`` (V_H of the paper), <= v_max.

    Regimes: rotation-limited (``|theta|/T > w_max``): ``E w_max / |theta|``; unconstrained:
    ``(E/T) sqrt(2(1-cos)/(2(1-cos) - sin^2))``; linear-speed-limited (v* above v_max): the larger root of
    ``T^2 u^2 - 2 T^2 v_max (sin/theta) u + 2 T^2 (1-cos)/theta^2 v_max^2 - E^2 = 0``.
    """
    th = abs(wrap(theta))
    if th < 1e-3:
        return v_max
    if th / T > w_max:
        return min(v_max, E * w_max / th)
    one_minus_cos = 1.0 - math.cos(th)
    sin = math.sin(th)
    denom = 2.0 * one_minus_cos - sin * sin
    vh = v_max if denom <= 1e-12 else (E / T) * math.sqrt(2.0 * one_minus_cos / denom)
    if v_star(vh, th) > v_max:
        vh = v_limited_speed(th, T, E, v_max)
    return min(v_max, vh)


def v_limited_speed(theta: float, T: float, E: float, v_max: float) -> float:
    """Holonomic speed tracked within ``E`` when ``v`` saturates at ``v_max``: the larger root (derived form
    ``(-b + sqrt(b^2 - 4ac)) / 2a``) of ``T^2 u^2 - 2 T^2 v_max (sin/theta) u + 2 T^2 (1-cos)/theta^2 v_max^2
    - E^2 = 0``; the vertex ``-b / 2a`` when the discriminant is negative. ``theta != 0``."""
    th = abs(theta)
    a = T * T
    b = -2.0 * T * T * v_max * math.sin(th) / th
    c = 2.0 * T * T * (1.0 - math.cos(th)) / (th * th) * v_max * v_max - E * E
    return (-b + math.sqrt(max(b * b - 4.0 * a * c, 0.0))) / (2.0 * a)


def ahv_polygon(yaw: float, T: float, E: float, v_max: float, w_max: float, n_chords: int = 10) -> np.ndarray:
    """Convex polygon (CCW, float64 ``[K, 2]``) inside the allowed holonomic velocities at heading ``yaw``.

    Vertices at ``V_H(theta)`` for ``n_chords + 1`` angles ``theta`` in ``[-pi/2, pi/2]`` plus the origin,
    reduced to their convex hull (collvoid uses the same 10 chords).
    """
    thetas = np.linspace(-math.pi / 2, math.pi / 2, n_chords + 1)
    pts = [(0.0, 0.0)]
    for th in thetas:
        s = max_holonomic_speed(float(th), T, E, v_max, w_max)
        pts.append((s * math.cos(yaw + th), s * math.sin(yaw + th)))
    return convex_hull(np.array(pts))


def convex_hull(points: np.ndarray) -> np.ndarray:
    """CCW convex hull (Andrew's monotone chain) of ``[N, 2]`` points, without collinear vertices."""
    pts = sorted(set(map(tuple, np.round(points, 12))))
    if len(pts) <= 2:
        return np.array(pts)

    def cross(o, a, b):
        return (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0])

    lower, upper = [], []
    for p in pts:
        while len(lower) >= 2 and cross(lower[-2], lower[-1], p) <= 1e-12:
            lower.pop()
        lower.append(p)
    for p in reversed(pts):
        while len(upper) >= 2 and cross(upper[-2], upper[-1], p) <= 1e-12:
            upper.pop()
        upper.append(p)
    return np.array(lower[:-1] + upper[:-1])


def clamp_forward_speed(v: float, yaw: float, lines: list[Line]) -> float:
    """Largest speed in ``[0, v]`` whose velocity along the heading satisfies every half-plane in ``lines``
    that the origin satisfies (a safety filter on the unicycle's actual motion: the tracking lag can point
    the robot elsewhere than ``u``)."""
    hx, hy = math.cos(yaw), math.sin(yaw)
    for ln in lines:
        nx, ny = -ln.direction[1], ln.direction[0]  # inward normal
        c = ln.point[0] * nx + ln.point[1] * ny  # constraint: vel . n >= c
        along = hx * nx + hy * ny
        if along < 0.0:
            v = min(v, c / along) if c <= 0.0 else 0.0
    return max(v, 0.0)


def polygon_lines(polygon: np.ndarray) -> list[Line]:
    """Half-planes (interior on the left) of a CCW convex polygon ``[K, 2]``."""
    lines = []
    k = len(polygon)
    for i in range(k):
        a, b = polygon[i], polygon[(i + 1) % k]
        d = b - a
        n = math.hypot(d[0], d[1])
        if n > 1e-12:
            lines.append(Line((float(a[0]), float(a[1])), (float(d[0] / n), float(d[1] / n))))
    return lines


@dataclass(frozen=True)
class NHORCAConfig:
    """NH-ORCA parameters (SI units); defaults for the Jackal spec and the 0.2 s control step."""

    radius: float = 0.30
    """Physical robot radius."""
    tracking_error: float = 0.10
    """E: radii are inflated to ``radius + E + safety``; P_AHV bounds the tracking error by E."""
    safety: float = 0.03
    time_to_holo: float = 0.4
    """T: time to reach the holonomic heading (collvoid ``time_to_holo``)."""
    v_max: float = 1.0
    w_max: float = 1.5
    a_max: float = 2.0
    alpha_max: float = 4.0
    tau: float = 3.0
    tau_obst: float = 1.0
    dt: float = 0.2
    neighbor_dist: float = 6.0
    max_neighbors: int = 10
    n_chords: int = 10
    deadlock_speed: float = 0.1
    """A robot whose chosen ``|u|`` stays below this while it wants to move (``|pref| > 0.3``) is blocked."""
    deadlock_turn: float = 0.5
    """Blocked robots rotate their preferred velocity clockwise by this many radians per blocked step (up to
    pi/2, a right-hand rule shared by all robots) and turn in place toward it - breaks symmetric jams; after
    12 blocked steps they try the other side, alternating every 12 steps."""


def limit_command(
    v: float, w: float, previous: np.ndarray, yaw: float, walls: list[Line], config: NHORCAConfig
) -> tuple[float, float]:
    """Apply the acceleration window around ``previous`` executed ``(v0, w0)`` float ``[2]``, then the wall
    safety clamp (:func:`clamp_forward_speed`) last: safety wins over the acceleration limit, so a forward
    ``v`` never exceeds what the wall half-planes ``walls`` allow along the heading ``yaw``."""
    v0, w0 = float(previous[0]), float(previous[1])
    dv, dw = config.a_max * config.dt, config.alpha_max * config.dt
    v = min(max(v, v0 - dv), v0 + dv)
    w = min(max(w, w0 - dw), w0 + dw)
    if v > 0.0:  # the clamp bounds forward motion; a (rare) backward command is left as it is
        v = clamp_forward_speed(v, yaw, walls)
    return v, w


class NHORCA:
    """NH-ORCA for a team: ``step(poses, velocities, preferred, active, walls) -> (v, w) [N, 2]``.

    Args:
        config: one :class:`NHORCAConfig` shared by every robot, or a sequence with one per robot (robot
            ``i`` plans with its own radius, limits, tracking error and horizons: mixed teams such as one
            Jackal among TurtleBots); default the Jackal defaults for everyone.

    Keeps each robot's last holonomic velocity ``u`` (the neighbours' velocities in the next step).
    Inactive robots (stopped, e.g. finished) are non-reciprocal static agents, inflated by their safety margin
    only (they have no tracking error): others take full responsibility for avoiding them. Symmetric jams
    (all ``u`` ~ 0 while robots want to move, see ``docs/experts.md``) are broken by the right-hand rule of
    :class:`NHORCAConfig` ``deadlock_turn``.
    """

    def __init__(self, config: NHORCAConfig | Sequence[NHORCAConfig] | None = None) -> None:
        if config is None or isinstance(config, NHORCAConfig):
            self.per_robot: list[NHORCAConfig] | None = None
            self.config = config or NHORCAConfig()
        else:
            configs = list(config)
            if not configs or not all(isinstance(c, NHORCAConfig) for c in configs):
                raise ValueError(
                    "config must be an NHORCAConfig or a non-empty sequence of them (one per robot)"
                )
            self.per_robot, self.config = configs, configs[0]
        self.u: np.ndarray | None = None
        self.blocked_steps: np.ndarray | None = None

    def configs(self, n: int) -> list[NHORCAConfig]:
        """The config of each of ``n`` robots (the shared one repeated, or the per-robot list)."""
        if self.per_robot is None:
            return [self.config] * n
        if len(self.per_robot) != n:
            raise ValueError(f"NHORCA has {len(self.per_robot)} per-robot configs but was given {n} robots")
        return self.per_robot

    def reset(self, poses: np.ndarray, velocities: np.ndarray) -> None:
        """Start from the measured velocities: ``u = v (cos yaw, sin yaw)``."""
        poses = np.asarray(poses, dtype=np.float64)
        v = np.asarray(velocities, dtype=np.float64)[:, 0]
        self.u = np.stack([v * np.cos(poses[:, 2]), v * np.sin(poses[:, 2])], axis=1)
        self.blocked_steps = np.zeros(len(poses), dtype=np.int64)

    def step(
        self,
        poses: np.ndarray,
        velocities: np.ndarray,
        preferred: np.ndarray,
        active: np.ndarray,
        walls: np.ndarray,
        circles: np.ndarray | None = None,
    ) -> np.ndarray:
        """Commands ``(v, w)`` float64 ``[N, 2]`` (zeros for inactive robots).

        ``poses`` ``[N, 3]``, ``velocities`` ``[N, 2]`` executed ``(v, w)``, ``preferred`` holonomic
        ``[N, 2]``, ``active`` bool ``[N]``, ``walls`` ``[W, 4]`` boxes ``(cx, cy, half_x, half_y)``,
        ``circles`` ``[C, 3]`` static discs ``(cx, cy, r)``. Robot ``i`` uses its own config (see
        :meth:`configs`); ORCA pairs combine the two robots' inflated radii.
        """
        poses = np.asarray(poses, dtype=np.float64)
        velocities = np.asarray(velocities, dtype=np.float64)
        active = np.asarray(active, dtype=bool)
        n = len(poses)
        cfgs = self.configs(n)
        if self.u is None or len(self.u) != n:
            self.reset(poses, velocities)
        u_prev = np.where(active[:, None], self.u, 0.0)
        physical = np.array([c.radius for c in cfgs])
        inflated = physical + np.array([c.tracking_error + c.safety for c in cfgs])
        # Stopped robots have no tracking error: only the safety margin inflates them.
        radii = np.where(active, inflated, physical + np.array([c.safety for c in cfgs]))
        commands = np.zeros((n, 2))
        u_new = np.zeros((n, 2))
        for i in np.flatnonzero(active):
            c = cfgs[i]
            yaw = float(poses[i, 2])
            soft = orca_lines(
                i, poses[:, :2], u_prev, radii, active, c.tau, c.dt, c.neighbor_dist, c.max_neighbors
            )
            obst_range = c.tau_obst * c.v_max + inflated[i]
            walls_i = box_lines(
                poses[i, :2], inflated[i], walls, c.tau_obst, c.dt, obst_range, c.radius, circles
            )
            ahv = polygon_lines(
                ahv_polygon(yaw, c.time_to_holo, c.tracking_error, c.v_max, c.w_max, c.n_chords)
            )
            pref = self._deadlock_preference(i, np.asarray(preferred[i], dtype=np.float64), c)
            u, _ = self._solve(walls_i, ahv, soft, pref, c.v_max)
            u_new[i] = u
            want = math.hypot(pref[0], pref[1]) > 0.3
            stuck = want and math.hypot(u[0], u[1]) < c.deadlock_speed
            self.blocked_steps[i] = self.blocked_steps[i] + 1 if stuck else 0
            if stuck:  # turning in place is always collision-free for a disc: face the (rotated) preference
                v = 0.0
                w = float(
                    np.clip(wrap(math.atan2(pref[1], pref[0]) - yaw) / c.time_to_holo, -c.w_max, c.w_max)
                )
            else:
                v, w = tracking_command(u, yaw, c.time_to_holo, c.v_max, c.w_max)
            commands[i] = limit_command(v, w, velocities[i], yaw, walls_i, c)
        self.u = u_new
        return commands

    def _deadlock_preference(self, i: int, pref: np.ndarray, c: NHORCAConfig) -> np.ndarray:
        """Robot ``i``'s preferred velocity float64 ``[2]``, rotated by the right-hand rule while it is
        blocked: clockwise first; a robot still blocked after 12 steps alternates sides every 12 steps."""
        if self.blocked_steps[i] <= 0:
            return pref
        k = int(self.blocked_steps[i]) - 1
        side = -1.0 if (k // 12) % 2 == 0 else 1.0
        turn = side * min(math.pi / 2, c.deadlock_turn * (k % 12 + 1))
        cs, sn = math.cos(turn), math.sin(turn)
        return np.array([cs * pref[0] - sn * pref[1], sn * pref[0] + cs * pref[1]])

    def _solve(
        self, walls: list[Line], ahv: list[Line], soft: list[Line], pref: np.ndarray, v_max: float
    ) -> tuple[np.ndarray, bool]:
        """Walls and P_AHV hard; if walls and P_AHV conflict (robot pushed into a wall), drop P_AHV."""
        hard = walls + ahv
        fail, _ = linear_program2(hard, v_max, (0.0, 0.0), False)
        if fail < len(hard):
            hard = walls
        return solve_velocity(hard, soft, pref, v_max)
