"""Running a training, TorchRL's way: every check (:func:`prepare_run`), the ``make_*`` pieces
(:func:`make_trainer`, :mod:`~navformer_rl.training.factories`), the start (:func:`start_run`: resume, init
weights, run files, logger), then the one loop (:func:`train_loop`). :func:`build_trainer` is the first three,
:func:`train` all four (every process of a ``torchrun`` launch runs it); ``navformer train`` calls
:func:`train`, the recipe (``recipes/navformer/navformer.py``) shows the same calls and runs the same loop.
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch

from navformer_rl.training import checkpoint as ckpt
from navformer_rl.training import distributed as dist
from navformer_rl.training.config import TrainConfig, named_run, validate_config, with_encoder_optimizer
from navformer_rl.training.config_io import RUN_INFO_KEY
from navformer_rl.training.datasets import check_datasets_fit_model, open_datasets, open_validation_datasets
from navformer_rl.training.factories import (
    TRAJECTORY_KEYS,
    context_steps,
    make_batchers,
    make_learner,
    make_model_and_losses,
    make_optimizers,
    seed_everything,
    start_alike,
)
from navformer_rl.training.init_from import InitSource, load_initial_weights, resolve_init_source
from navformer_rl.training.trainer import Trainer
from navformer_rl.training.validation import make_validator
from navformer_rl.utils.allocator import keep_freed_memory, release_free_memory
from navformer_rl.utils.devices import bfloat16_autocast_warning, resolve_device
from navformer_rl.utils.durable import atomic_write_text
from navformer_rl.utils.interrupts import StopRequest, stop_at_safe_point


@dataclass
class TrainResult:
    """What :func:`train` returns: the run directory, completed iterations, the last iteration's metrics
    (``loss``, ``loss_dt``, ``loss_byol``, ... floats) and the last checkpoint folder."""

    run_dir: Path
    iterations: int
    metrics: dict[str, float]
    checkpoint: Path | None

    def summary(self) -> str:
        """Three lines for the terminal: iterations and last losses, the run directory,
        the last checkpoint."""
        losses = ", ".join(
            f"{k}={self.metrics[k]:.4g}" for k in ("loss", "loss_dt", "loss_byol") if k in self.metrics
        )
        return (
            f"trained {self.iterations} iterations; {losses}\n"
            f"run directory: {self.run_dir}\n"
            f"checkpoint:    {self.checkpoint}"
        )


@dataclass
class PreparedRun:
    """A checked run, before anything is built (:func:`prepare_run`)."""

    cfg: TrainConfig
    """The configuration, named (``logger.exp_name``) and with its encoder optimiser resolved."""
    distributed: dist.Distributed
    """This process's place in a data-parallel run (one process by default)."""
    device: torch.device
    """Where this process trains."""
    datasets: dict[str, Any]
    """The opened training datasets (``e``, ``ca``, ``ssl``: those the run uses)."""
    validation_datasets: dict[str, Any]
    """The opened held-out datasets (``validation.*``; empty without)."""
    latest: Path | None
    """The checkpoint to resume (``resume=true`` and one exists), else None."""
    source: InitSource | None
    """``init_from``'s weights for a new run, else None."""


def prepare_run(cfg: TrainConfig, distributed: dist.Distributed | None = None) -> PreparedRun:
    """Validate ``cfg`` and open the datasets: every configuration error is raised here, before anything is
    built. A fresh run refuses an output directory that already holds checkpoints (pass ``resume=True`` to
    continue it). Resuming wins over ``init_from``: the run continues from its own checkpoint and keeps the
    source it recorded (a warning says so when ``init_from`` names another one).

    ``distributed``: this process's place in a data-parallel run (default: the process group already
    started, else one process, :func:`~navformer_rl.training.distributed.current`).
    """
    validate_config(cfg)
    if distributed is None:
        distributed = dist.current(cfg.device)
    _check_batches_split(cfg, distributed.world_size)
    if cfg.keep_freed_memory:
        keep_freed_memory()
    latest = ckpt.run_folder_latest(Path(cfg.output_dir), cfg.resume)
    if latest is not None:
        cfg = _recorded_init_from(cfg, latest)
    source = resolve_init_source(cfg) if cfg.init_from is not None and latest is None else None
    if cfg.logger.backend == "tensorboard":
        try:
            import tensorboard  # noqa: F401
        except ImportError:
            raise ValueError(
                "logger.backend=tensorboard needs the `tensorboard` package; use csv or none"
            ) from None
    datasets = open_datasets(cfg)
    check_datasets_fit_model(cfg, datasets)
    validation_datasets = open_validation_datasets(cfg)
    check_datasets_fit_model(cfg, validation_datasets, section="validation")
    cfg = with_encoder_optimizer(named_run(cfg, resuming=latest is not None))
    device = distributed.device or resolve_device(cfg.device)
    return PreparedRun(cfg, distributed, device, datasets, validation_datasets, latest, source)


