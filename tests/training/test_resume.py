"""Resume equality: 6 iterations straight == 3 iterations, checkpoint, a new process-like trainer, 3 more."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import pytest
import torch
from safetensors.torch import load_file

from navformer_rl.training import LogWindow, build_trainer, train
from navformer_rl.training.checkpoint import load_resume_state


def scalars(run_dir: Path, name: str) -> list[tuple[int, float]]:
    """The (step, value) rows of a CSV scalar file, in file order (duplicates kept)."""
    path = run_dir / "logs" / "navformer" / "scalars" / f"{name}.csv"
    with open(path) as handle:
        return [(int(step), float(value)) for step, value in csv.reader(handle)]


def crash_after_checkpoint(cfg) -> None:
    """A run that checkpoints at iteration 3, then runs (and logs) iteration 4 and "crashes": the trainer is
    dropped, so a resume must drop the row it logged after its checkpoint."""
    trainer = build_trainer(cfg)
    for _ in range(3):
        trainer.record(trainer.step())
    trainer.save_checkpoint()
    assert trainer.record(trainer.step())


def weights(run_dir: Path, iteration: int) -> dict[str, torch.Tensor]:
    return load_file(str(run_dir / "checkpoints" / f"iter_{iteration:06d}" / "model.safetensors"))


@pytest.mark.parametrize(
    "encoder_training, extra",
    [
        ("joint", []),
        ("joint", ["optim.encoder_optimizer=adamw"]),
        ("frozen", []),
        # float16 autocast on CPU is slow (~80 s here): checked with the slow tests
        pytest.param("joint", ["model.autocast_dtype=float16"], marks=pytest.mark.slow),
    ],
    ids=["joint", "joint-adamw", "frozen", "joint-float16"],
)
def test_resumed_run_equals_uninterrupted_run(tiny_config, tmp_path, encoder_training, extra):
    common = [f"encoder_training={encoder_training}", "optim.iterations=6", "checkpoint.keep_last=0", *extra]
    straight = train(tiny_config(*common, f"output_dir={tmp_path / 'straight'}", "checkpoint.interval=6"))

    # First process: checkpoint at iteration 3, one more iteration (its row is logged), then a "crash".
    interrupted_dir = tmp_path / "interrupted"
    crash_after_checkpoint(tiny_config(*common, f"output_dir={interrupted_dir}", "checkpoint.interval=3"))

    resumed = train(
        tiny_config(*common, f"output_dir={interrupted_dir}", "checkpoint.interval=3", "resume=true")
    )
    assert resumed.iterations == straight.iterations == 6

    for name in ("loss", "loss_dt", "loss_byol"):
        a, b = scalars(straight.run_dir, name), scalars(interrupted_dir, name)
        # the row the crashed process logged after its checkpoint (step 4) was dropped, not duplicated
        assert [step for step, _ in b] == [1, 2, 3, 4, 5, 6], name
        assert a == b, name
    assert [s for s, _ in scalars(interrupted_dir, "loss_dt_exploration")] == [1, 3, 5]  # D_e: odd iterations
    assert [s for s, _ in scalars(interrupted_dir, "loss_dt_collision_avoidance")] == [2, 4, 6]

    wa, wb = weights(straight.run_dir, 6), weights(interrupted_dir, 6)
    assert wa.keys() == wb.keys()
    for key in wa:
        assert torch.equal(wa[key], wb[key]), key
    ra, rb = load_resume_state(straight.checkpoint), load_resume_state(resumed.checkpoint)
    for key, value in ra["byol"].items():  # EMA target params, BYOL heads' BatchNorm statistics
        assert torch.equal(value, rb["byol"][key]), key
    # float16 autocast trains with loss scaling, whose state is part of the resume part
    scaled = "model.autocast_dtype=float16" in extra
    assert ("grad_scaler" in ra) == scaled
    if scaled:
        assert ra["grad_scaler"] == rb["grad_scaler"] and ra["grad_scaler"]["scale"] > 0
    assert straight.metrics == {
        **resumed.metrics,
        "frames_per_s": straight.metrics["frames_per_s"],
        "iteration_s": straight.metrics["iteration_s"],
    }


def test_drawing_batches_ahead_changes_nothing_but_the_wait(tiny_config, tmp_path):
    """data.prefetch draws the same batches: the same losses and weights; a run without it resumes a run
    with it (its checkpoint holds the samplers' state of the batches trained on, not of the one drawn
    ahead)."""
    common = ["optim.iterations=4", "checkpoint.keep_last=0"]
    plain = train(tiny_config(*common, "data.prefetch=false", f"output_dir={tmp_path / 'plain'}"))
    ahead_dir = tmp_path / "ahead"
    crash_after_checkpoint(tiny_config(*common, "checkpoint.interval=3", f"output_dir={ahead_dir}"))
    resumed = train(
        tiny_config(
            *common, "checkpoint.interval=3", "resume=true", "data.prefetch=false", f"output_dir={ahead_dir}"
        )
    )
    assert resumed.iterations == 4
    for name in ("loss", "loss_dt", "loss_byol"):
        assert scalars(plain.run_dir, name) == scalars(ahead_dir, name), name
    wa, wb = weights(plain.run_dir, 4), weights(ahead_dir, 4)
    assert all(torch.equal(wa[key], wb[key]) for key in wa)
    assert load_resume_state(plain.checkpoint)["cross_task"]["iteration"] == 4


def test_a_checkpoint_with_the_former_sampler_state_resumes_the_same(tiny_config, tmp_path):
    """Checkpoints written before CrossTaskReplayBuffer hold the CrossTaskSampler's layout, ``{"iteration",
    <task>: the trajectory sampler's state}``: they resume on the batches an uninterrupted run draws."""
    common = ["optim.iterations=4", "checkpoint.keep_last=0", "data.prefetch=false"]
    plain = train(tiny_config(*common, f"output_dir={tmp_path / 'plain'}"))
    old_dir = tmp_path / "old"
    crash_after_checkpoint(tiny_config(*common, "checkpoint.interval=3", f"output_dir={old_dir}"))
    resume_file = old_dir / "checkpoints" / "iter_000003" / "resume.pt"
    state = torch.load(resume_file, weights_only=True)
    cross_task = state["cross_task"]
    assert cross_task["exploration"]["generator"] is None  # the batchers' samplers own their generators
    state["cross_task"] = {"iteration": cross_task["iteration"]} | {
        task: cross_task[task]["sampler"] for task in ("exploration", "collision_avoidance")
    }
    torch.save(state, resume_file)
    resumed = train(tiny_config(*common, "checkpoint.interval=3", "resume=true", f"output_dir={old_dir}"))
    assert resumed.iterations == 4
    for name in ("loss", "loss_dt", "loss_byol"):
        assert scalars(plain.run_dir, name) == scalars(old_dir, name), name
    wa, wb = weights(plain.run_dir, 4), weights(old_dir, 4)
    assert all(torch.equal(wa[key], wb[key]) for key in wa)


