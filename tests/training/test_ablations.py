"""Every ablation of Table IV (and the DT baseline) builds and trains 2 iterations; the two encoder-training
modes give the optimisers the right parameters; trajectory chunks reproduce the whole-batch gradient."""

from __future__ import annotations

import math

import pytest
import torch

from navformer_rl.training import ABLATIONS, build_trainer, train, train_step
from navformer_rl.training.checkpoint import load_policy_model

EXPECTED_TASKS = {"no_de": ["collision_avoidance"] * 2, "no_dca": ["exploration"] * 2}


@pytest.mark.parametrize("ablation", list(ABLATIONS))
def test_every_ablation_trains_two_iterations(tiny_config, ablation):
    smaller = ["data.collision_batch_trajs=2", "data.ssl_batch_pairs=2"] if ablation == "resnet18" else []
    result = train(tiny_config(f"ablation={ablation}", "optim.iterations=2", *smaller))
    assert result.iterations == 2
    metrics = result.metrics
    assert math.isfinite(metrics["loss"]) and metrics["loss_dt"] > 0
    with_ssl = ablation not in ("no_ssl", "dt")
    assert ("loss_byol" in metrics) is with_ssl
    if with_ssl:
        assert metrics["loss"] == pytest.approx(metrics["loss_dt"] + metrics["loss_byol"])  # eq. 11
    else:
        assert metrics["loss"] == metrics["loss_dt"]
    tasks = EXPECTED_TASKS.get(ablation, ["exploration", "collision_avoidance"])
    assert f"loss_dt_{tasks[-1]}" in metrics  # the second iteration's task
    config, model = load_policy_model(result.run_dir)
    encoders = [name for name, _ in model.observation_encoders()]
    expected_encoders = {
        "no_fs": ["general"],
        "no_fg": ["static"],
        "resnet18": ["general"],
        "dt": ["general"],
    }.get(ablation, ["static", "general"])
    assert encoders == expected_encoders
    # BYOL trains exactly the encoders the model has (eq. 8 per encoder)
    byol_terms = sorted(k.removeprefix("byol_") for k in metrics if k.startswith("byol_"))
    assert byol_terms == (sorted(expected_encoders) if with_ssl else [])
    assert config.thsc is (ablation not in ("no_thsc", "dt"))
    assert config.encoder == ("resnet18" if ablation == "resnet18" else "cnn")


def _ids(params):
    return {id(p) for p in params}


def _owners(trainer) -> dict[str, set[int]]:
    return {
        name: {id(p) for g in opt.param_groups for p in g["params"]}
        for name, opt in trainer.optimizers.items()
    }


@pytest.mark.parametrize(
    ("overrides", "encoder_owner"),
    [
        ((), "dve"),  # the default: §VI's split, the encoders under Adam while both losses reach them
        (("optim.encoder_optimizer=adam",), "dve"),
        (("optim.encoder_optimizer=adamw",), "navformer"),
        (("encoder_training=frozen",), "dve"),
        (("encoder_training=frozen", "optim.encoder_optimizer=adamw"), "navformer"),
    ],
)
def test_optimisers_own_the_right_parameters(tiny_config, overrides, encoder_owner):
    trainer = build_trainer(tiny_config(*overrides, "optim.iterations=1"))
    groups = _owners(trainer)
    encoders = _ids(p for _, enc in trainer.model.observation_encoders() for p in enc.parameters())
    model = _ids(trainer.model.parameters())
    heads = _ids(trainer.byol_loss.parameters()) - model  # BYOL projectors + predictors
    assert not groups["navformer"] & groups["dve"]
    assert groups["navformer"] | groups["dve"] == model | heads
    assert encoders <= groups[encoder_owner]
    assert heads <= groups["dve"]
    assert groups["navformer"] - encoders == model - encoders  # embeddings, transformer, head: AdamW
    navformer, dve = trainer.optimizers["navformer"], trainer.optimizers["dve"]
    assert isinstance(navformer, torch.optim.AdamW)
    assert (navformer.param_groups[0]["lr"], navformer.param_groups[0]["weight_decay"]) == (2e-4, 1e-4)
    assert type(dve) is torch.optim.Adam
    assert (dve.param_groups[0]["lr"], dve.param_groups[0]["weight_decay"]) == (4e-4, 4e-4)


@pytest.mark.parametrize(
    ("ablation", "dve_owns_encoders"), [("no_ssl", True), ("dt", False), ("no_fs", True)]
)
def test_the_ablations_encoder_optimiser(tiny_config, ablation, dve_owns_encoders):
    """NavFormer's ablations keep §VI's split (no_ssl: an Adam of the encoders alone); DT, with one encoder
    and no DVE, trains everything with AdamW and has no Adam."""
    trainer = build_trainer(tiny_config(f"ablation={ablation}", "optim.iterations=1"))
    groups = _owners(trainer)
    encoders = _ids(p for _, enc in trainer.model.observation_encoders() for p in enc.parameters())
    assert trainer.cfg.optim.encoder_optimizer == ("adam" if dve_owns_encoders else "adamw")
    if dve_owns_encoders:
        assert encoders <= groups["dve"] and not encoders & groups["navformer"]
    else:
        assert set(groups) == {"navformer"} and groups["navformer"] == _ids(trainer.model.parameters())
    assert math.isfinite(trainer.step()["loss"])


