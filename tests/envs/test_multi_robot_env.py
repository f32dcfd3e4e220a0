"""TorchRL MultiRobotNavEnv (and the single-robot TorchRL wrapper): specs, keys, determinism, success."""

import dataclasses

import numpy as np
import pytest
import torch
from torchrl.collectors import Collector
from torchrl.envs.utils import check_env_specs, step_mdp

from navformer_rl.envs.multi_robot import MultiRobotNavEnv
from navformer_rl.envs.torchrl_target_nav import make_torchrl_target_nav_env
from navformer_rl.envs.world import EpisodeSpec, WorldConfig


def test_check_env_specs_and_keys():
    env = MultiRobotNavEnv(size=5.0, n_robots=2, seed=0)
    check_env_specs(env, seed=0)
    td = env.reset()
    assert td["agents", "pixels"].shape == (2, 84, 84, 3) and td["agents", "pixels"].dtype == torch.uint8
    assert td["agents", "target_pixels"].shape == (2, 84, 84, 3)
    assert td["agents", "step_count"].tolist() == [[0], [0]]
    assert td["privileged", "pose"].shape == (2, 3) and td["privileged", "success"].dtype == torch.bool
    assert (td["privileged", "shortest_path_length"] > 0).all()
    assert td["done"].shape == (1,) and not td["done"].any()
    assert env.reward_keys == [("agents", "reward")] and env.action_keys == [("agents", "action")]
    assert env.world.n_robots == 2 and env.simulator.n_robots == 2
    env.close()


def actions(n_steps, n_robots):
    return torch.from_numpy(
        np.random.default_rng(3).uniform(-1, 1, (n_steps, n_robots, 2)).astype(np.float32)
    )


def run(env, acts):
    td = env.reset()
    frames, poses = [td["agents", "pixels"]], [td["privileged", "pose"]]
    for a in acts:
        td["agents", "action"] = a
        td = step_mdp(env.step(td))
        frames.append(td["agents", "pixels"])
        poses.append(td["privileged", "pose"])
    return torch.stack(frames), torch.stack(poses)


def test_same_seed_same_rollout():
    acts = actions(12, 3)
    a = MultiRobotNavEnv(size=5.0, n_robots=3)
    b = MultiRobotNavEnv(size=5.0, n_robots=3)
    a.set_seed(8)
    b.set_seed(8)
    frames_a, poses_a = run(a, acts)
    frames_b, poses_b = run(b, acts)
    assert torch.equal(frames_a, frames_b) and torch.equal(poses_a, poses_b)
    b.set_seed(9)
    frames_c, _ = run(b, acts)
    assert not torch.equal(frames_a[0], frames_c[0])


def test_success_reward_once_robot_stays_put_and_episode_ends(make_open_world):
    # robot 0 is 1.6 m from its target (succeeds on its first step), robot 1 is 2.0 m from its target
    world = make_open_world(
        [(1.0, 1.0, 0.0), (1.0, 4.0, 0.0)], [(2.6, 1.0, "sphere", "red"), (3.0, 4.0, "box", "yellow")]
    )
    env = MultiRobotNavEnv(size=5.0, n_robots=2)
    env.set_next_episode(EpisodeSpec(world=world))
    td = env.reset()
    rewards, poses0 = [], []
    for t in range(3):
        td["agents", "action"] = torch.tensor([[1.0, 0.5], [1.0, 0.0]])
        out = env.step(td)
        nxt = out["next"]
        rewards.append(nxt["agents", "reward"].squeeze(-1).tolist())
        poses0.append(nxt["privileged", "pose"][0].clone())
        assert nxt["agents", "step_count"].tolist() == [[t + 1], [t + 1]]
        td = step_mdp(out)
    assert rewards == [[1.0, 0.0], [0.0, 0.0], [0.0, 1.0]]  # robot 1: 2.0 -> 1.8 -> 1.6 -> 1.4 m
    assert torch.equal(poses0[0], poses0[1]) and torch.equal(poses0[1], poses0[2])  # robot 0 stays put
    assert nxt["agents", "terminated"].all() and nxt["terminated"].item() and nxt["done"].item()
    assert not nxt["truncated"].item()
    assert nxt["privileged", "path_length"][0].item() == pytest.approx(0.2, abs=1e-4)


