"""The pieces of a training run, made TorchRL's way (``make_*``, as in ``sota-implementations``'
``decision_transformer/utils.py``): the batchers, the model and its losses, the optimisers, the learner
(what :func:`~navformer_rl.training.step.train_step` updates) and the logger.

:func:`~navformer_rl.training.run.make_trainer` and the recipe (``recipes/navformer/navformer.py``) call them
in this order after :func:`seed_everything`; the order is part of a seed's run (the model's and BYOL's heads'
initial weights come from the generators it seeds).
"""

from __future__ import annotations

import random
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import torch

from navformer_rl.tasks import DATASETS, TRAJECTORY_KINDS
from navformer_rl.training.config import TrainConfig, encoder_optimizer, model_config
from navformer_rl.training.distributed import (
    Distributed,
    ShardedAugmentation,
    ShardedPairBatcher,
    ShardedTrajectoryBatcher,
    rank_seed,
    use_global_batch_norm,
)
from navformer_rl.training.step import Learner

if TYPE_CHECKING:
    from torchrl.objectives import SoftUpdate
    from torchrl.record.loggers import Logger

    from navformer_rl.data import CrossTaskReplayBuffer
    from navformer_rl.modules import NavFormerModel
    from navformer_rl.objectives import ActionBinLoss, ActionMSELoss, BYOLLoss, BYOLTauSchedule

TRAJECTORY_KEYS = [("pixels",), ("action",), ("return_to_go",), ("step",)]
"""Keys gathered from D_e / D_ca per step (plus ``mask`` and ``target_pixels`` added by the batcher)."""
BATCH_KEYS = ["pixels", "action", "return_to_go", "step", "mask", "target_pixels"]
"""What an iteration takes from a trajectory batch to the device."""


def seed_everything(seed: int) -> None:
    """Seed Python's, NumPy's and torch's global generators from one ``seed``."""
    random.seed(seed)
    np.random.seed(seed % 2**32)
    torch.manual_seed(seed)


def context_steps(cfg: TrainConfig) -> int:
    """Steps of the training windows: ``data.context_steps``, else what fits the model's context."""
    return cfg.data.context_steps or model_config(cfg).window_steps


def make_batchers(
    cfg: TrainConfig, datasets: dict[str, Any], *, device: torch.device, distributed: Distributed
) -> tuple[CrossTaskReplayBuffer, Any]:
    """``(cross_task, pairs)``: the :class:`~navformer_rl.data.CrossTaskReplayBuffer` over the D_e / D_ca
    trajectory batchers (alternating, paper §VI) and D_ssl's pair batcher (None without SSL). With several
    processes every one draws the global batch and gathers its rows of it. With ``data.prefetch`` each batcher
    keeps two buffer sets (one batch trains while the next is gathered)."""
    from navformer_rl.data import CrossTaskReplayBuffer

    buffers = {"buffer_sets": 2 if cfg.data.prefetch else 1, "pin_memory": device.type == "cuda"}
    batchers = {}
    for seed_offset, kind in enumerate(TRAJECTORY_KINDS, start=1):
        size = getattr(cfg.data, DATASETS[kind].batch_key)
        dataset = datasets.get(kind)
        batchers[kind] = (
            None
            if dataset is None
            else dataset.trajectory_batcher(
                size, context_steps(cfg), seed=cfg.seed + seed_offset, keys=TRAJECTORY_KEYS, **buffers
            )
        )
    pairs = (
        datasets["ssl"].pair_batcher(cfg.data.ssl_batch_pairs, seed=cfg.seed + 3, **buffers)
        if cfg.uses_ssl
        else None
    )
    if distributed.enabled:  # every process draws the global batch and gathers its rows of it
        for kind, batcher in batchers.items():
            batchers[kind] = None if batcher is None else ShardedTrajectoryBatcher(batcher, distributed)
        if pairs is not None:
            pairs = ShardedPairBatcher(pairs, distributed)
    cross_task = CrossTaskReplayBuffer(batchers["e"], batchers["ca"])
    return cross_task, pairs


