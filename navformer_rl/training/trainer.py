"""One built training run, :class:`Trainer`: samplers, model, losses, optimisers, logger and validator;
one iteration (``step``), logging, and checkpoints that resume bit-identically (``save_checkpoint``,
``restore``). Built by :func:`navformer_rl.training.build_trainer`; one process of a data-parallel run
(:mod:`navformer_rl.training.distributed`) when given a :class:`~navformer_rl.training.distributed.Distributed`.
"""

from __future__ import annotations

import dataclasses
import math
import random
import time
from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import torch
from tensordict import TensorDict

from navformer_rl.data.prefetch import Prefetcher
from navformer_rl.data.samplers import split_by_length
from navformer_rl.tasks import DATASETS, TRAJECTORY_KINDS
from navformer_rl.training import checkpoint as ckpt
from navformer_rl.training.config import (
    TrainConfig,
    encoder_optimizer,
    model_config,
    with_encoder_optimizer,
)
from navformer_rl.training.distributed import (
    Distributed,
    ShardedAugmentation,
    ShardedPairBatcher,
    ShardedTrajectoryBatcher,
    rank_seed,
    shard_rows,
    use_global_batch_norm,
)
from navformer_rl.training.log_window import LogWindow
from navformer_rl.training.validation import make_validator
from navformer_rl.utils.devices import resolve_device

if TYPE_CHECKING:
    from torchrl.record.loggers import Logger

RESUME_MAY_CHANGE = frozenset(
    {
        "resume",
        "keep_freed_memory",
        "device",
        "output_dir",
        "logger",
        "checkpoint",
        "optim.iterations",
        "optim.length_groups",  # the same loss and gradient; only the dropout draws change
        "data.exploration_path",
        "data.collision_path",
        "data.ssl_path",
        "data.prefetch",
        "validation",
        "init_from",
    }
)
"""Settings a resumed run may change; any other difference from the checkpoint's config is refused
(``init_from`` only applies to a run's start: a resumed run continues from its own checkpoint)."""
TRAJECTORY_KEYS = [("pixels",), ("action",), ("return_to_go",), ("step",)]
"""Keys gathered from D_e / D_ca per step (plus ``mask`` and ``target_pixels`` added by the batcher)."""
BATCH_KEYS = ["pixels", "action", "return_to_go", "step", "mask", "target_pixels"]
"""What an iteration takes from a trajectory batch to the device."""


def _seed_everything(seed: int) -> None:
    """Seed Python's, NumPy's and torch's global generators from one ``seed``."""
    random.seed(seed)
    np.random.seed(seed % 2**32)
    torch.manual_seed(seed)


def _with_defaults(defaults: Mapping[str, Any], values: Mapping[str, Any]) -> dict[str, Any]:
    """``values`` with every section key it lacks taken from ``defaults`` (``model`` overrides as they are)."""
    merged = dict(defaults)
    for key, value in values.items():
        if isinstance(value, Mapping) and isinstance(defaults.get(key), Mapping) and key != "model":
            merged[key] = _with_defaults(defaults[key], value)
        else:
            merged[key] = value
    return merged


def _recorded_encoder_optimizer(recorded: Mapping[str, Any]) -> str:
    """The optimiser that stepped a recorded run's visual encoders: its ``optim.encoder_optimizer``, which a
    run records resolved; a run recorded before the setting existed had them under AdamW with
    ``encoder_training=joint`` and under Adam with ``frozen``."""
    value = (recorded.get("optim") or {}).get("encoder_optimizer")
    if value is not None:
        return value
    return "adam" if recorded.get("encoder_training") == "frozen" else "adamw"


def _comparable(values: Mapping[str, Any], prefix: str = "") -> dict[str, Any]:
    """``values`` flattened to dotted keys (``model`` overrides kept whole), less :data:`RESUME_MAY_CHANGE`."""
    flat: dict[str, Any] = {}
    for key, value in values.items():
        name = f"{prefix}{key}"
        if isinstance(value, Mapping) and key != "model":
            flat.update(_comparable(value, f"{name}."))
        else:
            flat[name] = value
    return {
        k: v
        for k, v in flat.items()
        if k not in RESUME_MAY_CHANGE and k.split(".")[0] not in RESUME_MAY_CHANGE
    }


