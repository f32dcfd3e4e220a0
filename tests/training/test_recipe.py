"""The two front ends of the one training loop: the hydra recipe (subprocess) and ``navformer train`` (library
CLI). Both resolve the packaged train.yaml to the same configuration and write the same layout: config,
checkpoint (run + resume parts), CSV scalars."""

from __future__ import annotations

import argparse
import csv
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
import torch
from safetensors.torch import load_file

from navformer_rl.training import TrainConfig, load_train_config
from navformer_rl.training import checkpoint as ckpt
from navformer_rl.training import cli as training_cli

ROOT = Path(__file__).resolve().parents[2]


def run_recipe(cwd: Path, *overrides: str) -> subprocess.CompletedProcess:
    """``recipes/navformer/navformer.py`` with ``overrides`` in a subprocess (one thread, TorchRL quiet)."""
    env = {**os.environ, "OMP_NUM_THREADS": "1", "RL_WARNINGS": "0", "RL_LOGGING_LEVEL": "WARNING"}
    return subprocess.run(
        [sys.executable, str(ROOT / "recipes/navformer/navformer.py"), *overrides],
        cwd=cwd,
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
    )


def check_run_files(run_dir: Path, iterations: int) -> None:
    """The files a finished run must have written (known iteration count)."""
    config = json.loads((run_dir / "train_config.json").read_text())
    assert config["optim"]["iterations"] == iterations and config["data"]["ssl_batch_pairs"] == 4
    latest = ckpt.latest_checkpoint(run_dir)
    assert latest is not None and latest.name == f"iter_{iterations:06d}"
    assert {p.name for p in latest.iterdir()} == {"config.json", "model.safetensors", "resume.pt"}
    assert ckpt.read_checkpoint_config(latest)["iteration"] == iterations
    config_obj, _ = ckpt.load_policy_model(run_dir)
    assert config_obj.d_embed == 16
    scalars = run_dir / "logs" / "navformer" / "scalars"
    for name in ("loss", "loss_dt", "loss_byol", "lr", "frames_per_s", "tau"):
        with open(scalars / f"{name}.csv") as handle:
            rows = list(csv.reader(handle))
        assert [int(step) for step, _ in rows] == list(range(1, iterations + 1)), name
    with open(scalars / "lr.csv") as handle:
        assert {float(v) for _, v in csv.reader(handle)} == {2e-4}
    with open(scalars / "loss_dt_exploration.csv") as handle:  # D_e on iterations 1 and 3
        assert [int(step) for step, _ in csv.reader(handle)] == [1, 3]
    assert (scalars / "time" / "forward_backward.csv").is_file()  # timeit averages


def test_recipe_script_smoke_run(base_overrides, tmp_path):
    run_dir = tmp_path / "recipe_run"
    overrides = [*base_overrides, "optim.iterations=3", f"output_dir={run_dir}"]
    overrides.append(f"hydra.run.dir={tmp_path / 'hydra'}")
    proc = run_recipe(tmp_path, *overrides)
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert f"run directory: {run_dir}" in proc.stdout
    check_run_files(run_dir, 3)
    assert (tmp_path / "hydra" / ".hydra" / "config.yaml").is_file()  # hydra's own record of the run


