"""One built training run, :class:`Trainer`: the batches, the learner, the logger and the validator of a run;
one iteration (``step``: :func:`~navformer_rl.training.step.train_step` with the run's metrics), logging, and
checkpoints that resume bit-identically (``save_checkpoint``, ``restore``). Made from the ``make_*``
factories (:mod:`navformer_rl.training.factories`) by :func:`navformer_rl.training.make_trainer`; one process
of a data-parallel run (:mod:`navformer_rl.training.distributed`) when given a
:class:`~navformer_rl.training.distributed.Distributed`.
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

import torch
from tensordict import TensorDict

from navformer_rl.data.prefetch import Prefetcher
from navformer_rl.training import checkpoint as ckpt
from navformer_rl.training.config import TrainConfig, model_config, with_encoder_optimizer
from navformer_rl.training.distributed import Distributed
from navformer_rl.training.factories import (
    BATCH_KEYS,
    TRAJECTORY_KEYS,
    ModelAndLosses,
    make_logger,
    parameter_groups,
)
from navformer_rl.training.log_window import LogWindow
from navformer_rl.training.step import Learner, make_backward, train_step

if TYPE_CHECKING:
    from torchrl.record.loggers import Logger

    from navformer_rl.data import CrossTaskReplayBuffer
    from navformer_rl.training.validation import Validator

__all__ = ["BATCH_KEYS", "RESUME_MAY_CHANGE", "TRAJECTORY_KEYS", "Trainer"]

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


def _with_defaults(defaults: Mapping[str, Any], values: Mapping[str, Any]) -> dict[str, Any]:
    """``values`` with every section key it lacks taken from ``defaults``
    (``model`` overrides as they are)."""
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
    """``values`` flattened to dotted keys (``model`` overrides kept whole), less
    :data:`RESUME_MAY_CHANGE`."""
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
    """The built training run: :func:`~navformer_rl.training.make_trainer` (or :func:`build_trainer`) makes
    it; then ``step()`` per iteration.

    Attributes:
        cfg: the :class:`TrainConfig`.  run_dir: output folder.  device: torch device.
        parts: :class:`~navformer_rl.training.factories.ModelAndLosses`; ``model``, ``actor``, ``dt_loss``,
            ``validation_loss``, ``byol_loss``, ``tau_schedule`` name its fields.
        learner: :class:`~navformer_rl.training.step.Learner`, what an iteration updates; ``optimizers``
            (``{"navformer": AdamW, "dve": Adam}``, "dve" absent when it would own nothing: ``ablation=dt``)
            and ``scaler`` (``torch.amp.GradScaler``, enabled only under float16 autocast) name its fields.
        backward: how L reaches the gradients (:func:`~navformer_rl.training.step.make_backward`): None for
            one backward, else the trajectory-chunk / data-parallel wrapper.
        cross_task: ``CrossTaskReplayBuffer`` of the D_e / D_ca batchers.
        pairs: D_ssl ``PairBatcher`` or None.
        batches: :class:`~navformer_rl.data.prefetch.Prefetcher` of ``(task, batch, pairs)`` over both
            (drawing one iteration ahead with ``data.prefetch``; :meth:`close` stops it).
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
        cross_task: CrossTaskReplayBuffer,
        pairs: Any,
        parts: ModelAndLosses,
        learner: Learner,
        validator: Validator | None = None,
        distributed: Distributed | None = None,
    ) -> None:
        self.cfg = with_encoder_optimizer(cfg)
        self.distributed = distributed if distributed is not None else Distributed()
        self.run_info: dict[str, Any] = {**self.distributed.run_info(), "init_from": None}
        self.run_dir = Path(self.cfg.output_dir)
        self.parts, self.learner = parts, learner
        self.device = next(parts.model.parameters()).device
        self.model_config = model_config(self.cfg)
        self.iteration = 0
        self.cross_task, self.pairs = cross_task, pairs
        self.batches = Prefetcher(
            self._draw_batches, self._sampler_state, self._load_sampler_state, enabled=self.cfg.data.prefetch
        )
        self.backward = make_backward(self.cfg, learner, self.distributed)
        self.validator = validator
        self.logger: Logger | None = None
        self.log_window = LogWindow()

    # -- the parts, by name -----------------------------------------------------------------------------
    model = property(lambda self: self.parts.model, doc="The ``NavFormerModel`` (the parameters).")
    actor = property(lambda self: self.parts.actor, doc="The model's parts as TensorDict modules.")
    dt_loss = property(lambda self: self.parts.dt_loss, doc="L_DT (eq. 10).")
    validation_loss = property(lambda self: self.parts.validation_loss, doc="Eq. 10's squared error.")
    byol_loss = property(lambda self: self.parts.byol_loss, doc="L_BYOL (eq. 8) or None.")
    tau_schedule = property(lambda self: self.parts.tau_schedule, doc="The EMA's tau schedule or None.")
    optimizers = property(lambda self: self.learner.optimizers, doc="``{name: optimiser}``.")
    scaler = property(lambda self: self.learner.scaler, doc="The float16 loss scaler.")

    def parameter_groups(self) -> dict[str, list[torch.nn.Parameter]]:
        """Which parameters each optimiser owns
        (:func:`~navformer_rl.training.factories.parameter_groups`)."""
        return parameter_groups(self.cfg, self.model, self.byol_loss)

    # -- batches --------------------------------------------------------------------------------------
    def _draw_batches(self) -> tuple[str, Any, Any]:
        """One iteration's ``(task, trajectory batch [N] with BATCH_KEYS, D_ssl pairs [B] or None)``."""
        batch = self.cross_task.sample()
        pairs = self.pairs.sample() if self.pairs is not None else None
        return self.cross_task.task_of(batch), batch.select(*BATCH_KEYS), pairs

    def _sampler_state(self) -> dict[str, Any]:
        """The samplers' positions and RNG states (``cross_task`` and, with SSL,
        ``pairs``) for a checkpoint."""
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
        """Run one training iteration (eq. 11, :func:`~navformer_rl.training.step.train_step`) and return its
        metrics as floats.

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
        out = train_step(self.learner, batch, pairs, self.backward)
        self.iteration += 1
        if self.device.type == "cuda":
            torch.cuda.synchronize(self.device)  # the timing covers the queued GPU work
        elapsed = time.perf_counter() - start
        return self._metrics(task, batch, pairs, out, elapsed)

    def _metrics(self, task: str, batch: TensorDict, pairs: TensorDict | None, out: Any, elapsed: float):
        """The iteration's metrics (see :meth:`step`); with several processes, the global batch's."""
        losses = {
            "loss_dt": out.loss_dt,
            "frames": batch["mask"].sum() + (2 * pairs.shape[0] if pairs is not None else 0),
        }
        if out.byol is not None:
            losses["weighted_loss_byol"] = out.loss_byol.detach()  # loss = L_DT + w L_BYOL
            losses.update({k: v.detach() for k, v in out.byol.items()})
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
        if out.byol is not None:
            total += float(losses["weighted_loss_byol"])
            metrics.update({k: float(losses[k]) for k in out.byol.keys()})
            metrics["tau"] = float(out.tau)
        if "dve" in self.optimizers:
            metrics["lr_dve"] = self.optimizers["dve"].param_groups[0]["lr"]
        metrics["loss"] = total
        if not math.isfinite(total):
            raise FloatingPointError(f"iteration {self.iteration}: the loss is {total} (metrics {metrics})")
        return metrics

    def _global_values(
        self, local: dict[str, torch.Tensor], pairs: TensorDict | None
    ) -> dict[str, torch.Tensor]:
        """The global batch's metrics from every process's ``local`` ones, in one all-reduce: ``loss_dt``,
        ``weighted_loss_byol`` and ``frames`` are already this process's part of the global value (summed);
        BYOL's per-encoder outputs are means over this process's pairs (weighted by its share, then summed:
        exact for the losses, a weighted mean of per-process values for ``projection_std_<encoder>``)."""
        share = pairs.shape[0] / self.cfg.data.ssl_batch_pairs if pairs is not None else 1.0
        parts = {"loss_dt", "weighted_loss_byol", "frames"}
        values = torch.stack([v.float() if k in parts else v.float() * share for k, v in local.items()])
        return dict(zip(local, self.distributed.all_reduce_sum(values).unbind(0), strict=True))

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
        """The run's TorchRL logger (:func:`~navformer_rl.training.factories.make_logger`)."""
        return make_logger(self.cfg, self.run_dir)

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
