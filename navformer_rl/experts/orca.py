"""Optimal Reciprocal Collision Avoidance (van den Berg et al. 2011), a float64 port of RVO2's math.

Half-planes are :class:`Line` ``(point, direction)``; a velocity ``v`` satisfies a line iff
``det(direction, point - v) <= 0`` (``v`` lies on the left of the directed line). The new velocity solves
``min |v - v_pref|`` s.t. all lines and ``|v| <= v_max`` with RVO2's incremental 2-D LP
(``linear_program1/2``) and, when infeasible, ``linear_program3`` (minimise the largest violation of the
soft lines while the first ``n_hard`` lines stay hard).

Static walls (axis-aligned boxes) enter as one hard half-plane per nearby box built at the box's closest
point: ``v . n >= -(d - r) / tau_obst`` (``n`` = unit vector from the closest point to the robot, ``d`` its
distance) - the linearisation of RVO2's obstacle velocity obstacle at its apex (see docs/experts.md).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

EPSILON = 1e-5
"""RVO2's ``RVO_EPSILON``: parallel-line tolerance."""


@dataclass(frozen=True)
class Line:
    """Directed line; the feasible half-plane is on its left. ``direction`` is a unit vector."""

    point: tuple[float, float]
    direction: tuple[float, float]


def _det(ax: float, ay: float, bx: float, by: float) -> float:
    return ax * by - ay * bx


def agent_line(
    rel_position: np.ndarray,
    rel_velocity: np.ndarray,
    own_velocity: np.ndarray,
    combined_radius: float,
    tau: float,
    dt: float,
    responsibility: float = 0.5,
) -> Line:
    """ORCA half-plane of agent A induced by neighbour B.

    ``rel_position = p_B - p_A``, ``rel_velocity = v_A - v_B``, ``own_velocity = v_A``; ``combined_radius =
    r_A + r_B``; ``tau`` time horizon; ``dt`` simulation step (used when already overlapping);
    ``responsibility`` 0.5 for reciprocal neighbours, 1.0 for neighbours that do not avoid.
    """
    px, py = float(rel_position[0]), float(rel_position[1])
    vx, vy = float(rel_velocity[0]), float(rel_velocity[1])
    r = combined_radius
    dist_sq = px * px + py * py
    r_sq = r * r
    if dist_sq > r_sq:
        inv_tau = 1.0 / tau
        wx, wy = vx - inv_tau * px, vy - inv_tau * py
        w_len_sq = wx * wx + wy * wy
        dot1 = wx * px + wy * py
        if dot1 < 0.0 and dot1 * dot1 > r_sq * w_len_sq:
            # Project on the cut-off circle.
            w_len = math.sqrt(w_len_sq)
            ux_, uy_ = wx / w_len, wy / w_len
            direction = (uy_, -ux_)
            ux, uy = (r * inv_tau - w_len) * ux_, (r * inv_tau - w_len) * uy_
        else:
            # Project on a leg.
            leg = math.sqrt(dist_sq - r_sq)
            if _det(px, py, wx, wy) > 0.0:
                direction = ((px * leg - py * r) / dist_sq, (px * r + py * leg) / dist_sq)
            else:
                direction = (-(px * leg + py * r) / dist_sq, -(-px * r + py * leg) / dist_sq)
            dot2 = vx * direction[0] + vy * direction[1]
            ux, uy = dot2 * direction[0] - vx, dot2 * direction[1] - vy
    else:
        # Already colliding: resolve within one simulation step.
        inv_dt = 1.0 / dt
        wx, wy = vx - inv_dt * px, vy - inv_dt * py
        w_len = math.hypot(wx, wy)
        if w_len < EPSILON:  # same position and velocity: any fixed direction breaks the tie
            wx, wy, w_len = 1.0, 0.0, 1.0
        ux_, uy_ = wx / w_len, wy / w_len
        direction = (uy_, -ux_)
        ux, uy = (r * inv_dt - w_len) * ux_, (r * inv_dt - w_len) * uy_
    point = (float(own_velocity[0]) + responsibility * ux, float(own_velocity[1]) + responsibility * uy)
    return Line(point, direction)


