"""Fixtures: tiny synthetic D_e / D_ca / D_ssl (real on-disk format, seeded, built once per session) and an
empty Minari datasets folder set as ``MINARI_DATASETS_PATH``."""

from __future__ import annotations

from pathlib import Path

import pytest

from navformer_rl.data import make_synthetic_dataset


@pytest.fixture(scope="session")
def source_datasets(tmp_path_factory) -> dict[str, Path]:
    """5 D_e trajectories (3-9 steps), 6 D_ca trajectories (2-6 steps), 4 D_ssl pairs."""
    root = tmp_path_factory.mktemp("export_sources")
    return {
        "e": make_synthetic_dataset(root / "e", "e", 5, 3, 9, seed=21),
        "ca": make_synthetic_dataset(root / "ca", "ca", 6, 2, 6, seed=22),
        "ssl": make_synthetic_dataset(root / "ssl", "ssl", 4, seed=23),
    }


@pytest.fixture
def minari_path(tmp_path, monkeypatch) -> Path:
    """An empty Minari datasets folder, set as ``MINARI_DATASETS_PATH``."""
    path = tmp_path / "minari"
    monkeypatch.setenv("MINARI_DATASETS_PATH", str(path))
    return path
