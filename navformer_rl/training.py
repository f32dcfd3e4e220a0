"""NavFormer cross-task training (paper §VI) as a library function: ``train(TrainConfig) -> TrainResult``.

One iteration (eq. 11)::

    task, batch = cross_task.sample()            # 25 trajectories of D_e or 150 of D_ca, alternating
    pairs       = ssl_batcher.sample()           # 512 (o^s, o^d) pairs of D_ssl     (unless SSL is ablated)
    L = NavFormerLoss(batch)["loss_dt"] + BYOLLoss(pairs)["loss_byol"]
    L.backward(); AdamW.step() (NavFormer); Adam.step() (DVE: BYOL projector/predictor [+ encoders])
    SoftUpdate.step(); tau <- cosine schedule    # BYOL's EMA target

The pieces are exposed so that a recipe can show the loop top to bottom (``recipes/navformer``):
:func:`load_train_config` (YAML/dict -> dataclasses), :func:`build_trainer` (validates everything, opens the
datasets, builds model, losses, optimisers, logger, restores a checkpoint when resuming), ``Trainer.step()``,
``Trainer.record()`` (adds the iteration's metrics to the log window and writes a row every
``logger.log_interval`` iterations), ``Trainer.save_checkpoint()``. :func:`train` is that loop with tqdm
progress.

Library code: no hydra here. Configuration comes as plain dataclasses; ``navformer train`` and the hydra
recipe both build them from the packaged ``navformer_rl/config/train.yaml`` layout.
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import math
import os
import random
import time
import types
import typing
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch

from navformer_rl import checkpoint as ckpt
from navformer_rl.checks import check_int, check_number
from navformer_rl.data.prefetch import Prefetcher
from navformer_rl.devices import check_device, resolve_device
from navformer_rl.durable import atomic_write_text
from navformer_rl.validation import (
    PATH_KEYS,
    ValidationConfig,
    make_validator,
    validate_validation_config,
)

ABLATIONS: dict[str, str] = {
    "none": "NavFormer as in the paper",
    "no_ssl": "w/o SSL: trained with L_DT only (no BYOL, no D_ssl)",
    "no_thsc": "w/o THSC: the action head reads h^ca_{o,t} only",
    "no_de": "w/o tau^e: L_DT on D_ca trajectories only",
    "no_dca": "w/o tau^ca: L_DT on D_e trajectories only",
    "no_fs": "w/o f_s: no static encoder (and no static BYOL)",
    "no_fg": "w/o f_g: no general encoder (target image through f_s)",
    "resnet18": "w ResNet18: a single, randomly initialised ResNet18 replaces the DVE",
    "dt": "DT baseline: single encoder, no THSC, trained with eq. 10 only",
}
"""Every value of ``TrainConfig.ablation``: the rows of paper Table IV plus the DT baseline (Table I)."""

_MODEL_ABLATION = {
    "none": "navformer",
    "no_ssl": "navformer",
    "no_de": "navformer",
    "no_dca": "navformer",
    "no_thsc": "no_thsc",
    "no_fs": "no_static_encoder",
    "no_fg": "no_general_encoder",
    "resnet18": "resnet18",
    "dt": "dt",
}
_NO_SSL = frozenset({"no_ssl", "dt"})
_NO_EXPLORATION = frozenset({"no_de"})
_NO_COLLISION = frozenset({"no_dca"})

ENCODER_TRAINING = ("joint", "frozen")
LOGGER_BACKENDS = ("csv", "tensorboard", "none")
MODEL_KEYS_SET_ELSEWHERE = {"detach_encoders": "encoder_training=frozen"}
RESUME_MAY_CHANGE = frozenset(
    {
        "resume",
        "device",
        "output_dir",
        "logger",
        "checkpoint",
        "optim.iterations",
        "data.exploration_path",
        "data.collision_path",
        "data.ssl_path",
        "data.prefetch",
        "validation",
    }
)
"""Settings a resumed run may change; any other difference from the checkpoint's config is refused."""
TRAJECTORY_KEYS = [("pixels",), ("action",), ("return_to_go",), ("step",)]
"""Keys gathered from D_e / D_ca per step (plus ``mask`` and ``target_pixels`` added by the batcher)."""
BATCH_KEYS = ["pixels", "action", "return_to_go", "step", "mask", "target_pixels"]
"""What an iteration takes from a trajectory batch to the device."""
DATASET_KEYS = {"e": "exploration_path", "ca": "collision_path", "ssl": "ssl_path"}
"""The config key (under ``data.``) of each dataset kind."""


