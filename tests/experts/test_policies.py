"""Simulator-driven experts: reaching targets, failure labelling, determinism, interface checks."""

import numpy as np
import pytest

from navformer_rl.constants import SUCCESS_RADIUS
from navformer_rl.envs.robots import JACKAL
from navformer_rl.envs.sim import COLLISION_ROBOT, Simulator
from navformer_rl.envs.world import WorldConfig, generate_world
from navformer_rl.experts.policies import ExpertConfig, ExplorationExpert, FCAController, NHORCAExpert


def rollout(expert, world, seed, max_steps=500):
    sim = Simulator(world, JACKAL, textured=False)
    try:
        expert.reset(world, sim, np.random.default_rng(seed))
        targets = world.target_positions
        success = np.zeros(sim.n_robots, dtype=bool)
        actions_log, robot_hits = [], 0
        for _ in range(max_steps):
            active = ~success & ~expert.failed
            if not active.any():
                break
            actions = expert.act(sim, active)
            assert actions.dtype == np.float32 and actions.shape == (sim.n_robots, 2)
            assert np.all(np.abs(actions) <= 1.0) and np.all(actions[~active] == 0.0)
            actions_log.append(actions.copy())
            contacts = sim.step(actions, active)
            robot_hits += int((contacts.kind == COLLISION_ROBOT).sum())
            success |= np.hypot(*(sim.poses[:, :2] - targets).T) <= SUCCESS_RADIUS
        return success, np.array(actions_log), robot_hits
    finally:
        sim.close()


@pytest.mark.parametrize("seed", [1, 2])
def test_exploration_expert_finds_target_in_maze(seed):
    world = generate_world(WorldConfig(size=7.5, kind="maze", n_robots=1), seed)
    success, actions, _ = rollout(ExplorationExpert(), world, seed)
    assert success.all()
    assert len(actions) < 500


def test_exploration_expert_is_deterministic():
    world = generate_world(WorldConfig(size=7.5, kind="maze", n_robots=1), 5)
    _, a, _ = rollout(ExplorationExpert(), world, 5, max_steps=60)
    _, b, _ = rollout(ExplorationExpert(), world, 5, max_steps=60)
    assert np.array_equal(a, b)


def test_timeout_is_labelled_failed():
    world = generate_world(WorldConfig(size=12.5, kind="maze", n_robots=1), 0)
    expert = ExplorationExpert(ExpertConfig(max_steps=5))
    sim = Simulator(world, JACKAL, textured=False)
    try:
        expert.reset(world, sim, np.random.default_rng(0))
        for _ in range(5):
            assert not expert.failed[0]
            sim.step(expert.act(sim))
        assert expert.failed[0] and not expert.reached[0]
        assert np.array_equal(expert.act(sim), np.zeros((1, 2), dtype=np.float32))  # a failed robot stops
    finally:
        sim.close()


def test_nh_orca_team_reaches_targets_without_robot_collisions():
    world = generate_world(WorldConfig(size=12.5, kind="arena", n_robots=6), 4)
    success, _, robot_hits = rollout(NHORCAExpert(), world, 4)
    assert success.all()
    assert robot_hits == 0


def test_fca_controller_team_in_maze():
    world = generate_world(WorldConfig(size=7.5, kind="maze", n_robots=3), 2)
    success, actions, robot_hits = rollout(FCAController(), world, 2)
    assert success.all()
    assert robot_hits == 0


def test_bad_inputs_raise_value_error():
    world = generate_world(WorldConfig(size=7.5, kind="maze", n_robots=1), 0)
    sim = Simulator(world, JACKAL, textured=False)
    try:
        expert = ExplorationExpert()
        with pytest.raises(ValueError, match="Generator"):
            expert.reset(world, sim, 0)
        expert.reset(world, sim, np.random.default_rng(0))
        with pytest.raises(ValueError, match="active"):
            expert.act(sim, np.ones(3, dtype=bool))
    finally:
        sim.close()
    with pytest.raises(ValueError, match="stop_radius"):
        ExpertConfig(stop_radius=2.0)


def test_nh_orca_goes_around_a_parked_robot():
    """Robot 1 is parked (inactive) on robot 0's straight route, 0.6 m below a box target: the gap above it
    is too narrow for NH-ORCA's inflated radii, so robot 0 must re-plan around it."""
    from navformer_rl.envs.world import TargetSpec, replace_layout

    base = generate_world(WorldConfig(size=12.5, kind="arena", n_robots=2, arena_inner_walls=(0, 0)), 0)
    targets = [
        TargetSpec(np.array([9.5, 6.0], dtype=np.float32), "sphere", "green"),
        TargetSpec(np.array([6.0, 7.1], dtype=np.float32), "box", "red"),
    ]
    starts = np.array([[2.5, 6.0, 0.0], [6.0, 6.0, 0.0]], dtype=np.float32)
    world = replace_layout(base, starts, targets)
    sim = Simulator(world, JACKAL, textured=False)
    try:
        expert = NHORCAExpert()
        expert.reset(world, sim, np.random.default_rng(0))
        active = np.array([True, False])
        for _ in range(300):
            contacts = sim.step(expert.act(sim, active), active)
            assert contacts.kind[0] != COLLISION_ROBOT
            if np.hypot(*(sim.poses[0, :2] - targets[0].position)) <= SUCCESS_RADIUS:
                break
        assert np.hypot(*(sim.poses[0, :2] - targets[0].position)) <= SUCCESS_RADIUS
    finally:
        sim.close()
