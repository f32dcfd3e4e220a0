"""Training configurations in and out: :func:`load_train_config` (``train.yaml`` + hydra-style
``key=value`` overrides), :func:`config_from_dict` (a nested dict, e.g. resolved YAML, with every key and
scalar type checked) and :func:`printable_config` (what ``navformer train --print-config`` writes).
"""

from __future__ import annotations

import dataclasses
import os
import types
import typing
from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

from navformer_rl.training.config import (
    CheckpointConfig,
    DataConfig,
    LoggerConfig,
    OptimConfig,
    SSLConfig,
    TrainConfig,
    ValidationConfig,
    model_config,
)

if TYPE_CHECKING:
    from omegaconf import DictConfig

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
    return Path(__file__).parent.parent / "config" / "train.yaml"


RESOLVED_MODEL_KEY = "resolved_model"
"""Key under which :func:`printable_config` (``navformer train --print-config``) shows the model a run builds.

It is output only: :func:`config_from_dict` accepts a configuration that has it (so printed YAML can be fed
back with ``--config``) but ignores it, warning when it differs from the model the configuration builds."""


RUN_INFO_KEY = "run"
"""Key under which a run's ``train_config.json`` records how the run was made (``world_size``, ``backend``,
``init_from``'s source; :attr:`~navformer_rl.training.trainer.Trainer.run_info`). Output only, like
:data:`RESOLVED_MODEL_KEY`: :func:`config_from_dict` ignores it, so the file reads back as a configuration."""


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
    does not describe the model the configuration builds; so is a :data:`RUN_INFO_KEY` section (a run's
    ``train_config.json`` reads back as its configuration).
    """
    values = dict(values)
    printed_model = values.pop(RESOLVED_MODEL_KEY, None)
    values.pop(RUN_INFO_KEY, None)
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


def read_config_file(path: str | os.PathLike | None, default: str | os.PathLike) -> DictConfig:
    """The YAML mapping at ``path`` (``default`` when None) as a struct ``DictConfig``: unknown keys are
    refused, except in its ``model`` section, whose model config checks the names itself. ValueError naming
    the file when it is not readable YAML or not a mapping."""
    import yaml
    from omegaconf import DictConfig, OmegaConf

    try:
        base = OmegaConf.load(path or default)
    except (OSError, yaml.YAMLError) as err:
        raise ValueError(f"--config {path}: cannot read it as YAML ({type(err).__name__}: {err})") from None
    if not isinstance(base, DictConfig):
        raise ValueError(
            f"--config {path}: expected a YAML mapping of config keys, got {type(base).__name__}"
        )
    OmegaConf.set_struct(base, True)
    if "model" in base:
        OmegaConf.set_struct(base.model, False)
    return base


def load_train_config(
    overrides: list[str] | None = None, path: str | os.PathLike | None = None
) -> TrainConfig:
    """Read ``train.yaml`` (packaged default, or ``path``) and apply hydra-style ``key=value`` overrides.

    Overrides are parsed with OmegaConf's dotlist (``optim.lr=1e-4``, ``data.ssl_path=/data/ssl``,
    ``model.autocast_dtype=bfloat16``); a key that is not in the file raises ``ValueError``.
    """
    from omegaconf import OmegaConf
    from omegaconf.errors import OmegaConfBaseException

    base = read_config_file(path, default_config_path())
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