@pytest.mark.parametrize("dtype, scaled", [(None, False), ("bfloat16", False), ("float16", True)])
def test_loss_scaling_only_under_float16(tiny_config, dtype, scaled):
    overrides = [] if dtype is None else [f"model.autocast_dtype={dtype}"]
    trainer = build_trainer(tiny_config(*overrides))
    assert trainer.scaler.is_enabled() is scaled
    assert ("grad_scaler" in trainer.resume_state()) is scaled


def test_resume_refuses_a_changed_configuration(tiny_config, tmp_path):
    run = tmp_path / "run"
    train(tiny_config("optim.iterations=2", f"output_dir={run}"))
    with pytest.raises(ValueError, match=r"differs in \['optim.lr'\]"):
        train(tiny_config("optim.iterations=4", f"output_dir={run}", "resume=true", "optim.lr=1e-3"))


def test_resume_without_checkpoint_starts_fresh_and_finished_run_is_a_no_op(tiny_config, tmp_path):
    run = tmp_path / "run"
    result = train(tiny_config("optim.iterations=2", f"output_dir={run}", "resume=true"))
    assert result.iterations == 2
    again = train(tiny_config("optim.iterations=2", f"output_dir={run}", "resume=true"))
    assert again.iterations == 2 and again.metrics == {} and again.checkpoint == result.checkpoint