def test_robot_driven_into_is_flagged_until_it_succeeds(make_open_world):
    """Robot 0 drives into robot 1, which stands still: both carry the collision flag on the contact steps.
    Once robot 1 has succeeded (parked), robot 0 driving into it again is charged to robot 0 only."""
    world = make_open_world(
        [(1.0, 2.5, 0.0), (2.0, 2.5, 0.5 * np.pi)], [(4.4, 4.4, "box", "red"), (2.0, 4.1, "sphere", "blue")]
    )
    env = MultiRobotNavEnv(size=5.0, n_robots=2)
    env.set_next_episode(EpisodeSpec(world=world))
    td = env.reset()
    push, leave = torch.tensor([[1.0, 0.0], [0.0, 0.0]]), torch.tensor([[0.0, 0.0], [1.0, 0.0]])
    flags, kinds = [], []
    # gap 0.4 m: 0.2 m, contact, still pushing; then robot 1 leaves for its target (1.6 m -> 1.4 m, success)
    # and robot 0 drives into the parked robot 1 again (its straight line passes 0.2 m from robot 1's centre)
    for action in (push, push, push, leave, push):
        td["agents", "action"] = action
        out = env.step(td)
        flags.append(out["next", "agents", "collision"].squeeze(-1).tolist())
        kinds.append(out["next", "agents", "collision_kind"].squeeze(-1).tolist())
        td = step_mdp(out)
    assert flags == [[False, False], [True, True], [True, True], [False, False], [True, False]]
    assert kinds == [[0, 0], [2, 2], [2, 2], [0, 0], [2, 0]]
    assert td["privileged", "success"].squeeze(-1).tolist() == [False, True]
    assert td["privileged", "collisions"].squeeze(-1).tolist() == [3, 2]


def test_truncation_at_max_steps(make_open_world):
    world = make_open_world([(1.0, 1.0, 0.0)], [(4.0, 4.0, "sphere", "blue")])
    env = MultiRobotNavEnv(size=5.0, n_robots=1, max_steps=4)
    env.set_next_episode(world)
    td = env.reset()
    td["agents", "action"] = torch.zeros(1, 2)
    rollout = env.rollout(10, auto_reset=False, tensordict=td, break_when_any_done=True)
    assert rollout.shape == (4,)
    assert rollout["next", "truncated"].squeeze(-1).tolist() == [False, False, False, True]
    assert rollout["next", "agents", "done"][-1].all() and not rollout["next", "agents", "terminated"].any()


def test_bad_inputs_raise_value_error():
    env = MultiRobotNavEnv(size=5.0, n_robots=2, seed=0)
    td = env.reset()
    td["agents", "action"] = torch.tensor([[float("nan"), 0.0], [0.0, 0.0]])
    with pytest.raises(ValueError, match="finite"):
        env.step(td)
    with pytest.raises(ValueError, match="robot style"):
        MultiRobotNavEnv(robots=["jackal", "roomba"])
    env.set_next_episode(EpisodeSpec(config=env.config.__class__(size=5.0, n_robots=3), world_seed=0))
    with pytest.raises(ValueError, match="3 robots"):
        env.reset()


def test_mixed_robot_styles():
    env = MultiRobotNavEnv(size=5.0, robots=["jackal", "turtlebot3"], seed=1)
    env.reset()
    assert [s.name for s in env.simulator.robot_specs] == ["jackal", "turtlebot3"]
    # each robot collides with its own style's disc: Jackal 0.30 m, TurtleBot3 0.20 m
    assert env.simulator.radii.tolist() == [0.30, 0.20]
    env.close()


def test_torchrl_wrapper_of_the_single_robot_env():
    env = make_torchrl_target_nav_env(size=5.0, n_robots=2)
    check_env_specs(env, seed=0)
    td = env.reset()
    assert td["pixels"].shape == (84, 84, 3) and td["privileged", "pose"].shape == (3,)
    # every entry of the gymnasium env's info is carried, with the same values
    step = env.rand_step(td)["next"]
    privileged = step["privileged"]
    assert set(privileged.keys()) >= {"distance_to_target", "robot_poses", "world_seed", "step"}
    assert privileged["robot_poses"].shape == (2, 3) and privileged["step"].item() == 1
    assert torch.allclose(privileged["robot_poses"][0], privileged["pose"])
    assert privileged["world_seed"].item() == env._env.unwrapped.world.seed
    target = privileged["target_position"]
    assert privileged["distance_to_target"].item() == pytest.approx(
        torch.linalg.vector_norm(privileged["pose"][:2] - target).item(), abs=1e-5
    )
    env.close()


