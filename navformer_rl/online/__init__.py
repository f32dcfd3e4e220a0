"""DSAC and MA-TDN trained online with PPO (paper §VII.A baselines), from TorchRL's parts.

Modules (one job each):

- :mod:`~navformer_rl.online.reward`: the shaped reward as a TorchRL ``Transform`` (``ShapedNavReward``).
- :mod:`~navformer_rl.online.envs`: the training env (``make_env``, worlds of mixed sizes, picklable
  ``EnvFactory`` for the collector's workers).
- :mod:`~navformer_rl.online.config`: ``PPOConfig`` and its sections, read from ``ppo.yaml`` + overrides.
- :mod:`~navformer_rl.online.ppo`: ``make_collector``, ``make_loss`` (``ClipPPOLoss`` + ``GAE``),
  ``make_optimizer``, GAE per worker (``robot_steps``) and the update (``ppo_update``).
- :mod:`~navformer_rl.online.curve`: fixed-episode evaluation, ``progress.csv`` and the learning-curve plot.
- :mod:`~navformer_rl.online.train`: ``train_ppo``, the loop with checkpoints and resume.
- :mod:`~navformer_rl.online.cli`: ``navformer train-ppo``.

The networks live in :mod:`navformer_rl.baselines` (``dsac``, ``matdn``, ``actor_critic``, ``online``).
"""

from __future__ import annotations

from navformer_rl.utils.lazy import lazy_exports

_EXPORTS = {
    "PPOConfig": "navformer_rl.online.config",
    "PPOResult": "navformer_rl.online.train",
    "RewardWeights": "navformer_rl.online.reward",
    "ShapedNavReward": "navformer_rl.online.reward",
    "load_ppo_config": "navformer_rl.online.config",
    "make_collector": "navformer_rl.online.ppo",
    "make_env": "navformer_rl.online.envs",
    "make_loss": "navformer_rl.online.ppo",
    "make_optimizer": "navformer_rl.online.ppo",
    "ppo_config_from_dict": "navformer_rl.online.config",
    "train_ppo": "navformer_rl.online.train",
}

__all__ = sorted(_EXPORTS)

__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
