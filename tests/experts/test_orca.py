"""ORCA / NH-ORCA: hand-derived one-step half-planes, swaps that must arrive without overlap, determinism."""

import math

import numpy as np
import pytest

from navformer_rl.experts.nh_orca import (
    NHORCA,
    NHORCAConfig,
    ahv_polygon,
    max_holonomic_speed,
    tracking_command,
    v_limited_speed,
    v_star,
)
from navformer_rl.experts.orca import (
    Line,
    ORCAConfig,
    agent_line,
    box_lines,
    orca_step,
    solve_velocity,
)

SQ15 = math.sqrt(15.0)


def test_head_on_half_planes_by_hand():
    """A at (-2,0) v=(1,0), B at (2,0) v=(-1,0), R=1, tau=2: w = 0, right leg.

    leg = sqrt(15); d_A = (-sqrt15/4, 1/4); u = (v_rel.d) d - v_rel = (-1/8, -sqrt15/8);
    point_A = v_A + u/2 = (15/16, -sqrt15/16). B gets the point reflection.
    """
    la = agent_line(np.array([4.0, 0.0]), np.array([2.0, 0.0]), np.array([1.0, 0.0]), 1.0, 2.0, 0.25)
    lb = agent_line(np.array([-4.0, 0.0]), np.array([-2.0, 0.0]), np.array([-1.0, 0.0]), 1.0, 2.0, 0.25)
    assert la.direction == pytest.approx((-SQ15 / 4, 0.25))
    assert la.point == pytest.approx((15 / 16, -SQ15 / 16))
    assert lb.direction == pytest.approx((SQ15 / 4, -0.25))
    assert lb.point == pytest.approx((-15 / 16, SQ15 / 16))
    va, ok = solve_velocity([], [la], np.array([1.0, 0.0]), 1.0)
    vb, _ = solve_velocity([], [lb], np.array([-1.0, 0.0]), 1.0)
    assert ok
    assert va == pytest.approx([15 / 16, -SQ15 / 16])  # both veer to their right, mirror images
    assert vb == pytest.approx(-va)


def test_cut_off_circle_branch_by_hand():
    """At rest, B 2 m ahead, R=1, tau=2: w = -p/tau, (w.p)^2 = 4 > R^2 |w|^2 = 1 -> cut-off circle.

    u = (R/tau - |w|) w_hat = (1/2, 0); point = u/2 = (1/4, 0); direction (0, 1): v_x <= 1/4.
    (The buggy test ``w.p > R^2|w|^2`` would take a leg instead.)
    """
    line = agent_line(np.array([2.0, 0.0]), np.zeros(2), np.zeros(2), 1.0, 2.0, 0.25)
    assert line.direction == pytest.approx((0.0, 1.0))
    assert line.point == pytest.approx((0.25, 0.0))
    v, _ = solve_velocity([], [line], np.array([1.0, 0.0]), 1.0)
    assert v == pytest.approx([0.25, 0.0])


def test_colliding_branch_uses_time_step():
    """Overlapping by 0.2 m (|p| = 0.8 < R = 1), at rest, dt = 0.25: push apart at (R - |p|)/dt / 2 each."""
    line = agent_line(np.array([0.8, 0.0]), np.zeros(2), np.zeros(2), 1.0, 3.0, 0.25)
    v, _ = solve_velocity([], [line], np.zeros(2), 2.0)
    assert v == pytest.approx([-(1.0 - 0.8) / 0.25 / 2, 0.0])


def test_linear_program3_balances_infeasible_lines():
    """v_x >= 0.5 and v_x <= -0.5 cannot both hold: the least-violation velocity has v_x = 0."""
    l1 = Line((0.5, 0.0), (0.0, -1.0))
    l2 = Line((-0.5, 0.0), (0.0, 1.0))
    v, feasible = solve_velocity([], [l1, l2], np.array([0.3, 0.4]), 1.0)
    assert not feasible
    assert v[0] == pytest.approx(0.0, abs=1e-9)


def test_box_line_by_hand():
    """Wall box x in [2, 3]; robot at x = 0.5, r = 0.5: gap 1 m, tau_obst 2 -> v_x <= 0.5."""
    lines = box_lines(np.array([0.5, 0.0]), 0.5, np.array([[2.5, 0.0, 0.5, 5.0]]), 2.0, 0.2, 5.0)
    assert len(lines) == 1
    v, _ = solve_velocity(lines, [], np.array([1.0, 0.3]), 2.0)
    assert v == pytest.approx([0.5, 0.3])


def run_holonomic(starts, goals, seed, steps=400, noise=0.02):
    cfg = ORCAConfig(radius=0.3, v_max=1.0, tau=3.0, dt=0.2)
    rng = np.random.default_rng(seed)
    pos = np.array(starts, dtype=np.float64)
    goals = np.array(goals, dtype=np.float64)
    vel = np.zeros_like(pos)
    min_gap = np.inf
    for _ in range(steps):
        to_goal = goals - pos
        dist = np.linalg.norm(to_goal, axis=1, keepdims=True)
        pref = to_goal / np.maximum(dist, 1.0)  # unit speed, slowing within 1 m
        angle = rng.uniform(0, 2 * np.pi, len(pos))
        pref += noise * rng.uniform(0, 1, (len(pos), 1)) * np.stack([np.cos(angle), np.sin(angle)], 1)
        vel = orca_step(pos, vel, pref, cfg)
        pos = pos + vel * cfg.dt
        d = np.linalg.norm(pos[:, None] - pos[None], axis=-1) + np.eye(len(pos)) * 1e9
        min_gap = min(min_gap, d.min() - 2 * cfg.radius)
        if np.all(np.linalg.norm(goals - pos, axis=1) < 0.05):
            break
    return pos, min_gap


