"""DSAC and MA-TDN as TensorDict modules: keys, shapes, specs, gradients through ClipPPOLoss,
MA-TDN's memory."""

from __future__ import annotations

import pytest
import torch
from tensordict import TensorDict
from torchrl.envs.utils import ExplorationType, set_exploration_type

from navformer_rl.baselines.actor_critic import ACTION_KEY, FEATURES_KEY, LOG_PROB_KEY, VALUE_KEY
from navformer_rl.baselines.matdn import MEMORY_KEY, MEMORY_MASK_KEY
from navformer_rl.baselines.online import OnlinePolicy
from navformer_rl.online.config import LossConfig
from navformer_rl.online.ppo import make_loss, robot_steps

from .conftest import CORRIDOR, SMALL, open_world, shaped_env

TWO_ROBOTS = open_world(
    [(0.8, 1.2, 0.0), (4.2, 4.2, 3.14)], [(4.0, 1.2, "sphere", "red"), (1.0, 4.2, "box", "blue")]
)


def sampled_rollout(net, method, steps=6, world=TWO_ROBOTS, seed=0):
    env = shaped_env(world, method, max_steps=steps)
    torch.manual_seed(seed)
    with torch.no_grad(), set_exploration_type(ExplorationType.RANDOM):
        return env.rollout(steps, net.actor(), break_when_any_done=False)


@pytest.mark.parametrize("method", ["dsac", "matdn"])
def test_actor_and_critic_keys_shapes_and_action_bounds(method, small_net):
    net = small_net(method)
    rollout = sampled_rollout(net, method)
    agents = rollout["agents"]
    assert agents.batch_size == (6, 2)
    action = agents[ACTION_KEY[1]]
    assert action.shape == (6, 2, 2) and action.dtype == torch.float32
    assert (action.abs() < 1).all()  # TanhNormal: squashed into the env's bounds, never clipped
    assert agents[LOG_PROB_KEY[1]].shape == (6, 2) and torch.isfinite(agents[LOG_PROB_KEY[1]]).all()
    assert agents["loc"].shape == agents["scale"].shape == (6, 2, 2) and (agents["scale"] > 0).all()
    value = net.critic()(rollout.clone())
    assert value[VALUE_KEY].shape == (6, 2, 1)
    # the critic writes its value only (the trunk's features and the next memory stay internal)
    assert set(net.critic().out_keys) == {VALUE_KEY}
    if method == "matdn":
        assert rollout[("next", *MEMORY_KEY)].shape == (6, 2, 4, 32)
        assert rollout[("next", *MEMORY_MASK_KEY)].dtype == torch.bool
    # the mean action is tanh(loc)
    td = rollout[0].exclude("next").clone()
    out = OnlinePolicy(net)(td)
    assert torch.allclose(out[ACTION_KEY], torch.tanh(out["agents", "loc"]))


@pytest.mark.parametrize("method", ["dsac", "matdn"])
def test_the_loss_runs_the_trunk_once_with_the_gradients_of_running_it_twice(method, small_net):
    net = small_net(method)
    loss = make_loss(net, LossConfig())
    steps = robot_steps(loss, sampled_rollout(net, method))
    calls = []
    hook = net.trunk.register_forward_hook(lambda *_: calls.append(1))
    torch.manual_seed(0)  # TanhNormal's entropy is a sampled estimate
    out = loss(steps.clone())
    hook.remove()
    assert len(calls) == 1  # the critic read the features the actor wrote
    total = out["loss_objective"] + out["loss_critic"] + out["loss_entropy"]
    reused = torch.autograd.grad(total, list(net.parameters()))
    # reference: the critic runs the trunk again on its own copy of the minibatch
    torch.manual_seed(0)
    actor_out = loss(steps.clone())
    value = net.critic()(steps.clone())[VALUE_KEY]
    critic_loss = LossConfig().critic_coeff * torch.nn.functional.smooth_l1_loss(
        value, steps["agents", "value_target"]
    )
    assert torch.allclose(actor_out["loss_critic"], critic_loss, atol=1e-6)
    separate = actor_out["loss_objective"] + actor_out["loss_entropy"] + critic_loss
    assert torch.allclose(separate, total)
    for mine, reference in zip(reused, torch.autograd.grad(separate, list(net.parameters()))):
        assert torch.allclose(mine, reference, atol=1e-6, rtol=1e-5)


@pytest.mark.parametrize("method", ["dsac", "matdn"])
def test_under_autocast_only_the_trunk_runs_in_bfloat16(method, small_net):
    net = small_net(method)
    steps = robot_steps(make_loss(net, LossConfig()), sampled_rollout(net, method))
    with torch.autocast("cpu", dtype=torch.bfloat16):
        out = net.actor()(steps.clone())
        value = net.critic()(steps.clone())[VALUE_KEY]
    assert out[FEATURES_KEY].dtype == torch.bfloat16
    assert out["agents", "loc"].dtype == out[LOG_PROB_KEY].dtype == value.dtype == torch.float32
    # float32 features: the heads are unchanged outside autocast
    reference = net.actor()(steps.clone())
    assert reference[FEATURES_KEY].dtype == torch.float32
    assert torch.allclose(out["agents", "loc"], reference["agents", "loc"], atol=0.05)