class Trainer:
    """The built training run. Use :func:`build_trainer`; then ``step()`` per iteration.

    Attributes:
        cfg: the :class:`TrainConfig`.  run_dir: output folder.  device: torch device.
        model: ``NavFormerModel`` (the parameters).  actor: its parts composed as TensorDict modules
            (``make_navformer_actor``), what the DT loss runs.  dt_loss: ``ActionMSELoss`` (``ActionBinLoss``
            with ``model.action_bins``).  validation_loss: ``ActionMSELoss`` on the same actor (the validation rows).
        byol_loss: ``BYOLLoss`` or None (no SSL).
        cross_task: ``CrossTaskReplayBuffer`` of the D_e / D_ca batchers.  pairs: D_ssl ``PairBatcher`` or None.
        batches: :class:`~navformer_rl.data.prefetch.Prefetcher` of ``(task, batch, pairs)`` over both
            (drawing one iteration ahead with ``data.prefetch``; :meth:`close` stops it).
        optimizers: ``{"navformer": AdamW, "dve": Adam}`` (:meth:`parameter_groups`; "dve" absent when it
            would own nothing: ``ablation=dt``).
        scaler: ``torch.amp.GradScaler``, enabled only under float16 autocast (loss scaling).
        iteration: completed iterations.  logger: TorchRL logger or None.
        log_window: :class:`LogWindow` of the iterations not logged yet (:meth:`record`).
        validator: :class:`~navformer_rl.training.validation.Validator` of the held-out sets, or None
            (:meth:`validation_due`, :meth:`validate`).
        distributed: this process's place in a data-parallel run (one process by default). With several,
            the batchers draw the global batch and gather this process's rows, BYOL's augmentation keeps
            its rows of the global draw, its BatchNorm normalises over the global batch, the gradients are
            summed over the processes before the optimisers step, and only rank 0 writes.
        run_info: recorded in the run files: ``world_size``, ``backend`` and ``init_from`` (the source
            checkpoint's identity, or None).
    """

    def __init__(
        self,
        cfg: TrainConfig,
        *,
        datasets: dict[str, Any],
        validation_datasets: dict[str, Any] | None = None,
        distributed: Distributed | None = None,
    ) -> None:
        from torchrl.objectives import SoftUpdate

        from navformer_rl.data import CrossTaskReplayBuffer
        from navformer_rl.modules import NavFormerModel, make_navformer_actor
        from navformer_rl.objectives import ActionBinLoss, ActionMSELoss, BYOLLoss, BYOLTauSchedule

        self.cfg = with_encoder_optimizer(cfg)
        cfg = self.cfg
        self.distributed = distributed if distributed is not None else Distributed()
        self.run_info: dict[str, Any] = {**self.distributed.run_info(), "init_from": None}
        self.run_dir = Path(cfg.output_dir)
        self.device = self.distributed.device or resolve_device(cfg.device)
        self.model_config = model_config(cfg)
        self.iteration = 0
        _seed_everything(cfg.seed)

        context = cfg.data.context_steps or self.model_config.window_steps
        # prefetching trains on one batch while the next is gathered: two buffer sets per batcher
        buffers = {"buffer_sets": 2 if cfg.data.prefetch else 1, "pin_memory": self.device.type == "cuda"}
        batchers = {}
        for seed_offset, kind in enumerate(TRAJECTORY_KINDS, start=1):
            size = getattr(cfg.data, DATASETS[kind].batch_key)
            dataset = datasets.get(kind)
            batchers[kind] = (
                None
                if dataset is None
                else dataset.trajectory_batcher(
                    size, context, seed=cfg.seed + seed_offset, keys=TRAJECTORY_KEYS, **buffers
                )
            )
        self.pairs = (
            datasets["ssl"].pair_batcher(cfg.data.ssl_batch_pairs, seed=cfg.seed + 3, **buffers)
            if cfg.uses_ssl
            else None
        )
        if self.distributed.enabled:  # every process draws the global batch and gathers its rows of it
            for kind, batcher in batchers.items():
                batchers[kind] = (
                    None if batcher is None else ShardedTrajectoryBatcher(batcher, self.distributed)
                )
            if self.pairs is not None:
                self.pairs = ShardedPairBatcher(self.pairs, self.distributed)
        self.cross_task = CrossTaskReplayBuffer(batchers["e"], batchers["ca"])
        self.batches = Prefetcher(
            self._draw_batches, self._sampler_state, self._load_sampler_state, enabled=cfg.data.prefetch
        )

        self.model = NavFormerModel(self.model_config).to(self.device)
        self.model.train()
        self.actor = make_navformer_actor(self.model, length_groups=self.cfg.optim.length_groups)
        self.dt_loss = (ActionBinLoss if self.model.config.action_bins else ActionMSELoss)(self.actor)
        # validation scores eq. 10's squared error whatever the training loss (comparable rows)
        self.validation_loss = (
            self.dt_loss if isinstance(self.dt_loss, ActionMSELoss) else ActionMSELoss(self.actor)
        )
        self.byol_loss = None
        self.updater = None
        self.tau_schedule = None
        if cfg.uses_ssl:
            self.byol_loss = BYOLLoss(
                self.model.dve,
                projection_dim=cfg.ssl.projection_dim,
                hidden_dim=cfg.ssl.hidden_dim,
                seed=cfg.seed + 4,
                augmentation=self._sharded_augmentation(),
                autocast_dtype=self.model_config.autocast_dtype,
            ).to(self.device)
            if self.distributed.enabled:  # the projector / predictor BatchNorm over the global batch
                use_global_batch_norm(self.byol_loss.online_network)
                use_global_batch_norm(self.byol_loss.predictor)
            self.updater = SoftUpdate(self.byol_loss, eps=cfg.ssl.tau_base)
            self.tau_schedule = BYOLTauSchedule(self.updater, cfg.optim.iterations, cfg.ssl.tau_base)
        self.optimizers = self._make_optimizers()
        # float16 autocast needs loss scaling (its gradients underflow); disabled, the scaler is a no-op
        self.scaler = torch.amp.GradScaler(
            self.device.type, enabled=self.model_config.autocast_dtype == "float16"
        )
        self.logger = None
        self.log_window = LogWindow()
        self.validator = make_validator(
            cfg.validation, validation_datasets or {}, datasets, context, keys=TRAJECTORY_KEYS
        )
        if self.distributed.enabled:
            # the same start on every process (as DistributedDataParallel does), then per-process dropout
            self.distributed.broadcast_tensors(self._state_tensors())
            if not self.distributed.is_main:
                _seed_everything(rank_seed(cfg.seed, self.distributed.rank))

    # -- construction helpers -------------------------------------------------------------------------
    def _sharded_augmentation(self) -> ShardedAugmentation | None:
        """BYOL's augmentation of this process's pairs of the global batch (None for one process: BYOL's own)."""
        if not self.distributed.enabled:
            return None
        total = self.cfg.data.ssl_batch_pairs
        return ShardedAugmentation(rows=self.distributed.rows(total), total=total, seed=self.cfg.seed + 4)

    def _state_tensors(self) -> list[torch.Tensor]:
        """Every parameter and buffer of the model and the BYOL loss (online, EMA target, BatchNorm statistics)."""
        modules = [self.model] if self.byol_loss is None else [self.model, self.byol_loss]
        return [t for module in modules for t in (*module.parameters(), *module.buffers())]

    def parameter_groups(self) -> dict[str, list[torch.nn.Parameter]]:
        """``{"navformer": [...], "dve": [...]}``: which parameters each optimiser owns (disjoint, complete).

        ``navformer`` (AdamW): the navigation network (token embeddings, transformer, head), plus the visual
        encoders when :func:`~navformer_rl.training.config.encoder_optimizer` is ``adamw``. ``dve`` (Adam):
        the visual encoders when it is ``adam`` (the paper's split, §VI), then BYOL's projectors and
        predictors; absent when it would be empty. Which losses reach the encoders is ``encoder_training``'s.
        """
        encoder_ids = {id(p) for p in self.model.dve.parameters()}
        model_params = [p for p in self.model.parameters() if p.requires_grad]
        encoders_under_adam = encoder_optimizer(self.cfg) == "adam"
        groups = {
            "navformer": [p for p in model_params if not (encoders_under_adam and id(p) in encoder_ids)]
        }
        dve = [p for p in model_params if id(p) in encoder_ids] if encoders_under_adam else []
        if self.byol_loss is not None:
            model_ids = {id(p) for p in model_params}
            dve += [p for p in self.byol_loss.parameters() if id(p) not in model_ids]
        if dve:
            groups["dve"] = dve
        return groups

    def _make_optimizers(self) -> dict[str, torch.optim.Optimizer]:
        groups = self.parameter_groups()
        optim = self.cfg.optim
        optimizers: dict[str, torch.optim.Optimizer] = {
            "navformer": torch.optim.AdamW(groups["navformer"], lr=optim.lr, weight_decay=optim.weight_decay)
        }
        if "dve" in groups:
            optimizers["dve"] = torch.optim.Adam(
                groups["dve"], lr=optim.dve_lr, weight_decay=optim.dve_weight_decay
            )
        return optimizers

    # -- batches --------------------------------------------------------------------------------------
    def _draw_batches(self) -> tuple[str, Any, Any]:
        """One iteration's ``(task, trajectory batch [N] with BATCH_KEYS, D_ssl pairs [B] or None)``."""
        batch = self.cross_task.sample()
        pairs = self.pairs.sample() if self.pairs is not None else None
        return self.cross_task.task_of(batch), batch.select(*BATCH_KEYS), pairs

    def _sampler_state(self) -> dict[str, Any]:
        """The samplers' positions and RNG states (``cross_task`` and, with SSL, ``pairs``) for a checkpoint."""
        state = {"cross_task": self.cross_task.state_dict()}
        if self.pairs is not None:
            state["pairs"] = self.pairs.state_dict()
        return state

    def _load_sampler_state(self, state: Mapping[str, Any]) -> None:
        self.cross_task.load_state_dict(state["cross_task"])
        if self.pairs is not None:
            self.pairs.load_state_dict(state["pairs"])

    def close(self) -> None:
        """Stop drawing batches ahead (the samplers keep the state of the batches handed out)."""
        self.batches.close()

    # -- one iteration --------------------------------------------------------------------------------
    def step(self) -> dict[str, float]:
        """Run one training iteration (eq. 11) and return its metrics as floats.

        Keys: ``loss`` (L), ``loss_dt``, ``loss_dt_<task>`` (task of this iteration), ``loss_byol``,
        ``byol_<encoder>``, ``projection_std_<encoder>``, ``tau``, ``lr``, ``lr_dve``, ``frames``
        (valid trajectory steps + 2 x pairs), ``frames_per_s``, ``iteration_s``.
        """
        from torchrl._utils import timeit

        sync = self.device.type == "cuda"  # time the GPU work of each phase, not its launches
        start = time.perf_counter()
        with timeit("sample", sync=sync):  # with data.prefetch: the wait for the batches drawn ahead
            task, batch, pairs = self.batches.next(draw_ahead=self.iteration + 1 < self.cfg.optim.iterations)
            batch = batch.to(self.device, non_blocking=True)
            pairs = pairs.to(self.device, non_blocking=True) if pairs is not None else None
        for optimizer in self.optimizers.values():
            optimizer.zero_grad(set_to_none=True)
        with timeit("forward_backward", sync=sync):
            loss_dt, loss_byol, byol_out = self._forward_backward(batch, pairs)
        if self.distributed.enabled:
            with timeit("all_reduce", sync=sync):
                groups = self.parameter_groups().values()
                self.distributed.all_reduce_gradients(p for group in groups for p in group)
        with timeit("optimizer", sync=sync):
            if self.cfg.optim.clip_grad_norm is not None:
                for optimizer in self.optimizers.values():
                    self.scaler.unscale_(optimizer)
                    params = [p for g in optimizer.param_groups for p in g["params"]]
                    torch.nn.utils.clip_grad_norm_(params, self.cfg.optim.clip_grad_norm)
            for optimizer in self.optimizers.values():
                self.scaler.step(optimizer)  # skipped (float16 only) when a gradient overflowed
            self.scaler.update()
            tau = None
            if self.updater is not None:
                tau = self.updater.eps
                self.updater.step()
                self.tau_schedule.step()
        self.iteration += 1
        if self.device.type == "cuda":
            torch.cuda.synchronize(self.device)  # the timing covers the queued GPU work
        elapsed = time.perf_counter() - start
        losses = {
            "loss_dt": loss_dt,
            "frames": batch["mask"].sum() + (2 * pairs.shape[0] if pairs is not None else 0),
        }
        if byol_out is not None:
            losses["weighted_loss_byol"] = loss_byol.detach()  # loss = L_DT + w L_BYOL
            losses.update({k: v.detach() for k, v in byol_out.items()})
        if self.distributed.enabled:
            losses = self._global_values(losses, pairs)
        frames = float(losses["frames"])
        metrics = {
            "loss_dt": float(losses["loss_dt"]),
            f"loss_dt_{task}": float(losses["loss_dt"]),
            "lr": self.optimizers["navformer"].param_groups[0]["lr"],
            "frames": frames,
            "frames_per_s": frames / elapsed,
            "iteration_s": elapsed,
        }
        total = metrics["loss_dt"]
        if byol_out is not None:
            total += float(losses["weighted_loss_byol"])
            metrics.update({k: float(losses[k]) for k in byol_out.keys()})
            metrics["tau"] = float(tau)
        if "dve" in self.optimizers:
            metrics["lr_dve"] = self.optimizers["dve"].param_groups[0]["lr"]
        metrics["loss"] = total
        if not math.isfinite(total):
            raise FloatingPointError(f"iteration {self.iteration}: the loss is {total} (metrics {metrics})")
        return metrics

    def _pair_share(self, pairs: TensorDict) -> float:
        """This process's share of the global D_ssl batch (1 for one process)."""
        return pairs.shape[0] / self.cfg.data.ssl_batch_pairs if self.distributed.enabled else 1.0

    def _global_values(
        self, local: dict[str, torch.Tensor], pairs: TensorDict | None
    ) -> dict[str, torch.Tensor]:
        """The global batch's metrics from every process's ``local`` ones, in one all-reduce: ``loss_dt``,
        ``weighted_loss_byol`` and ``frames`` are already this process's part of the global value (summed);
        BYOL's per-encoder outputs are means over this process's pairs (weighted by its share, then summed:
        exact for the losses, a weighted mean of per-process values for ``projection_std_<encoder>``)."""
        share = self._pair_share(pairs) if pairs is not None else 1.0
        parts = {"loss_dt", "weighted_loss_byol", "frames"}
        values = torch.stack([v.float() if k in parts else v.float() * share for k, v in local.items()])
        return dict(zip(local, self.distributed.all_reduce_sum(values).unbind(0), strict=True))

    def _forward_backward(
        self, batch: TensorDict, pairs: TensorDict | None
    ) -> tuple[torch.Tensor, torch.Tensor | None, TensorDict | None]:
        """L = L_DT + L_BYOL, one backward (or one per trajectory chunk, weighted to the same gradient).

        Every backward goes through ``self.scaler`` (loss scaling under float16 autocast, else unchanged).
        With several processes each one back-propagates its part of the global loss: L_DT's masked mean
        weighted by its valid steps over the global batch's (all-reduced), L_BYOL by its share of the pairs;
        summed over the processes (the gradients' all-reduce) that is the global batch's L.
        Returns ``(loss_dt, loss_byol, byol_out)``: the detached DT loss, BYOL's weighted loss (None without
        SSL) and the BYOL loss module's output TensorDict (None without SSL; this process's pairs).
        """
        chunks = self.cfg.optim.trajectory_chunks
        byol_out = self.byol_loss(pairs) if pairs is not None else None
        loss_byol = byol_out["loss_byol"] if byol_out is not None else None
        if loss_byol is not None and self.cfg.ssl.loss_weight != 1.0:
            loss_byol = loss_byol * self.cfg.ssl.loss_weight  # logged unweighted (byol_out)
        if chunks == 1 and not self.distributed.enabled:
            loss_dt = self.dt_loss(batch)["loss_dt"]
            self.scaler.scale(loss_dt if loss_byol is None else loss_dt + loss_byol).backward()
            return loss_dt.detach(), loss_byol, byol_out
        valid_total = batch["mask"].sum()
        if self.distributed.enabled:
            valid_total = self.distributed.all_reduce_sum(valid_total)
            if loss_byol is not None:
                loss_byol = loss_byol * self._pair_share(pairs)
        valid_total = valid_total.clamp_min(1)
        n = batch.shape[0]
        if self.cfg.optim.chunks_by_length:
            parts = split_by_length(batch, chunks)
        else:
            parts = [batch[shard_rows(n, i, min(chunks, n))] for i in range(min(chunks, n))]
        if loss_byol is not None and len(parts) > 1:
            self.scaler.scale(loss_byol).backward()
        loss_dt = torch.zeros((), device=self.device)
        for part in parts:
            # masked mean of the chunk x its share of the valid steps = its part of the batch's masked mean
            weighted = self.dt_loss(part)["loss_dt"] * (part["mask"].sum() / valid_total)
            together = loss_byol is not None and len(parts) == 1  # one backward, as one process does
            self.scaler.scale(weighted + loss_byol if together else weighted).backward()
            loss_dt += weighted.detach()
        return loss_dt, loss_byol, byol_out

    # -- validation -----------------------------------------------------------------------------------
    def validation_due(self) -> bool:
        """Whether the iteration just completed is one to validate (``validation.interval``, the last one)."""
        return self.validator is not None and self.validator.due(self.iteration, self.cfg.optim.iterations)

    def validate(self) -> dict[str, float]:
        """The teacher-forced action loss on every validation set: ``{"validation/loss_dt_<task>": float,
        "validation/train_loss_dt_<task>": float}`` (eval mode; the training's RNG states are left as they
        were). Empty without validation sets. With several processes each scores its share of the batches
        and every process gets the totals. The loss is eq. 10's squared error whatever the training loss
        (a ``model.action_bins`` run is scored on its decoded actions, comparable with the paper's head)."""
        if self.validator is None:
            return {}
        return self.validator(self.validation_loss, self.model, self.device, distributed=self.distributed)

    # -- logging --------------------------------------------------------------------------------------
    def make_logger(self) -> Logger | None:
        """TorchRL logger of ``cfg.logger.backend`` writing under ``<run_dir>/logs`` (None for ``none``)."""
        backend = self.cfg.logger.backend
        log_dir = str(self.run_dir / "logs")
        if backend == "csv":
            from torchrl.record.loggers.csv import CSVLogger

            return CSVLogger(self.cfg.logger.exp_name, log_dir=log_dir, video_format="pt")
        if backend == "tensorboard":
            from torchrl.record.loggers.tensorboard import TensorboardLogger

            return TensorboardLogger(self.cfg.logger.exp_name, log_dir=log_dir)
        return None

    def record(self, metrics: Mapping[str, float]) -> bool:
        """Add this iteration's ``metrics`` to :attr:`log_window` and, when the iteration is a multiple of
        ``logger.log_interval`` or the last one, :meth:`log` the window's summary. Returns True when a row was
        written."""
        self.log_window.add(metrics)
        due = self.iteration % self.cfg.logger.log_interval == 0
        if not (due or self.iteration == self.cfg.optim.iterations):
            return False
        self.log(self.log_window.pop_row())
        return True

    def log(self, metrics: Mapping[str, float], timings: bool = True) -> None:
        """Write ``metrics`` (plus, with ``timings``, ``timeit`` averages as ``time/<name>``) at the current
        iteration."""
        from torchrl._utils import timeit

        if self.logger is None:
            return
        row = dict(metrics)
        if timings:
            row.update(timeit.todict(prefix="time"))
        self.logger.log_metrics(row, step=self.iteration)

    # -- checkpoints ----------------------------------------------------------------------------------
    def resume_state(self) -> dict[str, Any]:
        """Everything beyond the model weights that a bit-identical continuation needs (plain containers)."""
        state: dict[str, Any] = {
            "iteration": self.iteration,
            "optimizers": {name: opt.state_dict() for name, opt in self.optimizers.items()},
            "rng": ckpt.capture_rng_state(),
            "log_window": self.log_window.state_dict(),
        }
        if self.scaler.is_enabled():
            state["grad_scaler"] = self.scaler.state_dict()
        if self.byol_loss is not None:
            state["byol"] = self.byol_loss.state_dict()
            state["byol_augmentation"] = self.byol_loss.augmentation.rng_state()
            state["tau_schedule"] = self.tau_schedule.state_dict()
        # after the batches handed out, not after one drawn ahead: a resumed run draws the next one again
        state.update(self.batches.state_dict())
        return state

    def save_checkpoint(self) -> Path:
        """Write the run part and the resume part at the current iteration (atomic); returns its folder.

        With several processes every one calls it: rank 0 gathers their RNG states (``rng_ranks`` in the
        resume part; the rest of the state is the same on every process) and writes; the others wait until
        the checkpoint is complete."""
        rng_ranks = self.distributed.gather_object(ckpt.capture_rng_state())
        folder = self.run_dir / ckpt.CHECKPOINTS_DIRNAME / ckpt.checkpoint_name(self.iteration)
        if self.distributed.is_main:
            state = self.resume_state()
            if self.distributed.enabled:
                state["rng_ranks"] = rng_ranks
            folder = ckpt.save_checkpoint(
                self.run_dir,
                self.iteration,
                model_state=self.model.state_dict(),
                model_config=dataclasses.asdict(self.model_config),
                train_config=self.cfg.to_dict(),
                resume_state=state,
                keep_last=self.cfg.checkpoint.keep_last,
                run_info=self.run_info,
            )
        self.distributed.barrier()
        return folder

    def restore(self, folder: Path) -> None:
        """Load a checkpoint written by :meth:`save_checkpoint` into this (freshly built) trainer.

        Raises:
            ValueError: the configuration differs from the checkpoint's in a setting a resume may not change
                (:data:`RESUME_MAY_CHANGE`), or the checkpoint was written by another number of processes.
        """
        header = ckpt.read_checkpoint_config(folder)
        recorded = ckpt.recorded_world_size(header)
        if recorded != self.distributed.world_size:
            raise ValueError(
                f"cannot resume {folder} with {self.distributed.world_size} process(es): it was written by "
                f"{recorded} (each process's random streams are part of the checkpoint); resume with "
                f"torchrun --nproc-per-node {recorded}" + (" or without torchrun" if recorded == 1 else "")
            )
        # a key the checkpoint lacks came after it was written; the run had that key's default
        saved = _with_defaults(TrainConfig().to_dict(), header["train_config"])
        saved["optim"]["encoder_optimizer"] = _recorded_encoder_optimizer(header["train_config"])
        before, now = _comparable(saved), _comparable(self.cfg.to_dict())
        changed = sorted(k for k in set(before) | set(now) if before.get(k) != now.get(k))
        if changed:
            raise ValueError(
                f"cannot resume {folder}: the configuration differs in {changed} "
                f"(checkpoint: {[before.get(k) for k in changed]}, now: {[now.get(k) for k in changed]})"
            )
        _, weights = ckpt.load_model_state(folder)
        ckpt.load_model_weights(self.model, weights, folder)
        state = ckpt.load_resume_state(folder)
        for name, optimizer in self.optimizers.items():
            optimizer.load_state_dict(state["optimizers"][name])
        self.batches.load_state_dict({k: state[k] for k in ("cross_task", "pairs") if k in state})
        if self.scaler.is_enabled():
            self.scaler.load_state_dict(state["grad_scaler"])
        if self.byol_loss is not None:
            self.byol_loss.load_state_dict(state["byol"])
            self.byol_loss.augmentation.set_rng_state(state["byol_augmentation"])
            self.tau_schedule.load_state_dict(state["tau_schedule"])
        ckpt.restore_rng_state(
            state["rng_ranks"][self.distributed.rank] if self.distributed.enabled else state["rng"]
        )
        if "log_window" in state:  # absent from checkpoints of earlier versions: their window starts empty
            self.log_window.load_state_dict(state["log_window"])
        self.iteration = int(state["iteration"])
        self.run_info["init_from"] = (header.get("run") or {}).get("init_from")
