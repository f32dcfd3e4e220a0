"""The shaped reward (``ShapedNavReward``): known answers on hand-made 5 m worlds."""

from __future__ import annotations

import pytest
import torch
from torchrl.envs import TransformedEnv
from torchrl.envs.utils import check_env_specs, step_mdp

from navformer_rl.online.reward import GEODESIC_KEY, RewardWeights, ShapedNavReward

from .conftest import CORRIDOR, open_world, shaped_env


def drive(env, actions, steps):
    """Step ``env`` with the fixed ``actions`` float ``[A, 2]`` until done or ``steps``;
    the stacked outputs."""
    td = env.reset()
    outs = []
    for _ in range(steps):
        td.set(("agents", "action"), torch.as_tensor(actions, dtype=torch.float32))
        td = env.step(td)
        outs.append(td["next"].clone())
        if bool(td["next", "done"]):
            break
        td = step_mdp(td)
    return torch.stack(outs)


def test_straight_to_the_target_earns_the_distance_the_bonus_and_the_step_costs():
    weights = RewardWeights(progress=1.0, collision=0.1, success=10.0, step=0.01)
    env = shaped_env(CORRIDOR, weights=weights)
    start = env.reset()
    # at reset the geodesic distance is the env's shortest path to the success disc (same field)
    assert start[GEODESIC_KEY].item() == pytest.approx(start["privileged", "shortest_path_length"].item())
    assert start[GEODESIC_KEY].item() == pytest.approx(1.9, abs=0.05)
    out = drive(env, [[1.0, 0.0]], 16)
    rewards = out["agents", "reward"].reshape(-1)
    n = len(rewards)
    assert bool(out[-1]["privileged", "success"]) and not bool(out[:-1]["privileged", "success"].any())
    # progress telescopes: the whole start distance, the bonus once, a step cost per step, no contact
    assert rewards.sum().item() == pytest.approx(start[GEODESIC_KEY].item() + 10.0 - 0.01 * n, abs=1e-4)
    assert rewards[-1].item() > 10.0 and (rewards[:-1] < 1.0).all()
    assert out[-1]["agents", "episode_reward"].item() == pytest.approx(rewards.sum().item(), abs=1e-4)
    check_env_specs(env)


def test_a_robot_that_has_arrived_earns_nothing_more_and_contact_costs():
    # robot 0 faces its target; robot 1 faces the outer wall 0.5 m away and keeps pushing into it
    world = open_world(
        [(0.8, 1.2, 0.0), (4.2, 4.2, 0.0)],
        [(4.0, 1.2, "sphere", "red"), (1.0, 4.2, "box", "blue")],
    )
    weights = RewardWeights(progress=1.0, collision=0.5, success=10.0, step=0.0)
    env = shaped_env(world, max_steps=20, weights=weights)
    out = drive(env, [[1.0, 0.0], [1.0, 0.0]], 20)
    success = out["privileged", "success"][:, 0, 0]
    arrived = int(success.int().argmax())
    assert bool(success[arrived]) and arrived < 15
    r0 = out["agents", "reward"][:, 0, 0]
    assert r0[arrived].item() > 10.0
    assert (r0[arrived + 1 :] == 0).all()  # parked: the step after arriving on earns 0
    collided = out["agents", "collision"][:, 1, 0]
    assert collided.any()
    r1 = out["agents", "reward"][:, 1, 0]
    # pushing into the wall: no progress (the geodesic does not change) and -0.5 per step in contact
    stuck = collided & (out[GEODESIC_KEY][:, 1, 0] == out[GEODESIC_KEY][:, 1, 0][-1])
    assert stuck[-3:].all()
    assert torch.allclose(r1[-3:], torch.full((3,), -0.5))


def test_the_reward_refuses_an_env_that_is_not_multi_robot_nav():
    from navformer_rl.envs.torchrl_target_nav import make_torchrl_target_nav_env

    env = TransformedEnv(make_torchrl_target_nav_env(size=5.0, n_robots=1), ShapedNavReward())
    with pytest.raises(ValueError, match="must be applied to a MultiRobotNavEnv"):
        env.reset()


def test_reward_weights_are_checked():
    with pytest.raises(ValueError, match="reward.collision must be a finite number >= 0"):
        RewardWeights(collision=-1.0)
