"""Factories of the NavFormer training recipe (TorchRL sota-implementations layout).

The recipe only turns hydra's config into the library's: the loop, the datasets, model, losses, optimisers
and logger all come from :mod:`navformer_rl.training`, which ``navformer train`` runs too.
"""

from __future__ import annotations

import os
from typing import Any

from omegaconf import DictConfig, OmegaConf

from navformer_rl.training import TrainConfig, config_from_dict

HYDRA_RUN_DIR = "${hydra:runtime.output_dir}"
"""``config.yaml``'s default ``output_dir``: the run folder hydra makes for each launch."""


def make_train_config(cfg: DictConfig) -> TrainConfig:
    """Hydra ``DictConfig`` (``train.yaml`` composed with ``config.yaml`` and the overrides) -> typed
    ``TrainConfig`` (every key and scalar type checked by :func:`~navformer_rl.training.config_from_dict`).

    ``resume=true`` needs ``output_dir=<the run to continue>``: hydra's default is a new, empty folder per
    launch, where resuming would silently start from scratch. So does a ``torchrun`` launch of several
    processes: hydra names each process's folder after the second it started, which may differ.
    """
    default_dir = OmegaConf.to_container(cfg, resolve=False).get("output_dir") == HYDRA_RUN_DIR
    if cfg.resume and default_dir:
        raise ValueError(
            "resume=true needs output_dir=<the run directory to continue>; without it each launch writes "
            "into a new hydra folder, which holds no checkpoint"
        )
    if default_dir and int(os.environ.get("WORLD_SIZE", "1") or 1) > 1:
        raise ValueError(
            "under torchrun the recipe needs output_dir=<run directory> (add hydra.run.dir=<the same> to "
            "keep hydra's records there): hydra names each process's folder after the second it started"
        )
    container: dict[str, Any] = OmegaConf.to_container(cfg, resolve=True)  # type: ignore[assignment]
    container.pop("hydra", None)
    return config_from_dict(container)
