"""Fixtures: tiny synthetic datasets in the real on-disk format (seeded, built once per session)."""

from __future__ import annotations

from pathlib import Path

import pytest

from navformer_rl.data import make_synthetic_dataset


@pytest.fixture(scope="session")
def e_dataset(tmp_path_factory) -> Path:
    """12 exploration trajectories of 5-30 steps."""
    return make_synthetic_dataset(tmp_path_factory.mktemp("data") / "e", "e", 12, 5, 30, seed=3)


@pytest.fixture(scope="session")
def ca_dataset(tmp_path_factory) -> Path:
    """20 collision-avoidance trajectories of 3-12 steps."""
    return make_synthetic_dataset(tmp_path_factory.mktemp("data") / "ca", "ca", 20, 3, 12, seed=4)


@pytest.fixture(scope="session")
def ssl_dataset(tmp_path_factory) -> Path:
    """40 image pairs."""
    return make_synthetic_dataset(tmp_path_factory.mktemp("data") / "ssl", "ssl", 40, seed=5)


def _folder_bytes(root: Path) -> dict[str, bytes]:
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(Path(root).rglob("*")) if p.is_file()}


@pytest.fixture
def folder_bytes():
    """``folder_bytes(root)``: every file under ``root`` (relative path -> content), for byte comparisons."""
    return _folder_bytes
