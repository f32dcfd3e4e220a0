"""DWA: limits, reaching a free-space goal, recovery when boxed in, slowly accelerating robots, the reference
implementations' low limits (clearance and goal on three courses), the Jackal's and TurtleBot's plans of
before.

``fixtures/dwa_plans.json`` holds the plans of the planner before its low-acceleration changes (commit
e821897) for the Jackal and the TurtleBot: seeded states and closed-loop drives in cluttered rooms
(:func:`scene`).
"""

import json
import math
from pathlib import Path

import numpy as np
import pytest

from navformer_rl.envs.robots import JACKAL, TURTLEBOT3
from navformer_rl.experts.dwa import ClearanceMap, DWAConfig, DWAPlanner
from navformer_rl.experts.policies import dwa_config

RES = 0.1
PLANS = Path(__file__).parent / "fixtures" / "dwa_plans.json"


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
REFERENCE = DWAConfig(
    v_max=1.0, w_max=math.radians(40), a_max=0.2, alpha_max=math.radians(40), dt=0.1, robot_radius=1.0
)
"""The limits of the common reference implementations of DWA (PythonRobotics): 0.2 m/s^2, 40 deg/s^2, a 1 m
radius, 0.1 s."""
TURTLEBOT = {"v_max": 0.26, "w_max": 1.82, "a_max": 1.0, "alpha_max": 3.0, "robot_radius": 0.2}


def test_thresholds_follow_the_limits():
    assert DWAConfig().forward_speed == pytest.approx(0.05)
    assert DWAConfig().safety_horizon == pytest.approx(1.6)
    assert DWAConfig().reach == pytest.approx(1.6)
    assert SLOW.forward_speed == pytest.approx(0.01)  # half of a_max * dt
    # one period, then the 2.5 m braking distance from 1 m/s
    assert SLOW.safety_horizon == pytest.approx(2.6)
    assert SLOW.reach == pytest.approx(2.6)
    np.testing.assert_allclose(SLOW.check_horizon(np.array([0.0, 0.02, 0.5])), [8.0, 4.0, 2.6])
    assert SLOW.rollout_step == pytest.approx(0.1)  # a rollout step is never longer than a period
    assert SLOW.slow_dynamics and SLOW.backoff_periods == 20
    assert not DWAConfig().slow_dynamics and DWAConfig().lookahead == 0.0
    assert not dwa_config(TURTLEBOT3, 0.2).slow_dynamics
    # a 1 m robot's map measures clearance up to its safety distance (the default cap is 0.9 m)
    assert REFERENCE.clearance_range == pytest.approx(1.12) and DWAConfig().clearance_range == 0.9
    assert REFERENCE.lookahead == pytest.approx(1.12 + 2.5)


def test_a_map_capped_below_the_safety_distance_is_refused():
    occ = room(6.0)
    clear = ClearanceMap(occ, RES, (0.0, 0.0), (3.0, 3.0), 3.0, REFERENCE.clearance_cap)
    with pytest.raises(ValueError, match="safety distance"):
        DWAPlanner(REFERENCE).plan(np.array([3.0, 3.0, 0.0]), np.zeros(2), np.array([5.0, 3.0]), clear)


def test_slowly_accelerating_robot_leaves_rest_and_reaches_goal():
    occ = room(8.0)
    pose, min_clear, recovered = drive(occ, (1.5, 1.5, math.pi / 8), np.array([6.0, 5.5]), 300, SLOW)
    assert np.hypot(*(pose[:2] - [6.0, 5.5])) < 0.25
    assert recovered == 0
    assert min_clear >= SLOW.robot_radius + SLOW.safety_margin


def test_slowly_braking_robot_stops_before_the_wall():
    """Goal beyond the wall: at 0.2 m/s^2 the robot needs 2.5 m to stop from full speed and must plan for
    it."""
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
    """Commands of the planner before its thresholds followed the limits
    (both robots reach 0.05 m/s in a step)."""
    cfg = DWAConfig(**robot)
    pose = np.array(pose)
    clear = ClearanceMap(room(6.0), RES, (0.0, 0.0), pose[:2], 3.0, cfg.clearance_cap)
    res = DWAPlanner(cfg).plan(pose, np.array(velocity), np.array(goal), clear)
    v, w, recovering = expected
    assert (res.v, res.w, res.recovering) == (pytest.approx(v), pytest.approx(w), recovering)


