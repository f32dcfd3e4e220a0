"""BYOLLoss (eqs. 6-8): loss values, EMA target, tau schedule, shared encoders, augmentations, and TorchRL's
loss contract (``TestBYOLLoss``)."""

import math

import pytest
import torch
from tensordict import TensorDict
from torchrl.objectives import SoftUpdate

from navformer_rl.modules import NavFormerConfig, NavFormerModel, make_navformer_actor
from navformer_rl.objectives import (
    ActionMSELoss,
    BYOLLoss,
    BYOLTauSchedule,
    byol_tau,
    joint_parameters,
    normalized_mse,
)
from navformer_rl.objectives.byol_augment import BYOLAugmentation

from .contract import LossContract


def pairs(n=8, seed=0):
    gen = torch.Generator().manual_seed(seed)
    shape = (n, 84, 84, 3)
    return TensorDict(
        {
            "pixels_static": torch.randint(0, 256, shape, dtype=torch.uint8, generator=gen),
            "pixels_dynamic": torch.randint(0, 256, shape, dtype=torch.uint8, generator=gen),
        },
        batch_size=[n],
    )


def make_byol(seed=0, **kwargs):
    torch.manual_seed(seed)
    model = NavFormerModel(NavFormerConfig(dropout=0.0))  # deterministic DT loss for gradient comparisons
    return model, BYOLLoss(model.static_encoder, model.general_encoder, seed=seed, **kwargs)


def test_normalized_mse_known_values():
    x = torch.tensor([[1.0, 0.0], [1.0, 0.0], [1.0, 0.0], [3.0, 4.0]])
    y = torch.tensor([[2.0, 0.0], [0.0, 5.0], [-1.0, 0.0], [0.6, 0.8]])
    # identical directions -> 0, orthogonal -> 2, opposite -> 4, scale does not matter
    torch.testing.assert_close(normalized_mse(x, y), torch.tensor([0.0, 2.0, 4.0, 0.0]))


def test_tau_schedule_follows_the_cosine_formula():
    assert byol_tau(0, 100) == pytest.approx(0.996)
    assert byol_tau(50, 100) == pytest.approx(0.998)
    assert byol_tau(100, 100) == pytest.approx(1.0)
    assert byol_tau(25, 100) == pytest.approx(1 - 0.004 * (math.cos(math.pi / 4) + 1) / 2)
    _, loss = make_byol()
    updater = SoftUpdate(loss, eps=0.9)
    schedule = BYOLTauSchedule(updater, total_steps=100)
    assert updater.eps == pytest.approx(0.996)
    schedule.step()
    assert updater.eps == pytest.approx(byol_tau(1, 100))
    restored = BYOLTauSchedule(updater, total_steps=100)
    restored.load_state_dict({"step_count": 50})
    assert updater.eps == pytest.approx(0.998)


def byol_by_hand(loss: BYOLLoss, batch: TensorDict, seed: int = 0) -> dict[str, torch.Tensor]:
    """Eqs. 6-8 recomputed from the loss's branches, with an augmentation replaying ``seed``'s first draws:
    ``{"static": ..., "general": ..., "loss_byol": their sum}``."""
    replay = BYOLAugmentation(seed=seed)
    v_d1 = replay(batch["pixels_dynamic"])
    v_s, v_d2 = replay(batch["pixels_static"]), replay(batch["pixels_dynamic"])
    assert (v_d1 - v_d2).abs().max() > 1e-3  # two different augmentations of o^d
    terms = {}
    for name, (a, b) in {"static": (v_s, v_d1), "general": (v_d1, v_d2)}.items():
        both = torch.cat([a, b])
        online = loss.online_network[name]
        projection = online(both)
        prediction = loss.predictor[name](projection)
        with torch.no_grad(), loss.target_online_network_params.to_module(loss.online_network):
            target = online(both)
        p_a, p_b = prediction.chunk(2)
        t_a, t_b = target.chunk(2)
        terms[name] = (normalized_mse(p_a, t_b) + normalized_mse(p_b, t_a)).mean()
    terms["loss_byol"] = terms["static"] + terms["general"]
    return terms


def test_loss_value_equals_the_symmetric_normalised_mse_of_its_branches():
    model, loss = make_byol()
    batch = pairs()
    out = loss(batch)
    assert set(out.keys()) == set(loss.out_keys)  # out_keys lists every entry forward writes
    expected = byol_by_hand(loss, batch)
    for name in ("static", "general"):
        torch.testing.assert_close(out[f"byol_{name}"], expected[name], rtol=1e-5, atol=1e-6)
    torch.testing.assert_close(out["loss_byol"], expected["loss_byol"], rtol=1e-5, atol=1e-6)
    assert 0 <= out["byol_static"] <= 8 and out["projection_std_general"] > 0


