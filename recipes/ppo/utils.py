"""Factories of the PPO baselines recipe (TorchRL sota-implementations layout).

The recipe only turns hydra's config into the library's: the env, collector, loss, optimiser and loop come
from :mod:`navformer_rl.online` (``make_env``, ``make_collector``, ``make_loss``, ``make_optimizer``,
``train_ppo``), which ``navformer train-ppo`` runs too.
"""

from __future__ import annotations

from typing import Any

from omegaconf import DictConfig, OmegaConf

from navformer_rl.online.config import PPOConfig, ppo_config_from_dict, validate_ppo_config

HYDRA_RUN_DIR = "${hydra:runtime.output_dir}"
"""``config.yaml``'s default ``output_dir``: the run folder hydra makes for each launch."""


def make_ppo_config(cfg: DictConfig) -> PPOConfig:
    """Hydra ``DictConfig`` (``ppo.yaml`` composed with ``config.yaml`` and the overrides) -> checked
    ``PPOConfig``. ``resume=true`` needs ``output_dir=<the run to continue>`` (hydra's default is a new,
    empty folder per launch, where resuming would silently start from scratch)."""
    if cfg.resume and OmegaConf.to_container(cfg, resolve=False).get("output_dir") == HYDRA_RUN_DIR:
        raise ValueError(
            "resume=true needs output_dir=<the run directory to continue>; without it each launch writes "
            "into a new hydra folder, which holds no checkpoint"
        )
    container: dict[str, Any] = OmegaConf.to_container(cfg, resolve=True)  # type: ignore[assignment]
    container.pop("hydra", None)
    ppo_cfg = ppo_config_from_dict(container)
    validate_ppo_config(ppo_cfg)
    return ppo_cfg
