"""gymnasium TargetNavEnv: API check, determinism, reward/termination/truncation, errors, plug-in policy."""

import dataclasses
import math

import cv2
import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import navformer_rl  # noqa: F401  (registers the id)
from navformer_rl.constants import MAX_EPISODE_STEPS
from navformer_rl.envs.obstacle_policy import GoalSeekingPolicy
from navformer_rl.envs.registration import ENV_ID
from navformer_rl.envs.target_nav import TargetNavEnv
from navformer_rl.envs.world import EpisodeSpec, WorldConfig


def test_registered_env_passes_gymnasium_check_env():
    env = gym.make(ENV_ID, size=5.0, n_robots=2, render_mode="rgb_array")
    check_env(env.unwrapped, skip_render_check=False)
    obs, info = env.reset(seed=1)
    assert obs["pixels"].shape == (84, 84, 3) and obs["target_pixels"].dtype == np.uint8
    assert info["robot_poses"].shape == (2, 3) and info["shortest_path_length"] > 0
    frame = env.render()
    # the 5 m map at 48 px/m with 12 px margins (264 px square), beside a column of two 132 px views
    assert frame.shape == (264, 264 + 132, 3) and frame.dtype == np.uint8
    # robot 0's camera view above its target image, each scaled up to 132 px
    camera, target = (
        cv2.resize(obs[key], (132, 132), interpolation=cv2.INTER_NEAREST)
        for key in ("pixels", "target_pixels")
    )
    assert np.array_equal(frame[:132, 264:], camera) and np.array_equal(frame[132:, 264:], target)
    env.close()


def rollout(env, seed, n_steps=15):
    obs, info = env.reset(seed=seed)
    actions = np.random.default_rng(99).uniform(-1, 1, size=(n_steps, 2)).astype(np.float32)
    frames, poses = [obs["pixels"]], [info["robot_poses"]]
    for a in actions:
        obs, _, term, trunc, info = env.step(a)
        frames.append(obs["pixels"])
        poses.append(info["robot_poses"])
        if term or trunc:
            break
    return np.stack(frames), np.stack(poses)


def test_same_seed_same_observations_and_trajectories():
    env_a = TargetNavEnv(size=5.0, n_robots=3)
    env_b = TargetNavEnv(size=5.0, n_robots=3)
    frames_a, poses_a = rollout(env_a, seed=4)
    frames_b, poses_b = rollout(env_b, seed=4)
    assert np.array_equal(frames_a, frames_b) and np.array_equal(poses_a, poses_b)
    frames_a2, _ = rollout(env_a, seed=4)  # the same env, reset again with the seed
    assert np.array_equal(frames_a, frames_a2)
    frames_c, _ = rollout(env_b, seed=5)
    assert not np.array_equal(frames_a[0], frames_c[0])


def test_reward_and_termination_on_success(make_open_world):
    # the target is 2.0 m ahead: after 3 steps of 0.2 m the robot is 1.4 m from it (< 1.5 m)
    world = make_open_world([(1.0, 2.5, 0.0)], [(3.0, 2.5, "sphere", "green")])
    env = TargetNavEnv(size=5.0, n_robots=1)
    obs, info = env.reset(seed=0, options={"episode": world})
    assert info["shortest_path_length"] == pytest.approx(0.5, abs=0.06)  # to the 1.5 m success region
    rewards, terms = [], []
    for _ in range(3):
        obs, reward, terminated, truncated, info = env.step(np.array([1.0, 0.0], dtype=np.float32))
        rewards.append(reward)
        terms.append(terminated)
        assert not truncated
    assert rewards == [0.0, 0.0, 1.0] and terms == [False, False, True]
    assert info["success"] and info["distance_to_target"] == pytest.approx(1.4, abs=1e-5)
    assert info["path_length"] == pytest.approx(0.6, abs=1e-5) and info["collisions"] == 0


