"""The shaped reward PPO trains on (not in the paper; ``docs/deviations.md``), as a TorchRL ``Transform``.

Per robot and step, for a robot still searching when the step starts::

    r = progress * (d_before - d_after) - collision * [in contact] + success * [arrived] - step

where ``d`` is the geodesic distance in metres from the robot to the 1.5 m success disc of its target, on
the world's occupancy grid inflated by the robot's radius (the distance field of
:meth:`~navformer_rl.envs.occupancy.OccupancyMap.distance_field`, the one the env's
``shortest_path_length`` uses). A robot that has already succeeded gets 0. The env's sparse success
reward (1 on arrival) is replaced.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from tensordict import TensorDictBase
from torchrl.data import Composite, Unbounded
from torchrl.envs.transforms import Transform

from navformer_rl.constants import SUCCESS_RADIUS
from navformer_rl.utils.checks import check_number

GEODESIC_KEY = ("privileged", "geodesic_distance")
"""float32 ``[A, 1]``: metres from each robot to its target's success disc (written by
:class:`ShapedNavReward`)."""
REWARD_KEY = ("agents", "reward")


@dataclass(frozen=True)
class RewardWeights:
    """Weights of the shaped reward (module docstring).

    Attributes:
        progress: per metre of geodesic progress towards the target.
        collision: subtracted on every step a robot is in contact (wall, target or robot).
        success: added once, on the step a robot reaches its target.
        step: subtracted on every step (time cost).
    """

    progress: float = 1.0
    collision: float = 0.1
    success: float = 10.0
    step: float = 0.01

    def __post_init__(self) -> None:
        for name in ("progress", "collision", "success", "step"):
            check_number(getattr(self, name), f"reward.{name}", at_least=0.0)


class ShapedNavReward(Transform):
    """Replaces ``("agents", "reward")`` of a ``MultiRobotNavEnv`` with the shaped reward.

    Reads (step input) ``("agents", "done")`` bool ``[A, 1]`` and ``("privileged", "geodesic_distance")``;
    (step output) ``("agents", "reward")`` (sparse: 1 on arrival), ``("agents", "collision")`` bool ``[A, 1]``
    and ``("privileged", "pose")`` float32 ``[A, 3]``. Writes ``("agents", "reward")`` float32 ``[A, 1]``
    and ``("privileged", "geodesic_distance")`` float32 ``[A, 1]`` (also on reset).

    It must sit directly on a ``MultiRobotNavEnv`` (it reads the current world from ``parent.base_env``).
    """

    def __init__(self, weights: RewardWeights | None = None) -> None:
        super().__init__(in_keys=[REWARD_KEY], out_keys=[REWARD_KEY])
        self.weights = weights or RewardWeights()
        self._fields: list[np.ndarray] = []
        self._occupancy = None
        self._clearances: list[float] = []

    # ------------------------------------------------------------------ geodesic distance
    def _base_env(self):
        from navformer_rl.envs.multi_robot import MultiRobotNavEnv

        parent = self.parent
        base = getattr(parent, "base_env", None)
        if not isinstance(base, MultiRobotNavEnv):
            raise ValueError(
                "ShapedNavReward must be applied to a MultiRobotNavEnv "
                "(TransformedEnv(MultiRobotNavEnv(...), ShapedNavReward())), "
                f"got base env {type(base).__name__}"
            )
        return base

    def _distances(self, poses: torch.Tensor) -> torch.Tensor:
        """Geodesic metres to the success discs for poses float ``[A, 3]`` -> float32 ``[A, 1]``."""
        xy = poses[:, :2].detach().cpu().numpy().astype(np.float64)
        out = np.empty(len(self._fields), dtype=np.float32)
        for i, (field, clearance) in enumerate(zip(self._fields, self._clearances)):
            out[i] = field[self._occupancy.snap_to_free(xy[i], clearance)]
        return torch.from_numpy(out).reshape(-1, 1).to(poses.device)

    def _reset(self, tensordict: TensorDictBase, tensordict_reset: TensorDictBase) -> TensorDictBase:
        env = self._base_env()
        world = env.world
        self._occupancy = world.occupancy
        self._clearances = [spec.radius for spec in env.robot_specs]
        # the env's reset computed the same fields for shortest_path_length: these come from its cache
        self._fields = [
            world.occupancy.distance_field(target, clearance, goal_radius=SUCCESS_RADIUS)
            for target, clearance in zip(world.robot_target_positions, self._clearances)
        ]
        tensordict_reset.set(GEODESIC_KEY, self._distances(tensordict_reset.get(("privileged", "pose"))))
        return tensordict_reset

    def _step(self, tensordict: TensorDictBase, next_tensordict: TensorDictBase) -> TensorDictBase:
        w = self.weights
        before = tensordict.get(GEODESIC_KEY)
        after = self._distances(next_tensordict.get(("privileged", "pose")))
        # inf: the robot was pushed off the target's component (should not happen); count no progress
        after = torch.where(torch.isfinite(after), after, before)
        active = ~tensordict.get(("agents", "done"))
        arrived = next_tensordict.get(REWARD_KEY) > 0
        collided = next_tensordict.get(("agents", "collision"))
        reward = (
            w.progress * (before - after)
            - w.collision * collided.to(after.dtype)
            + w.success * arrived.to(after.dtype)
            - w.step
        )
        next_tensordict.set(REWARD_KEY, torch.where(active, reward, torch.zeros_like(reward)))
        next_tensordict.set(GEODESIC_KEY, after)
        return next_tensordict

    # ------------------------------------------------------------------ specs
    def transform_observation_spec(self, observation_spec: Composite) -> Composite:
        group = observation_spec["privileged"]
        group[GEODESIC_KEY[1]] = Unbounded(
            (*group.shape, 1), dtype=torch.float32, device=observation_spec.device
        )
        return observation_spec

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        raise RuntimeError("ShapedNavReward works inside an env (TransformedEnv), not on stored data")
