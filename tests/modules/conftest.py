"""Synthetic trajectory batches for the model tests (data contract of docs/architecture.md)."""

import pytest
import torch


def make_batch(n: int, steps: int, seed: int = 0, action_dim: int = 2) -> dict[str, torch.Tensor]:
    """Random uint8 images, RTG, actions in [-1, 1], steps 0..T-1 and an all-valid mask."""
    gen = torch.Generator().manual_seed(seed)
    return {
        "target_pixels": torch.randint(0, 256, (n, 84, 84, 3), dtype=torch.uint8, generator=gen),
        "pixels": torch.randint(0, 256, (n, steps, 84, 84, 3), dtype=torch.uint8, generator=gen),
        "return_to_go": torch.rand(n, steps, 1, generator=gen),
        "action": torch.rand(n, steps, action_dim, generator=gen) * 2 - 1,
        "step": torch.arange(steps).expand(n, steps).clone(),
        "mask": torch.ones(n, steps, dtype=torch.bool),
    }


@pytest.fixture
def batch_factory():
    return make_batch