# ---------------------------------------------------------------- the reference limits, point obstacles
POINTS_ORIGIN = (-6.0, -6.0)
POINTS_SIZE = 24.0
SCATTERED = [(-1, -1), (0, 2), (4, 2), (5, 4), (5, 5), (5, 6), (5, 9), (8, 9), (7, 9), (8, 10), (9, 11)]
SCATTERED += [(12, 13), (12, 12), (15, 15), (13, 13)]
"""PythonRobotics' DWA course: point obstacles between the start (0, 0) and the goal (10, 10)."""


def time_bound(cfg: DWAConfig, distance: float, detour: float = 1.0) -> float:
    """Seconds to reach a goal ``distance`` away along a path ``detour`` times longer: the path at ``v_max``,
    plus reaching and leaving ``v_max``, plus turning about at ``w_max``, plus reaching and leaving
    ``w_max``."""
    return (
        detour * distance / cfg.v_max
        + cfg.v_max / cfg.a_max
        + math.pi / cfg.w_max
        + cfg.w_max / cfg.alpha_max
    )


def drive_among_points(cfg, points, start, goal, seconds):
    """Drive from ``start`` to within ``robot_radius`` of ``goal`` among point obstacles
    (grid cells of 0.1 m).

    Checks the window's limits at every step. Returns ``(steps or None, the least centre-to-point distance,
    recovery steps)``."""
    n = int(round(POINTS_SIZE / RES))
    occ = np.zeros((n, n), dtype=bool)
    for x, y in points:
        occ[math.floor((y - POINTS_ORIGIN[1]) / RES), math.floor((x - POINTS_ORIGIN[0]) / RES)] = True
    obstacles = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    planner = DWAPlanner(cfg)
    pose, goal = np.array(start, dtype=np.float64), np.asarray(goal, dtype=np.float64)
    vel = np.zeros(2)
    least, recovered = np.inf, 0
    for step in range(1, int(round(seconds / cfg.dt)) + 1):
        clear = ClearanceMap(occ, RES, POINTS_ORIGIN, pose[:2], cfg.map_half_size, cfg.clearance_range)
        res = planner.plan(pose, vel, goal, clear)
        assert abs(res.v - vel[0]) <= cfg.a_max * cfg.dt + 1e-9
        assert abs(res.w - vel[1]) <= cfg.alpha_max * cfg.dt + 1e-9
        recovered += res.recovering
        vel = np.array([res.v, res.w])
        pose[2] += vel[1] * cfg.dt
        pose[0] += vel[0] * math.cos(pose[2]) * cfg.dt
        pose[1] += vel[0] * math.sin(pose[2]) * cfg.dt
        if len(obstacles):
            least = min(least, float(np.hypot(*(obstacles - pose[:2]).T).min()))
        if np.hypot(*(pose[:2] - goal)) < cfg.robot_radius:
            return step, least, recovered
    return None, least, recovered


def test_reference_limits_reach_a_free_space_goal():
    bound = time_bound(REFERENCE, math.hypot(10, 10))
    steps, _, _ = drive_among_points(REFERENCE, [], (0.0, 0.0, math.pi / 8), (10.0, 10.0), bound)
    assert steps is not None


def test_reference_limits_turn_about_for_a_goal_behind_without_touching_the_points_ahead():
    """Facing a row of points 2.5 m ahead (the robot's front 1.5 m from it), the goal 6 m behind."""
    row = [(2.5, y) for y in np.arange(-2.0, 2.01, 0.5)]
    bound = time_bound(REFERENCE, 6.0)
    steps, least, _ = drive_among_points(REFERENCE, row, (0.0, 0.0, 0.0), (-6.0, 1.0), bound)
    assert steps is not None
    assert least >= REFERENCE.robot_radius


