"""An expert of :mod:`navformer_rl.experts.policies` (``reset`` / ``act``) as an evaluation policy."""

from __future__ import annotations

import numpy as np
import torch
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModuleBase
from tensordict.utils import NestedKey


class ExpertPolicy(TensorDictModuleBase):
    """Drives every robot of ``MultiRobotNavEnv`` with an expert controller (``reset(world, sim, rng)``,
    ``act(sim, active) -> float32 [R, 2]``).

    Privileged: after every reset the harness calls ``bind(env, seed)``, which resets the controller on
    ``env.world`` and ``env.simulator`` with a generator seeded by the episode seed. Each call reads
    ``done_key`` (``("agents", "done")`` bool ``[A, 1]``) to know which robots are still active and writes
    ``action_key`` float32 ``[A, 2]``.

    Args:
        controller: the expert (e.g. ``FCAController()``, ``ExplorationExpert()``).
    """

    def __init__(
        self,
        controller,
        done_key: NestedKey = ("agents", "done"),
        action_key: NestedKey = ("agents", "action"),
    ) -> None:
        super().__init__()
        self.done_key, self.action_key = done_key, action_key
        self.in_keys = [done_key]
        self.out_keys = [action_key]
        self.controller = controller
        self._simulator = None

    def bind(self, env, seed: int) -> None:
        """Start an episode: reset the controller on the env's current world and simulator."""
        self._simulator = env.simulator
        self.controller.reset(env.world, env.simulator, np.random.default_rng(int(seed)))

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        if self._simulator is None:
            raise RuntimeError(
                f"{type(self).__name__} is privileged: call bind(env, seed) after every env reset"
            )
        done = tensordict.get(self.done_key).reshape(-1).cpu().numpy()
        action = self.controller.act(self._simulator, ~done)
        tensordict.set(self.action_key, torch.from_numpy(action).to(tensordict.device or "cpu"))
        return tensordict
