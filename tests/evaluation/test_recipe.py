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
