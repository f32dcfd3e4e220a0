"""The training configuration: ``TrainConfig`` and its sections (the layout of ``train.yaml``), the
ablations, the static checks of a configuration (:func:`validate_config`) and the ``NavFormerConfig`` it
builds (:func:`model_config`).

Plain dataclasses, no hydra; :mod:`~navformer_rl.training.config_io` reads them from YAML, dicts and
``key=value`` overrides.
"""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from navformer_rl.tasks import ABLATIONS, DATASETS, TRAJECTORY_KINDS
from navformer_rl.utils.checks import check_int, check_number, check_seed
from navformer_rl.utils.devices import check_device

if TYPE_CHECKING:
    from navformer_rl.modules import NavFormerConfig


ENCODER_TRAINING = ("joint", "frozen")
ENCODER_OPTIMIZERS = ("adam", "adamw")
LOGGER_BACKENDS = ("csv", "tensorboard", "none")
MODEL_KEYS_SET_ELSEWHERE = {"detach_encoders": "encoder_training=frozen"}


TASK_OF_KIND = {kind: DATASETS[kind].task for kind in TRAJECTORY_KINDS}
"""The training task (metric suffix) of each trajectory dataset kind."""
PATH_KEYS = {kind: DATASETS[kind].path_key for kind in TRAJECTORY_KINDS}
"""The ``validation.`` key of each held-out dataset kind."""

DatasetPaths = str | list[str] | None
"""A dataset setting: one folder, a list of folders of one kind read as one (their trajectories in list
order, :class:`~navformer_rl.data.concat.ConcatNavDataset`), or None."""


def dataset_folders(value: DatasetPaths) -> list[str]:
    """The folders of a dataset setting: ``[]`` for None, ``[path]`` for one path, the list as given."""
    if value is None:
        return []
    return [value] if isinstance(value, str) else list(value)


def check_dataset_paths(value: object, key: str) -> None:
    """ValueError naming ``key`` unless ``value`` is None, a non-empty path or a non-empty list of them."""
    expected = "expected null, a dataset folder or a non-empty list of dataset folders"
    if value is None or (isinstance(value, str) and value.strip()):
        return
    if not isinstance(value, list | tuple) or not value:
        raise ValueError(f"{key}={value!r}: {expected}")
    for i, item in enumerate(value):
        if not isinstance(item, str) or not item.strip():
            raise ValueError(f"{key}[{i}]={item!r}: {expected}")


@dataclass
class ValidationConfig:
    """Held-out teacher-forced validation (scored by :mod:`navformer_rl.training.validation`).

    Attributes:
        exploration_path / collision_path: held-out D_e / D_ca dataset folders (collected with a seed other
            than the training data's), each one folder or a list read as one (as ``data.*_path``).
            Validation runs when at least one is set.
        interval: iterations between validations (the last iteration is always validated); 0 = never.
        batch_trajs: trajectories per forward pass (a memory setting: the result is the mean over all
            valid steps of all windows whatever the batch, up to float summation order).
        max_trajectories: validate on a seeded subset of at most this many trajectories per dataset;
            None = every trajectory.
        compare_training: also score windows of the training dataset of the same task
            (``validation/train_loss_dt_<task>``); skipped for a task the ablation does not train on.
        training_trajectories: how many training trajectories (a seeded subset) ``compare_training``
            scores. Per-trajectory losses vary widely, so a small subset's mean sits off the whole
            dataset's by a fixed amount; 256 keeps that within ~10 % at the medium scale of
            docs/studies.md.
        seed: the subsets and window offsets (independent of the run's ``seed``, so runs compare on the
            same windows).
    """

    exploration_path: DatasetPaths = None
    collision_path: DatasetPaths = None
    interval: int = 500
    batch_trajs: int = 16
    max_trajectories: int | None = None
    compare_training: bool = True
    training_trajectories: int = 256
    seed: int = 0

    @property
    def enabled(self) -> bool:
        return self.interval > 0 and any(getattr(self, key) for key in PATH_KEYS.values())

    def held_out_paths(self) -> dict[str, str | list[str]]:
        """``{kind: path or list of paths}`` of the held-out datasets set (kinds ``e`` / ``ca``)."""
        return {kind: getattr(self, key) for kind, key in PATH_KEYS.items() if getattr(self, key)}


