"""Factories of the NavFormer training recipe (TorchRL sota-implementations layout).

The recipe only wires library pieces together; everything it builds comes from
:mod:`navformer_rl.training`, which the ``navformer train`` command uses too.
"""

from __future__ import annotations

from typing import Any

from omegaconf import DictConfig, OmegaConf
from tqdm import tqdm

from navformer_rl.training import TrainConfig, Trainer, build_trainer, config_from_dict

HYDRA_RUN_DIR = "${hydra:runtime.output_dir}"
"""``config.yaml``'s default ``output_dir``: the run folder hydra makes for each launch."""


def make_train_config(cfg: DictConfig) -> TrainConfig:
    """Hydra ``DictConfig`` (``config.yaml`` + overrides, ``output_dir`` resolved) -> typed ``TrainConfig``.

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


def make_trainer(train_cfg: TrainConfig) -> Trainer:
    """Validate the config, open D_e / D_ca / D_ssl, build model, losses (NavFormerLoss, BYOLLoss),
    optimisers (AdamW + Adam), the EMA updater and the logger; restore the latest checkpoint on resume."""
    return build_trainer(train_cfg)


def make_progress_bar(train_cfg: TrainConfig, start: int) -> tqdm:
    """tqdm over the remaining iterations."""
    return tqdm(
        total=train_cfg.optim.iterations,
        initial=start,
        disable=not train_cfg.logger.progress,
        desc="navformer",
    )


def log_metrics(trainer: Trainer, metrics: dict[str, float]) -> None:
    """Add the iteration's metrics to the trainer's log window; every ``logger.log_interval`` iterations (and
    at the last) their means and the ``timeit`` averages go through the TorchRL logger."""
    trainer.record(metrics)