def test_truncation_and_collision_info(make_open_world):
    world = make_open_world([(4.5, 2.5, 0.0)], [(1.0, 2.5, "box", "white")])
    env = TargetNavEnv(size=5.0, n_robots=1, max_episode_steps=3)
    env.reset(seed=0, options={"episode": world})
    for t in range(3):
        _, reward, terminated, truncated, info = env.step(np.array([1.0, 0.0], dtype=np.float32))
        assert info["collision"] and info["collision_kind"] == 1  # pushing into the right wall
        assert truncated == (t == 2) and not terminated and reward == 0.0
    assert info["collisions"] == 3


def test_bad_actions_and_settings_raise_value_error():
    env = TargetNavEnv(size=5.0)
    env.reset(seed=0)
    with pytest.raises(ValueError, match="finite"):
        env.step(np.array([math.nan, 0.0]))
    with pytest.raises(ValueError, match="shape"):
        env.step(np.zeros(3))
    with pytest.raises(ValueError, match="outside the supported range"):
        TargetNavEnv(size=20.0)
    with pytest.raises(ValueError, match="turtlebot4"):
        TargetNavEnv(robot_style="turtlebot4")
    with pytest.raises(ValueError, match="render_mode"):
        TargetNavEnv(render_mode="human")
    with pytest.raises(ValueError, match=r"step\(\) needs an action: float \[2\]"):
        env.step(None)
    with pytest.raises(ValueError, match="actions must be numbers.*got 'fast'"):
        env.step("fast")


@pytest.mark.parametrize("seed", [-1, 2.5, "7"])
def test_bad_reset_seeds_raise_value_error(seed):
    env = TargetNavEnv(size=5.0)
    with pytest.raises(ValueError, match=f"seed must be a non-negative integer, got {seed!r}"):
        env.reset(seed=seed)
    with pytest.raises(ValueError, match="options must be a dict"):
        env.reset(seed=0, options=["episode"])


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"n_robots": 0}, "n_robots must be an integer >= 1, got 0"),
        ({"max_episode_steps": 1.5}, r"max_episode_steps must be an integer >= 1, got 1\.5"),
        ({"episodes_per_world": None}, "episodes_per_world must be an integer >= 1, got None"),
        ({"world_config": {"size": 5.0}}, "world_config must be a WorldConfig, got dict"),
        ({"world_config": WorldConfig(size=5.0, robot_radius=0.2)}, r"robot_radius=0\.2 .*jackal"),
    ],
)
def test_bad_settings_raise_value_error(kwargs, message):
    with pytest.raises(ValueError, match=message):
        TargetNavEnv(**{"size": 5.0, **kwargs})


def test_numpy_integer_seeds_are_accepted():
    env = TargetNavEnv(size=5.0)
    _, info = env.reset(seed=np.int64(4))
    assert info["world_seed"] == TargetNavEnv(size=5.0).reset(seed=4)[1]["world_seed"]


def test_turtlebots_fit_a_world_config_with_their_radius():
    env = TargetNavEnv(
        robot_style="turtlebot3", world_config=WorldConfig(size=5.0, n_robots=2, robot_radius=0.2)
    )
    assert env.config.robot_radius == 0.2
    env.reset(seed=0)
    # every robot of the episode is a TurtleBot3 with its 0.20 m disc
    assert [spec.name for spec in env.simulator.robot_specs] == ["turtlebot3", "turtlebot3"]
    assert env.simulator.radii.tolist() == [0.2, 0.2]
    env.close()


class WrongShapePolicy:
    """Returns three numbers per obstacle robot instead of (linear, angular)."""

    def reset(self, world, sim, rng):
        pass

    def act(self, sim, robot_indices):
        return np.zeros((len(robot_indices), 3), dtype=np.float32)


def test_obstacle_policy_with_bad_actions_raises_value_error():
    env = TargetNavEnv(size=5.0, n_robots=3, obstacle_policy=WrongShapePolicy())
    env.reset(seed=0)
    with pytest.raises(ValueError, match=r"obstacle_policy.act returned bad actions.*shape \(2, 2\)"):
        env.step(np.zeros(2, dtype=np.float32))


class RecordingPolicy:
    """Drives every obstacle straight ahead slowly and records what it was asked for."""

    def __init__(self):
        self.calls = []

    def reset(self, world, sim, rng):
        self.calls.append("reset")

    def act(self, sim, robot_indices):
        self.calls.append(list(robot_indices))
        return np.tile(np.array([[0.2, 0.0]], dtype=np.float32), (len(robot_indices), 1))