def validate_validation_config(cfg: ValidationConfig) -> None:
    """ValueError naming the key when a setting of ``cfg`` is out of range (no file is opened)."""
    for key in PATH_KEYS.values():
        check_dataset_paths(getattr(cfg, key), f"validation.{key}")
    check_int(cfg.interval, "validation.interval", minimum=0)
    check_int(cfg.batch_trajs, "validation.batch_trajs")
    if cfg.max_trajectories is not None:
        check_int(cfg.max_trajectories, "validation.max_trajectories")
    check_int(cfg.training_trajectories, "validation.training_trajectories")
    check_seed(cfg.seed, "validation.seed")


@dataclass
class DataConfig:
    """Datasets and batch shapes (paper §VI).

    Attributes:
        exploration_path / collision_path / ssl_path: dataset folders of D_e, D_ca, D_ssl (absolute paths
            recommended: the hydra recipe and ``navformer train`` read relative paths from where they start).
            A path may be None only when the ablation does not use that dataset. ``exploration_path`` /
            ``collision_path`` may also be a list of folders of that kind, read as one folder holding their
            trajectories in list order (e.g. the paper's data plus DAgger rounds:
            ``data.exploration_path=[data/e,data/dagger1/e]``).
        exploration_batch_trajs / collision_batch_trajs: trajectories per batch (25 / 150).
        ssl_batch_pairs: D_ssl image pairs per batch (512).
        context_steps: longest trajectory window in steps; None = what fits the model's context
            (``NavFormerConfig.window_steps`` = 1024 // 4 = 256 steps). Longer trajectories are cut to a
            window at a random offset.
        exploration_trajectories / collision_trajectories / ssl_pairs: train on the first N trajectories
            (pairs) of a dataset folder only; None = all of it (:meth:`~navformer_rl.data.NavDataset.head`).
            For data-scaling studies from one collection. With a list of folders: the first N of their
            concatenation.
        prefetch: draw the next iteration's batches in a background thread while this one trains
            (:class:`~navformer_rl.data.prefetch.Prefetcher`; the same batches, so the same losses). On CUDA
            the batches are also gathered into page-locked memory, so their copies to the GPU are
            asynchronous.
    """

    exploration_path: DatasetPaths = None
    collision_path: DatasetPaths = None
    ssl_path: str | None = None
    exploration_batch_trajs: int = 25
    collision_batch_trajs: int = 150
    ssl_batch_pairs: int = 512
    context_steps: int | None = None
    exploration_trajectories: int | None = None
    collision_trajectories: int | None = None
    ssl_pairs: int | None = None
    prefetch: bool = True


@dataclass
class SSLConfig:
    """BYOL settings (eqs. 6-8). ``projection_dim`` / ``hidden_dim``: projector and predictor MLP sizes;
    ``tau_base``: EMA rate at iteration 0, raised to 1 by BYOL's cosine schedule over the run;
    ``loss_weight``: w in L = L_DT + w L_BYOL (eq. 11 has w = 1; BYOL's loss is ~15x L_DT in the medium run
    of docs/studies.md, so with ``encoder_training=joint`` its gradient dominates the shared
    encoders)."""

    projection_dim: int = 128
    hidden_dim: int = 512
    tau_base: float = 0.996
    loss_weight: float = 1.0


@dataclass
class OptimConfig:
    """Optimisers (paper §VI): AdamW for NavFormer's navigation network, Adam for the DVE (the visual
    encoders f_s, f_g and BYOL's projectors and predictors). Both losses of eq. 11 reach the encoders under
    ``encoder_training=joint``, whichever optimiser steps them.

    Attributes:
        iterations: training iterations (10,000).
        lr / weight_decay: AdamW on the navigation network: token embeddings, transformer and head
            (2e-4 / 1e-4), plus the visual encoders with ``encoder_optimizer=adamw``.
        dve_lr / dve_weight_decay: Adam on BYOL's projectors and predictors, plus the visual encoders with
            ``encoder_optimizer=adam`` (paper: "0.0004 for the learning rate and weight decay").
        encoder_optimizer: which optimiser steps the visual encoders: ``adam`` (with the DVE, §VI's split),
            ``adamw`` (with the navigation network), or None: the ablation's, :func:`encoder_optimizer`
            (``adam`` for NavFormer and its ablations, ``adamw`` for ``dt``, whose one encoder is no DVE).
        clip_grad_norm: max global gradient norm per optimiser, or None (the paper clips nothing).
        trajectory_chunks: split each trajectory batch into this many equal chunks, backpropagated one after
            the other (memory lever; the gradient equals the whole batch's exactly: each chunk's loss is
            weighted by its share of valid steps). Must divide both trajectory batch sizes.
        chunks_by_length: with ``trajectory_chunks > 1``, order the batch's trajectories by length before
            chunking and crop each chunk to its own longest window: the loss and its gradient are the whole
            batch's, computed without most of the padding (on the paper-scale data a D_ca batch padded to its
            longest trajectory is ~4.5x its valid steps). Makes the chunking memory lever 1.3-1.8x faster
            there (benchmarks/model.md); dropout draws differ from the unsorted chunks', so training is not
            bit-identical to them.
        length_groups: run the transformer and the head of each trajectory batch in this many groups of
            similar trajectory length, each cropped to its longest (speed lever, opt-in; the encoders still
            see every valid frame in one pass, and the loss and gradient are the padded batch's:
            ``LengthGroups``). Dropout draws differ from the padded batch's, so not bit-identical to it.
    """

    iterations: int = 10_000
    lr: float = 2e-4
    weight_decay: float = 1e-4
    dve_lr: float = 4e-4
    dve_weight_decay: float = 4e-4
    encoder_optimizer: str | None = None
    clip_grad_norm: float | None = None
    trajectory_chunks: int = 1
    chunks_by_length: bool = False
    length_groups: int = 1


