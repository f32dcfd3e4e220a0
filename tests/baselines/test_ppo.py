"""PPO from TorchRL's parts: GAE per robot, the update's direction, and a short seeded run that learns."""

from __future__ import annotations

import pytest
import torch
from torchrl.envs.utils import ExplorationType, set_exploration_type

from navformer_rl.online.config import LossConfig, OptimConfig
from navformer_rl.online.envs import EPISODE_RETURN_KEY
from navformer_rl.online.ppo import make_collector, make_loss, make_optimizer, ppo_update, robot_steps

from .conftest import CORRIDOR, shaped_env
from .test_policies import sampled_rollout


def test_gae_per_robot_and_parked_robots_dropped(small_net):
    net = small_net("dsac")
    loss = make_loss(net, LossConfig(gamma=0.9, lmbda=0.8))
    data = sampled_rollout(net, "dsac", steps=6)
    # robot 1 reaches its target on step 2 (index 2): done and terminated from then on
    for key in ("done", "terminated"):
        flags = data["next", "agents", key].clone()
        flags[2:, 1] = True
        data["next", "agents", key] = flags
        root = data["agents", key].clone()
        root[3:, 1] = True
        data["agents", key] = root
    steps = robot_steps(loss, data)
    assert steps.shape == (6 + 3,)  # robot 0: 6 steps; robot 1: the 3 up to and including its arrival
    agents = steps["agents"]
    assert torch.allclose(agents["value_target"], agents["advantage"] + agents["state_value"], atol=1e-5)
    # robot 1's last kept step is terminal: its advantage is r - V(s), no bootstrap
    # steps are kept time-major, (t, robot): robot 1's third and last step is the sixth
    last = agents[5]
    reward = data["next", "agents", "reward"][2, 1]
    assert torch.allclose(last["advantage"], reward - last["state_value"], atol=1e-5)


@pytest.mark.parametrize("autocast_dtype", [None, "bfloat16"])
def test_one_update_makes_positive_advantage_actions_likelier(autocast_dtype, small_net):
    net = small_net("dsac")
    loss = make_loss(net, LossConfig(normalize_advantage=False, entropy_coeff=0.0, critic_coeff=0.0))
    steps = robot_steps(loss, sampled_rollout(net, "dsac", steps=8))
    sign = torch.tensor([1.0, -1.0]).repeat(8).reshape(-1, 1)
    steps.set(("agents", "advantage"), sign)
    actor = net.actor()
    before = actor.log_prob(steps.clone()).detach()
    optimizer = make_optimizer(loss, OptimConfig(lr=1e-3))
    cfg = OptimConfig(epochs=1, minibatch_size=16, autocast_dtype=autocast_dtype)
    stats = ppo_update(loss, optimizer, steps, cfg)
    after = actor.log_prob(steps.clone()).detach()
    change = (after - before).reshape(-1)
    assert change[sign.reshape(-1) > 0].mean() > 0 > change[sign.reshape(-1) < 0].mean()
    assert stats["clip_fraction"] == 0.0 and stats["grad_norm"] > 0


def sampled_returns(net, env, seeds=(1000, 1001, 1002, 1003)) -> float:
    """Mean shaped return of the sampled policy over episodes seeded by ``seeds`` (the torch RNG restored)."""
    state = torch.get_rng_state()
    returns = []
    for seed in seeds:
        torch.manual_seed(seed)
        with torch.no_grad(), set_exploration_type(ExplorationType.RANDOM):
            rollout = env.rollout(env.base_env.max_steps, net.actor(), break_when_any_done=True)
        returns.append(rollout[-1][("next", *EPISODE_RETURN_KEY)].sum().item())
    torch.set_rng_state(state)
    return sum(returns) / len(returns)


@pytest.mark.slow
@pytest.mark.parametrize("method", ["dsac", "matdn"])
def test_a_short_seeded_ppo_run_raises_the_return(method, small_net):
    """One robot facing its target 1.9 m from the success disc, 16-step episodes: 5 PPO batches of 64 frames
    (one in-process collector) raise the sampled policy's return on the same seeded episodes."""
    torch.set_num_threads(1)
    net = small_net(method)
    env = shaped_env(CORRIDOR, method)
    before = sampled_returns(net, env)
    loss = make_loss(net, LossConfig(gamma=0.9, entropy_coeff=0.0))
    optimizer = make_optimizer(loss, OptimConfig(lr=1e-3))
    collector = make_collector([lambda: shaped_env(CORRIDOR, method)], net.actor(), 64)
    generator = torch.Generator().manual_seed(0)
    try:
        for i, data in enumerate(collector):
            steps = robot_steps(loss, data)
            ppo_update(loss, optimizer, steps, OptimConfig(epochs=4, minibatch_size=32), generator)
            if i == 4:
                break
    finally:
        collector.shutdown()
    after = sampled_returns(net, env)
    assert after > before + 0.3, (before, after)


@pytest.mark.slow
def test_worker_processes_with_different_robot_counts_and_weight_updates(small_net):
    """A ``MultiSyncCollector`` over workers driving 1 and 2 robots: GAE per worker, every robot-step kept,
    and the workers act with the weights sent by ``update_policy_weights_``."""
    from navformer_rl.online.envs import EnvFactory
    from navformer_rl.online.reward import RewardWeights

    from .conftest import SMALL

    net = small_net("matdn")
    factories = [
        EnvFactory("matdn", SMALL["matdn"], (5.0,), n, RewardWeights(), seed, (("max_steps", 20),))
        for seed, n in ((1, 1), (2, 2))
    ]
    collector = make_collector(factories, net.actor(), 16)
    loss = make_loss(net, LossConfig())
    try:
        batches = iter(collector)
        data = next(batches)
        assert data.batch_size[0] == 2 and data[1]["agents"].batch_size == (8, 2)
        assert robot_steps(loss, data).shape == (8 * 1 + 8 * 2,)
        assert data[0]["agents", "action"][..., 0].abs().mean() < 0.9
        with torch.no_grad():
            net.policy_head[0].bias.copy_(torch.tensor([20.0, 0.0]))  # always full speed ahead
        collector.update_policy_weights_()
        data = next(batches)
        for worker in range(2):
            assert (data[worker]["agents", "action"][..., 0] > 0.99).all()
    finally:
        collector.shutdown()
