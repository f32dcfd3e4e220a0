"""Held-out validation during training (navformer_rl.training.validation): fixed windows, the eq. 10 value, no
effect on the training, the logged rows and their resume, and the configuration errors."""

from __future__ import annotations

import pytest
import torch

from navformer_rl.data import make_synthetic_dataset, open_dataset
from navformer_rl.training import build_trainer, train
from navformer_rl.training.checkpoint import capture_rng_state
from navformer_rl.training.validation import FixedTrajectoryBatches, evaluation_mode, teacher_forced_loss

from .test_resume import scalars, weights

HELD_OUT = ("loss_dt_exploration", "loss_dt_collision_avoidance")
TRAINING = ("train_loss_dt_exploration", "train_loss_dt_collision_avoidance")


@pytest.fixture(scope="module")
def held_out(tmp_path_factory):
    """Held-out D_e (5 trajectories, 4-14 steps) and D_ca (3, 3-9 steps), other seeds than the training's."""
    root = tmp_path_factory.mktemp("held_out")
    return {
        "e": make_synthetic_dataset(root / "e", "e", 5, 4, 14, seed=21),
        "ca": make_synthetic_dataset(root / "ca", "ca", 3, 3, 9, seed=22),
    }


def validation_overrides(held_out, *extra: str) -> list[str]:
    return [
        f"validation.exploration_path={held_out['e']}",
        f"validation.collision_path={held_out['ca']}",
        *extra,
    ]


def crash_after_checkpoint(cfg) -> None:
    """The loop of ``train`` (validating when due) up to a checkpoint at iteration 3, then iteration 4 (its
    rows are logged), then a "crash"."""
    trainer = build_trainer(cfg)
    for _ in range(4):
        trainer.record(trainer.step())
        if trainer.validation_due():
            trainer.log(trainer.validate(), timings=False)
        if trainer.iteration == 3:
            trainer.save_checkpoint()


def test_fixed_batches_cover_each_trajectory_once_with_the_same_windows(held_out):
    dataset = open_dataset(held_out["e"], kind="e")
    lengths = dataset.episodes.length
    a = FixedTrajectoryBatches(dataset, batch_trajs=2, context_steps=6, seed=3)
    batches = list(a)
    assert [b.shape[0] for b in batches] == [2, 2, 1]
    ids = torch.cat([b["trajectory"] for b in batches])
    assert sorted(ids.tolist()) == list(range(5))
    for batch in batches:
        # one window per trajectory, cut to the 6-step context, padded only to the batch's longest window
        expected = lengths[batch["trajectory"]].clamp(max=6)
        assert torch.equal(batch["mask"].sum(1), expected)
        assert batch["mask"].shape[1] == int(expected.max())
    # the same seed gives the same windows, pass after pass and object after object
    again = FixedTrajectoryBatches(dataset, batch_trajs=5, context_steps=6, seed=3)
    (whole,) = list(again)
    order = [int(i) for i in whole["trajectory"]]
    assert order == ids.tolist()
    for name in ("pixels", "action", "step"):
        flat = torch.cat([b[name][b["mask"]] for b in batches])
        assert torch.equal(flat, whole[name][whole["mask"]]), name
    assert a.valid_steps == int(lengths.clamp(max=6).sum())
    subset = FixedTrajectoryBatches(dataset, batch_trajs=4, context_steps=6, seed=3, max_trajectories=3)
    assert len(subset) == 3 and torch.equal(subset.trajectory, ids[:3])


def test_loss_is_eq10_over_all_valid_steps_whatever_the_batching(tiny_config, held_out):
    trainer = build_trainer(tiny_config())
    dataset = open_dataset(held_out["e"], kind="e")
    one_batch = FixedTrajectoryBatches(dataset, batch_trajs=5, context_steps=8, seed=0)
    one_by_one = FixedTrajectoryBatches(dataset, batch_trajs=1, context_steps=8, seed=0)
    actor = trainer.dt_loss.actor_network
    with evaluation_mode(trainer.model):
        # hand computation: squared error summed over the 2 action dims, averaged over the valid steps
        (batch,) = list(one_batch)
        prediction = actor(batch.clone())["action_pred"]
        error = (prediction - batch["action"]).pow(2).sum(-1)[batch["mask"]]
        expected = float(error.mean())
        got_one = teacher_forced_loss(trainer.dt_loss, one_batch, trainer.device)
        got_many = teacher_forced_loss(trainer.dt_loss, one_by_one, trainer.device)
    assert error.numel() == one_batch.valid_steps
    assert got_one == pytest.approx(expected, rel=1e-6)
    assert got_many == pytest.approx(expected, rel=1e-5)  # padding and batch size do not enter


def test_evaluation_mode_restores_the_training_mode_and_the_random_states(tiny_config):
    trainer = build_trainer(tiny_config())
    before = capture_rng_state()
    with evaluation_mode(trainer.model):
        assert not trainer.model.training and not torch.is_grad_enabled()
        torch.rand(3), __import__("random").random()
    after = capture_rng_state()
    assert trainer.model.training and torch.is_grad_enabled()
    assert torch.equal(before["torch"], after["torch"]) and before["python"] == after["python"]