def circle(n, radius=4.0):
    a = np.arange(n) * 2 * np.pi / n
    starts = np.stack([radius * np.cos(a), radius * np.sin(a)], 1)
    return starts, -starts


@pytest.mark.parametrize("n", [2, 4, 6])
def test_circle_swap_arrives_without_overlap(n):
    starts, goals = circle(n)
    pos, min_gap = run_holonomic(starts, goals, seed=n)
    assert np.all(np.linalg.norm(pos - goals, axis=1) < 0.05)
    assert min_gap > -1e-6


def test_determinism_with_seeded_generator():
    starts, goals = circle(5)
    a = run_holonomic(starts, goals, seed=3, steps=60)
    b = run_holonomic(starts, goals, seed=3, steps=60)
    assert np.array_equal(a[0], b[0]) and a[1] == b[1]


def test_v_star_and_tracking_by_hand():
    assert v_star(1.0, 0.0) == 1.0
    assert v_star(1.0, 1e-9) == pytest.approx(1.0)
    assert v_star(2.0, math.pi / 2) == pytest.approx(2.0 * math.pi / 4)
    assert v_star(1.0, -math.pi / 2) == pytest.approx(math.pi / 4)  # even in theta
    assert v_star(1.0, math.pi) == pytest.approx(0.0, abs=1e-12)
    v, w = tracking_command(np.array([0.0, 0.5]), 0.0, T=0.4, v_max=1.0, w_max=1.5)
    assert w == pytest.approx(1.5)  # theta/T = 3.93 clipped to w_max
    assert v == pytest.approx(0.5 * math.pi / 4)
    v, w = tracking_command(np.array([0.8, 0.0]), 0.0, T=0.4, v_max=1.0, w_max=1.5)
    assert (v, w) == (pytest.approx(0.8), 0.0)


def test_max_holonomic_speed_regimes_by_hand():
    T, E, vmax, wmax = 0.4, 0.1, 1.0, 1.5
    # rotation-limited: |theta|/T = 2.5 > 1.5 -> E w_max / theta = 0.15
    assert max_holonomic_speed(1.0, T, E, vmax, wmax) == pytest.approx(0.15)
    # unconstrained at theta = 0.5 with a tiny error budget: (E/T) sqrt(2(1-c)/(2(1-c)-s^2))
    th, e = 0.5, 0.01
    c, s = math.cos(th), math.sin(th)
    expected = (e / T) * math.sqrt(2 * (1 - c) / (2 * (1 - c) - s * s))
    assert max_holonomic_speed(th, T, e, vmax, wmax) == pytest.approx(expected)
    # linear-speed-limited: the larger root of the quadratic, checked by substitution, and capped at v_max
    vm, e = 0.5, 0.2
    u = v_limited_speed(th, T, e, vm)
    residual = T * T * u * u - 2 * T * T * vm * (s / th) * u + 2 * T * T * (1 - c) / th**2 * vm * vm - e**2
    assert residual == pytest.approx(0.0, abs=1e-12)
    assert u > vm * s / th  # larger root
    assert max_holonomic_speed(th, T, e, vm, wmax) == pytest.approx(min(vm, u))
    poly = ahv_polygon(0.3, T, E, vmax, wmax)
    area2 = np.sum(poly[:, 0] * np.roll(poly[:, 1], -1) - np.roll(poly[:, 0], -1) * poly[:, 1])
    assert area2 > 0  # counter-clockwise


@pytest.mark.parametrize("n", [2, 4, 6])
def test_nh_orca_unicycle_circle_swap(n):
    """Unicycles swap on a 3.5 m circle; gaps measured on the actual unicycle poses."""
    cfg = NHORCAConfig()
    starts, goals = circle(n, radius=3.5)
    poses = np.concatenate([starts, np.arctan2(-starts[:, 1:2], -starts[:, 0:1])], axis=1)
    vel = np.zeros((n, 2))
    planner = NHORCA(cfg)
    rng = np.random.default_rng(0)
    min_gap = np.inf
    for _ in range(300):
        to_goal = goals - poses[:, :2]
        dist = np.linalg.norm(to_goal, axis=1, keepdims=True)
        angle = rng.uniform(0, 2 * np.pi, n)
        noise = 0.02 * rng.uniform(0, 1, (n, 1)) * np.stack([np.cos(angle), np.sin(angle)], 1)
        pref = to_goal / np.maximum(dist, 1.0) + noise
        active = dist[:, 0] > 0.1
        cmd = planner.step(poses, vel, pref, active, np.zeros((0, 4)))
        assert np.all(cmd[:, 0] <= cfg.v_max + 1e-9) and np.all(np.abs(cmd[:, 1]) <= cfg.w_max + 1e-9)
        assert np.all(np.abs(cmd - vel) <= np.array([cfg.a_max, cfg.alpha_max]) * cfg.dt + 1e-9)
        vel = cmd
        poses[:, 2] += vel[:, 1] * cfg.dt
        poses[:, 0] += vel[:, 0] * np.cos(poses[:, 2]) * cfg.dt
        poses[:, 1] += vel[:, 0] * np.sin(poses[:, 2]) * cfg.dt
        d = np.linalg.norm(poses[:, None, :2] - poses[None, :, :2], axis=-1) + np.eye(n) * 1e9
        min_gap = min(min_gap, d.min() - 2 * cfg.radius)
        if not active.any():
            break
    assert np.all(np.linalg.norm(goals - poses[:, :2], axis=1) < 0.2)
    assert min_gap > 0.0
