"""The hydra recipe ``recipes/ppo/ppo.py``: the configuration ``navformer train-ppo`` resolves,
one-line errors."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from navformer_rl.online.config import load_ppo_config

ROOT = Path(__file__).resolve().parents[2]
TINY = [
    "method=dsac",
    "env.sizes=[5.0]",
    "env.robot_counts=[1]",
    "env.max_steps=4",
    "collector.num_workers=1",
    "collector.frames_per_batch=4",
    "collector.total_frames=4",
    "optim.minibatch_size=4",
    "optim.epochs=1",
    "eval.interval=0",
    "threads=1",
]


def run_recipe(cwd: Path, *overrides: str) -> subprocess.CompletedProcess:
    env = {**os.environ, "OMP_NUM_THREADS": "1", "RL_WARNINGS": "0", "RL_LOGGING_LEVEL": "WARNING"}
    return subprocess.run(
        [sys.executable, str(ROOT / "recipes/ppo/ppo.py"), *overrides],
        cwd=cwd,
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
    )


def recipe_utils():
    """``recipes/ppo/utils.py`` as a module (the recipe's folder is not a package)."""
    import importlib.util

    spec = importlib.util.spec_from_file_location("ppo_recipe_utils", ROOT / "recipes/ppo/utils.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_hydra_and_navformer_train_ppo_resolve_the_same_configuration(tmp_path):
    from hydra import compose, initialize_config_dir

    overrides = [*TINY, "+model.hidden=8", f"output_dir={tmp_path}"]
    with initialize_config_dir(config_dir=str(ROOT / "recipes/ppo"), version_base="1.3"):
        cfg = compose("config", overrides)
        resume = compose("config", ["resume=true"])
    expected = load_ppo_config([*TINY, "model.hidden=8", f"output_dir={tmp_path}"])
    assert recipe_utils().make_ppo_config(cfg) == expected
    with pytest.raises(ValueError, match="resume=true needs output_dir=<the run directory to continue>"):
        recipe_utils().make_ppo_config(resume)


@pytest.mark.slow
def test_a_mistake_is_one_line_and_leaves_no_run_folder(tmp_path):
    done = run_recipe(tmp_path, "method=a3c")
    assert done.returncode == 2
    assert done.stderr.strip() == "ppo.py: error: method='a3c': expected one of dsac, matdn"
    assert not (tmp_path / "outputs").exists()


@pytest.mark.slow
def test_the_recipe_trains_the_configuration_navformer_train_ppo_resolves(tmp_path):
    run_dir = tmp_path / "run"
    model = ["+model.d_embed=16", "+model.hidden=16"]  # hydra adds keys with '+'
    done = run_recipe(tmp_path, *TINY, *model, f"output_dir={run_dir}")
    assert done.returncode == 0, done.stderr
    assert "trained 1 PPO batches, 4 env frames" in done.stdout
    recorded = json.loads((run_dir / "ppo_config.json").read_text())
    expected = load_ppo_config([*TINY, "model.d_embed=16", "model.hidden=16", f"output_dir={run_dir}"])
    assert recorded == expected.to_dict()
    assert (run_dir / "checkpoints" / "iter_000001" / "model.safetensors").is_file()