def test_episodes_per_world_and_fixed_episodes():
    env = MultiRobotNavEnv(size=5.0, n_robots=2, episodes_per_world=2, seed=4)
    env.reset()
    first = env.world
    env.reset()
    assert np.array_equal(env.world.walls, first.walls) and not np.array_equal(env.world.starts, first.starts)
    env.set_next_episode(first)  # replay the first episode exactly
    td = env.reset()
    assert np.allclose(td["privileged", "pose"].numpy(), first.starts)
    env.reset()  # a fixed episode is not reused implicitly: a new world is drawn
    assert env.world.seed != first.seed and not np.array_equal(env.world.walls, first.walls)


@pytest.mark.parametrize("seed", [-1, 1.5, "3", True])
def test_bad_seeds_raise_value_error(seed):
    with pytest.raises(ValueError, match=f"seed must be a non-negative integer, got {seed!r}"):
        MultiRobotNavEnv(size=5.0, n_robots=1, seed=seed)
    env = MultiRobotNavEnv(size=5.0, n_robots=1, seed=np.int64(3))  # numpy integers are fine
    with pytest.raises(ValueError, match=f"seed must be a non-negative integer, got {seed!r}"):
        env.set_seed(seed)


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"n_robots": 0}, "n_robots must be an integer >= 1, got 0"),
        ({"n_robots": 2.5}, r"n_robots must be an integer >= 1, got 2\.5"),
        ({"robots": "jackal"}, "robots must be a list of robot style names.*got 'jackal'"),
        ({"robots": 2}, "robots must be a list of robot style names.*got 2"),
        ({"robots": []}, "at least one robot"),
        ({"max_steps": 1.5}, r"max_steps must be an integer >= 1, got 1\.5"),
        ({"max_steps": None}, "max_steps must be an integer >= 1, got None"),
        ({"episodes_per_world": 0}, "episodes_per_world must be an integer >= 1, got 0"),
        ({"world_config": {"size": 5.0}}, "world_config must be a WorldConfig, got dict"),
        (
            {"world_config": WorldConfig(size=5.0, n_robots=2, robot_radius=0.2)},
            r"robot_radius=0\.2 .*jackal",
        ),
        ({"device": "gpu0"}, "device must be a torch device.*got 'gpu0'"),
    ],
)
def test_bad_settings_raise_value_error(kwargs, message):
    with pytest.raises(ValueError, match=message):
        MultiRobotNavEnv(**{"size": 5.0, "n_robots": 2, **kwargs})


@pytest.mark.skipif(torch.cuda.is_available(), reason="CUDA is available here")
def test_cuda_device_without_cuda_raises_value_error():
    with pytest.raises(ValueError, match="needs CUDA"):
        MultiRobotNavEnv(size=5.0, n_robots=1, device="cuda")


def test_step_without_a_valid_action_raises_value_error():
    env = MultiRobotNavEnv(size=5.0, n_robots=2, seed=0)
    with pytest.raises(RuntimeError, match="reset"):
        env.step(env.full_action_spec.zero())
    td = env.reset()
    with pytest.raises(ValueError, match=r"\('agents', 'action'\): float \[2, 2\]"):
        env.step(td.clone())
    root = td.clone()
    root["action"] = torch.zeros(2, 2)
    with pytest.raises(ValueError, match="put it under 'agents'"):
        env.step(root)
    for bad, message in (
        (torch.zeros(2, 3), r"shape \(2, 2\).*clipped.*got shape \(2, 3\)"),
        (torch.tensor([[float("inf"), 0.0], [0.0, 0.0]]), "finite"),
    ):
        td["agents", "action"] = bad
        with pytest.raises(ValueError, match=message):
            env.step(td)
    td["agents", "action"] = torch.tensor([[5.0, -5.0], [0.0, 0.0]])  # out of range: clipped, not refused
    pose = env.step(td)["next", "privileged", "pose"]
    env.close()
    # the refused steps changed nothing, and the clipped action drives as [1, -1] does from the same state
    same = MultiRobotNavEnv(size=5.0, n_robots=2, seed=0)
    clipped = same.reset()
    assert torch.equal(clipped["privileged", "pose"], td["privileged", "pose"])
    clipped["agents", "action"] = torch.tensor([[1.0, -1.0], [0.0, 0.0]])
    expected = same.step(clipped)["next", "privileged", "pose"]
    same.close()
    assert torch.equal(pose, expected)
    assert not torch.equal(pose[0], td["privileged", "pose"][0])  # robot 0 did move