# --------------------------------------------------------------------------------------- configuration
@dataclass
class DataConfig:
    """Datasets and batch shapes (paper §VI).

    Attributes:
        exploration_path / collision_path / ssl_path: dataset folders of D_e, D_ca, D_ssl (absolute paths
            recommended; the hydra recipe changes directory). A path may be None only when the ablation does
            not use that dataset.
        exploration_batch_trajs / collision_batch_trajs: trajectories per batch (25 / 150).
        ssl_batch_pairs: D_ssl image pairs per batch (512).
        context_steps: longest trajectory window in steps; None = what fits the model's context
            (``NavFormerConfig.window_steps`` = 1024 // 4 = 256 steps). Longer trajectories are cut to a window
            at a random offset.
        prefetch: draw the next iteration's batches in a background thread while this one trains
            (:class:`~navformer_rl.data.prefetch.Prefetcher`; the same batches, so the same losses). On CUDA the
            batches are also gathered into page-locked memory, so their copies to the GPU are asynchronous.
    """

    exploration_path: str | None = None
    collision_path: str | None = None
    ssl_path: str | None = None
    exploration_batch_trajs: int = 25
    collision_batch_trajs: int = 150
    ssl_batch_pairs: int = 512
    context_steps: int | None = None
    prefetch: bool = True


@dataclass
class SSLConfig:
    """BYOL settings (eqs. 6-8). ``projection_dim`` / ``hidden_dim``: projector and predictor MLP sizes;
    ``tau_base``: EMA rate at iteration 0, raised to 1 by BYOL's cosine schedule over the run;
    ``loss_weight``: w in L = L_DT + w L_BYOL (eq. 11 has w = 1; BYOL's loss is ~15x L_DT in the medium run
    of docs/results.md, so with ``encoder_training=joint`` its gradient dominates the shared encoders)."""

    projection_dim: int = 128
    hidden_dim: int = 512
    tau_base: float = 0.996
    loss_weight: float = 1.0


@dataclass
class OptimConfig:
    """Optimisers (paper §VI): AdamW for NavFormer, Adam for the DVE (BYOL) parameters.

    Attributes:
        iterations: training iterations (10,000).
        lr / weight_decay: AdamW on the NavFormer parameters (2e-4 / 1e-4); includes the encoders when
            ``encoder_training=joint``.
        dve_lr / dve_weight_decay: Adam on the BYOL projectors and predictors, plus the encoders when
            ``encoder_training=frozen`` (paper: "0.0004 for the learning rate and weight decay").
        clip_grad_norm: max global gradient norm per optimiser, or None (the paper clips nothing).
        trajectory_chunks: split each trajectory batch into this many equal chunks, backpropagated one after
            the other (memory lever; the gradient equals the whole batch's exactly: each chunk's loss is
            weighted by its share of valid steps). Must divide both trajectory batch sizes.
    """

    iterations: int = 10_000
    lr: float = 2e-4
    weight_decay: float = 1e-4
    dve_lr: float = 4e-4
    dve_weight_decay: float = 4e-4
    clip_grad_norm: float | None = None
    trajectory_chunks: int = 1


@dataclass
class LoggerConfig:
    """``backend``: ``csv`` (TorchRL ``CSVLogger``), ``tensorboard`` (needs the ``tensorboard`` package) or
    ``none``; scalars go to ``<run_dir>/logs/<exp_name>``. ``log_interval``: iterations between log writes.
    ``progress``: tqdm progress bar."""

    backend: str = "csv"
    exp_name: str = "navformer"
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
            (:class:`~navformer_rl.validation.ValidationConfig` for the last).
        model: overrides of ``NavFormerConfig`` fields (architecture and perf levers: ``autocast_dtype``,
            ``channels_last``, ``encoder_micro_batch``), applied on top of the ablation's model.
        ablation: one of :data:`ABLATIONS`.
        encoder_training: ``joint`` - L = L_BYOL + L_DT trains the encoders (eq. 11, the paper);
            ``frozen`` - L_DT does not reach the encoders, which learn from BYOL only.
        seed: seeds torch, numpy, python and every sampler.
        device: ``auto`` (CUDA when available), ``cpu``, ``cuda`` or ``cuda:N``.
        output_dir: the run directory (checkpoints, logs, config).
        resume: continue from the run directory's latest checkpoint (start fresh when it has none).
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

    @property
    def uses_ssl(self) -> bool:
        return self.ablation not in _NO_SSL

    @property
    def uses_exploration(self) -> bool:
        return self.ablation not in _NO_EXPLORATION

    @property
    def uses_collision(self) -> bool:
        return self.ablation not in _NO_COLLISION

    def to_dict(self) -> dict[str, Any]:
        """Plain JSON-serialisable dict (the layout of ``train.yaml``)."""
        return dataclasses.asdict(self)


_SECTIONS = {
    "data": DataConfig,
    "ssl": SSLConfig,
    "optim": OptimConfig,
    "logger": LoggerConfig,
    "checkpoint": CheckpointConfig,
    "validation": ValidationConfig,
}