@dataclass
class ModelAndLosses:
    """The model and what trains it (:func:`make_model_and_losses`)."""

    model: NavFormerModel
    """The parameters (``NavFormerModel``), in training mode."""
    actor: Any
    """Its parts composed as TensorDict modules (``make_navformer_actor``), what the DT loss runs."""
    dt_loss: ActionMSELoss | ActionBinLoss
    """L_DT (eq. 10): ``ActionMSELoss``, or ``ActionBinLoss`` with ``model.action_bins``."""
    validation_loss: ActionMSELoss
    """Eq. 10's squared error on the same actor, whatever the training loss (comparable validation rows)."""
    byol_loss: BYOLLoss | None
    """L_BYOL (eq. 8) on the DVE's encoders; None without SSL."""
    ema: SoftUpdate | None
    """BYOL's EMA target update; None without SSL."""
    tau_schedule: BYOLTauSchedule | None
    """The cosine schedule of the EMA's tau over ``optim.iterations``; None without SSL."""


def make_model_and_losses(
    cfg: TrainConfig, *, device: torch.device, distributed: Distributed
) -> ModelAndLosses:
    """The model of ``cfg`` (its ablation and ``model`` overrides) on ``device``, its actor, L_DT, the
    validation loss and, with SSL, L_BYOL with its EMA target and tau schedule. With several processes BYOL
    augments this process's pairs of the global draw and its projector / predictor BatchNorm normalises over
    the global batch."""
    from torchrl.objectives import SoftUpdate

    from navformer_rl.modules import NavFormerModel, make_navformer_actor
    from navformer_rl.objectives import ActionBinLoss, ActionMSELoss, BYOLLoss, BYOLTauSchedule

    config = model_config(cfg)
    model = NavFormerModel(config).to(device)
    model.train()
    actor = make_navformer_actor(model, length_groups=cfg.optim.length_groups)
    dt_loss = (ActionBinLoss if config.action_bins else ActionMSELoss)(actor)
    validation_loss = dt_loss if isinstance(dt_loss, ActionMSELoss) else ActionMSELoss(actor)
    byol_loss = ema = tau_schedule = None
    if cfg.uses_ssl:
        augmentation = None  # one process: BYOL's own
        if distributed.enabled:  # this process's pairs of the global batch
            total = cfg.data.ssl_batch_pairs
            augmentation = ShardedAugmentation(rows=distributed.rows(total), total=total, seed=cfg.seed + 4)
        byol_loss = BYOLLoss(
            model.dve,
            projection_dim=cfg.ssl.projection_dim,
            hidden_dim=cfg.ssl.hidden_dim,
            seed=cfg.seed + 4,
            augmentation=augmentation,
            autocast_dtype=config.autocast_dtype,
        ).to(device)
        if distributed.enabled:  # the projector / predictor BatchNorm over the global batch
            use_global_batch_norm(byol_loss.online_network)
            use_global_batch_norm(byol_loss.predictor)
        ema = SoftUpdate(byol_loss, eps=cfg.ssl.tau_base)
        tau_schedule = BYOLTauSchedule(ema, cfg.optim.iterations, cfg.ssl.tau_base)
    return ModelAndLosses(model, actor, dt_loss, validation_loss, byol_loss, ema, tau_schedule)