@dataclass
class LoggerConfig:
    """``backend``: ``csv`` (TorchRL ``CSVLogger``), ``tensorboard`` (needs the ``tensorboard`` package) or
    ``none``; scalars go to ``<run_dir>/logs/<exp_name>``, the progress bar reads ``train <exp_name>``
    (None: named after the ablation, see :func:`named_run`). ``log_interval``: iterations between log
    writes. ``progress``: tqdm progress bar."""

    backend: str = "csv"
    exp_name: str | None = None
    log_interval: int = 1
    progress: bool = True


@dataclass
class CheckpointConfig:
    """``interval``: iterations between checkpoints (a final one is always written);
    ``keep_last``: how many checkpoint folders to keep (0 = all)."""

    interval: int = 500
    keep_last: int = 3


@dataclass
class TrainConfig:
    """Everything :func:`train` needs. Defaults are the paper's (§IV, §VI).

    Attributes:
        data / ssl / optim / logger / checkpoint / validation: see the section classes
            (:class:`ValidationConfig` for the last).
        model: overrides of ``NavFormerConfig`` fields (architecture and perf levers: ``autocast_dtype``,
            ``channels_last``, ``encoder_micro_batch``), applied on top of the ablation's model.
        ablation: one of :data:`ABLATIONS`.
        encoder_training: ``joint`` - L = L_BYOL + L_DT trains the encoders (eq. 11, the paper);
            ``frozen`` - L_DT does not reach the encoders, which learn from BYOL only.
        seed: seeds torch, numpy, python and every sampler.
        device: ``auto`` (CUDA when available), ``cpu``, ``cuda`` or ``cuda:N``.
        output_dir: the run directory (checkpoints, logs, config).
        resume: continue from the run directory's latest checkpoint (start fresh when it has none).
        init_from: start from trained weights (fine-tuning) with fresh optimisers and schedules: a run
            directory, a checkpoint folder or file, or ``pretrained:NAME``; its model must be the configured
            one (:mod:`navformer_rl.training.init_from`). None: random initialisation. A resumed run continues
            from its own checkpoint and keeps the source it recorded.
        keep_freed_memory: glibc's ``malloc`` serves big tensors from the heap and keeps freed memory
            (:func:`navformer_rl.utils.allocator.keep_freed_memory`): the same values, 0.8-0.95x the time of a
            CPU iteration, the process's memory stays at its peak between checkpoints (after each one
            ``release_free_memory`` hands the free pages back). No effect on other C libraries.
    """

    data: DataConfig = field(default_factory=DataConfig)
    model: dict[str, Any] = field(default_factory=dict)
    ablation: str = "none"
    encoder_training: str = "joint"
    ssl: SSLConfig = field(default_factory=SSLConfig)
    optim: OptimConfig = field(default_factory=OptimConfig)
    logger: LoggerConfig = field(default_factory=LoggerConfig)
    checkpoint: CheckpointConfig = field(default_factory=CheckpointConfig)
    validation: ValidationConfig = field(default_factory=ValidationConfig)
    seed: int = 0
    device: str = "auto"
    output_dir: str = "runs/navformer"
    resume: bool = False
    init_from: str | None = None
    keep_freed_memory: bool = True

    @property
    def uses_ssl(self) -> bool:
        return ABLATIONS[self.ablation].uses_ssl

    @property
    def uses_exploration(self) -> bool:
        return "e" in ABLATIONS[self.ablation].datasets

    @property
    def uses_collision(self) -> bool:
        return "ca" in ABLATIONS[self.ablation].datasets

    def to_dict(self) -> dict[str, Any]:
        """Plain JSON-serialisable dict (the layout of ``train.yaml``)."""
        return dataclasses.asdict(self)


