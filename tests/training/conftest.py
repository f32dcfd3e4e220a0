"""Fixtures: tiny synthetic D_e / D_ca / D_ssl (real on-disk format) and a tiny training configuration."""

from __future__ import annotations

from pathlib import Path

import pytest

from navformer_rl.data import make_synthetic_dataset
from navformer_rl.training import TrainConfig, load_train_config

TINY_OVERRIDES = [
    "data.exploration_batch_trajs=2",
    "data.collision_batch_trajs=4",
    "data.ssl_batch_pairs=4",
    "model.d_embed=16",
    "model.d_head=8",
    "model.n_blocks=1",
    "model.max_timestep=64",
    "ssl.projection_dim=8",
    "ssl.hidden_dim=16",
    "logger.progress=false",
]
"""A model and batches small enough for a training iteration in well under a second on one core."""


@pytest.fixture(scope="session")
def datasets(tmp_path_factory) -> dict[str, Path]:
    """6 D_e trajectories (5-12 steps), 8 D_ca trajectories (3-8 steps), 16 D_ssl pairs."""
    root = tmp_path_factory.mktemp("training_data")
    return {
        "e": make_synthetic_dataset(root / "e", "e", 6, 5, 12, seed=11),
        "ca": make_synthetic_dataset(root / "ca", "ca", 8, 3, 8, seed=12),
        "ssl": make_synthetic_dataset(root / "ssl", "ssl", 16, seed=13),
    }


def data_overrides(datasets: dict[str, Path]) -> list[str]:
    return [
        f"data.exploration_path={datasets['e']}",
        f"data.collision_path={datasets['ca']}",
        f"data.ssl_path={datasets['ssl']}",
    ]


@pytest.fixture
def tiny_config(datasets, tmp_path):
    """``tiny_config(*overrides) -> TrainConfig`` on the tiny datasets, writing into a fresh tmp folder."""

    def make(*overrides: str) -> TrainConfig:
        base = [*data_overrides(datasets), *TINY_OVERRIDES, f"output_dir={tmp_path / 'run'}"]
        return load_train_config([*base, *overrides])

    return make


@pytest.fixture
def base_overrides(datasets) -> list[str]:
    """Overrides pointing at the tiny datasets with the tiny model (no output_dir)."""
    return [*data_overrides(datasets), *TINY_OVERRIDES]
