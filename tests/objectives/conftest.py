"""Synthetic trajectory batches for the loss tests (data contract of docs/architecture.md)."""

import pytest

from .contract import trajectories


@pytest.fixture
def td_factory():
    """``factory(n, steps, seed)`` -> TensorDict ``[n]`` of random uint8 images, RTG, actions in [-1, 1],
    steps 0..T-1 and an all-valid mask (per-step keys ``[n, T, ...]``, ``target_pixels``
    ``[n, 84, 84, 3]``)."""
    return trajectories