def test_obstacle_policy_is_pluggable_and_obstacles_can_be_turtlebots():
    env = TargetNavEnv(size=5.0, n_robots=3, obstacle_policy=RecordingPolicy(), obstacle_style="turtlebot3")
    policy = env.obstacle_policy  # the env's own copy
    _, info0 = env.reset(seed=2)
    _, _, _, _, info1 = env.step(np.zeros(2, dtype=np.float32))
    assert policy.calls == ["reset", [1, 2]]
    assert [s.name for s in env.simulator.robot_specs] == ["jackal", "turtlebot3", "turtlebot3"]
    assert np.allclose(info1["robot_poses"][0], info0["robot_poses"][0])  # robot 0 was told to stand still
    with pytest.raises(ValueError, match="obstacle_policy"):
        TargetNavEnv(obstacle_policy=object())


def test_episodes_per_world_reuses_the_maze_with_fresh_starts():
    env = TargetNavEnv(size=5.0, n_robots=2, episodes_per_world=2)
    env.reset(seed=0)
    first, sim = env.world, env.simulator
    env.reset()
    second = env.world
    assert np.array_equal(first.walls, second.walls) and env.simulator is sim  # same scene, same client
    assert not np.array_equal(first.starts, second.starts)
    assert np.allclose(env.simulator.poses, second.starts)
    env.reset()
    assert env.world.seed != first.seed


def test_a_fixed_episode_is_not_reused_by_later_plain_resets(make_open_world):
    env = TargetNavEnv(size=5.0, n_robots=1, episodes_per_world=3)
    env.reset(seed=0)
    drawn = env.world
    fixed = make_open_world([(1.0, 2.5, 0.0)], [(4.0, 2.5, "sphere", "green")])
    env.reset(options={"episode": fixed})
    assert env.world is fixed
    env.reset()  # a new world is drawn: neither the fixed layout nor the earlier maze
    assert not np.array_equal(env.world.walls, fixed.walls) and env.world.seed != drawn.seed
    second = env.world
    env.reset()  # ... which then serves its episodes_per_world episodes as usual
    assert np.array_equal(env.world.walls, second.walls) and env.world.seed == second.seed
    with pytest.raises(ValueError, match="2 robots"):
        env.reset(
            options={
                "episode": make_open_world(
                    [(1.0, 1.0, 0.0), (1.0, 4.0, 0.0)],
                    [(4.0, 1.0, "sphere", "red"), (4.0, 4.0, "box", "blue")],
                )
            }
        )


def turn_in_place(env, n_steps):
    """Step ``n_steps`` times turning in place (never succeeds); returns the step's info where the episode
    ended, or the last one."""
    for _ in range(n_steps):
        _, _, terminated, truncated, info = env.step(np.array([0.0, 1.0], dtype=np.float32))
        if terminated or truncated:
            break
    return terminated, truncated, info


def test_gym_make_truncates_at_its_max_episode_steps_also_beyond_500(make_open_world):
    world = make_open_world([(1.0, 2.5, 0.0)], [(4.0, 4.0, "sphere", "green")])
    env = gym.make(ENV_ID, size=5.0, n_robots=1, textured=False)
    assert env.spec.max_episode_steps == MAX_EPISODE_STEPS  # registered with the paper's horizon
    assert env.unwrapped.max_episode_steps is None  # gymnasium's TimeLimit truncates, not the env
    longer = gym.make(ENV_ID, size=5.0, n_robots=1, textured=False, max_episode_steps=MAX_EPISODE_STEPS + 1)
    assert longer.spec.max_episode_steps == MAX_EPISODE_STEPS + 1
    longer.reset(seed=0, options={"episode": world})
    terminated, truncated, info = turn_in_place(longer, MAX_EPISODE_STEPS + 5)
    assert truncated and not terminated and info["step"] == MAX_EPISODE_STEPS + 1  # not cut short at 500
    shorter = gym.make(ENV_ID, size=5.0, n_robots=1, textured=False, max_episode_steps=3)
    shorter.reset(seed=0, options={"episode": world})
    terminated, truncated, info = turn_in_place(shorter, 10)
    assert truncated and info["step"] == 3