def test_torchrl_wrapper_refuses_bad_actions_and_seeds():
    env = make_torchrl_target_nav_env(size=5.0, n_robots=1)
    with pytest.raises(ValueError, match="seed must be a non-negative integer, got -1"):
        env.set_seed(-1)
    td = env.reset()
    with pytest.raises(ValueError, match="step\\(\\) needs the action at key 'action': float \\[2\\]"):
        env.step(td.clone())
    for bad, message in (
        (torch.zeros(3), r"shape \(1, 2\) or \(2,\)"),
        (torch.tensor([float("nan"), 0.0]), "finite"),
    ):
        td["action"] = bad
        with pytest.raises(ValueError, match=message):
            env.step(td)
    td["action"] = torch.zeros(2)
    step = env.step(td)["next"]
    env.close()
    # standing still: the pose is unchanged, and only this valid step advanced the step counter
    assert torch.equal(step["privileged", "pose"], td["privileged", "pose"])
    assert td["privileged", "step"].item() == 0 and step["privileged", "step"].item() == 1


def test_stepping_an_ended_episode_is_an_error_and_rollouts_still_reset(make_open_world):
    world = make_open_world([(1.0, 1.0, 0.0)], [(4.0, 4.0, "sphere", "blue")])
    env = MultiRobotNavEnv(size=5.0, n_robots=1, max_steps=2, textured=False, seed=0)
    env.set_next_episode(world)
    td = env.reset()
    for _ in range(2):
        td["agents", "action"] = torch.zeros(1, 2)
        td = step_mdp(env.step(td))
    assert td["truncated"].item() and td["agents", "step_count"].item() == 2
    td["agents", "action"] = torch.zeros(1, 2)
    with pytest.raises(RuntimeError, match=r"the episode ended .*max_steps=2.*call reset\(\)"):
        env.step(td)
    step_count_spec = env.observation_spec["agents", "step_count"]
    rollout = env.rollout(7, break_when_any_done=False)  # resets after each truncation
    assert rollout["next", "agents", "step_count"].flatten().tolist() == [1, 2, 1, 2, 1, 2, 1]
    assert step_count_spec.is_in(rollout["next", "agents", "step_count"])
    collector = Collector(env, None, frames_per_batch=5, total_frames=10)  # SyncDataCollector
    for batch in collector:
        assert step_count_spec.is_in(batch["next", "agents", "step_count"])
        assert batch["next", "agents", "step_count"].max().item() <= 2
    collector.shutdown()


def test_an_episode_for_smaller_robots_or_a_failed_reset_is_refused_clearly(make_open_world):
    env = MultiRobotNavEnv(size=5.0, n_robots=2, textured=False, seed=0)
    env.reset()
    env.set_next_episode(
        EpisodeSpec(config=WorldConfig(size=5.0, n_robots=2, robot_radius=0.2), world_seed=0)
    )
    with pytest.raises(ValueError, match=r"the episode's world\.config\.robot_radius=0\.2 m .*jackal"):
        env.reset()
    good = make_open_world(
        [(1.0, 1.0, 0.0), (1.0, 4.0, 0.0)], [(4.0, 1.0, "sphere", "red"), (4.0, 4.0, "box", "blue")]
    )
    starts = np.array([[1.0, 1.0, 0.0], [3.6, 4.0, 0.0]], dtype=np.float32)  # robot 1 in its box target
    env.set_next_episode(dataclasses.replace(good, starts=starts))  # unchecked starts
    with pytest.raises(ValueError, match="overlaps"):
        env.reset()
    assert env.simulator is None
    with pytest.raises(RuntimeError, match=r"call reset\(\) before step\(\)"):
        env.step(env.full_action_spec.zero().update(env.full_observation_spec.zero()))
    env.set_next_episode(good)
    assert env.reset()["agents", "step_count"].tolist() == [[0], [0]]  # usable again