def test_the_recipe_and_navformer_train_run_the_same_training(base_overrides, tmp_path):
    """The recipe spells out the make_* calls that ``navformer train`` makes: the same seed gives the same
    losses, weights and resume state (both in a subprocess, one thread)."""
    overrides = [*base_overrides, "optim.iterations=3", "model.dropout=0.1"]
    recipe = run_recipe(
        tmp_path, *overrides, f"output_dir={tmp_path / 'recipe'}", f"hydra.run.dir={tmp_path}"
    )
    assert recipe.returncode == 0, recipe.stderr[-3000:]
    env = {**os.environ, "OMP_NUM_THREADS": "1", "RL_WARNINGS": "0", "RL_LOGGING_LEVEL": "WARNING"}
    command = subprocess.run(
        [sys.executable, "-m", "navformer_rl", "train", *overrides, f"output_dir={tmp_path / 'command'}"],
        cwd=tmp_path,
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert command.returncode == 0, command.stderr[-3000:]
    first, second = (ckpt.latest_checkpoint(tmp_path / name) for name in ("recipe", "command"))
    wa, wb = (load_file(str(folder / ckpt.WEIGHTS_FILENAME)) for folder in (first, second))
    assert wa.keys() == wb.keys() and all(torch.equal(wa[key], wb[key]) for key in wa)
    ra, rb = ckpt.load_resume_state(first), ckpt.load_resume_state(second)
    for key in ("optimizers", "byol", "cross_task", "pairs"):
        assert repr(ra[key]) == repr(rb[key]), key
    for name in ("loss", "loss_dt", "loss_byol"):
        rows = [
            (tmp_path / run / "logs" / "navformer" / "scalars" / f"{name}.csv").read_text()
            for run in ("recipe", "command")
        ]
        assert rows[0] == rows[1], name


@pytest.mark.parametrize(
    ("bad", "message"),
    [
        (["ablation=no_thcs"], "unknown ablation 'no_thcs'"),
        (
            ["data.collision_batch_trajs=9"],
            "holds 8 trajectories, fewer than one batch of data.collision_batch_trajs=9",
        ),
    ],
)
def test_recipe_reports_a_mistake_in_one_line_and_leaves_no_folder(base_overrides, tmp_path, bad, message):
    """Like `navformer train`: one line, exit status 2, no traceback; hydra's run folder
    (outputs/navformer/<date>/<time>/, made before the script runs) is removed again."""
    work = tmp_path / "work"
    work.mkdir()
    proc = run_recipe(work, *base_overrides, *bad)
    assert proc.returncode == 2, proc.stderr[-3000:]
    assert "Traceback" not in proc.stderr
    assert len(proc.stderr.splitlines()) == 1 and proc.stderr.startswith("navformer.py: error: ")
    assert message in proc.stderr
    assert list(work.iterdir()) == []


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="navformer")
    training_cli.register(parser.add_subparsers(dest="command"))
    return parser


def test_navformer_train_command_smoke_run(base_overrides, tmp_path, capsys):
    run_dir = tmp_path / "cli_run"
    args = _parser().parse_args(["train", *base_overrides, "optim.iterations=3", f"output_dir={run_dir}"])
    assert args.run(args) == 0
    assert f"run directory: {run_dir}" in capsys.readouterr().out
    check_run_files(run_dir, 3)


def test_navformer_train_help_and_print_config(capsys):
    with pytest.raises(SystemExit) as exit_info:
        _parser().parse_args(["train", "--help"])
    assert exit_info.value.code == 0
    text = capsys.readouterr().out
    assert "KEY=VALUE" in text and "no_thsc" in text and "resume=true" in text
    args = _parser().parse_args(["train", "--print-config", "ablation=dt"])  # as in --help: no data yet
    assert args.run(args) == 0
    printed = capsys.readouterr().out
    assert "ablation: dt" in printed and "lr: 0.0002" in printed


@pytest.mark.parametrize("source", ["overrides", "config_file"])
def test_print_config_shows_the_model_the_ablation_builds(tmp_path, capsys, source):
    """The ``model:`` section holds only the user's overrides (``{}`` with a --config FILE without one);
    ``resolved_model:`` is the whole NavFormerConfig of the run, and the output reads back as --config."""
    import yaml

    if source == "overrides":
        argv = ["train", "--print-config", "ablation=dt"]
    else:
        (tmp_path / "mine.yaml").write_text("ablation: dt\n")
        argv = ["train", "--print-config", "--config", str(tmp_path / "mine.yaml")]
    args = _parser().parse_args(argv)
    assert args.run(args) == 0
    printed = yaml.safe_load(capsys.readouterr().out)
    resolved = printed["resolved_model"]
    switches = ("thsc", "use_static_encoder", "use_general_encoder", "encoder", "detach_encoders")
    assert {k: resolved[k] for k in switches} == {
        "thsc": False,
        "use_static_encoder": False,
        "use_general_encoder": True,
        "encoder": "cnn",
        "detach_encoders": False,
    }
    assert (resolved["d_embed"], resolved["n_blocks"], resolved["image_size"]) == (128, 3, 84)
    if source == "config_file":
        assert printed["model"] == {}
    (tmp_path / "printed.yaml").write_text(yaml.safe_dump(printed))
    again = _parser().parse_args(["train", "--print-config", "--config", str(tmp_path / "printed.yaml")])
    assert again.run(again) == 0
    assert yaml.safe_load(capsys.readouterr().out) == printed