def test_a_directly_built_env_truncates_at_its_own_max_episode_steps(make_open_world):
    env = TargetNavEnv(size=5.0, n_robots=1, max_episode_steps=4, textured=False)
    assert env.spec is None and env.max_episode_steps == 4
    env.reset(seed=0, options={"episode": make_open_world([(1.0, 2.5, 0.0)], [(4.0, 4.0, "box", "red")])})
    terminated, truncated, info = turn_in_place(env, 10)
    assert truncated and not terminated and info["step"] == 4
    assert TargetNavEnv(size=5.0).max_episode_steps == MAX_EPISODE_STEPS


def test_one_obstacle_policy_object_given_to_two_envs_is_not_shared():
    shared = GoalSeekingPolicy()
    env_a = TargetNavEnv(size=5.0, n_robots=2, obstacle_policy=shared, textured=False)
    env_b = TargetNavEnv(size=5.0, n_robots=2, obstacle_policy=shared, textured=False)
    assert env_a.obstacle_policy is not shared and env_a.obstacle_policy is not env_b.obstacle_policy
    reference = TargetNavEnv(size=5.0, n_robots=2, obstacle_policy=GoalSeekingPolicy(), textured=False)
    env_a.reset(seed=1)
    env_b.reset(seed=2)  # a shared policy would now steer env_a's obstacle to env_b's target
    reference.reset(seed=1)
    for _ in range(8):
        _, _, _, _, info_a = env_a.step(np.zeros(2, dtype=np.float32))
        _, _, _, _, info_ref = reference.step(np.zeros(2, dtype=np.float32))
    assert np.array_equal(info_a["robot_poses"], info_ref["robot_poses"])
    vec = gym.make_vec(
        ENV_ID, num_envs=2, vectorization_mode="sync", size=5.0, n_robots=2, obstacle_policy=shared
    )
    assert vec.envs[0].unwrapped.obstacle_policy is not vec.envs[1].unwrapped.obstacle_policy
    vec.close()


def test_a_fixed_episode_built_for_smaller_robots_is_refused():
    episode = EpisodeSpec(config=WorldConfig(size=5.0, n_robots=1, robot_radius=0.2), world_seed=0)
    env = TargetNavEnv(size=5.0, n_robots=1)
    with pytest.raises(
        ValueError, match=r"the episode's world\.config\.robot_radius=0\.2 m .*jackal robot's radius 0\.3"
    ):
        env.reset(seed=0, options={"episode": episode})
    with pytest.raises(ValueError, match=r"world\.config\.robot_radius=0\.2"):
        env.reset(options={"episode": episode.build()})  # a WorldSpec too
    turtlebots = TargetNavEnv(size=5.0, n_robots=1, robot_style="turtlebot3")
    assert turtlebots.reset(seed=0, options={"episode": episode})[1]["world_seed"] == 0  # radius 0.2 fits


def test_a_reset_that_fails_building_the_simulator_leaves_the_env_not_reset(make_open_world):
    good = make_open_world([(1.0, 2.5, 0.0)], [(4.0, 4.0, "sphere", "green")])
    in_wall = dataclasses.replace(good, starts=np.array([[0.3, 2.5, 0.0]], dtype=np.float32))  # unchecked
    env = TargetNavEnv(size=5.0, n_robots=1, textured=False)
    for previous in (None, good):  # a new scene (the old simulator is closed) and the same scene (re-posed)
        env.reset(seed=0, options={"episode": previous} if previous is not None else None)
        with pytest.raises(ValueError, match="overlaps"):
            env.reset(options={"episode": in_wall})
        assert env.simulator is None
        with pytest.raises(RuntimeError, match=r"call reset\(\) before step\(\)"):
            env.step(np.zeros(2, dtype=np.float32))
        assert env.render() is None
    _, info = env.reset(options={"episode": good})  # usable again
    assert env.step(np.zeros(2, dtype=np.float32))[4]["step"] == 1 and info["step"] == 0
