"""Synthetic trajectory batches for the loss tests (data contract of docs/architecture.md)."""

import pytest
import torch
from tensordict import TensorDict


@pytest.fixture
def td_factory():
    """``factory(n, steps, seed)`` -> TensorDict ``[n]`` of random uint8 images, RTG, actions in [-1, 1],
    steps 0..T-1 and an all-valid mask (per-step keys ``[n, T, ...]``, ``target_pixels`` ``[n, 84, 84, 3]``)."""

    def factory(n: int, steps: int, seed: int = 0) -> TensorDict:
        gen = torch.Generator().manual_seed(seed)
        data = {
            "target_pixels": torch.randint(0, 256, (n, 84, 84, 3), dtype=torch.uint8, generator=gen),
            "pixels": torch.randint(0, 256, (n, steps, 84, 84, 3), dtype=torch.uint8, generator=gen),
            "return_to_go": torch.rand(n, steps, 1, generator=gen),
            "action": torch.rand(n, steps, 2, generator=gen) * 2 - 1,
            "step": torch.arange(steps).expand(n, steps).clone(),
            "mask": torch.ones(n, steps, dtype=torch.bool),
        }
        return TensorDict(data, batch_size=[n])

    return factory
