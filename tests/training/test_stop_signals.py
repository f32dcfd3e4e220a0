"""Ctrl-C and SIGTERM during training: the iteration under way finishes, a checkpoint is saved, the resume
equals the uninterrupted run; a second signal stops at once; the command reports it in one line."""

from __future__ import annotations

import os
import signal
from pathlib import Path

import pytest
import torch
from safetensors.torch import load_file

from navformer_rl.cli.main import main
from navformer_rl.training import train
from navformer_rl.training.trainer import Trainer
from navformer_rl.utils.interrupts import Terminated

COMMON = ["optim.iterations=6", "checkpoint.keep_last=0", "checkpoint.interval=100"]


def signal_after(monkeypatch, iteration: int, *signums: int) -> None:
    """Make ``Trainer.step`` send ``signums`` to this process right after finishing ``iteration``."""
    step = Trainer.step

    def step_then_signal(self: Trainer) -> dict[str, float]:
        metrics = step(self)
        if self.iteration == iteration:
            for signum in signums:
                os.kill(os.getpid(), signum)
        return metrics

    monkeypatch.setattr(Trainer, "step", step_then_signal)


def checkpoints(run_dir: Path) -> list[str]:
    return sorted(p.name for p in (run_dir / "checkpoints").glob("iter_*"))


@pytest.mark.parametrize(
    "signum, raised", [(signal.SIGTERM, Terminated), (signal.SIGINT, KeyboardInterrupt)], ids=["term", "int"]
)
def test_a_signal_checkpoints_the_finished_iteration_and_the_resume_equals_the_straight_run(
    tiny_config, tmp_path, monkeypatch, signum, raised
):
    straight = train(tiny_config(*COMMON, f"output_dir={tmp_path / 'straight'}"))
    handlers = signal.getsignal(signal.SIGINT), signal.getsignal(signal.SIGTERM)
    stopped = tmp_path / "stopped"
    with monkeypatch.context() as patch:
        signal_after(patch, 4, signum)
        with pytest.raises(raised) as info:
            train(tiny_config(*COMMON, f"output_dir={stopped}"))
    assert type(info.value) is raised
    assert (signal.getsignal(signal.SIGINT), signal.getsignal(signal.SIGTERM)) == handlers
    assert checkpoints(stopped) == ["iter_000004"]  # not due before iteration 100, saved on the signal

    resumed = train(tiny_config(*COMMON, f"output_dir={stopped}", "resume=true"))
    assert resumed.iterations == 6
    final = "checkpoints/iter_000006/model.safetensors"
    a, b = load_file(str(straight.run_dir / final)), load_file(str(stopped / final))
    assert a.keys() == b.keys() and all(torch.equal(a[key], b[key]) for key in a)


def test_a_second_signal_stops_at_once_without_a_checkpoint(tiny_config, tmp_path, monkeypatch):
    signal_after(monkeypatch, 2, signal.SIGTERM, signal.SIGTERM)
    run_dir = tmp_path / "run"
    with pytest.raises(Terminated):
        train(tiny_config(*COMMON, f"output_dir={run_dir}"))
    assert checkpoints(run_dir) == []


def test_a_signal_after_the_last_iteration_ends_the_run_normally(tiny_config, tmp_path, monkeypatch):
    signal_after(monkeypatch, 6, signal.SIGTERM)
    result = train(tiny_config(*COMMON, f"output_dir={tmp_path / 'run'}"))
    assert result.iterations == 6 and checkpoints(result.run_dir) == ["iter_000006"]


def test_the_train_command_reports_sigterm_in_one_line_with_status_143(
    base_overrides, tmp_path, monkeypatch, capsys
):
    signal_after(monkeypatch, 3, signal.SIGTERM)
    run_dir = tmp_path / "run"
    assert main(["train", *base_overrides, *COMMON, f"output_dir={run_dir}"]) == 143
    assert capsys.readouterr().err.strip().splitlines()[-1] == (
        "navformer train: terminated (finished work is kept; rerun to resume)"
    )
    assert checkpoints(run_dir) == ["iter_000003"]