def make_trainer(run: PreparedRun) -> Trainer:
    """The run's pieces, made in the order a seed's run depends on (as the recipe shows them)."""
    cfg, device, distributed = run.cfg, run.device, run.distributed
    seed_everything(cfg.seed)
    cross_task, pairs = make_batchers(cfg, run.datasets, device=device, distributed=distributed)
    parts = make_model_and_losses(cfg, device=device, distributed=distributed)
    learner = make_learner(cfg, parts, make_optimizers(cfg, parts))
    validator = make_validator(
        cfg.validation, run.validation_datasets, run.datasets, context_steps(cfg), keys=TRAJECTORY_KEYS
    )
    start_alike(parts, cfg, distributed)
    return Trainer(
        cfg,
        cross_task=cross_task,
        pairs=pairs,
        parts=parts,
        learner=learner,
        validator=validator,
        distributed=distributed,
    )


def start_run(run: PreparedRun, trainer: Trainer) -> Trainer:
    """Restore the checkpoint to resume or load ``init_from``'s weights; rank 0 writes ``train_config.json``,
    drops log rows written after the restored checkpoint and opens the logger. Returns ``trainer``."""
    cfg, distributed = run.cfg, run.distributed
    slow_bf16 = bfloat16_autocast_warning(trainer.device, trainer.model_config.autocast_dtype)
    if slow_bf16 is not None and distributed.is_main:
        warnings.warn(slow_bf16, UserWarning, stacklevel=3)
    if run.latest is not None:
        trainer.restore(run.latest)
    elif run.source is not None:
        load_initial_weights(trainer, run.source)
    if trainer.iteration > cfg.optim.iterations:
        raise ValueError(
            f"{run.latest} is at iteration {trainer.iteration}, "
            f"beyond optim.iterations={cfg.optim.iterations}"
        )
    if distributed.is_main:
        run_dir = trainer.run_dir
        run_dir.mkdir(parents=True, exist_ok=True)
        record = {**cfg.to_dict(), RUN_INFO_KEY: trainer.run_info}
        atomic_write_text(run_dir / "train_config.json", json.dumps(record, indent=2, sort_keys=True))
        # rows a crashed run logged after its last checkpoint (all of them when it crashed before the first)
        _truncate_csv_scalars(run_dir / "logs" / cfg.logger.exp_name / "scalars", trainer.iteration)
        trainer.logger = trainer.make_logger()
    return trainer


def build_trainer(cfg: TrainConfig, distributed: dist.Distributed | None = None) -> Trainer:
    """A ready :class:`Trainer` of ``cfg``: :func:`prepare_run` (every check), :func:`make_trainer`,
    :func:`start_run` (restored when resuming, started from ``init_from``'s weights when fine-tuning)."""
    run = prepare_run(cfg, distributed)
    return start_run(run, make_trainer(run))


def _check_batches_split(cfg: TrainConfig, world_size: int) -> None:
    """ValueError when a global batch the run draws has fewer rows than there are processes."""
    if world_size == 1:
        return
    sizes = {"data.ssl_batch_pairs": (cfg.uses_ssl, cfg.data.ssl_batch_pairs)}
    sizes["data.exploration_batch_trajs"] = (cfg.uses_exploration, cfg.data.exploration_batch_trajs)
    sizes["data.collision_batch_trajs"] = (cfg.uses_collision, cfg.data.collision_batch_trajs)
    for key, (used, size) in sizes.items():
        if used and size < world_size:
            raise ValueError(
                f"{key}={size} is smaller than the {world_size} processes: the batch sizes are global and "
                f"every process needs at least one row; use {key}>={world_size} or fewer processes"
            )


def _recorded_init_from(cfg: TrainConfig, latest: Path) -> TrainConfig:
    """``cfg`` with the ``init_from`` the resumed run recorded (a resume continues from its own checkpoint;
    a warning when ``cfg`` names another source)."""
    recorded: Any = ckpt.read_checkpoint_config(latest)["train_config"].get("init_from")
    if cfg.init_from is not None and cfg.init_from != recorded:
        warnings.warn(
            f"init_from={cfg.init_from} is ignored: resuming {latest} (the run started from "
            f"{recorded or 'random weights'})",
            UserWarning,
            stacklevel=3,
        )
    return dataclasses.replace(cfg, init_from=recorded)


