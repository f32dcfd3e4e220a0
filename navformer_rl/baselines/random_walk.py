"""Velocity Random Walk (VRW), the paper's lower bound (§VII.A): actions uniform in ``[-1, 1]^2``."""

from __future__ import annotations

import numpy as np
import torch
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModuleBase
from tensordict.utils import NestedKey


class RandomWalkPolicy(TensorDictModuleBase):
    """Every robot draws ``(linear, angular)`` independently and uniformly from ``[-1, 1]^2`` each step.

    Reads ``reference_key`` (default ``("agents", "step_count")`` int64 ``[*R, 1]``) only for the robot
    batch shape ``R``; writes ``action_key`` (``("agents", "action")``) float32 ``[*R, 2]``.
    Seeded: ``bind(env, seed)`` (called by the harness after each reset) or ``reseed(seed)`` restarts the
    stream, so an episode's actions depend on its seed only.

    Args:
        seed: initial seed.
    """

    def __init__(
        self,
        seed: int = 0,
        reference_key: NestedKey = ("agents", "step_count"),
        action_key: NestedKey = ("agents", "action"),
    ) -> None:
        super().__init__()
        self.reference_key, self.action_key = reference_key, action_key
        self.in_keys = [reference_key]
        self.out_keys = [action_key]
        self.reseed(seed)

    def reseed(self, seed: int) -> None:
        """Restart the random stream from ``seed``."""
        self._rng = np.random.default_rng(int(seed))

    def bind(self, env, seed: int) -> None:
        """Harness hook after a reset: reseed with the episode's seed (``env`` is not used)."""
        self.reseed(seed)

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        lead = tensordict.get(self.reference_key).shape[:-1]
        action = self._rng.uniform(-1.0, 1.0, size=(*lead, 2)).astype(np.float32)
        tensordict.set(self.action_key, torch.from_numpy(action).to(tensordict.device or "cpu"))
        return tensordict