@pytest.mark.parametrize("method", ["dsac", "matdn"])
def test_clip_ppo_loss_reaches_every_parameter(method, small_net):
    net = small_net(method)
    loss = make_loss(net, LossConfig())
    steps = robot_steps(loss, sampled_rollout(net, method))
    assert steps.shape == (12,)
    out = loss(steps)
    assert {"loss_objective", "loss_critic", "loss_entropy"} <= set(out.keys())
    (out["loss_objective"] + out["loss_critic"] + out["loss_entropy"]).backward()
    no_grad = [n for n, p in net.named_parameters() if p.grad is None or not p.grad.abs().sum() > 0]
    assert no_grad == []
    # one set of trunk parameters: the actor and the critic share it, the optimiser sees it once
    assert len({id(p) for p in loss.parameters()}) == len(list(net.parameters()))


def test_matdn_memory_holds_the_past_embeddings_and_empties_at_episode_start(small_net):
    net = small_net("matdn")
    trunk = net.trunk.module
    rollout = sampled_rollout(net, "matdn", steps=7, world=CORRIDOR)
    pixels = rollout["agents", "pixels"][:, 0]  # [T, H, W, 3], robot 0
    with torch.no_grad():
        embeddings = trunk.encoder(pixels)  # e_t, [T, d]
    mask = rollout["agents", "memory_mask"][:, 0]  # [T, M]: at step t the memory holds e_0 .. e_{t-1}
    assert mask.sum(-1).tolist() == [0, 1, 2, 3, 4, 4, 4]
    memory = rollout["agents", "memory"][:, 0]
    for t in range(1, 7):
        filled = min(t, 4)
        assert torch.allclose(memory[t, -filled:], embeddings[t - filled : t], atol=1e-5)
        assert (memory[t, : 4 - filled] == 0).all()

    # a step with step_count 0 starts from an empty memory, whatever memory it is given
    td = rollout[5].exclude("next").clone()
    fresh = td.clone()
    fresh.set(("agents", "step_count"), torch.zeros_like(td["agents", "step_count"]))
    empty = fresh.clone()
    empty.set(MEMORY_KEY, torch.zeros_like(td[MEMORY_KEY]))
    empty.set(MEMORY_MASK_KEY, torch.zeros_like(td[MEMORY_MASK_KEY]))
    missing = fresh.clone().exclude(MEMORY_KEY, MEMORY_MASK_KEY)
    with torch.no_grad():
        outs = [net.trunk(x.clone()) for x in (fresh, empty, missing, td)]
    for out in outs[1:3]:
        assert torch.equal(out[FEATURES_KEY], outs[0][FEATURES_KEY])
    assert outs[0][("next", *MEMORY_MASK_KEY)].sum(-1).tolist() == [1]  # only the current embedding
    assert not torch.allclose(outs[3][FEATURES_KEY], outs[0][FEATURES_KEY])  # a full memory is read


def test_matdn_reads_only_filled_slots(small_net):
    """Attention covers the filled slots and the current embedding: what lies in an empty slot is ignored."""
    net = small_net("matdn")
    rollout = sampled_rollout(net, "matdn", steps=3, world=CORRIDOR)
    td = rollout[2].exclude("next").clone()  # memory: 2 of 4 slots filled (the newest two)
    assert td[MEMORY_MASK_KEY][0].tolist() == [False, False, True, True]
    noisy = td.clone()
    memory = noisy[MEMORY_KEY].clone()
    memory[:, :2] = torch.randn_like(memory[:, :2]) * 10
    noisy.set(MEMORY_KEY, memory)
    changed = td.clone()
    memory = changed[MEMORY_KEY].clone()
    memory[:, 2:] = torch.randn_like(memory[:, 2:]) * 10
    changed.set(MEMORY_KEY, memory)
    with torch.no_grad():
        base, ignored, read = (net.trunk(x)[FEATURES_KEY] for x in (td, noisy, changed))
    assert torch.allclose(base, ignored, atol=1e-6)
    assert not torch.allclose(base, read, atol=1e-3)


def test_policies_run_on_a_flat_batch_of_robot_steps(small_net):
    """The PPO update feeds robot-steps without a robot dimension; DSAC's trunk maps each independently."""
    net = small_net("dsac")
    rollout = sampled_rollout(net, "dsac", steps=2)
    flat = TensorDict({"agents": rollout["agents"].reshape(-1)}, batch_size=[4])
    with torch.no_grad():
        features = net.trunk(flat.clone())[FEATURES_KEY]
        per_robot = net.trunk(rollout.exclude("next").clone())[FEATURES_KEY].reshape(4, -1)
    assert torch.allclose(features, per_robot, atol=1e-6)
    assert SMALL["dsac"].hidden == features.shape[-1]