def _truncate_csv_scalars(folder: Path, last_step: int) -> None:
    """Drop CSV rows written after ``last_step`` (by a run that crashed after its last checkpoint)."""
    if not folder.is_dir():
        return
    for csv in folder.rglob("*.csv"):
        rows = csv.read_text().splitlines()
        kept = [row for row in rows if row and int(row.split(",", 1)[0]) <= last_step]
        if len(kept) != len(rows):
            atomic_write_text(csv, "".join(f"{row}\n" for row in kept))


def _stop_agreed(stop: StopRequest, trainer: Trainer) -> bool:
    """Whether a Ctrl-C or SIGTERM came to any process of the run (one collective per iteration when
    several train, so that every process saves the same checkpoint and stops after the same iteration)."""
    distributed = trainer.distributed
    if not distributed.enabled:
        return stop.requested
    flag = torch.tensor([float(stop.requested)], device=distributed.device or trainer.device)
    return bool(distributed.all_reduce_sum(flag).item() > 0)


def train(cfg: TrainConfig) -> TrainResult:
    """Train NavFormer as configured: :func:`build_trainer`, then :func:`train_loop`; see
    :mod:`navformer_rl.training` for one iteration. ``navformer train`` calls it; the recipe makes the same
    calls.

    Under ``torchrun`` every process calls it: :func:`~navformer_rl.training.distributed.process_group` starts
    the process group (and destroys it at the end, also on an error); rank 0 alone writes checkpoints, logs,
    run files and the progress bar; every process returns the same :class:`TrainResult`.
    """
    with dist.process_group(cfg.device):
        return _train(cfg)


def _train(cfg: TrainConfig) -> TrainResult:
    return train_loop(build_trainer(cfg))  # inside the process group started above


def train_loop(trainer: Trainer) -> TrainResult:
    """The one training loop, from the trainer's iteration to ``optim.iterations``.

    Per iteration: ``Trainer.step()`` (eq. 11), ``Trainer.record()`` (a log row every
    ``logger.log_interval`` iterations), validation when due, a checkpoint every ``checkpoint.interval``
    iterations and at the end (then, with ``keep_freed_memory``, ``malloc_trim`` hands the free heap back), a
    tqdm bar named after ``logger.exp_name``. ``timeit`` times the phases (``time/<phase>`` in the log rows).

    A Ctrl-C or SIGTERM (a scheduler's preemption) lets the iteration under way finish, saves a checkpoint
    and then raises (``KeyboardInterrupt``, :class:`~navformer_rl.utils.interrupts.Terminated` for SIGTERM),
    so ``resume=True`` loses nothing; a second one stops at once, back to the last checkpoint.

    Returns a :class:`TrainResult`. A resumed run produces the same subsequent losses and weights as an
    uninterrupted run.
    """
    from torchrl._utils import timeit
    from tqdm import tqdm

    cfg = trainer.cfg
    distributed = trainer.distributed
    timeit.erase()
    metrics: dict[str, float] = {}
    last_checkpoint = None
    total = cfg.optim.iterations
    bar = tqdm(
        total=total,
        initial=trainer.iteration,
        disable=not (cfg.logger.progress and distributed.is_main),
        desc=f"train {trainer.cfg.logger.exp_name}",
    )
    with contextlib.closing(bar), contextlib.closing(trainer), stop_at_safe_point() as stop:
        while trainer.iteration < total:
            metrics = trainer.step()
            trainer.record(metrics)
            if trainer.validation_due():
                with timeit("validation"):
                    trainer.log(trainer.validate(), timings=False)
            stopping = _stop_agreed(stop, trainer)
            if stopping or trainer.iteration % cfg.checkpoint.interval == 0 or trainer.iteration == total:
                with timeit("checkpoint"):
                    last_checkpoint = trainer.save_checkpoint()
                    if cfg.keep_freed_memory:  # the kept heap's fragmentation must not grow for the whole run
                        release_free_memory()
            bar.update(1)
            bar.set_postfix(loss=f"{metrics['loss']:.4f}", fps=f"{metrics['frames_per_s']:.0f}")
            if stopping and trainer.iteration < total:
                raise stop.interrupt()
    distributed.barrier()  # rank 0 has written everything
    if last_checkpoint is None:
        last_checkpoint = ckpt.latest_checkpoint(trainer.run_dir)
    return TrainResult(trainer.run_dir, trainer.iteration, metrics, last_checkpoint)