def test_target_gets_no_gradient_and_is_not_a_parameter():
    _, loss = make_byol()
    loss(pairs())["loss_byol"].backward()
    parameter_ids = {id(p) for p in loss.parameters()}
    targets = list(loss.target_online_network_params.values(True, True))
    assert targets and all(id(t) not in parameter_ids for t in targets)
    assert all(t.grad is None for t in targets)
    online = list(loss.online_network_params.values(True, True))
    assert any(p.grad is not None and p.grad.abs().sum() > 0 for p in online if p.requires_grad)


def test_ema_target_follows_the_formula_after_one_update():
    _, loss = make_byol()
    updater = SoftUpdate(loss, eps=0.99)
    before = loss.target_online_network_params.clone()
    optimizer = torch.optim.SGD(loss.parameters(), lr=0.5)
    loss(pairs())["loss_byol"].backward()
    optimizer.step()
    updater.step()
    online = loss.online_network_params
    checked = 0
    for key, new_target in loss.target_online_network_params.items(True, True):
        if not isinstance(online[key], torch.nn.Parameter):
            continue  # BatchNorm running statistics move with the forward passes themselves
        checked += 1
        expected = 0.99 * before[key] + 0.01 * online[key].detach()
        torch.testing.assert_close(new_target, expected, rtol=1e-6, atol=1e-7)
    assert checked == len(list(loss.online_network.parameters()))
    weight = ("static", "encoder", "linear", "weight")
    assert not torch.equal(loss.target_online_network_params[weight], before[weight])  # it moved
    assert not torch.equal(loss.target_online_network_params[weight], online[weight].detach())  # not a copy


def test_encoders_are_shared_with_the_model_and_one_step_trains_both_losses(td_factory):
    model, byol = make_byol()
    assert byol.online_network["static"].encoder is model.static_encoder
    assert byol.online_network["general"].encoder is model.general_encoder
    dt = ActionMSELoss(make_navformer_actor(model))
    params = joint_parameters(dt, byol)
    assert len({id(p) for p in params}) == len(params)
    assert {id(p) for p in model.parameters()} <= {id(p) for p in params}
    td, batch = td_factory(2, 3), pairs()
    weight = model.static_encoder.linear.weight
    dt(td)["loss_dt"].backward()
    grad_dt = weight.grad.clone()
    weight.grad = None
    byol(batch)["loss_byol"].backward()
    grad_byol = weight.grad.clone()
    weight.grad = None
    byol.augmentation.set_rng_state(BYOLAugmentation(seed=0).rng_state())  # replay the same views
    (dt(td)["loss_dt"] + byol(batch)["loss_byol"]).backward()  # eq. 11
    torch.testing.assert_close(weight.grad, grad_dt + grad_byol, rtol=1e-4, atol=1e-7)


def test_single_encoder_byol_and_bad_arguments():
    torch.manual_seed(0)
    model = NavFormerModel(NavFormerConfig.dt_baseline())
    loss = BYOLLoss(None, model.general_encoder)
    out = loss(TensorDict({"pixels_dynamic": pairs()["pixels_dynamic"]}, batch_size=[8]))
    assert set(out.keys()) == {"loss_byol", "byol_general", "projection_std_general"}
    torch.testing.assert_close(out["loss_byol"], out["byol_general"])
    with pytest.raises(ValueError, match="at least one"):
        BYOLLoss(None, None)


def test_augmentation_draws_parameters_per_sample_and_is_seeded():
    image = torch.randint(
        0, 256, (1, 84, 84, 3), dtype=torch.uint8, generator=torch.Generator().manual_seed(0)
    )
    batch = image.expand(6, 84, 84, 3).contiguous()
    global_state = torch.get_rng_state()
    views = BYOLAugmentation(seed=3)(batch)
    assert torch.equal(torch.get_rng_state(), global_state)  # the global RNG is untouched
    assert views.shape == (6, 3, 84, 84) and views.dtype == torch.float32
    assert 0 <= views.min() and views.max() <= 1
    for i in range(1, 6):  # the same image gets a different view in every row
        assert (views[i] - views[0]).abs().max() > 1e-3
    torch.testing.assert_close(BYOLAugmentation(seed=3)(batch), views)
    assert (BYOLAugmentation(seed=4)(batch) - views).abs().max() > 1e-3