def parameter_groups(
    cfg: TrainConfig, model: NavFormerModel, byol_loss: BYOLLoss | None
) -> dict[str, list[torch.nn.Parameter]]:
    """``{"navformer": [...], "dve": [...]}``: which parameters each optimiser owns (disjoint, complete).

    ``navformer`` (AdamW): the navigation network (token embeddings, transformer, head), plus the visual
    encoders when :func:`~navformer_rl.training.config.encoder_optimizer` is ``adamw``. ``dve`` (Adam): the
    visual encoders when it is ``adam`` (the paper's split, §VI), then BYOL's projectors and predictors;
    absent when it would be empty. Which losses reach the encoders is ``encoder_training``'s.
    """
    encoder_ids = {id(p) for p in model.dve.parameters()}
    model_params = [p for p in model.parameters() if p.requires_grad]
    encoders_under_adam = encoder_optimizer(cfg) == "adam"
    groups = {"navformer": [p for p in model_params if not (encoders_under_adam and id(p) in encoder_ids)]}
    dve = [p for p in model_params if id(p) in encoder_ids] if encoders_under_adam else []
    if byol_loss is not None:
        model_ids = {id(p) for p in model_params}
        dve += [p for p in byol_loss.parameters() if id(p) not in model_ids]
    if dve:
        groups["dve"] = dve
    return groups


def make_optimizers(cfg: TrainConfig, parts: ModelAndLosses) -> dict[str, torch.optim.Optimizer]:
    """``{"navformer": AdamW(lr, weight_decay), "dve": Adam(dve_lr, dve_weight_decay)}`` (the ``optim.*``
    values) over :func:`parameter_groups` ("dve" absent when it would own nothing: ``ablation=dt``)."""
    groups = parameter_groups(cfg, parts.model, parts.byol_loss)
    optim = cfg.optim
    optimizers: dict[str, torch.optim.Optimizer] = {
        "navformer": torch.optim.AdamW(groups["navformer"], lr=optim.lr, weight_decay=optim.weight_decay)
    }
    if "dve" in groups:
        optimizers["dve"] = torch.optim.Adam(
            groups["dve"], lr=optim.dve_lr, weight_decay=optim.dve_weight_decay
        )
    return optimizers


def make_learner(
    cfg: TrainConfig, parts: ModelAndLosses, optimizers: dict[str, torch.optim.Optimizer]
) -> Learner:
    """What :func:`~navformer_rl.training.step.train_step` runs and updates: the losses, the optimisers,
    BYOL's EMA and a loss scaler (enabled only under float16 autocast, whose gradients underflow)."""
    device = next(parts.model.parameters()).device
    float16 = parts.model.config.autocast_dtype == "float16"
    return Learner(
        dt_loss=parts.dt_loss,
        byol_loss=parts.byol_loss,
        optimizers=optimizers,
        ema=parts.ema,
        tau_schedule=parts.tau_schedule,
        scaler=torch.amp.GradScaler(device.type, enabled=float16),
        byol_weight=cfg.ssl.loss_weight,
        clip_grad_norm=cfg.optim.clip_grad_norm,
    )


def start_alike(parts: ModelAndLosses, cfg: TrainConfig, distributed: Distributed) -> None:
    """Several processes: the same start on every process (rank 0's parameters and buffers, as
    ``DistributedDataParallel`` does), then per-process seeds for the dropout masks. One process: nothing."""
    if not distributed.enabled:
        return
    modules = [parts.model] if parts.byol_loss is None else [parts.model, parts.byol_loss]
    distributed.broadcast_tensors(
        [t for module in modules for t in (*module.parameters(), *module.buffers())]
    )
    if not distributed.is_main:
        seed_everything(rank_seed(cfg.seed, distributed.rank))


def make_logger(cfg: TrainConfig, run_dir: Path) -> Logger | None:
    """TorchRL logger of ``cfg.logger.backend`` writing under ``<run_dir>/logs`` (None for ``none``)."""
    backend = cfg.logger.backend
    log_dir = str(run_dir / "logs")
    if backend == "csv":
        from torchrl.record.loggers.csv import CSVLogger

        return CSVLogger(cfg.logger.exp_name, log_dir=log_dir, video_format="pt")
    if backend == "tensorboard":
        from torchrl.record.loggers.tensorboard import TensorboardLogger

        return TensorboardLogger(cfg.logger.exp_name, log_dir=log_dir)
    return None