def default_config_path() -> Path:
    """The packaged default configuration (``navformer_rl/config/train.yaml``)."""
    return Path(__file__).parent / "config" / "train.yaml"


RESOLVED_MODEL_KEY = "resolved_model"
"""Key under which :func:`printable_config` (``navformer train --print-config``) shows the model a run builds.

It is output only: :func:`config_from_dict` accepts a configuration that has it (so printed YAML can be fed
back with ``--config``) but ignores it, warning when it differs from the model the configuration builds."""


def printable_config(cfg: TrainConfig) -> dict[str, Any]:
    """``cfg.to_dict()`` plus, right after ``model``, :data:`RESOLVED_MODEL_KEY`: every field of the
    ``NavFormerConfig`` the run builds (:func:`model_config`: the ablation's model, the ``model.*``
    overrides, ``detach_encoders`` from ``encoder_training``)."""
    resolved = dataclasses.asdict(model_config(cfg))
    printed: dict[str, Any] = {}
    for key, value in cfg.to_dict().items():
        printed[key] = value
        if key == "model":
            printed[RESOLVED_MODEL_KEY] = resolved
    return printed


def _warn_if_resolved_model_differs(cfg: TrainConfig, printed: Any) -> None:
    """Warn when a configuration's (ignored) ``resolved_model`` is not the model ``cfg`` builds."""
    import warnings

    if not isinstance(printed, Mapping):
        raise ValueError(
            f"{RESOLVED_MODEL_KEY} must be a mapping (as --print-config writes it), got {printed!r}"
        )
    try:
        built = dataclasses.asdict(model_config(cfg))
    except ValueError:
        return  # an invalid model configuration is reported by validate_config
    differ = sorted(k for k in set(built) | set(printed) if built.get(k) != printed.get(k))
    if differ:
        warnings.warn(
            f"{RESOLVED_MODEL_KEY} is output of --print-config and is ignored; it differs from the model "
            f"this configuration builds in {differ} (built: {[built.get(k) for k in differ]}): set "
            "ablation= or model.<key> to change the model",
            UserWarning,
            stacklevel=3,
        )


def config_from_dict(values: Mapping[str, Any]) -> TrainConfig:
    """Build a :class:`TrainConfig` from a nested dict (e.g. a resolved YAML / OmegaConf container).

    Unknown keys raise ``ValueError`` naming them and the accepted ones; missing keys keep their defaults.
    A :data:`RESOLVED_MODEL_KEY` section (printed by ``--print-config``) is ignored, with a warning when it
    does not describe the model the configuration builds.
    """
    values = dict(values)
    printed_model = values.pop(RESOLVED_MODEL_KEY, None)
    cfg = _config_from_values(values)
    if printed_model is not None:
        _warn_if_resolved_model_differs(cfg, printed_model)
    return cfg


def _config_from_values(values: dict[str, Any]) -> TrainConfig:
    top = {f.name for f in dataclasses.fields(TrainConfig)}
    unknown = sorted(set(values) - top)
    if unknown:
        raise ValueError(f"unknown training config keys {unknown}; expected keys among {sorted(top)}")
    kwargs: dict[str, Any] = {}
    for name, value in values.items():
        if name in _SECTIONS:
            if value is None:
                value = {}
            if not isinstance(value, Mapping):
                raise ValueError(f"training config section {name!r} must be a mapping, got {value!r}")
            section = _SECTIONS[name]
            known = {f.name for f in dataclasses.fields(section)}
            bad = sorted(set(value) - known)
            if bad:
                raise ValueError(
                    f"unknown keys {[f'{name}.{k}' for k in bad]}; {name} accepts {sorted(known)}"
                )
            _check_types(section, value, f"{name}.")
            kwargs[name] = section(**value)
        elif name == "model":
            from navformer_rl.modules import NavFormerConfig

            if value is not None and not isinstance(value, Mapping):
                raise ValueError(f"training config section 'model' must be a mapping, got {value!r}")
            model = dict(value or {})
            _check_types(NavFormerConfig, model, "model.")
            kwargs[name] = model
        else:
            kwargs[name] = value
    _check_types(TrainConfig, {k: v for k, v in kwargs.items() if k not in _SECTIONS and k != "model"})
    return TrainConfig(**kwargs)


_SCALAR_TYPES: dict[Any, tuple[type, ...]] = {int: (int,), float: (int, float), bool: (bool,), str: (str,)}


