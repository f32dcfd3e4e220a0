"""DWA: limits, reaching a free-space goal, recovery when boxed in, slowly accelerating robots."""

import math

import numpy as np
import pytest

from navformer_rl.experts.dwa import ClearanceMap, DWAConfig, DWAPlanner

RES = 0.1


def room(size_m: float) -> np.ndarray:
    n = int(round(size_m / RES))
    occ = np.zeros((n, n), dtype=bool)
    occ[0, :] = occ[-1, :] = occ[:, 0] = occ[:, -1] = True
    return occ


def drive(occ, pose, goal, steps, cfg=None):
    cfg = cfg or DWAConfig()
    planner = DWAPlanner(cfg)
    pose = np.array(pose, dtype=np.float64)
    vel = np.zeros(2)
    min_clear = np.inf
    recovered = 0
    for _ in range(steps):
        clear = ClearanceMap(occ, RES, (0.0, 0.0), pose[:2], 3.0, cfg.clearance_cap)
        res = planner.plan(pose, vel, np.asarray(goal, dtype=np.float64), clear)
        assert abs(res.v - vel[0]) <= cfg.a_max * cfg.dt + 1e-9
        assert abs(res.w - vel[1]) <= cfg.alpha_max * cfg.dt + 1e-9
        assert -cfg.backoff_speed - 1e-9 <= res.v <= cfg.v_max + 1e-9 and abs(res.w) <= cfg.w_max + 1e-9
        recovered += res.recovering
        vel = np.array([res.v, res.w])
        pose[2] += vel[1] * cfg.dt
        pose[0] += vel[0] * math.cos(pose[2]) * cfg.dt
        pose[1] += vel[0] * math.sin(pose[2]) * cfg.dt
        min_clear = min(min_clear, float(clear(pose[None, :2])[0]))
        if np.hypot(*(pose[:2] - goal)) < 0.25:
            break
    return pose, min_clear, recovered


def test_window_respects_limits_from_many_states():
    cfg = DWAConfig()
    planner = DWAPlanner(cfg)
    rng = np.random.default_rng(0)
    for _ in range(50):
        v0, w0 = rng.uniform(-0.2, 1.0), rng.uniform(-1.5, 1.5)
        vs, ws = planner.window(np.array([v0, w0]))
        assert vs.min() >= max(0.0, v0 - 0.4) - 1e-12 and vs.max() <= min(1.0, v0 + 0.4) + 1e-12
        assert ws.min() >= max(-1.5, w0 - 0.8) - 1e-12 and ws.max() <= min(1.5, w0 + 0.8) + 1e-12


def test_reaches_free_space_goal():
    occ = room(8.0)
    pose, min_clear, _ = drive(occ, (1.5, 1.5, math.pi), np.array([6.0, 5.5]), 120)
    assert np.hypot(*(pose[:2] - [6.0, 5.5])) < 0.25
    assert min_clear >= 0.30


def test_recovery_when_every_forward_sample_is_blocked():
    """Nose 0.25 m from a wall (inside the 0.36 m safety distance), goal straight through the wall."""
    occ = room(6.0)
    cfg = DWAConfig()
    pose = np.array([5.66, 3.0, 0.0])
    clear = ClearanceMap(occ, RES, (0.0, 0.0), pose[:2], 3.0, cfg.clearance_cap)
    assert clear(pose[None, :2])[0] == pytest.approx(0.25)
    res = DWAPlanner(cfg).plan(pose, np.zeros(2), np.array([7.0, 3.0]), clear)
    assert res.recovering
    assert res.v == pytest.approx(-cfg.backoff_speed) and res.w == 0.0  # backing off gains clearance


def test_recovers_and_reaches_goal_behind_it():
    """Boxed against a wall facing away from the goal: recovery, then the goal is reached."""
    occ = room(6.0)
    pose, min_clear, recovered = drive(occ, (5.66, 3.0, 0.0), np.array([2.0, 3.5]), 150)
    assert recovered > 0
    assert np.hypot(*(pose[:2] - [2.0, 3.5])) < 0.25
    assert min_clear >= 0.25


def test_clearance_map_values():
    occ = np.zeros((40, 40), dtype=bool)
    occ[:, 30] = True  # wall cells covering x in [3.0, 3.1)
    cm = ClearanceMap(occ, RES, (0.0, 0.0), (2.0, 2.0), 2.0, 1.0)
    assert cm(np.array([[2.55, 2.0]]))[0] == pytest.approx(0.45)
    assert cm(np.array([[0.5, 2.0]]))[0] == pytest.approx(1.0)  # capped