def test_reference_limits_cross_a_scattered_field_with_clearance():
    """The reported failure: the planner brushed a point closer than its radius,
    then never reached the goal."""
    bound = time_bound(REFERENCE, math.hypot(10, 10), detour=3.0)  # takes 35.5 s here
    steps, least, _ = drive_among_points(REFERENCE, SCATTERED, (0.0, 0.0, math.pi / 8), (10.0, 10.0), bound)
    assert least >= REFERENCE.robot_radius
    assert steps is not None


def test_jackal_limits_cross_the_same_field():
    cfg = DWAConfig(robot_radius=1.0)
    bound = time_bound(cfg, math.hypot(10, 10), detour=2.0)
    steps, least, recovered = drive_among_points(cfg, SCATTERED, (0.0, 0.0, math.pi / 8), (10.0, 10.0), bound)
    assert steps is not None and least >= cfg.robot_radius and recovered == 0


# ------------------------------------------------------- the Jackal's and TurtleBot's plans of before
def scene(seed: int) -> np.ndarray:
    """An 8 m room (0.1 m cells) with a seeded clutter of boxes and single occupied cells."""
    rng = np.random.default_rng(seed)
    n = 80
    occ = np.zeros((n, n), dtype=bool)
    occ[0, :] = occ[-1, :] = occ[:, 0] = occ[:, -1] = True
    for _ in range(rng.integers(3, 12)):
        r, c = rng.integers(2, n - 6, 2)
        h, w = rng.integers(1, 6, 2)
        occ[r : r + h, c : c + w] = True
    for _ in range(rng.integers(0, 30)):
        r, c = rng.integers(1, n - 1, 2)
        occ[r, c] = True
    return occ


def random_states(seed: int, spec, n: int):
    """``n`` seeded (pose, velocity, goal) in the 8 m room, velocities within the robot's limits."""
    rng = np.random.default_rng(1000 + seed)
    for _ in range(n):
        pose = np.array([rng.uniform(0.3, 7.7), rng.uniform(0.3, 7.7), rng.uniform(-math.pi, math.pi)])
        vel = np.array([rng.uniform(-0.2, spec.v_max), rng.uniform(-spec.w_max, spec.w_max)])
        yield pose, vel, rng.uniform(0.5, 7.5, 2)


@pytest.mark.parametrize("spec", [JACKAL, TURTLEBOT3], ids=lambda spec: spec.name)
def test_jackal_and_turtlebot_plans_equal_the_recorded_ones(spec):
    """15 seeded states and a 30-step drive to (7, 7) in each of 4 cluttered rooms, as recorded."""
    expected = json.loads(PLANS.read_text())[spec.name]
    cfg = dwa_config(spec, 0.2)
    plans = []
    for seed in range(4):
        occ = scene(seed)

        def clear_at(xy, occ=occ):
            return ClearanceMap(occ, RES, (0.0, 0.0), xy, cfg.map_half_size, cfg.clearance_range)

        for pose, vel, goal in random_states(seed, spec, 15):
            res = DWAPlanner(cfg).plan(pose, vel, goal, clear_at(pose[:2]))
            plans.append([res.v, res.w, res.recovering])
        planner = DWAPlanner(cfg)
        pose, vel, goal = np.array([1.0, 1.0, 0.0]), np.zeros(2), np.array([7.0, 7.0])
        for _ in range(30):
            res = planner.plan(pose, vel, goal, clear_at(pose[:2]))
            plans.append([res.v, res.w, res.recovering])
            vel = np.array([res.v, res.w])
            pose[2] += vel[1] * cfg.dt
            pose[0] += vel[0] * math.cos(pose[2]) * cfg.dt
            pose[1] += vel[0] * math.sin(pose[2]) * cfg.dt
    assert len(plans) == len(expected)
    for index, (got, want) in enumerate(zip(plans, expected, strict=True)):
        assert got == [pytest.approx(want[0], abs=1e-9), pytest.approx(want[1], abs=1e-9), want[2]], index
