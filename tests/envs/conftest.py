"""Shared tiny worlds for the env tests (5 m: the fastest to build and render)."""

from __future__ import annotations

import numpy as np
import pytest

from navformer_rl.envs.world import TargetSpec, WorldConfig, generate_world, world_from_layout

SIZE = 5.0
OUTER_WALLS = np.array(
    [(2.5, 0.0, 2.55, 0.05), (2.5, 5.0, 2.55, 0.05), (0.0, 2.5, 0.05, 2.55), (5.0, 2.5, 0.05, 2.55)],
    dtype=np.float32,
)
"""The four outer walls of a 5 m world: inner faces at 0.05 and 4.95 m."""


def open_world(starts, targets: list[tuple[float, float, str, str]], walls=OUTER_WALLS):
    """A 5 m world with only ``walls`` (default: the outer ones); targets are ``(x, y, shape, colour)``."""
    specs = [TargetSpec(np.array([x, y], dtype=np.float32), shape, color) for x, y, shape, color in targets]
    return world_from_layout(SIZE, walls, specs, np.asarray(starts, dtype=np.float32))


@pytest.fixture
def make_open_world():
    return open_world


@pytest.fixture(scope="session")
def tiny_maze():
    """A seeded 5 m maze with 3 robots."""
    return generate_world(WorldConfig(size=SIZE, n_robots=3), seed=7)
