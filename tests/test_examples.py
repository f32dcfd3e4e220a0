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
        # PYTHONPATH: the checkout under test, not wherever the environment installed navformer_rl
        env={
            "OMP_NUM_THREADS": "1",
            "PATH": "/usr/bin:/bin",
            "RL_LOGGING_LEVEL": "WARNING",
            "PYTHONPATH": str(ROOT),
        },
    )


def test_training_example_runs_and_alternates_tasks():
    out = run("examples/train_with_torchrl_pieces.py", "--iterations", "2")
    assert out.returncode == 0, out.stderr
    *iterations, held_out = [line.split() for line in out.stdout.splitlines() if line.strip()]
    assert [line[1] for line in iterations] == ["exploration", "collision_avoidance"]
    assert all(float(line[3]) > 0 and float(line[5]) > 0 for line in iterations)
    assert held_out[:3] == ["held-out", "D_e", "L_DT"] and float(held_out[3]) > 0


def test_compose_example_trains_on_torchrl_buffers_and_collects_without_warnings():
    out = run("examples/compose_with_torchrl.py", "--steps", "4", "--frames", "20")
    assert out.returncode == 0, out.stderr
    assert "Warning" not in out.stderr, out.stderr  # the Collector finds the transforms the policy needs
    steps = [line.split() for line in out.stdout.splitlines() if line.startswith("step ")]
    assert [line[2] for line in steps] == ["exploration", "collision_avoidance"] * 2
    assert all(float(line[-3]) > 0 and float(line[-1]) > 0 for line in steps)  # L_DT, L_BYOL
    collected = [
        line for line in out.stdout.splitlines() if line.startswith("collected (10,): actions (10, 2, 2)")
    ]
    assert len(collected) == 2


def test_swap_the_head_example_trains_and_decodes_with_its_own_head():
    out = run("examples/swap_the_head.py", "--iterations", "3")
    assert out.returncode == 0, out.stderr
    assert (
        "module=MLPHead(" in out.stdout
        and "in_keys=[('hidden', 'target'), ('hidden', 'observation')" in out.stdout
    )
    losses = [float(line.split()[-1]) for line in out.stdout.splitlines() if "L_DT" in line]
    assert len(losses) == 3 and losses[-1] < losses[0]
    decoded = [line for line in out.stdout.splitlines() if line.startswith("decoded step")]
    assert len(decoded) == 3


def test_pretrain_dve_example_feeds_a_frozen_dve_to_a_torchrl_actor():
    out = run("examples/pretrain_dve_with_byol.py", "--iterations", "2")
    assert out.returncode == 0, out.stderr
    losses = [float(line.split()[-1]) for line in out.stdout.splitlines() if "L_BYOL" in line]
    assert len(losses) == 2 and all(0 < loss < 16 for loss in losses)  # two encoders' terms, each in [0, 8]
    assert "action (3, 2), log-prob (3,)" in out.stdout
    trainable = int(out.stdout.split("trainable parameters after the frozen DVE: ")[1].split()[0])
    assert 0 < trainable < 100_000  # the MLP only: the DVE alone holds 414,272


@pytest.mark.parametrize(
    ("ablation", "parts"),
    [("none", ["DualVisualEncoder", "CausalTransformer", "THSCHead"]), ("dt", ["ObservationHead"])],
)
def test_module_tree_example_prints_every_part_with_its_keys(ablation, parts):
    out = run("examples/print_module_tree.py", "--ablation", ablation)
    assert out.returncode == 0, out.stderr
    for part in parts:
        assert f"  {part}  (" in out.stdout
    assert out.stdout.count("reads:") == 3 and "writes: action_pred" in out.stdout
    assert ("('embed', 'static')" in out.stdout) == (ablation == "none")


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
