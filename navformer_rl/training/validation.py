"""Validation during training: the teacher-forced action loss (eq. 10) on held-out expert trajectories.

The training loss says how well the model fits the trajectories it trains on; whether it generalises to
new mazes needs the same loss on trajectories it never saw - D_e / D_ca collected with another seed
(``navformer collect e --n 24 --seed 99 --out data/val_e``). Every ``validation.interval`` iterations the
trainer computes, with the model in eval mode (no dropout) and no gradient::

    validation/loss_dt_<task>        masked action MSE over every held-out window (eq. 10)
    validation/train_loss_dt_<task>  the same on windows of the training data (compare_training)

where ``<task>`` is ``exploration`` (D_e) or ``collision_avoidance`` (D_ca). The second key is the
like-for-like reference: the logged ``loss_dt_<task>`` is measured in train mode (dropout on) on each
iteration's random batch, so it reads higher than an eval-mode loss on the same data. A held-out loss that
rises while the training one falls is overfitting.

Each set is fixed when the run starts: one window per trajectory (the longest ones cut to the model's
context at a seeded offset, as in training) for a seeded subset of ``max_trajectories`` trajectories, so
every validation of a run - and of every run with the same ``validation.seed``, whatever its training seed
or ablation - scores the same windows. Validation draws no random number from the training's generators
(their states are restored after it), so a run with validation trains bit-identically to one without.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Any

import torch
from tensordict import TensorDict

from navformer_rl.training import checkpoint as ckpt
from navformer_rl.training.config import TASK_OF_KIND, ValidationConfig
from navformer_rl.utils.checks import check_int, check_seed

PREFIX = "validation"
"""Logged metric names start with ``validation/``."""


class FixedTrajectoryBatches:
    """The same padded trajectory batches at every pass over a dataset (for validation).

    At construction: one window of at most ``context_steps`` steps per trajectory (the offset drawn once
    with ``seed``), for the first ``max_trajectories`` trajectories of a seeded permutation (all when None).
    Iterating gathers them, ``batch_trajs`` at a time, as ``TensorDict`` ``[n]`` batches with the keys of
    :meth:`~navformer_rl.data.samplers.TrajectoryBatcher.sample` (``pixels`` uint8 ``[n, T, 84, 84, 3]``,
    ``action`` ``[n, T, 2]``, ``return_to_go`` ``[n, T, 1]``, ``step`` ``[n, T]``, ``mask`` bool ``[n, T]``,
    ``target_pixels`` uint8 ``[n, 84, 84, 3]``, ``trajectory`` ``[n]``), T the longest window of the batch.
    Only the window indices are kept between passes; the pixels are gathered into fresh tensors each time.
    """

    def __init__(
        self,
        dataset: Any,
        batch_trajs: int,
        context_steps: int,
        seed: int,
        keys: list[tuple[str, ...]] | None = None,
        max_trajectories: int | None = None,
    ) -> None:
        from navformer_rl.data import TrajectorySampler

        total = dataset.num_trajectories
        count = total if max_trajectories is None else min(int(max_trajectories), total)
        whole = TrajectorySampler(total, context_steps, seed=seed, episodes=dataset.episodes).draw()
        self.index = whole.index[:count].clone()  # not a view: the whole dataset's draw is freed
        self.mask = whole.mask[:count].clone()
        self.trajectory = whole.trajectory[:count].clone()
        self.batch_trajs = min(int(batch_trajs), count)
        self._batcher = dataset.trajectory_batcher(
            self.batch_trajs, context_steps, seed=seed, keys=keys, reuse_buffers=False
        )

    def __len__(self) -> int:
        """Number of windows (trajectories) in the set."""
        return int(self.trajectory.numel())

    @property
    def valid_steps(self) -> int:
        """Valid steps over all windows: the number of terms of the loss."""
        return int(self.mask.sum())

    def __iter__(self) -> Iterator[TensorDict]:
        return self.batches()

    def batches(self, rank: int = 0, world_size: int = 1) -> Iterator[TensorDict]:
        """The batches in order; with ``world_size`` > 1 only every ``world_size``-th one from number ``rank``
        (one process's share of a data-parallel validation)."""
        from navformer_rl.data.samplers import TrajectoryDraw

        step = self.batch_trajs * world_size
        for start in range(rank * self.batch_trajs, len(self), step):
            rows = slice(start, start + self.batch_trajs)
            steps = int(self.mask[rows].sum(1).max())
            yield self._batcher.gather(
                TrajectoryDraw(
                    index=self.index[rows, :steps],
                    mask=self.mask[rows, :steps],
                    trajectory=self.trajectory[rows],
                )
            )


@contextlib.contextmanager
def evaluation_mode(model: torch.nn.Module) -> Iterator[None]:
    """``model.eval()`` under ``torch.no_grad()``; afterwards the model's train/eval mode and the global
    RNG states (torch, numpy, python) are as they were, so the surrounding training is not disturbed."""
    rng = ckpt.capture_rng_state()
    was_training = model.training
    model.eval()
    try:
        with torch.no_grad():
            yield
    finally:
        model.train(was_training)
        ckpt.restore_rng_state(rng)


def teacher_forced_loss(loss_module: Any, batches: FixedTrajectoryBatches, device: torch.device) -> float:
    """Eq. 10 over every window of ``batches``: the squared action error summed over the action dims and
    averaged over all valid steps (each batch's masked mean weighted by its valid steps).

    ``loss_module``: a :class:`~navformer_rl.objectives.ActionMSELoss` (reads the batch keys, writes
    ``loss_dt``). Call it inside :func:`evaluation_mode`.
    """
    return teacher_forced_sum(loss_module, batches, device) / max(batches.valid_steps, 1)


def teacher_forced_sum(
    loss_module: Any,
    batches: FixedTrajectoryBatches,
    device: torch.device,
    rank: int = 0,
    world_size: int = 1,
) -> float:
    """The squared action errors summed over the valid steps of the batches ``batches.batches(rank,
    world_size)`` (:func:`teacher_forced_loss` times the valid steps, for one process's share)."""
    total = 0.0
    for batch in batches.batches(rank, world_size):
        batch = batch.to(device)
        total += float(loss_module(batch)["loss_dt"]) * int(batch["mask"].sum())
    return total


class Validator:
    """The validation sets of a run and when to score them.

    Args:
        cfg: the :class:`ValidationConfig`.
        sets: ``{metric name: FixedTrajectoryBatches}``, e.g. ``{"loss_dt_exploration": ...,
            "train_loss_dt_exploration": ...}`` (see :func:`make_validator`).
    """

    def __init__(self, cfg: ValidationConfig, sets: Mapping[str, FixedTrajectoryBatches]) -> None:
        self.cfg = cfg
        self.sets = dict(sets)

    def due(self, iteration: int, iterations: int) -> bool:
        """Whether completed ``iteration`` (of ``iterations``) is validated."""
        return iteration % self.cfg.interval == 0 or iteration == iterations

    def __call__(
        self, loss_module: Any, model: torch.nn.Module, device: torch.device, distributed: Any = None
    ) -> dict[str, float]:
        """``{"validation/<metric>": float}`` for every set, ``model`` in eval mode (see
        :func:`evaluation_mode`).

        ``distributed``: a :class:`~navformer_rl.training.distributed.Distributed` of several processes
        shares the batches out (each scores every N-th one; the sums are all-reduced, every process gets
        the totals); None or one process scores every batch.
        """
        rank, world_size = (distributed.rank, distributed.world_size) if distributed is not None else (0, 1)
        with evaluation_mode(model):
            sums = {
                name: teacher_forced_sum(loss_module, batches, device, rank, world_size)
                for name, batches in self.sets.items()
            }
        if world_size > 1:
            totals = distributed.all_reduce_sum(
                torch.tensor(list(sums.values()), dtype=torch.float64, device=device)
            )
            sums = dict(zip(sums, totals.tolist(), strict=True))
        return {
            f"{PREFIX}/{name}": sums[name] / max(batches.valid_steps, 1)
            for name, batches in self.sets.items()
        }


def make_validator(
    cfg: ValidationConfig,
    held_out: Mapping[str, Any],
    training: Mapping[str, Any],
    context_steps: int,
    keys: list[tuple[str, ...]] | None = None,
) -> Validator | None:
    """The run's :class:`Validator` (None when validation is off).

    Args:
        cfg: the run's validation settings.
        held_out: ``{kind: NavDataset}`` opened from ``cfg``'s paths (kinds ``e`` / ``ca``).
        training: the run's training datasets ``{kind: NavDataset}`` (for ``compare_training``).
        context_steps: the training windows' length (``data.context_steps`` or the model's window).
        keys: per-step keys to gather (default: every trajectory key of the schema).
    """
    if not cfg.enabled:
        return None
    sets: dict[str, FixedTrajectoryBatches] = {}
    for kind, dataset in held_out.items():
        task = TASK_OF_KIND[kind]
        options = {"context_steps": context_steps, "seed": cfg.seed, "keys": keys}
        held = FixedTrajectoryBatches(
            dataset, cfg.batch_trajs, max_trajectories=cfg.max_trajectories, **options
        )
        sets[f"loss_dt_{task}"] = held
        if cfg.compare_training and kind in training:
            sets[f"train_loss_dt_{task}"] = FixedTrajectoryBatches(
                training[kind], cfg.batch_trajs, max_trajectories=cfg.training_trajectories, **options
            )
    return Validator(cfg, sets)


def score_checkpoints(
    checkpoints: list[str],
    datasets: Mapping[str, str],
    batch_trajs: int = 16,
    max_trajectories: int | None = None,
    seed: int = 0,
    device: str = "cpu",
    context_steps: int | None = None,
) -> list[dict[str, Any]]:
    """The teacher-forced action loss (eq. 10, eval mode) of trained checkpoints on trajectory datasets.

    The offline form of the trainer's validation (``navformer validate``): score checkpoints of one run at
    several iterations, or of several runs, on the same windows (fixed by ``seed``, as ``validation.seed``;
    each window at most ``context_steps`` steps, default the model's context,
    ``NavFormerConfig.window_steps``, as in the paper's training).

    Args:
        checkpoints: checkpoint paths in any form :func:`~navformer_rl.training.checkpoint.resolve_checkpoint`
            takes.
        datasets: ``{kind: folder}`` with kinds ``e`` (D_e) and / or ``ca`` (D_ca).
        batch_trajs / max_trajectories / seed: as in :class:`ValidationConfig`.
        device: ``cpu``, ``cuda``, ``cuda:N`` or ``auto``.
        context_steps: the windows' length for every checkpoint, 1 to the models' window (a checkpoint trained
            with ``data.context_steps=W`` is scored as it trained with W); None: each model's whole window.

    Returns:
        One dict per checkpoint: ``{"checkpoint": folder, "iteration": int, "loss_dt_<task>": float, ...}``.

    Raises:
        FileNotFoundError / ValueError: a missing checkpoint or dataset, a dataset of the wrong kind or
            one the model cannot read, an unknown kind or device (all before any scoring).
    """
    from navformer_rl.data import open_dataset
    from navformer_rl.data.fit import check_model_reads
    from navformer_rl.modules import make_navformer_actor
    from navformer_rl.modules.decoding.incremental import check_window_steps
    from navformer_rl.objectives import ActionMSELoss
    from navformer_rl.utils.devices import check_device, resolve_device

    unknown = sorted(set(datasets) - set(TASK_OF_KIND))
    if unknown or not datasets:
        raise ValueError(
            f"dataset kinds {unknown or '(none)'}: expected one or more of {sorted(TASK_OF_KIND)}"
        )
    check_int(batch_trajs, "batch_trajs")
    if max_trajectories is not None:
        check_int(max_trajectories, "max_trajectories")
    check_seed(seed)
    torch_device = resolve_device(check_device(device))
    opened = {}
    for kind, path in datasets.items():
        if not Path(path).exists():
            raise FileNotFoundError(f"{kind} dataset {str(path)!r} does not exist")
        opened[kind] = open_dataset(path, kind=kind)
    names = {kind: f"{kind} dataset {str(path)!r}" for kind, path in datasets.items()}
    folders = [ckpt.resolve_checkpoint(path) for path in checkpoints]
    models = [ckpt.load_policy_model(folder) for folder in folders]  # every checkpoint checked first
    for config, _ in models:
        check_model_reads(config, opened, names, tunable=False)
        check_window_steps(context_steps, config.window_steps, "context_steps (--context-steps)")
    rows = []
    for folder, (config, model) in zip(folders, models, strict=True):
        model.to(torch_device)
        loss = ActionMSELoss(make_navformer_actor(model))
        row: dict[str, Any] = {
            "checkpoint": str(folder),
            "iteration": int(ckpt.read_checkpoint_config(folder)["iteration"]),
        }
        with evaluation_mode(model):
            for kind, dataset in opened.items():
                window = config.window_steps if context_steps is None else context_steps
                batches = FixedTrajectoryBatches(
                    dataset, batch_trajs, window, seed, max_trajectories=max_trajectories
                )
                row[f"loss_dt_{TASK_OF_KIND[kind]}"] = teacher_forced_loss(loss, batches, torch_device)
        rows.append(row)
    return rows