def box_lines(
    position: np.ndarray,
    radius: float,
    walls: np.ndarray,
    tau_obst: float,
    dt: float,
    max_range: float,
    physical_radius: float | None = None,
    circles: np.ndarray | None = None,
) -> list[Line]:
    """Hard half-planes for static obstacles within ``max_range``: boxes ``float [W, 4] = (cx, cy, half_x,
    half_y)`` and optional discs ``float [C, 3] = (cx, cy, r)``.

    For each obstacle, with closest point ``q``, ``n = (p - q)/|p - q|`` and gap ``g = |p - q| - radius``:
    ``v . n >= -g / tau_obst``; when the *physical* disc (``physical_radius``, default ``radius``) overlaps,
    ``v . n >= -g / dt`` (leave the overlap in one step). With a safety-inflated ``radius`` a robot inside
    the inflation only is pushed out gently (at ``-g / tau_obst``).
    """
    physical_radius = radius if physical_radius is None else physical_radius
    p = np.asarray(position, dtype=np.float64)
    normals, dists = [], []
    if len(walls):
        lo = walls[:, :2] - walls[:, 2:]
        hi = walls[:, :2] + walls[:, 2:]
        diff = p - np.clip(p, lo, hi)
        dist = np.hypot(diff[:, 0], diff[:, 1])
        for k in np.flatnonzero(dist < max_range):
            d = float(dist[k])
            if d < 1e-9:  # centre inside the box: push out along the shallowest axis
                pen = np.concatenate([p - lo[k], hi[k] - p])
                axis = int(np.argmin(pen))
                n = np.zeros(2)
                n[axis % 2] = -1.0 if axis < 2 else 1.0
                d = -float(pen[axis])
            else:
                n = diff[k] / d
            normals.append(n)
            dists.append(d)
    if circles is not None and len(circles):
        diff = p - circles[:, :2]
        centre_dist = np.hypot(diff[:, 0], diff[:, 1])
        for k in np.flatnonzero(centre_dist - circles[:, 2] < max_range):
            n = diff[k] / centre_dist[k] if centre_dist[k] > 1e-9 else np.array([1.0, 0.0])
            normals.append(n)
            dists.append(float(centre_dist[k] - circles[k, 2]))
    lines = []
    for n, d in zip(normals, dists):
        gap = d - radius
        c = -gap / (tau_obst if d > physical_radius else dt)
        lines.append(Line((c * n[0], c * n[1]), (float(n[1]), float(-n[0]))))
    return lines


def linear_program1(
    lines: list[Line], line_no: int, radius: float, opt: tuple[float, float], direction_opt: bool
) -> tuple[float, float] | None:
    """Optimum on line ``line_no`` subject to lines ``[0, line_no)`` and the speed disk; None if empty."""
    ln = lines[line_no]
    (px, py), (dx, dy) = ln.point, ln.direction
    dot = px * dx + py * dy
    disc = dot * dot + radius * radius - (px * px + py * py)
    if disc < 0.0:
        return None
    sq = math.sqrt(disc)
    t_left, t_right = -dot - sq, -dot + sq
    for i in range(line_no):
        (qx, qy), (ex, ey) = lines[i].point, lines[i].direction
        denom = _det(dx, dy, ex, ey)
        numer = _det(ex, ey, px - qx, py - qy)
        if abs(denom) <= EPSILON:
            if numer < 0.0:
                return None
            continue
        t = numer / denom
        if denom >= 0.0:
            t_right = min(t_right, t)
        else:
            t_left = max(t_left, t)
        if t_left > t_right:
            return None
    if direction_opt:
        t = t_right if opt[0] * dx + opt[1] * dy > 0.0 else t_left
    else:
        t = dx * (opt[0] - px) + dy * (opt[1] - py)
        t = min(max(t, t_left), t_right)
    return px + t * dx, py + t * dy


def linear_program2(
    lines: list[Line], radius: float, opt: tuple[float, float], direction_opt: bool
) -> tuple[int, tuple[float, float]]:
    """Incremental LP; returns ``(index of the first failing line or len(lines), result)``."""
    if direction_opt:
        result = (opt[0] * radius, opt[1] * radius)
    elif opt[0] ** 2 + opt[1] ** 2 > radius * radius:
        n = math.hypot(*opt)
        result = (opt[0] / n * radius, opt[1] / n * radius)
    else:
        result = opt
    for i, ln in enumerate(lines):
        if _det(*ln.direction, ln.point[0] - result[0], ln.point[1] - result[1]) > 0.0:
            new = linear_program1(lines, i, radius, opt, direction_opt)
            if new is None:
                return i, result
            result = new
    return len(lines), result