def test_validation_is_logged_and_leaves_the_training_bit_identical(tiny_config, held_out, tmp_path):
    common = ["optim.iterations=5", "checkpoint.keep_last=0", "checkpoint.interval=5"]
    plain = train(tiny_config(*common, f"output_dir={tmp_path / 'plain'}"))
    validated = train(
        tiny_config(
            *common,
            *validation_overrides(held_out, "validation.interval=2"),
            f"output_dir={tmp_path / 'val'}",
        )
    )
    for name in ("loss", "loss_dt", "loss_byol"):
        assert scalars(plain.run_dir, name) == scalars(validated.run_dir, name), name
    wa, wb = weights(plain.run_dir, 5), weights(validated.run_dir, 5)
    assert all(torch.equal(wa[key], wb[key]) for key in wa)
    rows = {name: scalars(validated.run_dir, f"validation/{name}") for name in HELD_OUT + TRAINING}
    for name, values in rows.items():
        assert [step for step, _ in values] == [2, 4, 5], name  # every 2 iterations and the last
        assert all(value > 0 for _, value in values), name
    assert not (plain.run_dir / "logs" / "navformer" / "scalars" / "validation").exists()

    # the logged value is the eval-mode loss of that iteration's weights: rebuilt from the final checkpoint
    # (dropout off, so scoring again gives the same number)
    again = build_trainer(
        tiny_config(
            *common, *validation_overrides(held_out), f"output_dir={validated.run_dir}", "resume=true"
        )
    )
    assert again.iteration == 5
    scores = again.validate()
    assert scores == again.validate()
    for name, values in rows.items():
        assert scores[f"validation/{name}"] == pytest.approx(values[-1][1], rel=1e-6), name


def test_a_resumed_run_logs_the_same_validation_rows(tiny_config, held_out, tmp_path):
    common = [
        "optim.iterations=6",
        "checkpoint.keep_last=0",
        *validation_overrides(held_out, "validation.interval=2"),
    ]
    straight = train(tiny_config(*common, "checkpoint.interval=6", f"output_dir={tmp_path / 'straight'}"))
    interrupted = tmp_path / "interrupted"
    crash_after_checkpoint(tiny_config(*common, "checkpoint.interval=3", f"output_dir={interrupted}"))
    # the validation settings may change on resume (they do not touch the training)
    train(
        tiny_config(
            *common,
            "checkpoint.interval=3",
            "resume=true",
            "validation.batch_trajs=1",
            f"output_dir={interrupted}",
        )
    )
    for name in HELD_OUT + TRAINING:
        a, b = scalars(straight.run_dir, f"validation/{name}"), scalars(interrupted, f"validation/{name}")
        assert [s for s, _ in a] == [s for s, _ in b] == [2, 4, 6], name
        assert [v for _, v in a] == pytest.approx([v for _, v in b], rel=1e-5), name


def test_the_training_comparison_follows_the_data_the_ablation_trains_on(tiny_config, held_out):
    trainer = build_trainer(tiny_config("ablation=no_de", *validation_overrides(held_out)))
    assert sorted(trainer.validator.sets) == [
        "loss_dt_collision_avoidance",
        "loss_dt_exploration",
        "train_loss_dt_collision_avoidance",
    ]
    # the training comparison scores min(training_trajectories, dataset) windows: all 8 tiny D_ca ones
    assert len(trainer.validator.sets["train_loss_dt_collision_avoidance"]) == 8
    assert len(trainer.validator.sets["loss_dt_collision_avoidance"]) == 3
    fewer = build_trainer(tiny_config(*validation_overrides(held_out, "validation.training_trajectories=2")))
    assert len(fewer.validator.sets["train_loss_dt_exploration"]) == 2
    only_ca = build_trainer(
        tiny_config(f"validation.collision_path={held_out['ca']}", "validation.compare_training=false")
    )
    assert sorted(only_ca.validator.sets) == ["loss_dt_collision_avoidance"]
    assert build_trainer(tiny_config()).validator is None  # no held-out path: no validation
    off = build_trainer(tiny_config(*validation_overrides(held_out, "validation.interval=0")))
    assert off.validator is None and off.validate() == {}


@pytest.mark.parametrize(
    "overrides, error, message",
    [
        (["validation.exploration_path=/nonexistent/e"], FileNotFoundError, "validation.exploration_path="),
        (["validation.interval=-1"], ValueError, "validation.interval must be an integer >= 0"),
        (["validation.batch_trajs=0"], ValueError, "validation.batch_trajs must be an integer >= 1"),
        (["validation.max_trajectories=0"], ValueError, "validation.max_trajectories must be"),
        (["validation.training_trajectories=0"], ValueError, "validation.training_trajectories must be"),
        (["validation.seed=-3"], ValueError, "validation.seed must be a non-negative integer"),
        (["validation.shuffle=true"], ValueError, "validation.shuffle"),
    ],
)
def test_bad_validation_settings_are_refused_before_training(tiny_config, overrides, error, message):
    with pytest.raises(error, match=message):
        build_trainer(tiny_config(*overrides))


