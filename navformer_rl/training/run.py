"""Running a training: :func:`build_trainer` (every check, then a ready
:class:`~navformer_rl.training.trainer.Trainer`, restored when resuming) and :func:`train` (the loop with tqdm
progress, checkpoints and validation) returning a :class:`TrainResult`.
"""

from __future__ import annotations

import contextlib
import json
from dataclasses import dataclass
from pathlib import Path

from navformer_rl.training import checkpoint as ckpt
from navformer_rl.training.config import TrainConfig, named_run, validate_config
from navformer_rl.training.datasets import check_datasets_fit_model, open_datasets, open_validation_datasets
from navformer_rl.training.trainer import Trainer
from navformer_rl.utils.allocator import keep_freed_memory, release_free_memory
from navformer_rl.utils.durable import atomic_write_text


@dataclass
class TrainResult:
    """What :func:`train` returns: the run directory, completed iterations, the last iteration's metrics
    (``loss``, ``loss_dt``, ``loss_byol``, ... floats) and the last checkpoint folder."""

    run_dir: Path
    iterations: int
    metrics: dict[str, float]
    checkpoint: Path | None

    def summary(self) -> str:
        """Three lines for the terminal: iterations and last losses, the run directory, the last checkpoint."""
        losses = ", ".join(
            f"{k}={self.metrics[k]:.4g}" for k in ("loss", "loss_dt", "loss_byol") if k in self.metrics
        )
        return (
            f"trained {self.iterations} iterations; {losses}\n"
            f"run directory: {self.run_dir}\n"
            f"checkpoint:    {self.checkpoint}"
        )


def build_trainer(cfg: TrainConfig) -> Trainer:
    """Validate ``cfg``, open the datasets, build everything and (when resuming) restore the latest checkpoint.

    Every configuration error is raised here, before the first iteration. A fresh run refuses an
    output directory that already holds checkpoints (pass ``resume=True`` to continue it).
    """
    validate_config(cfg)
    if cfg.keep_freed_memory:
        keep_freed_memory()
    run_dir = Path(cfg.output_dir)
    if run_dir.exists() and not run_dir.is_dir():
        raise ValueError(f"output_dir={str(run_dir)!r} is a file; expected a folder (created if missing)")
    latest = ckpt.latest_checkpoint(run_dir) if (run_dir / ckpt.CHECKPOINTS_DIRNAME).is_dir() else None
    if latest is not None and not cfg.resume:
        raise FileExistsError(
            f"output_dir={str(run_dir)!r} already holds checkpoints (latest {latest.name}); "
            "set resume=true to continue that run or choose another output_dir"
        )
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
    cfg = named_run(cfg, resuming=latest is not None)
    trainer = Trainer(cfg, datasets=datasets, validation_datasets=validation_datasets)
    if latest is not None:
        trainer.restore(latest)
    if trainer.iteration > cfg.optim.iterations:
        raise ValueError(
            f"{latest} is at iteration {trainer.iteration}, beyond optim.iterations={cfg.optim.iterations}"
        )
    run_dir.mkdir(parents=True, exist_ok=True)
    atomic_write_text(run_dir / "train_config.json", json.dumps(cfg.to_dict(), indent=2, sort_keys=True))
    # rows a crashed run logged after its last checkpoint (all of them when it crashed before the first)
    _truncate_csv_scalars(run_dir / "logs" / cfg.logger.exp_name / "scalars", trainer.iteration)
    trainer.logger = trainer.make_logger()
    return trainer


def _truncate_csv_scalars(folder: Path, last_step: int) -> None:
    """Drop CSV rows written after ``last_step`` (by a run that crashed after its last checkpoint)."""
    if not folder.is_dir():
        return
    for csv in folder.rglob("*.csv"):
        rows = csv.read_text().splitlines()
        kept = [row for row in rows if row and int(row.split(",", 1)[0]) <= last_step]
        if len(kept) != len(rows):
            atomic_write_text(csv, "".join(f"{row}\n" for row in kept))


def train(cfg: TrainConfig) -> TrainResult:
    """Train NavFormer as configured; see :mod:`navformer_rl.training` for one iteration.

    The one training loop: ``navformer train`` and the hydra recipe (``recipes/navformer``) both call it.
    Per iteration: ``Trainer.step()``, ``Trainer.record()`` (a log row every ``logger.log_interval``
    iterations), validation when due, a checkpoint every ``checkpoint.interval`` iterations and at the end
    (then, with ``keep_freed_memory``, ``malloc_trim`` hands the free heap back), a tqdm bar named after
    ``logger.exp_name``. ``timeit`` times the phases (``time/<phase>`` in the log rows).

    Returns a :class:`TrainResult`. With ``resume=True`` the run continues from the latest checkpoint and
    produces the same subsequent losses and weights as an uninterrupted run.
    """
    from torchrl._utils import timeit
    from tqdm import tqdm

    trainer = build_trainer(cfg)
    timeit.erase()
    metrics: dict[str, float] = {}
    last_checkpoint = None
    total = cfg.optim.iterations
    bar = tqdm(
        total=total,
        initial=trainer.iteration,
        disable=not cfg.logger.progress,
        desc=f"train {trainer.cfg.logger.exp_name}",
    )
    with contextlib.closing(bar), contextlib.closing(trainer):
        while trainer.iteration < total:
            metrics = trainer.step()
            trainer.record(metrics)
            if trainer.validation_due():
                with timeit("validation"):
                    trainer.log(trainer.validate(), timings=False)
            if trainer.iteration % cfg.checkpoint.interval == 0 or trainer.iteration == total:
                with timeit("checkpoint"):
                    last_checkpoint = trainer.save_checkpoint()
                    if cfg.keep_freed_memory:  # the kept heap's fragmentation must not grow for the whole run
                        release_free_memory()
            bar.update(1)
            bar.set_postfix(loss=f"{metrics['loss']:.4f}", fps=f"{metrics['frames_per_s']:.0f}")
    if last_checkpoint is None:
        last_checkpoint = ckpt.latest_checkpoint(trainer.run_dir)
    return TrainResult(trainer.run_dir, trainer.iteration, metrics, last_checkpoint)
