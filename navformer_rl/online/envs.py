"""The PPO training env: a ``MultiRobotNavEnv`` whose worlds take turns in size, with the shaped reward, the
episode return and the method's recurrent-state primers.

``make_env`` builds one; :class:`EnvFactory` is its picklable form for the collector's worker processes.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any

import numpy as np
from torchrl.envs import Compose, RewardSum, TransformedEnv

from navformer_rl.envs.multi_robot import MultiRobotNavEnv
from navformer_rl.envs.world import WorldSpec
from navformer_rl.online.reward import REWARD_KEY, RewardWeights, ShapedNavReward

EPISODE_RETURN_KEY = ("agents", "episode_reward")
"""float32 ``[A, 1]``: each robot's shaped return so far in the episode (TorchRL ``RewardSum``)."""


class MixedSizeNavEnv(MultiRobotNavEnv):
    """A ``MultiRobotNavEnv`` that draws every new world's side uniformly from ``sizes`` (with the env's
    seeded generator); everything else is ``MultiRobotNavEnv``'s (``kwargs``: ``n_robots``, ``kind``,
    ``max_steps``, ``episodes_per_world``, ``textured``, ``seed``, ...). A single size is the plain env."""

    def __init__(self, sizes: tuple[float, ...] | list[float], **kwargs: Any) -> None:
        sizes = tuple(float(s) for s in sizes)
        if not sizes:
            raise ValueError("MixedSizeNavEnv needs at least one world size")
        super().__init__(size=sizes[0], **kwargs)
        self.sizes = sizes

    def _draw_world(self) -> WorldSpec:
        new_world = self._next_episode is None and not (
            self.world is not None and self._episodes_in_world < self.episodes_per_world
        )
        if new_world and len(self.sizes) > 1:
            size = self.sizes[int(self._rng.integers(len(self.sizes)))]
            self.config = dataclasses.replace(self.config, size=size)
        return super()._draw_world()


def make_env(
    sizes: list[float] | tuple[float, ...],
    n_robots: int,
    *,
    reward: RewardWeights | None = None,
    primers: list | tuple = (),
    seed: int | None = None,
    **env_kwargs: Any,
) -> TransformedEnv:
    """``TransformedEnv(MixedSizeNavEnv, Compose(ShapedNavReward, RewardSum, *primers))``.

    Keys beyond ``MultiRobotNavEnv``'s: ``("agents", "reward")`` is the shaped reward,
    ``("privileged", "geodesic_distance")`` and :data:`EPISODE_RETURN_KEY`; the primers' keys (MA-TDN:
    its memory). ``env_kwargs``: ``kind``, ``max_steps``, ``episodes_per_world``, ``textured``.
    """
    base = MixedSizeNavEnv(sizes, n_robots=n_robots, seed=seed, **env_kwargs)
    transforms = [
        ShapedNavReward(reward),
        RewardSum(in_keys=[REWARD_KEY], out_keys=[EPISODE_RETURN_KEY], reset_keys=["_reset"]),
        *primers,
    ]
    return TransformedEnv(base, Compose(*transforms))


@dataclass(frozen=True)
class EnvFactory:
    """A picklable zero-argument env factory (the collector builds each worker's env in that worker).

    ``model_config`` is the method's config (for its primers).
    """

    method: str
    model_config: Any
    sizes: tuple[float, ...]
    n_robots: int
    reward: RewardWeights
    seed: int
    env_kwargs: tuple[tuple[str, Any], ...] = ()

    def __call__(self) -> TransformedEnv:
        from navformer_rl.baselines.online import env_primers

        return make_env(
            self.sizes,
            self.n_robots,
            reward=self.reward,
            primers=env_primers(self.method, self.model_config, self.n_robots),
            seed=self.seed,
            **dict(self.env_kwargs),
        )


def worker_seed(seed: int, worker: int, round_: int = 0) -> int:
    """The env seed of collector worker ``worker`` in collector round ``round_`` (a new round after each
    resume), from the run's ``seed``."""
    return int(np.random.SeedSequence([seed, worker, round_]).generate_state(1)[0])