def test_a_held_out_dataset_of_the_wrong_kind_is_refused(tiny_config, held_out):
    with pytest.raises(ValueError, match="validation.exploration_path"):
        build_trainer(tiny_config(f"validation.exploration_path={held_out['ca']}"))


@pytest.mark.parametrize("head", [[], ["model.action_bins=5"]], ids=["paper_head", "action_bins"])
def test_scoring_a_checkpoint_offline_gives_the_logged_validation(
    tiny_config, held_out, tmp_path, capsys, head
):
    """The offline score is eq. 10's squared error; so is the logged validation, a binned head's too."""
    from navformer_rl.cli import main
    from navformer_rl.training.validation import score_checkpoints

    run = train(
        tiny_config(
            "optim.iterations=4",
            "checkpoint.interval=2",
            "checkpoint.keep_last=0",
            *validation_overrides(held_out, "validation.interval=2"),
            f"output_dir={tmp_path / 'run'}",
            *head,
        )
    )
    folders = sorted((run.run_dir / "checkpoints").glob("iter_*"))
    rows = score_checkpoints([str(f) for f in folders], {"e": str(held_out["e"]), "ca": str(held_out["ca"])})
    assert [row["iteration"] for row in rows] == [2, 4]
    for name in HELD_OUT:
        logged = scalars(run.run_dir, f"validation/{name}")
        assert [row[name] for row in rows] == pytest.approx([value for _, value in logged], rel=1e-6), name

    out = tmp_path / "val.json"
    assert (
        main(
            [
                "validate",
                "--checkpoint",
                str(run.run_dir),
                "--collision",
                str(held_out["ca"]),
                "--json",
                str(out),
            ]
        )
        == 0
    )
    printed = capsys.readouterr().out
    assert (
        "| loss_dt_collision_avoidance |" in printed
        and f"{rows[1]['loss_dt_collision_avoidance']:.4f}" in printed
    )
    assert __import__("json").loads(out.read_text())[0]["iteration"] == 4


def test_scoring_on_the_training_windows_of_a_short_window_run_gives_its_logged_validation(
    tiny_config, held_out, tmp_path
):
    """A run trained with ``data.context_steps=2`` validates on 2-step windows; ``context_steps=2`` offline
    scores the same windows, the default (the whole window) others."""
    from navformer_rl.training.validation import score_checkpoints

    run = train(
        tiny_config(
            "optim.iterations=2",
            "data.context_steps=2",
            *validation_overrides(held_out, "validation.interval=2"),
            f"output_dir={tmp_path / 'run'}",
        )
    )
    datasets = {"e": str(held_out["e"]), "ca": str(held_out["ca"])}
    (short,) = score_checkpoints([str(run.run_dir)], datasets, context_steps=2)
    (whole,) = score_checkpoints([str(run.run_dir)], datasets)
    for name in HELD_OUT:
        (logged,) = [value for _, value in scalars(run.run_dir, f"validation/{name}")]
        assert short[name] == pytest.approx(logged, rel=1e-6), name
        assert whole[name] != pytest.approx(logged, rel=1e-6), name


@pytest.mark.parametrize(
    "arguments, message",
    [
        ([], "give --exploration DIR and / or --collision DIR"),
        (["--collision", "{ca}", "--context-steps", "300"], "context_steps (--context-steps)=300: expected"),
        (["--exploration", "{ca}"], "holds a 'ca' dataset, expected 'e'"),
        (["--collision", "/nonexistent/ca"], "ca dataset '/nonexistent/ca' does not exist"),
        (["--collision", "{ca}", "--device", "tpu"], "device"),
    ],
)
def test_validate_command_refuses_bad_input_in_one_line(
    tiny_config, held_out, tmp_path, capsys, arguments, message
):
    from navformer_rl.cli import main

    run = train(tiny_config("optim.iterations=1", f"output_dir={tmp_path / 'run'}"))
    arguments = [a.format(ca=held_out["ca"]) for a in arguments]
    assert main(["validate", "--checkpoint", str(run.run_dir), *arguments]) == 2
    error = capsys.readouterr().err
    assert (
        error.startswith("navformer validate: error:") and message in error and len(error.splitlines()) == 1
    )


def test_validate_command_names_a_bad_flag(held_out, capsys):
    from navformer_rl.cli import main

    with pytest.raises(SystemExit) as exit_info:
        main(["validate", "--checkpoint", "x", "--collision", str(held_out["ca"]), "--batch-trajs", "0"])
    assert exit_info.value.code == 2
    assert capsys.readouterr().err.splitlines()[-1] == (
        "navformer validate: error: argument --batch-trajs: expected an integer >= 1, got 0"
    )
