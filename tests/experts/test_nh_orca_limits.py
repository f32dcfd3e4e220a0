"""NH-ORCA limits: the wall safety clamp wins over the acceleration window; mixed teams plan per robot."""

import numpy as np
import pytest

from navformer_rl.envs.robots import JACKAL, TURTLEBOT3
from navformer_rl.envs.sim import Simulator
from navformer_rl.envs.world import WorldConfig, generate_world
from navformer_rl.experts.nh_orca import NHORCA, NHORCAConfig, limit_command
from navformer_rl.experts.orca import box_lines
from navformer_rl.experts.policies import (
    ExplorationExpert,
    FCAController,
    NHORCAExpert,
    nh_orca_config,
    nh_orca_configs,
)

RIGHT_WALL = np.array([[5.5, 2.5, 0.5, 2.5]])
"""A box whose left face is the line x = 5.0."""


def test_safety_clamp_is_applied_after_the_acceleration_window():
    """Heading at a wall 0.2 m beyond the ORCA radius (0.43 m) at 1 m/s: the wall half-plane allows
    v <= 0.2 / tau_obst = 0.2 m/s, the acceleration window [0.6, 1.4] would raise it to 0.6 m/s."""
    cfg = NHORCAConfig()
    radius = cfg.radius + cfg.tracking_error + cfg.safety
    x = 5.0 - radius - 0.2
    poses = np.array([[x, 2.5, 0.0]])
    velocities = np.array([[1.0, 0.0]])
    command = NHORCA(cfg).step(poses, velocities, np.array([[1.0, 0.0]]), np.array([True]), RIGHT_WALL)
    assert command[0, 0] == pytest.approx(0.2, abs=1e-6)
    walls = box_lines(poses[0, :2], radius, RIGHT_WALL, cfg.tau_obst, cfg.dt, 2.0, cfg.radius)
    v, w = limit_command(0.2, 0.0, velocities[0], 0.0, walls, cfg)
    assert v == pytest.approx(0.2, abs=1e-9) and w == 0.0  # clamp last: 0.6 from the window is lowered
    v, w = limit_command(1.4, 1.5, np.array([0.1, 0.0]), 0.0, [], cfg)
    assert (v, w) == pytest.approx((0.5, 0.8))  # no wall: the acceleration window alone


MIXED = [nh_orca_config(JACKAL, 0.2), nh_orca_config(TURTLEBOT3, 0.2)]


def test_each_robot_plans_within_its_own_speed_limits():
    """A Jackal (v0 0.8) and a TurtleBot3 (v0 0.26) both want 1 m/s straight ahead in free space: each gets
    min(its v_max, v0 + its a_max dt) - 1.0 and 0.26 m/s - before any normalisation or clipping."""
    poses = np.array([[1.0, 1.0, 0.0], [1.0, 4.0, 0.0]])
    velocities = np.array([[0.8, 0.0], [TURTLEBOT3.v_max, 0.0]])
    pref = np.array([[1.0, 0.0], [1.0, 0.0]])
    command = NHORCA(MIXED).step(poses, velocities, pref, np.ones(2, bool), np.zeros((0, 4)))
    assert command[:, 0] == pytest.approx([JACKAL.v_max, TURTLEBOT3.v_max])
    shared = NHORCA(MIXED[0]).step(poses, velocities, pref, np.ones(2, bool), np.zeros((0, 4)))
    assert shared[1, 0] > TURTLEBOT3.v_max + 0.3  # the Jackal's limits would plan 0.66 m/s


def test_orca_pairs_use_each_robot_radius():
    """Side by side 0.8 m apart at the same velocity: per-robot inflated radii 0.43 + 0.33 = 0.76 m leave
    them apart, so both keep their preferred velocity; two Jackal radii (0.86 m) would push them apart."""
    poses = np.array([[2.0, 2.0, 0.0], [2.0, 2.8, 0.0]])
    velocities = np.array([[0.2, 0.0], [0.2, 0.0]])
    pref = np.array([[0.2, 0.0], [0.2, 0.0]])
    active = np.ones(2, bool)
    planner = NHORCA(MIXED)
    planner.step(poses, velocities, pref, active, np.zeros((0, 4)))
    assert planner.u == pytest.approx(pref, abs=1e-9)
    shared = NHORCA(MIXED[0])
    shared.step(poses, velocities, pref, active, np.zeros((0, 4)))
    assert shared.u[0, 1] < -0.1 and shared.u[1, 1] > 0.1  # overlapping for Jackal radii: pushed apart


def test_per_robot_configs_are_checked():
    with pytest.raises(ValueError, match="2 per-robot configs but was given 3"):
        NHORCA(MIXED).step(np.zeros((3, 3)), np.zeros((3, 2)), np.zeros((3, 2)), np.ones(3, bool), [])
    with pytest.raises(ValueError, match="sequence of them"):
        NHORCA([])
    with pytest.raises(ValueError, match="2 NH-ORCA configs given for 3 robots"):
        nh_orca_configs([JACKAL] * 3, 0.2, MIXED)
    assert nh_orca_configs([JACKAL, TURTLEBOT3], 0.2, MIXED[1]) == [MIXED[1], MIXED[1]]


@pytest.fixture(scope="module")
def mixed_team():
    """One Jackal and three TurtleBot3 in a 12.5 m arena (paper Table III's mixed team)."""
    world = generate_world(WorldConfig(size=12.5, kind="arena", n_robots=4, robot_radius=JACKAL.radius), 3)
    sim = Simulator(world, [JACKAL] + [TURTLEBOT3] * 3, textured=False)
    yield world, sim
    sim.close()


def test_experts_configure_each_robot_from_its_spec(mixed_team):
    world, sim = mixed_team
    specs = sim.robot_specs
    for expert in (NHORCAExpert(), FCAController()):
        expert.reset(world, sim, np.random.default_rng(0))
        configs = expert.planner.configs(4)
        assert [c.radius for c in configs] == [s.radius for s in specs]
        assert [(c.v_max, c.w_max, c.a_max) for c in configs] == [(s.v_max, s.w_max, s.a_max) for s in specs]
    assert [n.config.robot_radius for n in expert.navigators] == [s.radius for s in specs]
    assert expert.navigators[1].config.inflation_margin == pytest.approx(0.10)  # FCA's E + safety
    exploration = ExplorationExpert()
    exploration.reset(world, sim, np.random.default_rng(0))
    assert [d.config.v_max for d in exploration.dwas] == [s.v_max for s in specs]
    assert [n.config.robot_radius for n in exploration.navigators] == [s.radius for s in specs]


def test_mixed_team_planned_commands_respect_each_robot_limits(mixed_team):
    """The raw NH-ORCA commands of a short mixed-team rollout, before normalisation and clipping."""
    world, sim = mixed_team
    sim.set_poses(world.starts)
    expert = NHORCAExpert()
    expert.reset(world, sim, np.random.default_rng(0))
    raw, step = [], expert.planner.step
    expert.planner.step = lambda *args: raw.append(step(*args)) or raw[-1]
    for _ in range(25):
        sim.step(expert.act(sim))
    limits = np.array([(s.v_max, s.w_max) for s in sim.robot_specs])
    raw = np.array(raw)
    assert np.all(np.abs(raw) <= limits + 1e-9)
    assert raw[:, 1:, 0].max() == pytest.approx(TURTLEBOT3.v_max, abs=1e-3)  # they do reach their v_max