def default_exp_name(ablation: str) -> str:
    """A run's name after its ablation, as evaluation labels it: ``navformer`` for ``none``, ``dt``, else
    ``navformer-<ablation>``."""
    return {"none": "navformer", "dt": "dt"}.get(ablation, f"navformer-{ablation}")


def encoder_optimizer(cfg: TrainConfig) -> str:
    """Which optimiser steps the visual encoders: ``optim.encoder_optimizer`` when set, else ``adamw`` for
    ``ablation=dt`` (the DT baseline has one encoder and no DVE: AdamW trains it with the rest, §VII.A) and
    ``adam`` for NavFormer and its Table IV ablations (§VI: "The training of the DVE ... The Adam optimizer
    used 0.0004 for the learning rate and weight decay"; docs/deviations.md)."""
    if cfg.optim.encoder_optimizer is not None:
        return cfg.optim.encoder_optimizer
    return "adamw" if cfg.ablation == "dt" else "adam"


def with_encoder_optimizer(cfg: TrainConfig) -> TrainConfig:
    """``cfg`` with ``optim.encoder_optimizer`` resolved (:func:`encoder_optimizer`), as a run records it."""
    optim = dataclasses.replace(cfg.optim, encoder_optimizer=encoder_optimizer(cfg))
    return dataclasses.replace(cfg, optim=optim)


def named_run(cfg: TrainConfig, resuming: bool) -> TrainConfig:
    """``cfg`` with ``logger.exp_name`` filled in when it is None: a resumed run keeps the name its folder's
    ``train_config.json`` recorded (its logs continue in the same folder), a new one takes
    :func:`default_exp_name`."""
    if cfg.logger.exp_name is not None:
        return cfg
    name = None
    recorded = Path(cfg.output_dir) / "train_config.json"
    if resuming and recorded.is_file():
        name = (json.loads(recorded.read_text()).get("logger") or {}).get("exp_name")
    logger = dataclasses.replace(cfg.logger, exp_name=name or default_exp_name(cfg.ablation))
    return dataclasses.replace(cfg, logger=logger)


