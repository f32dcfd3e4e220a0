"""PPO checkpoints: the house layout, save/load equality, refusals, and update-level resume equality."""

from __future__ import annotations

import pytest
import torch

from navformer_rl.baselines.online import build_net, load_online_net, load_online_policy
from navformer_rl.online.config import LossConfig, OptimConfig
from navformer_rl.online.ppo import make_loss, make_optimizer, ppo_update, robot_steps
from navformer_rl.training import checkpoint as ckpt

from .conftest import SMALL
from .test_policies import sampled_rollout


@pytest.mark.parametrize("method", ["dsac", "matdn"])
def test_saved_and_loaded_networks_are_equal_and_act_alike(method, ppo_checkpoints):
    run_dir, net = ppo_checkpoints[method]
    loaded, config = load_online_net(run_dir, method)
    assert config == SMALL[method]
    saved = net.state_dict()
    assert loaded.state_dict().keys() == saved.keys()
    assert all(torch.equal(loaded.state_dict()[k], v) for k, v in saved.items())
    policy, _ = load_online_policy(run_dir / "checkpoints" / "iter_000001" / "model.safetensors", method)
    td = sampled_rollout(net, method, steps=2)[1].exclude("next")
    assert torch.equal(policy(td.clone())["agents", "action"], policy(td.clone())["agents", "action"])
    with torch.no_grad():
        expected = torch.tanh(net.actor()(td.clone())["agents", "loc"])
    assert torch.equal(policy(td.clone())["agents", "action"], expected)


def test_a_checkpoint_of_another_method_is_refused(ppo_checkpoints):
    run_dir, _ = ppo_checkpoints["dsac"]
    with pytest.raises(
        ValueError, match="holds the dsac baseline, not matdn; evaluate it with --method dsac"
    ):
        load_online_net(run_dir, "matdn")
    with pytest.raises(ValueError, match="unknown online method 'dt'"):
        load_online_net(run_dir, "dt")
    with pytest.raises(FileNotFoundError, match="no checkpoint"):
        load_online_net(run_dir / "missing", "dsac")


def test_a_ppo_checkpoint_read_as_navformer_names_its_method(ppo_checkpoints):
    run_dir, _ = ppo_checkpoints["matdn"]
    expected = r"holds the matdn baseline .*`navformer evaluate --method matdn` evaluates it"
    with pytest.raises(ValueError, match=expected):
        ckpt.load_policy_model(run_dir)
    with pytest.raises(ValueError, match=expected):
        ckpt.read_model_config(run_dir)


def test_resuming_from_a_checkpoint_gives_the_uninterrupted_update(tmp_path, small_net):
    """Two PPO updates in a row equal one update, a checkpoint, a restore into fresh objects, one update."""
    torch.set_num_threads(1)
    optim_cfg = OptimConfig(lr=1e-3, epochs=2, minibatch_size=8)

    def build():
        net = small_net("dsac")
        loss = make_loss(net, LossConfig())
        optimizer = make_optimizer(loss, optim_cfg)
        return net, loss, optimizer

    net, loss, optimizer = build()
    batches = [robot_steps(loss, sampled_rollout(net, "dsac", steps=4, seed=s)) for s in (1, 2)]
    straight_net, straight_loss, straight_opt = build()
    torch.manual_seed(7)
    for batch in batches:
        ppo_update(straight_loss, straight_opt, batch.clone(), optim_cfg)

    first_net, first_loss, first_opt = build()
    torch.manual_seed(7)
    ppo_update(first_loss, first_opt, batches[0].clone(), optim_cfg)
    folder = ckpt.save_checkpoint(
        tmp_path,
        1,
        model_state=first_net.state_dict(),
        model_config={"method": "dsac", **SMALL["dsac"].to_dict()},
        train_config={},
        resume_state={"optimizer": first_opt.state_dict(), "rng": ckpt.capture_rng_state()},
    )
    del first_net, first_loss, first_opt
    resumed_net, resumed_loss, resumed_opt = build()
    resumed_net.load_state_dict(ckpt.load_model_state(folder)[1])
    resume = ckpt.load_resume_state(folder)
    resumed_opt.load_state_dict(resume["optimizer"])
    ckpt.restore_rng_state(resume["rng"])
    ppo_update(resumed_loss, resumed_opt, batches[1].clone(), optim_cfg)

    expected = straight_net.state_dict()
    assert all(torch.equal(resumed_net.state_dict()[k], v) for k, v in expected.items())
    assert not torch.equal(expected["policy_head.0.weight"], build()[0].state_dict()["policy_head.0.weight"])


def test_state_dict_has_one_copy_of_the_shared_trunk():
    net = build_net("matdn", SMALL["matdn"])
    keys = list(net.state_dict())
    assert any(k.startswith("trunk.") for k in keys) and any(k.startswith("value_head.") for k in keys)
    assert not any(k.startswith(("actor", "critic", "_views")) for k in keys)