def test_resnet18_byol_step_keeps_batch_statistics_in_the_heads_only():
    torch.manual_seed(0)
    model = NavFormerModel(NavFormerConfig.ablation("resnet18"))  # a single (general) ResNet18 encoder
    assert model.static_encoder is None
    loss = BYOLLoss(None, model.general_encoder)
    updater = SoftUpdate(loss, eps=0.996)
    optimizer = torch.optim.AdamW(loss.parameters(), lr=1e-3)
    batch = TensorDict({"pixels_dynamic": pairs(4)["pixels_dynamic"]}, batch_size=[4])
    # the encoder's GroupNorm keeps no running statistics; BYOL's projector/predictor BatchNorm1d do
    assert not list(model.general_encoder.buffers())
    head_stats = "online_network_params.general.projector.1.running_mean"
    assert torch.count_nonzero(loss.state_dict()[head_stats]) == 0
    norm = model.general_encoder.stem[1]
    assert isinstance(norm, torch.nn.GroupNorm)
    norm_weight = norm.weight.detach().clone()
    first = loss(batch)["loss_byol"]
    first.backward()
    optimizer.step()
    updater.step()
    assert torch.isfinite(first) and torch.isfinite(loss(batch)["loss_byol"])
    assert not torch.equal(norm.weight.detach(), norm_weight)  # the GroupNorm affine parameters train
    state = loss.state_dict()
    assert not any("encoder" in key and "running" in key for key in state)
    # training-mode BatchNorm1d updated the heads' statistics, and the EMA target keeps its own copy
    online = state[head_stats]
    target = state["target_" + head_stats]
    assert torch.count_nonzero(online) == online.numel()
    assert target.data_ptr() != online.data_ptr() and torch.count_nonzero(target) == target.numel()


def test_augmentation_does_not_depend_on_the_chunk_size():
    batch = torch.randint(
        0, 256, (10, 84, 84, 3), dtype=torch.uint8, generator=torch.Generator().manual_seed(1)
    )
    whole = BYOLAugmentation(seed=5, chunk=1000)(batch)
    torch.testing.assert_close(BYOLAugmentation(seed=5, chunk=3)(batch), whole)


def test_augmentation_writes_the_requested_dtype_and_layout():
    pixels = torch.randint(
        0, 256, (6, 84, 84, 3), dtype=torch.uint8, generator=torch.Generator().manual_seed(1)
    )
    reference = BYOLAugmentation(seed=4)(pixels)
    views = BYOLAugmentation(seed=4)(pixels, dtype=torch.bfloat16, channels_last=True)
    assert views.dtype == torch.bfloat16 and views.is_contiguous(memory_format=torch.channels_last)
    assert torch.equal(views, reference.to(torch.bfloat16))  # the same views, rounded once


def test_soft_update_can_be_made_after_the_loss_has_run():
    """TorchRL users often build the target updater after a first forward; the target parameters must
    still be free of gradients then."""
    _, loss = make_byol()
    loss(pairs())
    assert not any(p.requires_grad for p in loss.target_online_network_params.values(True, True))
    # TorchRL's eps is BYOL's tau: target <- eps * target + (1 - eps) * online
    updater = SoftUpdate(loss, eps=0.99)
    online, target = loss.online_network_params, loss.target_online_network_params
    gen = torch.Generator().manual_seed(0)
    with torch.no_grad():  # an optimiser step's worth of change, so that online and target differ
        for p in online.values(True, True):
            if p.requires_grad:
                p.add_(0.1 * torch.randn(p.shape, generator=gen))
    old_target, old_online = target.detach().clone(), online.detach().clone()
    updater.step()
    assert not any(p.requires_grad for p in target.values(True, True))
    moved = 0
    for key, p in online.items(True, True):
        new = target.get(key)
        if p.requires_grad:  # a parameter: the EMA step
            expected = 0.99 * old_target.get(key) + 0.01 * old_online.get(key)
            torch.testing.assert_close(new, expected, rtol=1e-5, atol=1e-6)
            moved += int(not torch.equal(new, old_target.get(key)))
        else:  # a buffer (BatchNorm statistics): SoftUpdate leaves it alone
            assert torch.equal(new, old_target.get(key))
    assert moved > 0
    assert (online.detach() == old_online).all()  # the online branch is not touched


def test_train_and_eval_reach_the_heads_batchnorm():
    """convert_to_functional keeps the projector / predictor outside the child modules: eval() still
    reaches their BatchNorm (running statistics, not batch statistics)."""
    from navformer_rl.modules import NavFormerConfig, NavFormerModel

    model = NavFormerModel(NavFormerConfig())
    loss = BYOLLoss(model.static_encoder, model.general_encoder)
    norms = [
        m
        for net in (loss.online_network, loss.predictor)
        for m in net.modules()
        if isinstance(m, torch.nn.BatchNorm1d)
    ]
    assert norms and all(m.training for m in norms)
    assert loss.eval() is loss and not any(m.training for m in norms)
    loss.train()
    assert all(m.training for m in norms)


