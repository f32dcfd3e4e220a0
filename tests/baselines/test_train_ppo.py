"""``train_ppo`` / ``navformer train-ppo``: a tiny run end to end, resume, the configuration's checks."""

from __future__ import annotations

import csv
import json
import math
import re

import pytest
import torch

from navformer_rl.cli import main
from navformer_rl.online.config import PPOConfig, load_ppo_config, validate_ppo_config
from navformer_rl.online.curve import ProgressLog, running_mean
from navformer_rl.online.train import train_ppo
from navformer_rl.training import checkpoint as ckpt

TINY = [
    "method=matdn",
    "model.d_embed=16",
    "model.memory_size=2",
    "model.n_heads=2",
    "model.hidden=16",
    "env.sizes=[5.0]",
    "env.robot_counts=[2]",
    "env.max_steps=5",
    "collector.num_workers=1",
    "collector.frames_per_batch=6",
    "collector.total_frames=12",
    "optim.minibatch_size=6",
    "optim.epochs=1",
    "eval.interval=2",
    "eval.episodes=1",
    "eval.n_robots=1",
    "eval.max_steps=3",
    "checkpoint.interval=1",
    "checkpoint.keep_last=0",
    "threads=1",
]
"""Two PPO batches of 6 env steps (2 robots, 5-step episodes), one 3-step evaluation episode."""


def test_a_tiny_run_then_its_resume(tmp_path):
    run_dir = tmp_path / "run"
    result = train_ppo(load_ppo_config([*TINY, f"output_dir={run_dir}"]))
    assert (result.iterations, result.frames) == (2, 12)
    rows = list(csv.DictReader(open(run_dir / "progress.csv")))
    assert [int(r["frames"]) for r in rows] == [6, 12]
    assert rows[0]["eval_success_rate"] == "nan" and float(rows[1]["eval_success_rate"]) == 0.0
    assert int(rows[1]["robot_frames"]) <= 24 and int(rows[1]["episodes"]) == 2  # 12 steps, 5-step episodes
    assert (run_dir / "learning_curve.png").stat().st_size > 0
    assert json.loads((run_dir / "ppo_config.json").read_text())["method"] == "matdn"
    latest = ckpt.latest_checkpoint(run_dir)
    assert latest.name == "iter_000002"
    assert ckpt.read_checkpoint_config(latest)["model_config"]["method"] == "matdn"

    with pytest.raises(FileExistsError, match="set resume=true"):
        train_ppo(load_ppo_config([*TINY, f"output_dir={run_dir}"]))
    # resume: the weights of the checkpoint, and the run goes on to the new total
    resumed = train_ppo(
        load_ppo_config([*TINY, f"output_dir={run_dir}", "resume=true", "collector.total_frames=18"])
    )
    assert (resumed.iterations, resumed.frames) == (3, 18)
    rows = list(csv.DictReader(open(run_dir / "progress.csv")))
    assert [int(r["iteration"]) for r in rows] == [1, 2, 3]
    state_2 = ckpt.load_model_state(run_dir / "checkpoints" / "iter_000002")[1]
    state_3 = ckpt.load_model_state(run_dir)[1]
    assert not all(torch.equal(state_2[k], state_3[k]) for k in state_2)
    # resuming with another model is refused
    with pytest.raises(ValueError, match="resume: checkpoint .* holds model"):
        train_ppo(load_ppo_config([*TINY, f"output_dir={run_dir}", "resume=true", "model.hidden=8"]))


def test_the_packaged_config_is_the_dataclass_defaults():
    assert load_ppo_config() == PPOConfig()
    validate_ppo_config(PPOConfig())


@pytest.mark.parametrize(
    ("override", "message"),
    [
        ("method=a3c", "method='a3c': expected one of dsac, matdn"),
        ("model.memory=3", r"unknown keys \['model.memory'\]"),
        ("collector.frames_per_batch=100", "must be a multiple of collector.num_workers=3"),
        ("env.sizes=[30.0]", r"env.sizes\[...\] must be a finite number >= 5 and <= 17.5"),
        ("optim.lrr=0.1", "bad PPO config override 'optim.lrr'"),
        ("loss.loss_critic_type=huber", "loss.loss_critic_type='huber'"),
        ("optim.autocast_dtype=int8", r"optim.autocast_dtype='int8': expected null or one of"),
    ],
)
def test_bad_settings_are_one_line_errors(override, message, capsys):
    assert main(["train-ppo", override]) == 2
    err = capsys.readouterr().err
    assert err.startswith("navformer train-ppo: error:") and len(err.strip().splitlines()) == 1
    assert re.search(message, err)


def test_print_config_is_a_valid_config_file(tmp_path, capsys):
    assert main(["train-ppo", "--print-config", "method=matdn", "model.memory_size=8"]) == 0
    text = capsys.readouterr().out
    path = tmp_path / "ppo.yaml"
    path.write_text(text)
    cfg = load_ppo_config(path=path)
    assert cfg.method == "matdn" and cfg.model == {"memory_size": 8}


def test_running_mean_skips_batches_without_finished_episodes():
    nan = float("nan")
    out = running_mean([nan, 1.0, 3.0, nan, 5.0, 7.0], window=2)
    assert math.isnan(out[0])
    assert out[1:] == [1.0, 2.0, 2.0, 4.0, 6.0]


def _fake_run(folder, method, returns):
    folder.mkdir()
    (folder / "ppo_config.json").write_text(json.dumps({"method": method}))
    log = ProgressLog(folder)
    for i, value in enumerate(returns, start=1):
        log.append({"iteration": i, "frames": 100 * i, "train_return": value,
                    "train_success_rate": value / 10,
                    "eval_return": value if i % 2 == 0 else math.nan})  # fmt: skip


def test_compare_plots_several_runs_into_one_png(tmp_path, capsys):
    _fake_run(tmp_path / "a", "dsac", [1.0, 2.0, 3.0])
    _fake_run(tmp_path / "b", "matdn", [0.5, 0.5, 1.0])
    out = tmp_path / "curves.png"
    assert main(["train-ppo", "--compare", str(tmp_path / "a"), str(tmp_path / "b"), "--out", str(out)]) == 0
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert capsys.readouterr().out.strip() == f"wrote {out}"


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--out", "{png}", "method=dsac"], "takes no overrides; got method=dsac"),
        ([], "--compare needs --out PNG"),
        (["{missing}", "--out", "{png}"], "no progress.csv and ppo_config.json there"),
    ],
)
def test_compare_refuses_bad_input_in_one_line(tmp_path, capsys, extra, message):
    _fake_run(tmp_path / "a", "dsac", [1.0])
    extra = [e.format(missing=tmp_path / "missing", png=tmp_path / "x.png") for e in extra]
    assert main(["train-ppo", "--compare", str(tmp_path / "a"), *extra]) == 2
    err = capsys.readouterr().err
    assert err.startswith("navformer train-ppo: error:") and len(err.strip().splitlines()) == 1
    assert message in err
    assert not (tmp_path / "x.png").exists()