def test_both_losses_reach_the_encoders_under_the_split(tiny_config):
    """eq. 11 with §VI's optimisers: L_DT and L_BYOL each give every encoder a gradient, and one iteration's
    Adam step moves the encoders (Adam's state holds them)."""
    trainer = build_trainer(tiny_config("optim.iterations=1"))
    batch = trainer.cross_task.sample()
    encoders = [p for _, enc in trainer.model.observation_encoders() for p in enc.parameters()]
    batch = batch.select("pixels", "action", "return_to_go", "step", "mask", "target_pixels")
    for loss in (
        lambda: trainer.dt_loss(batch)["loss_dt"],
        lambda: trainer.byol_loss(trainer.pairs.sample())["loss_byol"],
    ):
        trainer.model.zero_grad(set_to_none=True)
        loss().backward()
        grads = [p.grad for p in encoders]
        assert all(g is not None for g in grads) and sum(float(g.abs().sum()) for g in grads) > 0
    before = [p.detach().clone() for p in encoders]
    trainer.step()
    assert all(not torch.equal(b, p) for b, p in zip(before, encoders, strict=True))
    assert all(p in trainer.optimizers["dve"].state for p in encoders)


def test_a_bad_encoder_optimiser_is_named(tiny_config):
    with pytest.raises(
        ValueError, match=r"optim.encoder_optimizer='sgd': expected null .* \['adam', 'adamw'\]"
    ):
        build_trainer(tiny_config("optim.encoder_optimizer=sgd"))


def test_frozen_mode_keeps_the_dt_loss_out_of_the_encoders(tiny_config):
    trainer = build_trainer(tiny_config("encoder_training=frozen", "optim.iterations=1"))
    batch = trainer.cross_task.sample()
    trainer.dt_loss(batch.select("pixels", "action", "return_to_go", "step", "mask", "target_pixels"))[
        "loss_dt"
    ].backward()
    for _, encoder in trainer.model.observation_encoders():
        assert all(p.grad is None for p in encoder.parameters())
    assert trainer.model.head.weight.grad is not None


def test_trajectory_chunks_give_the_whole_batch_gradient(tiny_config, tmp_path):
    """Known answer: with dropout off, chunking the D_e batch of 2 in 2 leaves the update unchanged."""
    results = {}
    for chunks in (1, 2):
        trainer = build_trainer(
            tiny_config(
                "model.dropout=0.0",
                "ablation=no_ssl",
                # AdamW's first step is ~lr * sign(gradient); Adam's coupled weight decay could flip the sign
                # of a near-zero encoder gradient on float noise, hiding what this test compares
                "optim.encoder_optimizer=adamw",
                f"optim.trajectory_chunks={chunks}",
                f"output_dir={tmp_path / str(chunks)}",
                "optim.iterations=1",
                "data.collision_batch_trajs=4",
            )
        )
        metrics = trainer.step()
        results[chunks] = (metrics["loss_dt"], {k: v.clone() for k, v in trainer.model.state_dict().items()})
    assert results[2][0] == pytest.approx(results[1][0], rel=1e-6)
    for key, value in results[1][1].items():
        torch.testing.assert_close(results[2][1][key], value, rtol=1e-5, atol=1e-6)