def _check_types(config_cls: type, values: Mapping[str, Any], prefix: str = "") -> None:
    """ValueError naming the key when a value does not have its field's scalar type (``int``, ``float``,
    ``bool``, ``str``, optionally ``None``); other field types are left to the config's own checks."""
    hints = typing.get_type_hints(config_cls)
    for key, value in values.items():
        hint = hints.get(key)
        options = typing.get_args(hint) if isinstance(hint, types.UnionType) else (hint,)
        if any(option not in _SCALAR_TYPES and option is not type(None) for option in options):
            continue
        if value is None and type(None) in options:
            continue
        allowed = tuple(t for option in options if option in _SCALAR_TYPES for t in _SCALAR_TYPES[option])
        if isinstance(value, bool) and bool not in allowed or not isinstance(value, allowed):
            expected = " or ".join("null" if o is type(None) else o.__name__ for o in options)
            raise ValueError(f"{prefix}{key}={value!r}: expected {expected}")


def load_train_config(
    overrides: list[str] | None = None, path: str | os.PathLike | None = None
) -> TrainConfig:
    """Read ``train.yaml`` (packaged default, or ``path``) and apply hydra-style ``key=value`` overrides.

    Overrides are parsed with OmegaConf's dotlist (``optim.lr=1e-4``, ``data.ssl_path=/data/ssl``,
    ``model.autocast_dtype=bfloat16``); a key that is not in the file raises ``ValueError``.
    """
    import yaml
    from omegaconf import DictConfig, OmegaConf
    from omegaconf.errors import OmegaConfBaseException

    try:
        base = OmegaConf.load(path or default_config_path())
    except (OSError, yaml.YAMLError) as err:
        raise ValueError(f"--config {path}: cannot read it as YAML ({type(err).__name__}: {err})") from None
    if not isinstance(base, DictConfig):
        raise ValueError(
            f"--config {path}: expected a YAML mapping of config keys, got {type(base).__name__}"
        )
    OmegaConf.set_struct(base, True)
    if "model" in base:
        OmegaConf.set_struct(base.model, False)  # any NavFormerConfig field; NavFormerConfig checks names
    try:
        if overrides:
            bad = [item for item in overrides if "=" not in item]
            if bad:
                raise ValueError(f"overrides must look like key=value, got {bad}")
            printed = [
                item for item in overrides if item.split("=", 1)[0].split(".")[0] == RESOLVED_MODEL_KEY
            ]
            if printed:
                raise ValueError(
                    f"{printed}: {RESOLVED_MODEL_KEY} is output of --print-config; set ablation= or "
                    "model.<key>=... to change the model"
                )
            base = OmegaConf.merge(base, OmegaConf.from_dotlist(list(overrides)))
        container = OmegaConf.to_container(base, resolve=True)
    except OmegaConfBaseException as err:
        key = getattr(err, "full_key", None)
        reason = str(err).splitlines()[0]
        where = f" {key!r}" if key else ""
        if key and key.startswith("+"):  # hydra's "add a key": this config's keys are fixed
            hint, reason = None, "keys cannot be added with '+'; set one of the config's keys"
        else:
            hint = _closest_key(base, key) if key else None
        suggestion = f"; did you mean {hint!r}?" if hint else ""
        raise ValueError(
            f"bad training config override{where}: {reason}{suggestion} (keys: docs/training.md)"
        ) from None
    return config_from_dict(container)


def _closest_key(config: Any, key: str) -> str | None:
    """The dotted key of ``config`` (an OmegaConf mapping) most like the unknown ``key``, or None."""
    import difflib

    from omegaconf import OmegaConf

    def dotted(node: Any, prefix: str = "") -> list[str]:
        if not OmegaConf.is_dict(node):
            return [prefix[:-1]]
        return [k for name, child in node.items() for k in dotted(child, f"{prefix}{name}.")]

    matches = difflib.get_close_matches(key, dotted(config), n=1, cutoff=0.75)
    return matches[0] if matches else None


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
    for name in ("exploration_batch_trajs", "collision_batch_trajs", "ssl_batch_pairs"):
        check_int(getattr(cfg.data, name), f"data.{name}")
    if cfg.data.ssl_batch_pairs < 2 and cfg.uses_ssl:
        raise ValueError(
            f"data.ssl_batch_pairs={cfg.data.ssl_batch_pairs}: BYOL's BatchNorm needs at least 2 pairs"
        )
    if cfg.data.context_steps is not None:
        check_int(cfg.data.context_steps, "data.context_steps")
    for name in ("iterations", "trajectory_chunks"):
        check_int(getattr(cfg.optim, name), f"optim.{name}")
    for name in ("exploration_batch_trajs", "collision_batch_trajs"):
        size = getattr(cfg.data, name)
        if size % cfg.optim.trajectory_chunks:
            raise ValueError(
                f"data.{name}={size} is not divisible by optim.trajectory_chunks={cfg.optim.trajectory_chunks}"
            )
    for name in ("lr", "weight_decay", "dve_lr", "dve_weight_decay"):
        check_number(getattr(cfg.optim, name), f"optim.{name}", at_least=0)
    if cfg.optim.lr == 0 or (cfg.uses_ssl and cfg.optim.dve_lr == 0):
        raise ValueError("optim.lr / optim.dve_lr must be > 0")
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
        if require_data and used and not path:
            raise ValueError(f"{key} is not set, but ablation={cfg.ablation!r} trains on {name}")
    model = model_config(cfg)  # NavFormerConfig validates its own fields
    if cfg.data.context_steps is not None and cfg.data.context_steps > model.window_steps:
        raise ValueError(
            f"data.context_steps={cfg.data.context_steps} needs {cfg.data.context_steps * model.tokens_per_step} "
            f"tokens; the model's context of {model.context_tokens} tokens holds at most {model.window_steps} steps"
        )