def test_navformer_cli_reports_bad_config_in_one_line(capsys):
    """Through the real ``navformer`` entry point (every subcommand module must import)."""
    import importlib

    from navformer_rl import cli

    for module in cli.SUBCOMMAND_MODULES:
        importlib.import_module(module)  # an ImportError fails the test
    status = cli.main(["train", "ablation=no_attention"])
    assert status == 2
    err = capsys.readouterr().err
    assert err.startswith("navformer train: error: unknown ablation 'no_attention'")


def recipe_config(*overrides: str) -> TrainConfig:
    """What the recipe trains with for ``overrides``: hydra composes ``recipes/navformer/config.yaml`` (the
    packaged train.yaml + hydra settings) as ``@hydra.main`` does, then the recipe's ``make_train_config``."""
    import importlib.util

    from hydra import compose, initialize_config_dir

    spec = importlib.util.spec_from_file_location("recipe_utils", ROOT / "recipes/navformer/utils.py")
    utils = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(utils)
    with initialize_config_dir(config_dir=str(ROOT / "recipes/navformer"), version_base="1.3"):
        return utils.make_train_config(compose("config", overrides=list(overrides)))


def changed_overrides(node: dict, prefix: str = "") -> list[str]:
    """``key=value`` for every leaf of a train.yaml mapping, each value changed from its default where its
    type allows (bools flipped, ints + 1, floats halved in exponent notation, null paths set; strings and
    other nulls kept)."""
    items = []
    for key, value in node.items():
        name = f"{prefix}{key}"
        if isinstance(value, dict):
            items += changed_overrides(value, f"{name}.")
        elif isinstance(value, bool):
            items.append(f"{name}={str(not value).lower()}")
        elif isinstance(value, int):
            items.append(f"{name}={value + 1}")
        elif isinstance(value, float):
            items.append(f"{name}={value / 2:e}")
        elif value is None:
            items.append(f"{name}=/data/{key}" if key.endswith("_path") else f"{name}=null")
        else:
            items.append(f"{name}={value}")
    return items


def test_recipe_accepts_every_packaged_key_and_resolves_as_navformer_train():
    """The recipe composes the packaged train.yaml: each of its keys (a new one included, with no edit of the
    recipe) is accepted, and the same overrides give `navformer train`'s configuration."""
    import yaml

    packaged = yaml.safe_load((ROOT / "navformer_rl/config/train.yaml").read_text())
    overrides = changed_overrides(packaged)
    assert len(overrides) > 50 and "optim.lr=1.000000e-04" in overrides
    assert "data.exploration_path=/data/exploration_path" in overrides
    recipe = recipe_config(*overrides)
    assert recipe.to_dict() == load_train_config(overrides).to_dict()
    assert (recipe.optim.lr, recipe.optim.iterations, recipe.data.prefetch) == (1e-4, 10_001, False)
    # defaults: only output_dir differs (hydra's run folder unless given)
    assert (
        recipe_config("output_dir=/runs/a").to_dict() == load_train_config(["output_dir=/runs/a"]).to_dict()
    )


def test_recipe_sets_other_model_fields_with_a_plus():
    """model.* fields not listed in train.yaml: `+model.<field>=` in hydra, `model.<field>=` in navformer
    train; the same configuration."""
    recipe = recipe_config("+model.thsc=false", "ablation=no_ssl", "output_dir=/runs/a")
    cli = load_train_config(["model.thsc=false", "ablation=no_ssl", "output_dir=/runs/a"])
    assert recipe == cli and recipe.model == {**load_train_config().model, "thsc": False}


def test_recipe_refuses_resume_without_a_run_directory():
    # output_dir left at hydra's per-launch folder: nothing to resume there
    with pytest.raises(ValueError, match="resume=true needs output_dir="):
        recipe_config("resume=true")