# PythonRobotics' classic limits: 0.2 m/s^2 x 0.1 s = 0.02 m/s of speed change per step.
SLOW = DWAConfig(v_max=1.0, w_max=math.radians(40), a_max=0.2, alpha_max=math.radians(40), dt=0.1)
TURTLEBOT = {"v_max": 0.26, "w_max": 1.82, "a_max": 1.0, "alpha_max": 3.0, "robot_radius": 0.2}


def test_thresholds_follow_the_limits():
    assert DWAConfig().forward_speed == pytest.approx(0.05)
    assert DWAConfig().safety_horizon == pytest.approx(1.6)
    assert DWAConfig().reach == pytest.approx(1.6)
    assert SLOW.forward_speed == pytest.approx(0.01)  # half of a_max * dt
    assert SLOW.safety_horizon == pytest.approx(2.5)  # covers the 2.5 m braking distance from 1 m/s
    assert SLOW.reach == pytest.approx(2.5)
    np.testing.assert_allclose(SLOW.check_horizon(np.array([0.0, 0.02, 0.5])), [8.0, 4.0, 2.5])


def test_slowly_accelerating_robot_leaves_rest_and_reaches_goal():
    occ = room(8.0)
    pose, min_clear, recovered = drive(occ, (1.5, 1.5, math.pi / 8), np.array([6.0, 5.5]), 300, SLOW)
    assert np.hypot(*(pose[:2] - [6.0, 5.5])) < 0.25
    assert recovered == 0
    assert min_clear >= SLOW.robot_radius + SLOW.safety_margin


def test_slowly_braking_robot_stops_before_the_wall():
    """Goal beyond the wall: at 0.2 m/s^2 the robot needs 2.5 m to stop from full speed and must plan for it."""
    occ = room(8.0)
    pose, min_clear, _ = drive(occ, (1.0, 4.0, 0.0), np.array([9.0, 4.0]), 300, SLOW)
    assert min_clear >= SLOW.robot_radius
    assert pose[0] > 7.0  # it did drive up to the wall


@pytest.mark.parametrize(
    ("robot", "pose", "velocity", "goal", "expected"),
    [
        ({}, (1.5, 1.5, 0.3), (0.0, 0.0), (4.5, 4.0), (0.4, 0.22857142857142865, False)),
        ({}, (3.0, 3.0, 2.0), (0.6, -0.4), (1.0, 1.0), (0.2, 0.4, False)),
        ({}, (5.2, 3.0, 0.0), (0.5, 0.2), (1.0, 3.5), (0.1, 1.0, False)),
        ({}, (5.66, 3.0, 0.0), (0.0, 0.0), (7.0, 3.0), (-0.2, 0.0, True)),
        ({}, (1.0, 4.5, -1.0), (0.3, 1.0), (5.0, 1.0), (0.7, 0.2, False)),
        ({}, (4.9, 1.0, -0.3), (1.0, 0.0), (5.0, 5.0), (0.6, 0.8, True)),
        (TURTLEBOT, (1.5, 1.5, 0.3), (0.0, 0.0), (4.5, 4.0), (0.2, 0.25714285714285723, False)),
        (TURTLEBOT, (3.0, 3.0, 2.0), (0.6, -0.4), (1.0, 1.0), (0.26, 0.2, False)),
        (TURTLEBOT, (5.66, 3.0, 0.0), (0.0, 0.0), (7.0, 3.0), (-0.2, 0.0, True)),
        (TURTLEBOT, (4.9, 1.0, -0.3), (1.0, 0.0), (5.0, 5.0), (0.26, 0.6, False)),
    ],
)
def test_jackal_and_turtlebot_plans_are_unchanged(robot, pose, velocity, goal, expected):
    """Commands of the planner before its thresholds followed the limits (both robots reach 0.05 m/s in a step)."""
    cfg = DWAConfig(**robot)
    pose = np.array(pose)
    clear = ClearanceMap(room(6.0), RES, (0.0, 0.0), pose[:2], 3.0, cfg.clearance_cap)
    res = DWAPlanner(cfg).plan(pose, np.array(velocity), np.array(goal), clear)
    v, w, recovering = expected
    assert (res.v, res.w, res.recovering) == (pytest.approx(v), pytest.approx(w), recovering)