def model_config(cfg: TrainConfig):
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
    return NavFormerConfig.ablation(_MODEL_ABLATION[cfg.ablation], **changes)


# --------------------------------------------------------------------------------------------- trainer
@dataclass
class TrainResult:
    """What :func:`train` returns: the run directory, completed iterations, the last iteration's metrics
    (``loss``, ``loss_dt``, ``loss_byol``, ... floats) and the last checkpoint folder."""

    run_dir: Path
    iterations: int
    metrics: dict[str, float]
    checkpoint: Path | None


def _seed_everything(seed: int) -> None:
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


def _comparable(values: Mapping[str, Any], prefix: str = "") -> dict[str, Any]:
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


class LogWindow:
    """The metrics of the iterations since the last log row, summarised into the next one.

    Every metric is averaged over the iterations that reported it - ``loss_dt_exploration`` over the D_e
    iterations only, ``loss_dt_collision_avoidance`` over the D_ca ones, so an even ``logger.log_interval``
    still logs both tasks; ``frames_per_s`` is the window's frames over its seconds; ``lr``, ``lr_dve`` and
    ``tau`` are the logged iteration's own values. Part of the resume state, so a resumed run logs the same
    rows as an uninterrupted one whatever the checkpoint and log intervals.
    """

    LAST_VALUE_KEYS = ("lr", "lr_dve", "tau")

    def __init__(self) -> None:
        self._sums: dict[str, float] = {}
        self._counts: dict[str, int] = {}
        self._last: dict[str, float] = {}

    def __len__(self) -> int:
        """Iterations in the window."""
        return self._counts.get("loss", 0)

    def add(self, metrics: Mapping[str, float]) -> None:
        """Add one iteration's metrics (the dict of :meth:`Trainer.step`)."""
        for key, value in metrics.items():
            if key in self.LAST_VALUE_KEYS:
                self._last[key] = float(value)
            else:
                self._sums[key] = self._sums.get(key, 0.0) + float(value)
                self._counts[key] = self._counts.get(key, 0) + 1

    def pop_row(self) -> dict[str, float]:
        """The summarised row (empty for an empty window); the window starts over."""
        row = {key: total / self._counts[key] for key, total in self._sums.items()}
        if self._sums.get("iteration_s", 0.0) > 0.0 and "frames" in self._sums:
            row["frames_per_s"] = self._sums["frames"] / self._sums["iteration_s"]
        row.update(self._last)
        self.__init__()
        return row

    def state_dict(self) -> dict[str, dict]:
        """``{"sums": {metric: float}, "counts": {metric: int}, "last": {metric: float}}`` (plain containers,
        ``weights_only``-safe in ``resume.pt``)."""
        return {"sums": dict(self._sums), "counts": dict(self._counts), "last": dict(self._last)}

    def load_state_dict(self, state: Mapping[str, Mapping]) -> None:
        """Inverse of :meth:`state_dict`."""
        self._sums = {str(k): float(v) for k, v in state["sums"].items()}
        self._counts = {str(k): int(v) for k, v in state["counts"].items()}
        self._last = {str(k): float(v) for k, v in state["last"].items()}


