"""The hydra evaluation recipe runs end to end (a subprocess, like TorchRL's sota smoke tests)."""

import csv
import os
import subprocess
import sys
from pathlib import Path

import pytest

RECIPE = Path(__file__).resolve().parents[2] / "recipes" / "evaluate" / "evaluate.py"


@pytest.mark.slow  # a fresh interpreter importing torch, torchrl and hydra: 10-50 s on the shared 2 cores
def test_recipe_smoke(tmp_path):
    out = tmp_path / "run"
    overrides = [
        "method=vrw", "protocol=smoke", "trials_per_setup=1", "max_steps=4", "maps_per_setup=0",
        "videos_per_setup=0", "progress=false", f"output_dir={out}", f"hydra.run.dir={tmp_path / 'hydra'}",
    ]  # fmt: skip
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    done = subprocess.run(
        [sys.executable, str(RECIPE), *overrides], capture_output=True, text=True, env=env, timeout=300
    )
    assert done.returncode == 0, done.stderr[-2000:]
    rows = list(csv.DictReader((out / "summary.csv").open()))
    assert [(r["method"], r["setup"], r["n_robot_trials"]) for r in rows] == [("vrw", "7.5m-2r", "2")]
    assert "| 7.5m-2r | 7.5 × 7.5 | 2 |" in done.stdout
    # it says first where it writes and how to resume there (its default folder is new on every run)
    assert done.stdout.startswith(f"output folder: {out}\n")
    assert (
        "method=vrw protocol=smoke" in done.stdout
        and f"output_dir={out} hydra.run.dir={out}\n" in done.stdout
    )


def _recipe_utils():
    import importlib.util

    spec = importlib.util.spec_from_file_location("evaluate_recipe_utils", RECIPE.parent / "utils.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_recipe_generation_keys_default_to_the_paper_and_are_refused_beside_a_file(tmp_path):
    from omegaconf import OmegaConf

    from navformer_rl.evaluation.episodes import save_episode_set

    utils = _recipe_utils()
    cfg = OmegaConf.load(RECIPE.parent / "config.yaml")
    cfg.output_dir = str(tmp_path)
    cfg.trials_per_setup, cfg.max_steps = 2, 7
    generated = utils.make_episode_set(cfg)
    assert len(generated) == 2 and generated.max_steps == 7
    cfg.trials_per_setup = None  # null = the paper's 60 trials (smoke: one setup), 500 steps
    cfg.max_steps = None
    paper = utils.make_episode_set(cfg)
    assert len(paper) == 60 and paper.max_steps == 500
    path = save_episode_set(generated, tmp_path / "set.json")
    cfg.episodes = str(path)
    assert utils.make_episode_set(cfg) == generated
    cfg.max_steps = 50
    with pytest.raises(ValueError, match="max_steps: only with `protocol`"):
        utils.make_episode_set(cfg)
    cfg.max_steps, cfg.setups = None, ["7.5m-2r"]
    with pytest.raises(ValueError, match="setups: only with `protocol`"):
        utils.make_episode_set(cfg)
    cfg.episodes, cfg.protocol, cfg.trials_per_setup, cfg.max_steps = None, "table1", 1, 7
    cfg.setups = ["12.5m-2r", "7.5m-2r"]
    assert utils.make_episode_set(cfg).setups == ["7.5m-2r", "12.5m-2r"]


def test_recipe_prints_how_to_resume_its_output_folder(tmp_path):
    utils = _recipe_utils()
    overrides = ["method=vrw", "label=my label", "output_dir=old", "hydra.run.dir=elsewhere"]
    hint = utils.resume_hint("outputs/evaluate/vrw/x", overrides)
    folder = Path("outputs/evaluate/vrw/x").resolve()
    assert hint.splitlines()[0] == f"output folder: {folder}"
    assert hint.splitlines()[-1] == (
        f"  python recipes/evaluate/evaluate.py method=vrw 'label=my label' output_dir={folder} "
        f"hydra.run.dir={folder}"
    )


def test_recipe_refuses_a_label_naming_another_ablation_before_generating_episodes(
    tmp_path, checkpoint_factory
):
    from omegaconf import OmegaConf

    from navformer_rl.modules import NavFormerConfig

    utils = _recipe_utils()
    cfg = OmegaConf.load(RECIPE.parent / "config.yaml")
    cfg.output_dir = str(tmp_path / "out")
    cfg.method, cfg.protocol = "navformer", "table1"  # generating table1 would take a minute
    cfg.checkpoint = str(checkpoint_factory(tmp_path / "full", NavFormerConfig(), {"ablation": "none"}))
    cfg.label = "navformer-no_fg"
    with pytest.raises(ValueError, match="names the training ablation 'no_fg'.*trained with ablation=none"):
        utils.check_policy(cfg)  # what the recipe's main calls first


def _run_recipe(cwd: Path, *overrides: str, **env: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, str(RECIPE), *overrides],
        cwd=cwd,
        capture_output=True,
        text=True,
        env={**os.environ, "OMP_NUM_THREADS": "1", **env},
        timeout=300,
    )


@pytest.mark.parametrize(
    ("overrides", "message"),
    [
        (["method=navformr"], "unknown method 'navformr'; expected one of navformer, dt, vrw, fca"),
        (["method=dt"], "method 'dt' needs a checkpoint"),
        (["method=vrw", "protocol=tabl1"], "unknown protocol 'tabl1'"),
    ],
)
def test_recipe_reports_a_mistake_in_one_line_and_leaves_no_folder(tmp_path, overrides, message):
    """Like `navformer evaluate`: one line, exit status 2, no traceback; the folder hydra made for the run
    (outputs/evaluate/<method>/<time>/, with its .hydra/ records) is removed again."""
    done = _run_recipe(tmp_path, *overrides, "progress=false")
    assert done.returncode == 2, done.stderr[-2000:]
    assert "Traceback" not in done.stderr
    assert len(done.stderr.splitlines()) == 1
    assert done.stderr.startswith(f"evaluate.py: error: {message}")
    assert list(tmp_path.iterdir()) == []  # not even an empty outputs/
    if not overrides[0].startswith("method=vrw"):  # a bad policy is refused before the resume hint
        assert done.stdout == ""


def test_recipe_keeps_a_refused_runs_folder_that_holds_anything_else(tmp_path):
    run_dir = tmp_path / "earlier"
    run_dir.mkdir()
    (run_dir / "run.json").write_text("{}")
    done = _run_recipe(tmp_path, "method=navformr", f"output_dir={run_dir}", f"hydra.run.dir={run_dir}")
    assert done.returncode == 2 and done.stderr.startswith("evaluate.py: error: unknown method 'navformr'")
    assert (run_dir / "run.json").read_text() == "{}" and (run_dir / ".hydra").is_dir()


def test_recipe_shows_the_traceback_with_navformer_debug(tmp_path):
    done = _run_recipe(tmp_path, "method=navformr", NAVFORMER_DEBUG="1")
    assert done.returncode not in (0, 2)
    assert "Traceback" in done.stderr and "ValueError: unknown method 'navformr'" in done.stderr


def test_recipe_refuses_an_unknown_cluster_level_before_anything_runs():
    from omegaconf import OmegaConf

    cfg = OmegaConf.load(RECIPE.parent / "config.yaml")
    assert cfg.cluster == "trial"
    cfg.cluster = "maze"
    with pytest.raises(ValueError, match="cluster='maze': expected one of trial, world"):
        _recipe_utils().check_policy(cfg)