def test_log_window_averages_each_metric_over_the_iterations_that_reported_it():
    window = LogWindow()
    window.add({"loss": 1.0, "loss_dt_exploration": 0.5, "frames": 10.0, "iteration_s": 1.0, "lr": 2e-4})
    window.add(
        {"loss": 3.0, "loss_dt_collision_avoidance": 2.5, "frames": 30.0, "iteration_s": 1.0, "lr": 1e-4}
    )
    restored = LogWindow()
    restored.load_state_dict(window.state_dict())
    assert len(restored) == 2
    row = restored.pop_row()
    assert row == {
        "loss": 2.0,
        "loss_dt_exploration": 0.5,  # only the D_e iteration
        "loss_dt_collision_avoidance": 2.5,
        "frames": 20.0,
        "iteration_s": 1.0,
        "frames_per_s": 20.0,  # 40 frames in 2 s, not the mean of the two rates
        "lr": 1e-4,  # the logged iteration's own value
    }
    assert len(restored) == 0 and restored.pop_row() == {}


def test_every_log_row_summarises_its_window_also_across_a_resume(tiny_config, tmp_path):
    """An even log interval (D_e on odd iterations, D_ca on even) still logs both tasks; a checkpoint
    between two rows (interval 3 vs 2) resumes with the unlogged iterations, so the rows match."""
    common = ["optim.iterations=6", "checkpoint.keep_last=0", "logger.log_interval=4"]
    straight = train(tiny_config(*common, f"output_dir={tmp_path / 'straight'}", "checkpoint.interval=6"))
    # rows at 4 and at the last iteration (6), each averaging its window
    assert [s for s, _ in scalars(straight.run_dir, "loss")] == [4, 6]
    assert [s for s, _ in scalars(straight.run_dir, "loss_dt_exploration")] == [4, 6]
    assert [s for s, _ in scalars(straight.run_dir, "loss_dt_collision_avoidance")] == [4, 6]
    # the crashed process: checkpoint at 3 (iterations 1-3 not logged yet), a row at 4, then gone
    interrupted_dir = tmp_path / "interrupted"
    crash_after_checkpoint(tiny_config(*common, f"output_dir={interrupted_dir}", "checkpoint.interval=3"))
    train(tiny_config(*common, f"output_dir={interrupted_dir}", "checkpoint.interval=3", "resume=true"))
    for name in ("loss", "loss_dt", "loss_dt_exploration", "loss_dt_collision_avoidance", "loss_byol", "tau"):
        assert scalars(interrupted_dir, name) == scalars(straight.run_dir, name), name


def test_a_run_that_crashed_before_its_first_checkpoint_restarts_its_logs(tiny_config, tmp_path):
    run = tmp_path / "run"
    cfg = tiny_config("optim.iterations=3", f"output_dir={run}", "checkpoint.interval=3")
    trainer = build_trainer(cfg)
    for _ in range(2):
        trainer.record(trainer.step())
    del trainer  # crashed before iteration 3's checkpoint: nothing to resume from
    train(tiny_config("optim.iterations=3", f"output_dir={run}", "checkpoint.interval=3", "resume=true"))
    assert [s for s, _ in scalars(run, "loss")] == [1, 2, 3]  # not 1, 2, 1, 2, 3