class TestBYOLLoss(LossContract):
    """TorchRL's loss contract (:class:`~tests.objectives.contract.LossContract`) for L_BYOL (eq. 8)."""

    out_keys = ("loss_byol", "byol_static", "byol_general", "projection_std_static", "projection_std_general")
    default_keys = {"pixels_static": "pixels_static", "pixels_dynamic": "pixels_dynamic"}

    @staticmethod
    def make(seed: int = 0) -> tuple[NavFormerModel, BYOLLoss]:
        torch.manual_seed(seed)
        model = NavFormerModel(NavFormerConfig(dropout=0.0))
        return model, BYOLLoss(model.static_encoder, model.general_encoder, seed=0)  # the same augmentations

    def batch(self) -> TensorDict:
        return pairs(4)

    def trained(self, model):
        return model.dve  # the encoders BYOL shares with the model

    def equation(self, model, loss, td) -> torch.Tensor:
        return byol_by_hand(loss, td)["loss_byol"]  # the first call's augmentations, replayed

    def renamed(self, model, td):
        _, default = self.make()
        expected = default(td)["loss_byol"].detach()
        _, loss = self.make()
        loss.set_keys(pixels_static=("pair", "static"), pixels_dynamic="dynamic")
        assert set(loss.in_keys) == {("pair", "static"), "dynamic"}
        moved = TensorDict(
            {("pair", "static"): td["pixels_static"], "dynamic": td["pixels_dynamic"]},
            batch_size=td.batch_size,
        )
        return loss, moved, expected

    def test_reset_parameters_recursive_restarts_the_target_from_the_online_branch(self):
        model, loss = self.make()
        updater = SoftUpdate(loss, eps=0.5)
        optimizer = torch.optim.SGD(loss.parameters(), lr=1.0)
        loss(pairs(4))["loss_byol"].backward()
        optimizer.step()
        updater.step()  # the target now differs from the online networks
        online, target = loss.online_network_params, loss.target_online_network_params
        weight = ("static", "encoder", "linear", "weight")
        assert not torch.equal(target[weight], online[weight].data)
        shared = model.static_encoder.linear.weight
        heads = {
            "projector": online["general", "projector", "0", "weight"].detach().clone(),
            "predictor": loss.predictor_params["static", "0", "weight"].detach().clone(),
        }
        loss.reset_parameters_recursive()
        assert model.static_encoder.linear.weight is shared  # the model's own parameter, re-drawn in place
        assert not torch.equal(online["general", "projector", "0", "weight"], heads["projector"])
        assert not torch.equal(loss.predictor_params["static", "0", "weight"], heads["predictor"])
        assert (target == online.data).all()  # the EMA target restarts as a copy of the online branch

    def test_the_target_gets_no_gradient(self):
        _, loss = self.make()
        loss(pairs(4))["loss_byol"].backward()
        assert all(t.grad is None for t in loss.target_online_network_params.values(True, True))
        for params in (loss.online_network_params, loss.predictor_params):
            for name in ("static", "general"):
                grads = [p.grad for p in params[name].values(True, True) if isinstance(p, torch.nn.Parameter)]
                assert grads and all(g is not None for g in grads), name

    def test_torchrl_sum_of_both_losses_is_eq_11(self, td_factory):
        model, byol = self.make()
        dt = ActionMSELoss(make_navformer_actor(model))
        outputs = [dt(td_factory(2, 3)), byol(pairs(4))]
        # what a TorchRL trainer optimises: every entry whose name starts with "loss"
        total = sum(value for out in outputs for key, value in out.items() if key.startswith("loss"))
        torch.testing.assert_close(total, outputs[0]["loss_dt"] + outputs[1]["loss_byol"], rtol=0, atol=0)


def test_bf16_autocast_gives_the_fp32_loss_to_bf16_precision_and_gradients():
    """``autocast_dtype="bfloat16"`` (the CPU training lever) computes eq. 8 in bf16: close to fp32,
    finite grads."""
    _, fp32 = make_byol(seed=3)
    model, bf16 = make_byol(seed=3, autocast_dtype="bfloat16")
    batch = pairs(8, seed=1)
    reference = fp32(batch.clone())["loss_byol"]
    out = bf16(batch.clone())
    torch.testing.assert_close(out["loss_byol"].float(), reference, rtol=5e-2, atol=5e-2)
    out["loss_byol"].backward()
    grads = [p.grad for p in model.static_encoder.parameters()]
    assert all(g is not None and torch.isfinite(g).all() for g in grads) and any(
        g.abs().sum() > 0 for g in grads
    )