class Trainer:
    """The built training run. Use :func:`build_trainer`; then ``step()`` per iteration.

    Attributes:
        cfg: the :class:`TrainConfig`.  run_dir: output folder.  device: torch device.
        model: ``NavFormerModel``.  dt_loss: ``NavFormerLoss``.  byol_loss: ``BYOLLoss`` or None (no SSL).
        cross_task: ``CrossTaskSampler``.  pairs: D_ssl ``PairBatcher`` or None.
        batches: :class:`~navformer_rl.data.prefetch.Prefetcher` of ``(task, batch, pairs)`` over both
            (drawing one iteration ahead with ``data.prefetch``; :meth:`close` stops it).
        optimizers: ``{"navformer": AdamW, "dve": Adam}`` ("dve" absent without SSL).
        scaler: ``torch.amp.GradScaler``, enabled only under float16 autocast (loss scaling).
        iteration: completed iterations.  logger: TorchRL logger or None.
        log_window: :class:`LogWindow` of the iterations not logged yet (:meth:`record`).
        validator: :class:`~navformer_rl.validation.Validator` of the held-out sets, or None
            (:meth:`validation_due`, :meth:`validate`).
    """

    def __init__(
        self, cfg: TrainConfig, *, datasets: dict[str, Any], validation_datasets: dict[str, Any] | None = None
    ) -> None:
        from torchrl.objectives import SoftUpdate

        from navformer_rl.data import CrossTaskSampler
        from navformer_rl.modules import NavFormerModel, make_navformer_actor
        from navformer_rl.objectives import BYOLLoss, BYOLTauSchedule, NavFormerLoss

        self.cfg = cfg
        self.run_dir = Path(cfg.output_dir)
        self.device = resolve_device(cfg.device)
        self.model_config = model_config(cfg)
        self.iteration = 0
        _seed_everything(cfg.seed)

        context = cfg.data.context_steps or self.model_config.window_steps
        # prefetching trains on one batch while the next is gathered: two buffer sets per batcher
        buffers = {"buffer_sets": 2 if cfg.data.prefetch else 1, "pin_memory": self.device.type == "cuda"}
        batchers = {}
        for task, key, size, seed_offset in (
            ("exploration", "e", cfg.data.exploration_batch_trajs, 1),
            ("collision_avoidance", "ca", cfg.data.collision_batch_trajs, 2),
        ):
            dataset = datasets.get(key)
            batchers[task] = (
                None
                if dataset is None
                else dataset.trajectory_batcher(
                    size, context, seed=cfg.seed + seed_offset, keys=TRAJECTORY_KEYS, **buffers
                )
            )
        self.cross_task = CrossTaskSampler(batchers["exploration"], batchers["collision_avoidance"])
        self.pairs = (
            datasets["ssl"].pair_batcher(cfg.data.ssl_batch_pairs, seed=cfg.seed + 3, **buffers)
            if cfg.uses_ssl
            else None
        )
        self.batches = Prefetcher(
            self._draw_batches, self._sampler_state, self._load_sampler_state, enabled=cfg.data.prefetch
        )

        self.model = NavFormerModel(self.model_config).to(self.device)
        self.model.train()
        self.dt_loss = NavFormerLoss(make_navformer_actor(self.model))
        self.byol_loss = None
        self.updater = None
        self.tau_schedule = None
        if cfg.uses_ssl:
            self.byol_loss = BYOLLoss(
                self.model.static_encoder,
                self.model.general_encoder,
                projection_dim=cfg.ssl.projection_dim,
                hidden_dim=cfg.ssl.hidden_dim,
                seed=cfg.seed + 4,
                autocast_dtype=self.model_config.autocast_dtype,
            ).to(self.device)
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

    # -- construction helpers -------------------------------------------------------------------------
    def parameter_groups(self) -> dict[str, list[torch.nn.Parameter]]:
        """``{"navformer": [...], "dve": [...]}``: which parameters each optimiser owns (disjoint)."""
        encoders = [m for _, m in self.model.observation_encoders()]
        encoder_ids = {id(p) for enc in encoders for p in enc.parameters()}
        model_params = [p for p in self.model.parameters() if p.requires_grad]
        frozen = self.cfg.encoder_training == "frozen"
        navformer = [p for p in model_params if not (frozen and id(p) in encoder_ids)]
        groups = {"navformer": navformer}
        if self.byol_loss is not None:
            model_ids = {id(p) for p in model_params}
            dve = [p for p in self.byol_loss.parameters() if id(p) not in model_ids]
            if frozen:
                dve = [p for p in model_params if id(p) in encoder_ids] + dve
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
        task, batch = self.cross_task.sample()
        pairs = self.pairs.sample() if self.pairs is not None else None
        return task, batch.select(*BATCH_KEYS), pairs

    def _sampler_state(self) -> dict[str, Any]:
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
        ``loss_byol_<encoder>``, ``projection_std_<encoder>``, ``tau``, ``lr``, ``lr_dve``, ``frames``
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
        frames = int(batch["mask"].sum()) + (2 * pairs.shape[0] if pairs is not None else 0)
        metrics = {
            "loss_dt": float(loss_dt),
            f"loss_dt_{task}": float(loss_dt),
            "lr": self.optimizers["navformer"].param_groups[0]["lr"],
            "frames": float(frames),
            "frames_per_s": frames / elapsed,
            "iteration_s": elapsed,
        }
        total = float(loss_dt)
        if byol_out is not None:
            total += float(loss_byol.detach())  # weighted: loss = L_DT + w L_BYOL
            metrics.update({k: float(v.detach()) for k, v in byol_out.items()})
            metrics["tau"] = float(tau)
            metrics["lr_dve"] = self.optimizers["dve"].param_groups[0]["lr"]
        metrics["loss"] = total
        if not math.isfinite(total):
            raise FloatingPointError(f"iteration {self.iteration}: the loss is {total} (metrics {metrics})")
        return metrics

    def _forward_backward(self, batch, pairs):
        """L = L_DT + L_BYOL, one backward (or one per trajectory chunk, weighted to the same gradient).

        Every backward goes through ``self.scaler`` (loss scaling under float16 autocast, else unchanged).
        """
        chunks = self.cfg.optim.trajectory_chunks
        byol_out = self.byol_loss(pairs) if pairs is not None else None
        loss_byol = byol_out["loss_byol"] if byol_out is not None else None
        if loss_byol is not None and self.cfg.ssl.loss_weight != 1.0:
            loss_byol = loss_byol * self.cfg.ssl.loss_weight  # logged unweighted (byol_out)
        if chunks == 1:
            loss_dt = self.dt_loss(batch)["loss_dt"]
            self.scaler.scale(loss_dt if loss_byol is None else loss_dt + loss_byol).backward()
            return loss_dt.detach(), loss_byol, byol_out
        if loss_byol is not None:
            self.scaler.scale(loss_byol).backward()
        valid_total = batch["mask"].sum().clamp_min(1)
        loss_dt = torch.zeros((), device=self.device)
        for part in batch.split(batch.shape[0] // chunks):
            # masked mean of the chunk x its share of the valid steps = its part of the batch's masked mean
            weighted = self.dt_loss(part)["loss_dt"] * (part["mask"].sum() / valid_total)
            self.scaler.scale(weighted).backward()
            loss_dt += weighted.detach()
        return loss_dt, loss_byol, byol_out

    # -- validation -----------------------------------------------------------------------------------
    def validation_due(self) -> bool:
        """Whether the iteration just completed is one to validate (``validation.interval``, the last one)."""
        return self.validator is not None and self.validator.due(self.iteration, self.cfg.optim.iterations)

    def validate(self) -> dict[str, float]:
        """The teacher-forced action loss on every validation set: ``{"validation/loss_dt_<task>": float,
        "validation/train_loss_dt_<task>": float}`` (eval mode; the training's RNG states are left as they
        were). Empty without validation sets."""
        if self.validator is None:
            return {}
        return self.validator(self.dt_loss, self.model, self.device)

    # -- logging --------------------------------------------------------------------------------------
    def make_logger(self):
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
        """Write the run part and the resume part at the current iteration (atomic)."""
        return ckpt.save_checkpoint(
            self.run_dir,
            self.iteration,
            model_state=self.model.state_dict(),
            model_config=dataclasses.asdict(self.model_config),
            train_config=self.cfg.to_dict(),
            resume_state=self.resume_state(),
            keep_last=self.cfg.checkpoint.keep_last,
        )

    def restore(self, folder: Path) -> None:
        """Load a checkpoint written by :meth:`save_checkpoint` into this (freshly built) trainer."""
        header = ckpt.read_checkpoint_config(folder)
        # a key the checkpoint lacks came after it was written; the run had that key's default
        saved = _with_defaults(TrainConfig().to_dict(), header["train_config"])
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
        ckpt.restore_rng_state(state["rng"])
        if "log_window" in state:  # absent from checkpoints of earlier versions: their window starts empty
            self.log_window.load_state_dict(state["log_window"])
        self.iteration = int(state["iteration"])


def open_datasets(cfg: TrainConfig) -> dict[str, Any]:
    """Open (and validate: schema version, kind, file sizes) the datasets the configuration uses.

    A dataset smaller than one batch is refused with the batch-size key to lower and the largest value that
    fits (every such dataset in one message, so that a single edit of the command line fixes them all).
    """
    wanted = {
        "e": (cfg.uses_exploration, "exploration_path", "exploration_batch_trajs"),
        "ca": (cfg.uses_collision, "collision_path", "collision_batch_trajs"),
        "ssl": (cfg.uses_ssl, "ssl_path", "ssl_batch_pairs"),
    }
    datasets = {}
    too_small: list[tuple[str, str, int | None]] = []
    for kind, (used, key, batch_key) in wanted.items():
        if not used:
            continue
        path = getattr(cfg.data, key)
        dataset = _open_dataset(path, kind, f"data.{key}")
        available = dataset.num_trajectories if kind != "ssl" else len(dataset)
        batch = getattr(cfg.data, batch_key)
        if batch > available:
            unit = "pairs" if kind == "ssl" else "trajectories"
            problem = (
                f"data.{key}={path!r} holds {available} {unit}, fewer than one batch of "
                f"data.{batch_key}={batch}"
            )
            too_small.append((problem, f"data.{batch_key}", _largest_batch(cfg, kind, available)))
        datasets[kind] = dataset
    if too_small:
        fixes = " ".join(f"{key}={fits}" for _, key, fits in too_small if fits is not None)
        hopeless = [key for _, key, fits in too_small if fits is None]
        chunks = cfg.optim.trajectory_chunks
        if hopeless:
            advice = f"no value of {' / '.join(hopeless)} fits this little data: collect more data"
            if chunks > 1 and any(key != "data.ssl_batch_pairs" for key in hopeless):
                advice += f" or lower optim.trajectory_chunks={chunks}"
            advice += f" (and add {fixes})" if fixes else ""
        else:
            if len(too_small) == 1:
                largest = "the largest batch size that fits"
                largest += f" and is a multiple of optim.trajectory_chunks={chunks}" if chunks > 1 else ""
            else:
                largest = "the largest batch sizes that fit"
                largest += f" and are multiples of optim.trajectory_chunks={chunks}" if chunks > 1 else ""
            advice = f"add {fixes} ({largest}) or collect more data"
        raise ValueError("; ".join([*(problem for problem, _, _ in too_small), advice]))
    return datasets


def open_validation_datasets(cfg: TrainConfig) -> dict[str, Any]:
    """Open (and validate) the held-out datasets of ``cfg.validation`` (``{}`` when validation is off)."""
    if not cfg.validation.enabled:
        return {}
    return {
        kind: _open_dataset(path, kind, f"validation.{PATH_KEYS[kind]}")
        for kind, path in cfg.validation.held_out_paths().items()
    }


def _open_dataset(path: str, kind: str, key: str) -> Any:
    """``open_dataset(path, kind)`` with errors that name the config ``key``."""
    from navformer_rl.data import open_dataset

    if not Path(path).exists():
        raise FileNotFoundError(f"{key}={path!r} does not exist")
    try:
        return open_dataset(path, kind=kind)
    except (ValueError, FileNotFoundError) as err:
        raise type(err)(f"{key}: {err}") from None


def _largest_batch(cfg: TrainConfig, kind: str, available: int) -> int | None:
    """The largest valid batch size of dataset ``kind`` holding ``available`` items (None when none is).

    Trajectory batches must divide by ``optim.trajectory_chunks``; BYOL needs at least 2 pairs.
    """
    if kind == "ssl":
        return available if available >= 2 else None
    fits = available - available % cfg.optim.trajectory_chunks
    return fits if fits > 0 else None


def check_datasets_fit_model(cfg: TrainConfig, datasets: Mapping[str, Any], section: str = "data") -> None:
    """Raise ``ValueError`` when the model of ``cfg`` cannot read ``datasets`` (opened by :func:`open_datasets`,
    or by :func:`open_validation_datasets` with ``section="validation"``: the config section that errors name).

    Checked: image size and action width (every dataset's images are ``image_size`` square; trajectory
    actions are ``action_dim`` wide) and the timestep table (the longest trajectory's last step must be
    ``< model.max_timestep``): :func:`navformer_rl.data.fit.check_model_reads`.
    """
    from navformer_rl.data.fit import check_model_reads

    names = {kind: f"{section}.{DATASET_KEYS[kind]}" for kind in datasets}
    check_model_reads(model_config(cfg), datasets, names, tunable=True)


def build_trainer(cfg: TrainConfig) -> Trainer:
    """Validate ``cfg``, open the datasets, build everything and (when resuming) restore the latest checkpoint.

    Every configuration error is raised here, before the first iteration. A fresh run refuses an
    output directory that already holds checkpoints (pass ``resume=True`` to continue it).
    """
    validate_config(cfg)
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
    """Train NavFormer as configured; see the module docstring for one iteration.

    Returns a :class:`TrainResult`. Checkpoints are written every ``checkpoint.interval`` iterations and at
    the end; with ``resume=True`` the run continues from the latest one and produces the same subsequent
    losses and weights as an uninterrupted run.
    """
    from torchrl._utils import timeit
    from tqdm import tqdm

    trainer = build_trainer(cfg)
    timeit.erase()
    metrics: dict[str, float] = {}
    last_checkpoint = None
    total = cfg.optim.iterations
    bar = tqdm(
        total=total, initial=trainer.iteration, disable=not cfg.logger.progress, desc="navformer train"
    )
    with contextlib.closing(bar), contextlib.closing(trainer):
        while trainer.iteration < total:
            metrics = trainer.step()
            trainer.record(metrics)
            if trainer.validation_due():
                with timeit("validation"):
                    trainer.log(trainer.validate(), timings=False)
            if trainer.iteration % cfg.checkpoint.interval == 0 or trainer.iteration == total:
                last_checkpoint = trainer.save_checkpoint()
            bar.update(1)
            bar.set_postfix(loss=f"{metrics['loss']:.4f}", fps=f"{metrics['frames_per_s']:.0f}")
    if last_checkpoint is None:
        last_checkpoint = ckpt.latest_checkpoint(trainer.run_dir)
    return TrainResult(trainer.run_dir, trainer.iteration, metrics, last_checkpoint)