def test_rng_restore_sets_the_states_of_the_gpus_it_sees(monkeypatch):
    """A checkpoint saved with 2 visible GPUs resumes where 1 is visible (and the other way round)."""
    from navformer_rl.training.checkpoint import capture_rng_state, restore_rng_state

    state = capture_rng_state()
    state["cuda"] = [torch.zeros(16, dtype=torch.uint8), torch.ones(16, dtype=torch.uint8)]
    restored = []
    monkeypatch.setattr(torch.cuda, "is_available", lambda: True)
    monkeypatch.setattr(torch.cuda, "set_rng_state", lambda s, device: restored.append((device, int(s[0]))))
    monkeypatch.setattr(torch.cuda, "device_count", lambda: 1)
    restore_rng_state(state)
    assert restored == [(0, 0)]
    restored.clear()
    monkeypatch.setattr(torch.cuda, "device_count", lambda: 4)
    restore_rng_state(state)
    assert restored == [(0, 0), (1, 1)]


def test_a_checkpoint_from_before_a_new_key_resumes_with_that_keys_default(tiny_config, tmp_path):
    """A key added to the config after a checkpoint was written (here ssl.loss_weight) counts as its
    default when resuming; a checkpoint that recorded another value is still refused."""
    import json

    run = tmp_path / "run"
    first = train(tiny_config("optim.iterations=2", f"output_dir={run}"))
    header_path = first.checkpoint / "config.json"
    header = json.loads(header_path.read_text())
    del header["train_config"]["ssl"]["loss_weight"]  # as written by the version before the key existed
    header_path.write_text(json.dumps(header))
    assert train(tiny_config("optim.iterations=3", f"output_dir={run}", "resume=true")).iterations == 3

    other = tmp_path / "other"
    train(tiny_config("optim.iterations=2", f"output_dir={other}", "ssl.loss_weight=0.5"))
    with pytest.raises(ValueError, match=r"differs in \['ssl.loss_weight'\]"):
        train(tiny_config("optim.iterations=3", f"output_dir={other}", "resume=true"))


@pytest.mark.parametrize(("encoder_training", "legacy_optimizer"), [("joint", "adamw"), ("frozen", "adam")])
def test_a_checkpoint_from_before_the_encoder_optimizer_key_resumes_with_its_own_optimiser(
    tiny_config, tmp_path, encoder_training, legacy_optimizer
):
    """A run recorded before ``optim.encoder_optimizer`` existed had its encoders under AdamW (``joint``) or
    Adam (``frozen``): it resumes with that optimiser named, and a resume with the other one is refused."""
    import json

    run = tmp_path / "run"
    common = [f"encoder_training={encoder_training}", f"output_dir={run}"]
    first = train(tiny_config(*common, "optim.iterations=2", f"optim.encoder_optimizer={legacy_optimizer}"))
    header_path = first.checkpoint / "config.json"
    header = json.loads(header_path.read_text())
    del header["train_config"]["optim"]["encoder_optimizer"]  # as written before the key existed
    header_path.write_text(json.dumps(header))
    other = "adam" if legacy_optimizer == "adamw" else "adamw"
    with pytest.raises(ValueError, match=r"differs in \['optim.encoder_optimizer'\]"):
        train(tiny_config(*common, "optim.iterations=3", "resume=true", f"optim.encoder_optimizer={other}"))
    resumed = tiny_config(
        *common, "optim.iterations=3", "resume=true", f"optim.encoder_optimizer={legacy_optimizer}"
    )
    assert train(resumed).iterations == 3


@pytest.mark.parametrize(
    ("override", "section", "key", "value"),
    [
        ("keep_freed_memory=false", None, "keep_freed_memory", False),
        ("optim.length_groups=2", "optim", "length_groups", 2),
    ],
)
def test_resume_may_change_a_setting_that_keeps_the_objective(
    tiny_config, tmp_path, override, section, key, value
):
    """The allocator setting and ``optim.length_groups`` (the same loss and gradient) may change on resume."""
    run = tmp_path / "run"
    train(tiny_config("optim.iterations=2", f"output_dir={run}"))
    resumed = train(tiny_config("optim.iterations=3", f"output_dir={run}", "resume=true", override))
    assert resumed.iterations == 3
    recorded = json.loads((run / "train_config.json").read_text())
    assert (recorded[section] if section else recorded)[key] == value