def validate_config(cfg: TrainConfig, require_data: bool = True) -> None:
    """Static checks of ``cfg`` (no file is opened); :func:`build_trainer` also checks the datasets.

    ``require_data=False`` skips the check that the data paths the ablation needs are set (for printing
    or composing a configuration before the datasets exist).
    """
    if cfg.ablation not in ABLATIONS:
        raise ValueError(f"unknown ablation {cfg.ablation!r}; expected one of {list(ABLATIONS)}")
    if cfg.encoder_training not in ENCODER_TRAINING:
        raise ValueError(
            f"encoder_training={cfg.encoder_training!r}: expected one of {list(ENCODER_TRAINING)}"
        )
    if cfg.encoder_training == "frozen" and not cfg.uses_ssl:
        raise ValueError(
            f"encoder_training=frozen with ablation={cfg.ablation!r}: without BYOL nothing would train the "
            "encoders; use encoder_training=joint"
        )
    if cfg.logger.backend not in LOGGER_BACKENDS:
        raise ValueError(f"logger.backend={cfg.logger.backend!r}: expected one of {list(LOGGER_BACKENDS)}")
    check_device(cfg.device)
    if cfg.init_from is not None and (not isinstance(cfg.init_from, str) or not cfg.init_from.strip()):
        raise ValueError(
            f"init_from={cfg.init_from!r}: expected null, a run directory, a checkpoint or pretrained:NAME"
        )
    for name in ("exploration_batch_trajs", "collision_batch_trajs", "ssl_batch_pairs"):
        check_int(getattr(cfg.data, name), f"data.{name}")
    if cfg.data.ssl_batch_pairs < 2 and cfg.uses_ssl:
        raise ValueError(
            f"data.ssl_batch_pairs={cfg.data.ssl_batch_pairs}: BYOL's BatchNorm needs at least 2 pairs"
        )
    if cfg.data.context_steps is not None:
        check_int(cfg.data.context_steps, "data.context_steps")
    for name in ("iterations", "trajectory_chunks", "length_groups"):
        check_int(getattr(cfg.optim, name), f"optim.{name}")
    if not isinstance(cfg.optim.chunks_by_length, bool):
        raise ValueError(f"optim.chunks_by_length={cfg.optim.chunks_by_length!r}: expected true or false")
    if cfg.optim.chunks_by_length and cfg.optim.trajectory_chunks == 1:
        raise ValueError(
            "optim.chunks_by_length=true needs optim.trajectory_chunks > 1 (got 1): "
            "it sorts and crops the chunks"
        )
    for name in ("exploration_batch_trajs", "collision_batch_trajs"):
        size = getattr(cfg.data, name)
        if size % cfg.optim.trajectory_chunks:
            raise ValueError(
                f"data.{name}={size} is not divisible by "
                f"optim.trajectory_chunks={cfg.optim.trajectory_chunks}"
            )
    for name in ("lr", "weight_decay", "dve_lr", "dve_weight_decay"):
        check_number(getattr(cfg.optim, name), f"optim.{name}", at_least=0)
    adam_used = cfg.uses_ssl or encoder_optimizer(cfg) == "adam"
    if cfg.optim.lr == 0 or (adam_used and cfg.optim.dve_lr == 0):
        raise ValueError("optim.lr / optim.dve_lr must be > 0")
    if cfg.optim.encoder_optimizer not in (None, *ENCODER_OPTIMIZERS):
        raise ValueError(
            f"optim.encoder_optimizer={cfg.optim.encoder_optimizer!r}: expected null (the ablation's) or one "
            f"of {list(ENCODER_OPTIMIZERS)}"
        )
    if cfg.optim.clip_grad_norm is not None and not cfg.optim.clip_grad_norm > 0:
        raise ValueError(f"optim.clip_grad_norm={cfg.optim.clip_grad_norm!r}: expected None or a number > 0")
    check_int(cfg.logger.log_interval, "logger.log_interval")
    check_int(cfg.checkpoint.interval, "checkpoint.interval")
    if cfg.checkpoint.keep_last < 0:
        raise ValueError(f"checkpoint.keep_last={cfg.checkpoint.keep_last}: expected >= 0 (0 keeps all)")
    validate_validation_config(cfg.validation)
    check_number(cfg.ssl.tau_base, "ssl.tau_base", at_least=0.5, at_most=1)
    check_number(cfg.ssl.loss_weight, "ssl.loss_weight", greater_than=0)
    check_int(cfg.ssl.projection_dim, "ssl.projection_dim")
    check_int(cfg.ssl.hidden_dim, "ssl.hidden_dim")
    for key, instead in MODEL_KEYS_SET_ELSEWHERE.items():
        if key in cfg.model:
            raise ValueError(f"model.{key} is set by the training config; use {instead}")
    needed = {
        "data.exploration_path": (cfg.uses_exploration, cfg.data.exploration_path, "D_e"),
        "data.collision_path": (cfg.uses_collision, cfg.data.collision_path, "D_ca"),
        "data.ssl_path": (cfg.uses_ssl, cfg.data.ssl_path, "D_ssl"),
    }
    for key, (used, path, name) in needed.items():
        check_dataset_paths(path, key)
        if key == "data.ssl_path" and not isinstance(path, str | None):
            raise ValueError(f"{key}={path!r}: expected null or one D_ssl dataset folder")
        if require_data and used and not path:
            raise ValueError(f"{key} is not set, but ablation={cfg.ablation!r} trains on {name}")
    model = model_config(cfg)  # NavFormerConfig validates its own fields
    if cfg.data.context_steps is not None and cfg.data.context_steps > model.window_steps:
        raise ValueError(
            f"data.context_steps={cfg.data.context_steps} needs "
            f"{cfg.data.context_steps * model.tokens_per_step} tokens; "
            f"the model's context of {model.context_tokens} tokens holds at most {model.window_steps} steps"
        )


def model_config(cfg: TrainConfig) -> NavFormerConfig:
    """The ``NavFormerConfig`` of ``cfg``: the ablation's model, ``cfg.model`` overrides, encoder mode."""
    from navformer_rl.modules import NavFormerConfig

    known = {f.name for f in dataclasses.fields(NavFormerConfig)}
    unknown = sorted(set(cfg.model) - known)
    if unknown:
        raise ValueError(
            f"unknown model keys {[f'model.{k}' for k in unknown]}; NavFormerConfig has {sorted(known)}"
        )
    changes = dict(cfg.model)
    changes["detach_encoders"] = cfg.encoder_training == "frozen"
    return NavFormerConfig.ablation(cfg.ablation, **changes)