def linear_program3(
    lines: list[Line], n_hard: int, begin: int, radius: float, result: tuple[float, float]
) -> tuple[float, float]:
    """Minimise the largest violation of soft lines ``[n_hard, ...)``, keeping lines ``[0, n_hard)`` hard."""
    distance = 0.0
    for i in range(begin, len(lines)):
        li = lines[i]
        if _det(*li.direction, li.point[0] - result[0], li.point[1] - result[1]) > distance:
            proj = list(lines[:n_hard])
            for j in range(n_hard, i):
                lj = lines[j]
                determinant = _det(*li.direction, *lj.direction)
                if abs(determinant) <= EPSILON:
                    if li.direction[0] * lj.direction[0] + li.direction[1] * lj.direction[1] > 0.0:
                        continue
                    point = (0.5 * (li.point[0] + lj.point[0]), 0.5 * (li.point[1] + lj.point[1]))
                else:
                    s = (
                        _det(*lj.direction, li.point[0] - lj.point[0], li.point[1] - lj.point[1])
                        / determinant
                    )
                    point = (li.point[0] + s * li.direction[0], li.point[1] + s * li.direction[1])
                dx, dy = lj.direction[0] - li.direction[0], lj.direction[1] - li.direction[1]
                n = math.hypot(dx, dy)
                proj.append(Line(point, (dx / n, dy / n)))
            fail, new = linear_program2(proj, radius, (-li.direction[1], li.direction[0]), True)
            if fail >= len(proj):
                result = new
            distance = _det(*li.direction, li.point[0] - result[0], li.point[1] - result[1])
    return result


def solve_velocity(
    hard: list[Line], soft: list[Line], v_pref: np.ndarray, v_max: float
) -> tuple[np.ndarray, bool]:
    """Velocity closest to ``v_pref`` within ``|v| <= v_max``, the ``hard`` lines and the ``soft`` lines.

    Returns ``(float64 [2], feasible)``; when the soft lines cannot all hold, ``linear_program3`` minimises
    their largest violation (``feasible`` False).
    """
    lines = hard + soft
    opt = (float(v_pref[0]), float(v_pref[1]))
    fail, result = linear_program2(lines, v_max, opt, False)
    if fail < len(lines):
        result = linear_program3(lines, len(hard), fail, v_max, result)
        return np.array(result), False
    return np.array(result), True


@dataclass(frozen=True)
class ORCAConfig:
    """Holonomic ORCA parameters (SI units)."""

    radius: float = 0.3
    v_max: float = 1.0
    tau: float = 3.0
    tau_obst: float = 1.0
    dt: float = 0.2
    neighbor_dist: float = 10.0
    max_neighbors: int = 10


def orca_lines(
    i: int,
    positions: np.ndarray,
    velocities: np.ndarray,
    radii: np.ndarray,
    reciprocal: np.ndarray,
    tau: float,
    dt: float,
    neighbor_dist: float,
    max_neighbors: int,
) -> list[Line]:
    """ORCA lines of agent ``i`` from its nearest neighbours (sorted by distance).

    ``positions``/``velocities``: float ``[N, 2]``; ``radii``: ``[N]``; ``reciprocal``: bool ``[N]``, False
    for agents that do not avoid (agent ``i`` then takes full responsibility).
    """
    rel = positions - positions[i]
    dist = np.hypot(rel[:, 0], rel[:, 1])
    dist[i] = np.inf
    order = np.argsort(dist, kind="stable")
    lines = []
    for j in order[:max_neighbors]:
        if dist[j] >= neighbor_dist:
            break
        lines.append(
            agent_line(
                rel[j],
                velocities[i] - velocities[j],
                velocities[i],
                float(radii[i] + radii[j]),
                tau,
                dt,
                0.5 if reciprocal[j] else 1.0,
            )
        )
    return lines


def orca_step(
    positions: np.ndarray,
    velocities: np.ndarray,
    preferred: np.ndarray,
    config: ORCAConfig,
    walls: np.ndarray | None = None,
) -> np.ndarray:
    """New holonomic velocities ``float64 [N, 2]`` for all agents (all reciprocal), from the old ones."""
    positions = np.asarray(positions, dtype=np.float64)
    velocities = np.asarray(velocities, dtype=np.float64)
    n = len(positions)
    radii = np.full(n, config.radius)
    reciprocal = np.ones(n, dtype=bool)
    walls = np.zeros((0, 4)) if walls is None else np.asarray(walls, dtype=np.float64)
    out = np.zeros((n, 2))
    for i in range(n):
        soft = orca_lines(
            i,
            positions,
            velocities,
            radii,
            reciprocal,
            config.tau,
            config.dt,
            config.neighbor_dist,
            config.max_neighbors,
        )
        hard = box_lines(
            positions[i],
            config.radius,
            walls,
            config.tau_obst,
            config.dt,
            config.tau_obst * config.v_max + config.radius,
        )
        out[i], _ = solve_velocity(hard, soft, preferred[i], config.v_max)
    return out