def test_length_levers_give_the_whole_batch_gradient_without_the_padding(tiny_config, tmp_path):
    """Known answer: with dropout off, a batch of trajectories of four lengths gives the same loss and
    gradients in one padded forward, in length-sorted chunks cropped to their own longest window
    (``optim.chunks_by_length``) and with the transformer run in length groups (``optim.length_groups``)."""
    batch = build_trainer(
        tiny_config("optim.iterations=1", f"output_dir={tmp_path / 'draw'}")
    ).cross_task.sample()
    batch = batch.select("pixels", "action", "return_to_go", "step", "mask", "target_pixels").clone()
    steps = batch["mask"].shape[1]
    keep = [steps, max(steps // 2, 1), max(steps // 4, 1), 1][: batch.shape[0]]
    batch["mask"] = batch["mask"] & (torch.arange(steps) < torch.tensor(keep)[:, None])
    assert batch["mask"].sum(1).unique().numel() > 1  # the lengths differ, so cropping drops padding
    grads, losses = {}, {}
    for name, overrides in {
        "padded": ["optim.trajectory_chunks=1"],
        "by_length": ["optim.trajectory_chunks=2", "optim.chunks_by_length=true"],
        "length_groups": ["optim.length_groups=3"],
    }.items():
        trainer = build_trainer(
            tiny_config(
                "model.dropout=0.0",
                "ablation=no_ssl",
                "optim.iterations=1",
                "data.exploration_batch_trajs=4",
                f"output_dir={tmp_path / name}",
                *overrides,
            )
        )
        out = train_step(trainer.learner, batch.clone(), None, trainer.backward)  # the gradients stay
        losses[name] = float(out.loss_dt)
        grads[name] = {n: p.grad.clone() for n, p in trainer.model.named_parameters() if p.grad is not None}
        trainer.close()
    for lever in ("by_length", "length_groups"):
        assert losses[lever] == pytest.approx(losses["padded"], rel=1e-6)
        assert grads[lever].keys() == grads["padded"].keys()
        for name, grad in grads["padded"].items():  # float32 sums in another order: relative to the norm
            error = (grads[lever][name] - grad).norm() / grad.norm().clamp_min(1e-12)
            assert error < 1e-5, (lever, name)


def test_byol_loss_weight_scales_byols_share_of_the_gradient(tiny_config, tmp_path):
    """Known answer: L = L_DT + w L_BYOL, so every gradient is g_DT + w g_BYOL. Over the same batches and
    dropout masks, g_BYOL = (g(1) - g(0.5)) / 0.5, and then g(0.1) must equal g(1) - 0.9 g_BYOL."""
    grads, metrics = {}, {}
    for weight in (1.0, 0.5, 0.1):
        trainer = build_trainer(
            tiny_config(
                f"ssl.loss_weight={weight}", "optim.iterations=1", f"output_dir={tmp_path / str(weight)}"
            )
        )
        task, batch, pairs = trainer.batches.next(draw_ahead=False)
        out = train_step(trainer.learner, batch, pairs)  # the gradients stay after the optimisers' steps
        grads[weight] = {n: p.grad.clone() for n, p in trainer.model.named_parameters() if p.grad is not None}
        metrics[weight] = (
            float(out.loss_dt),
            float(out.byol["loss_byol"].detach()),
            float(out.loss_byol.detach()),
        )
        trainer.close()
    # the logged BYOL loss is unweighted; the one summed into L is weighted
    assert metrics[0.5][1] == pytest.approx(metrics[1.0][1], rel=1e-6)
    assert metrics[0.5][2] == pytest.approx(0.5 * metrics[1.0][1], rel=1e-6)
    byol_share = {n: (grads[1.0][n] - grads[0.5][n]) / 0.5 for n in grads[1.0]}
    encoder = "static_encoder"
    assert any(
        encoder in n and byol_share[n].abs().max() > 0 for n in byol_share
    )  # BYOL reaches the encoders
    for name, g in grads[0.1].items():
        torch.testing.assert_close(g, grads[1.0][name] - 0.9 * byol_share[name], rtol=1e-4, atol=1e-6)


def test_byol_loss_weight_must_be_positive(tiny_config):
    with pytest.raises(ValueError, match="ssl.loss_weight"):
        build_trainer(tiny_config("ssl.loss_weight=0"))


def test_the_binned_head_trains_chunked_like_whole_and_loads_back(tiny_config, tmp_path):
    """``model.action_bins``: the cross-entropy L_DT, the same update in trajectory chunks (known answer, as
    for the paper's head), and a checkpoint that loads back with its head."""
    results = {}
    for chunks in (1, 2):
        trainer = build_trainer(
            tiny_config(
                "model.dropout=0.0",
                "model.action_bins=5",
                "ablation=no_ssl",
                # AdamW's first step is ~lr * sign(gradient); Adam's coupled weight decay could flip the sign
                # of a near-zero encoder gradient on float noise, hiding what this test compares
                "optim.encoder_optimizer=adamw",
                f"optim.trajectory_chunks={chunks}",
                f"output_dir={tmp_path / str(chunks)}",
                "optim.iterations=1",
                "data.collision_batch_trajs=4",
            )
        )
        assert type(trainer.dt_loss).__name__ == "ActionBinLoss"
        metrics = trainer.step()
        results[chunks] = (metrics["loss_dt"], {k: v.clone() for k, v in trainer.model.state_dict().items()})
        trainer.close()
    assert (
        0 < results[1][0] <= 2 * math.log(5) + 1
    )  # cross-entropy of 2 action dims over 5 bins, near ln 5 each
    assert results[2][0] == pytest.approx(results[1][0], rel=1e-6)
    for key, value in results[1][1].items():
        torch.testing.assert_close(results[2][1][key], value, rtol=1e-5, atol=1e-6)
    result = train(
        tiny_config("model.action_bins=5", "optim.iterations=2", f"output_dir={tmp_path / 'saved'}")
    )
    config, model = load_policy_model(result.run_dir)
    assert config.action_bins == 5 and type(model.head).__name__ == "BinnedActionHead"
