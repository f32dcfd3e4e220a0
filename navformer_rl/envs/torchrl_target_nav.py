"""TorchRL wrapper of the single-robot gymnasium env (``GymWrapper``) with its privileged ``info``.

Keys: ``pixels`` and ``target_pixels`` uint8 ``[84, 84, 3]``, ``action`` float32 ``[2]`` (required by
``step``: ValueError when missing, of the wrong shape or NaN/inf; finite values are clipped to [-1, 1]),
``reward`` float32 ``[1]``, ``done``/``terminated``/``truncated`` bool ``[1]``, and ``("privileged", k)`` for
every entry of :class:`TargetNavEnv`'s ``info``: ``pose`` float32 ``[3]``, ``velocity`` ``[2]``,
``target_position`` ``[2]``, ``success``/``collision`` bool ``[1]``, ``collision_kind``/``collisions`` int64
``[1]``, ``path_length``/``shortest_path_length``/``distance_to_target`` float32 ``[1]``, ``robot_poses``
float32 ``[n_robots, 3]`` (every robot, the controlled one first), ``world_seed``/``step`` int64 ``[1]``.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch
from tensordict import TensorDictBase
from torchrl.data import Categorical, Composite, Unbounded
from torchrl.envs.gym_like import BaseInfoDictReader
from torchrl.envs.libs.gym import GymWrapper

from navformer_rl.envs.target_nav import TargetNavEnv

_PRIVILEGED: dict[str, tuple[tuple[int, ...], torch.dtype]] = {
    "pose": ((3,), torch.float32),
    "velocity": ((2,), torch.float32),
    "target_position": ((2,), torch.float32),
    "success": ((1,), torch.bool),
    "collision": ((1,), torch.bool),
    "collision_kind": ((1,), torch.int64),
    "collisions": ((1,), torch.int64),
    "path_length": ((1,), torch.float32),
    "shortest_path_length": ((1,), torch.float32),
    "distance_to_target": ((1,), torch.float32),
    "world_seed": ((1,), torch.int64),
    "step": ((1,), torch.int64),
}


class PrivilegedInfoReader(BaseInfoDictReader):
    """Copies :class:`TargetNavEnv`'s ``info`` entries to ``("privileged", key)`` with fixed specs.

    Args:
        n_robots: robots in the env (the first dimension of ``robot_poses``).
    """

    def __init__(self, n_robots: int) -> None:
        self._entries = {**_PRIVILEGED, "robot_poses": ((n_robots, 3), torch.float32)}
        specs = {}
        for key, (shape, dtype) in self._entries.items():
            specs[key] = (
                Categorical(2, shape=shape, dtype=dtype)
                if dtype is torch.bool
                else Unbounded(shape, dtype=dtype)
            )
        self._spec = Composite(privileged=Composite(specs, shape=()), shape=())

    def __call__(self, info_dict: dict[str, Any], tensordict: TensorDictBase) -> TensorDictBase:
        for key, (shape, dtype) in self._entries.items():
            value = torch.as_tensor(np.asarray(info_dict[key]), dtype=dtype).reshape(shape)
            tensordict.set(("privileged", key), value)
        return tensordict

    @property
    def info_spec(self) -> Composite:
        return self._spec


class TargetNavGymWrapper(GymWrapper):
    """``GymWrapper`` of :class:`TargetNavEnv` whose ``step`` refuses a tensordict without ``"action"`` with a
    ValueError naming the key and the expected value (the plain wrapper raises a ``KeyError`` from inside
    tensordict). Shapes and values are checked by :class:`TargetNavEnv` (ValueError); seeds by its ``reset``.
    """

    def _step(self, tensordict: TensorDictBase) -> TensorDictBase:
        if tensordict.get("action", None) is None:
            raise ValueError(
                "step() needs the action at key 'action': float [2] (linear, angular) in [-1, 1]; the "
                f"tensordict has keys {sorted(tensordict.keys(True, True), key=str)}"
            )
        return super()._step(tensordict)


def make_torchrl_target_nav_env(**kwargs) -> GymWrapper:
    """``TargetNavGymWrapper(TargetNavEnv(**kwargs))`` (a ``GymWrapper``) with the privileged info reader
    registered.

    ``kwargs`` are :class:`TargetNavEnv`'s (``size``, ``n_robots``, ``kind``, ``robot_style``, ...).
    """
    base = TargetNavEnv(**kwargs)
    env = TargetNavGymWrapper(base)
    env.set_info_dict_reader(PrivilegedInfoReader(len(base.robot_specs)))
    return env
