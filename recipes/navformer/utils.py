"""Factories of the NavFormer training recipe (TorchRL sota-implementations layout).

The recipe only turns hydra's config into the library's: the loop, the datasets, model, losses, optimisers
and logger all come from :mod:`navformer_rl.training`, which ``navformer train`` runs too.
"""

from __future__ import annotations

from typing import Any

from omegaconf import DictConfig, OmegaConf

from navformer_rl.training import TrainConfig, config_from_dict

HYDRA_RUN_DIR = "${hydra:runtime.output_dir}"
"""``config.yaml``'s default ``output_dir``: the run folder hydra makes for each launch."""


def make_train_config(cfg: DictConfig) -> TrainConfig:
    """Hydra ``DictConfig`` (``train.yaml`` composed with ``config.yaml`` and the overrides) -> typed
    ``TrainConfig`` (every key and scalar type checked by :func:`~navformer_rl.training.config_from_dict`).

    ``resume=true`` needs ``output_dir=<the run to continue>``: hydra's default is a new, empty folder per
    launch, where resuming would silently start from scratch.
    """
    if cfg.resume and OmegaConf.to_container(cfg, resolve=False).get("output_dir") == HYDRA_RUN_DIR:
        raise ValueError(
            "resume=true needs output_dir=<the run directory to continue>; without it each launch writes "
            "into a new hydra folder, which holds no checkpoint"
        )
    container: dict[str, Any] = OmegaConf.to_container(cfg, resolve=True)  # type: ignore[assignment]
    container.pop("hydra", None)
    return config_from_dict(container)
