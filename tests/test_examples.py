"""The examples and the top-level CLI run as documented."""

import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def run(*args: str, timeout: int = 300) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, *args],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=timeout,
        env={"OMP_NUM_THREADS": "1", "PATH": "/usr/bin:/bin", "RL_LOGGING_LEVEL": "WARNING"},
    )


def test_training_example_runs_and_alternates_tasks():
    out = run("examples/train_with_torchrl_pieces.py", "--iterations", "2")
    assert out.returncode == 0, out.stderr
    *iterations, held_out = [line.split() for line in out.stdout.splitlines() if line.strip()]
    assert [line[1] for line in iterations] == ["exploration", "collision_avoidance"]
    assert all(float(line[3]) > 0 and float(line[5]) > 0 for line in iterations)
    assert held_out[:3] == ["held-out", "D_e", "L_DT"] and float(held_out[3]) > 0


def test_custom_policy_example_is_evaluated(tmp_path):
    out = run(
        "examples/custom_policy_evaluation.py", "--out", str(tmp_path), "--trials", "1", "--max-steps", "20"
    )
    assert out.returncode == 0, out.stderr
    for name in ("make_colour_servo", "vrw"):
        assert (tmp_path / name / "episodes.jsonl").read_text().count("\n") == 2  # 1 trial x 2 robots
        assert (tmp_path / name / "summary.md").is_file()


def test_cli_lists_every_subcommand():
    out = run("-m", "navformer_rl.cli", "--help")
    assert out.returncode == 0
    for command in ("demo", "world-demo", "collect", "train", "validate", "evaluate"):
        assert command in out.stdout


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["world-demo", "--size", "3", "--out", "unused"], "size"),
        (["evaluate", "--method", "nonsense", "--protocol", "smoke", "--out", "unused"], "nonsense"),
        (["demo", "--iterations", "0", "--out", "unused"], "iterations"),
    ],
)
def test_cli_bad_input_is_one_clear_line(args, message, tmp_path):
    out = subprocess.run(
        [sys.executable, "-m", "navformer_rl.cli", *args],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert out.returncode == 2
    assert "Traceback" not in out.stderr
    assert message in out.stderr


def test_collector_example_collects_across_episode_resets():
    # 2 mazes x 30 steps with 12-step episodes: each env resets twice inside the collection
    out = run(
        "examples/collect_with_navformer_policy.py",
        "--frames",
        "60",
        "--frames-per-batch",
        "20",
        "--max-steps",
        "12",
    )
    assert out.returncode == 0, out.stderr
    batches = [line for line in out.stdout.splitlines() if line.startswith("batch (2, 10)")]
    assert len(batches) == 3
    assert "replay buffer: 60 env steps" in out.stdout and "'pixels'" in out.stdout
