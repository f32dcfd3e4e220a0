"""The PPO configuration: :class:`PPOConfig` and its sections (the layout of
``navformer_rl/config/ppo.yaml``), read from YAML + hydra-style ``key=value`` overrides
(:func:`load_ppo_config`) or a nested dict (:func:`ppo_config_from_dict`), every key, type and range checked
(ValueError naming the key).

Plain dataclasses, no hydra; ``navformer train-ppo`` and the recipe ``recipes/ppo`` both build them.
"""

from __future__ import annotations

import dataclasses
import os
import types
import typing
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from navformer_rl.baselines.online import ONLINE_METHODS
from navformer_rl.constants import MAX_EPISODE_STEPS, MAX_WORLD_SIZE, MIN_WORLD_SIZE
from navformer_rl.utils.checks import check_int, check_number, check_seed

PPO_AUTOCAST_DTYPES = ("bfloat16",)
"""``optim.autocast_dtype`` values: bfloat16 only (float16 would need loss scaling,
which the update lacks)."""


@dataclass
class EnvConfig:
    """The training worlds (``MultiRobotNavEnv``).

    Attributes:
        sizes: world sides in metres; every new world draws one uniformly (paper: 7.5, 12.5, 17.5).
        robot_counts: robots per env; worker ``i`` of the collector drives ``robot_counts[i % len]`` robots
            (paper: 2, 4, 6). Every robot runs the policy.
        kind: ``maze`` or ``arena``.
        max_steps: episode length (500 in the paper).
        episodes_per_world: resets (fresh starts and targets) before a new world is drawn.
        textured: tiled floor and coloured walls in the camera images (as in the datasets).
    """

    sizes: list[float] = field(default_factory=lambda: [7.5, 12.5, 17.5])
    robot_counts: list[int] = field(default_factory=lambda: [2, 4, 6])
    kind: str = "maze"
    max_steps: int = MAX_EPISODE_STEPS
    episodes_per_world: int = 1
    textured: bool = True


@dataclass
class RewardConfig:
    """The shaped reward (:class:`~navformer_rl.online.reward.RewardWeights`)."""

    progress: float = 1.0
    collision: float = 0.1
    success: float = 10.0
    step: float = 0.01


@dataclass
class CollectorConfig:
    """Data collection.

    Attributes:
        num_workers: env processes (a ``MultiSyncCollector``); 1 collects in this process (``Collector``).
        frames_per_batch: env steps per PPO batch, over all workers (a step of an env with A robots holds A
            robot-steps); a multiple of ``num_workers``.
        total_frames: env steps of the whole run.
    """

    num_workers: int = 3
    frames_per_batch: int = 1536
    total_frames: int = 300_000


@dataclass
class LossConfig:
    """``ClipPPOLoss`` and ``GAE``."""

    gamma: float = 0.99
    lmbda: float = 0.95
    clip_epsilon: float = 0.2
    entropy_coeff: float = 0.001
    critic_coeff: float = 0.5
    loss_critic_type: str = "smooth_l1"
    normalize_advantage: bool = True


@dataclass
class OptimConfig:
    """Adam on every parameter; ``epochs`` passes over each batch in minibatches of ``minibatch_size``
    robot-steps; gradients clipped to ``max_grad_norm``; ``anneal_lr``: linear decay to 0 over the run;
    ``autocast_dtype``: ``"bfloat16"`` runs the update's trunk in that precision under autocast (the heads,
    log-probs and values stay float32), None: float32 throughout."""

    lr: float = 3e-4
    epochs: int = 4
    minibatch_size: int = 256
    max_grad_norm: float = 0.5
    anneal_lr: bool = False
    autocast_dtype: str | None = None


@dataclass
class EvalConfig:
    """The learning curve's success rate: every ``interval`` batches (and after the last) the deterministic
    policy (mean action) runs ``episodes`` fixed episodes (worlds seeded from ``seed``, sizes cycling through
    ``env.sizes``, ``n_robots`` robots, ``max_steps`` steps); 0 turns it off."""

    interval: int = 10
    episodes: int = 6
    n_robots: int = 2
    max_steps: int = MAX_EPISODE_STEPS
    seed: int = 10_000


@dataclass
class CheckpointConfig:
    """``interval``: batches between checkpoints (a final one is always written); ``keep_last``: checkpoint
    folders kept (0 = all)."""

    interval: int = 10
    keep_last: int = 3


@dataclass
class PPOConfig:
    """Everything :func:`~navformer_rl.online.train.train_ppo` needs.

    Attributes:
        method: ``dsac`` or ``matdn``.
        model: fields of the method's config (``DSACConfig`` / ``MATDNConfig``); missing ones keep defaults.
        seed: seeds torch, numpy, python and the envs.
        output_dir: the run directory (checkpoints, ``ppo_config.json``, ``logs/``, ``learning_curve.png``).
        resume: continue from the run directory's latest checkpoint (start fresh when it has none).
        threads: torch threads of the training process (0: torch's default).
    """

    method: str = "dsac"
    model: dict[str, Any] = field(default_factory=dict)
    seed: int = 0
    output_dir: str = "runs/ppo"
    resume: bool = False
    threads: int = 0
    env: EnvConfig = field(default_factory=EnvConfig)
    reward: RewardConfig = field(default_factory=RewardConfig)
    collector: CollectorConfig = field(default_factory=CollectorConfig)
    loss: LossConfig = field(default_factory=LossConfig)
    optim: OptimConfig = field(default_factory=OptimConfig)
    eval: EvalConfig = field(default_factory=EvalConfig)
    checkpoint: CheckpointConfig = field(default_factory=CheckpointConfig)

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)


_SECTIONS: dict[str, type] = {
    "env": EnvConfig,
    "reward": RewardConfig,
    "collector": CollectorConfig,
    "loss": LossConfig,
    "optim": OptimConfig,
    "eval": EvalConfig,
    "checkpoint": CheckpointConfig,
}
LOSS_CRITIC_TYPES = ("l1", "l2", "smooth_l1")


def default_ppo_config_path() -> Path:
    """The packaged default configuration (``navformer_rl/config/ppo.yaml``)."""
    return Path(__file__).parent.parent / "config" / "ppo.yaml"


def model_config(cfg: PPOConfig):
    """The method's model configuration (``DSACConfig`` / ``MATDNConfig``) from ``cfg.model``; ValueError
    naming an unknown field or a bad value."""
    from navformer_rl.baselines.online import model_config_class

    config_cls = model_config_class(cfg.method)
    known = {f.name for f in dataclasses.fields(config_cls)}
    unknown = sorted(set(cfg.model) - known)
    if unknown:
        raise ValueError(
            f"unknown keys {[f'model.{k}' for k in unknown]}; {cfg.method} accepts {sorted(known)}"
        )
    return config_cls(**cfg.model)


def validate_ppo_config(cfg: PPOConfig) -> None:
    """ValueError naming the key when a setting of ``cfg`` is out of range (no env or file is opened)."""
    if cfg.method not in ONLINE_METHODS:
        raise ValueError(f"method={cfg.method!r}: expected one of {', '.join(ONLINE_METHODS)}")
    model_config(cfg)
    check_seed(cfg.seed)
    check_int(cfg.threads, "threads", minimum=0)
    env = cfg.env
    if not env.sizes:
        raise ValueError("env.sizes is empty: expected a list of world sides in metres, e.g. [7.5, 12.5]")
    for size in env.sizes:
        check_number(size, "env.sizes[...]", at_least=MIN_WORLD_SIZE, at_most=MAX_WORLD_SIZE, unit="metres")
    if not env.robot_counts:
        raise ValueError("env.robot_counts is empty: expected a list of robot counts, e.g. [2, 4, 6]")
    for count in env.robot_counts:
        check_int(count, "env.robot_counts[...]")
    if env.kind not in ("maze", "arena"):
        raise ValueError(f"env.kind={env.kind!r}: expected 'maze' or 'arena'")
    check_int(env.max_steps, "env.max_steps")
    check_int(env.episodes_per_world, "env.episodes_per_world")
    for name in ("progress", "collision", "success", "step"):
        check_number(getattr(cfg.reward, name), f"reward.{name}", at_least=0.0)
    col = cfg.collector
    check_int(col.num_workers, "collector.num_workers")
    check_int(col.frames_per_batch, "collector.frames_per_batch")
    if col.frames_per_batch % col.num_workers:
        raise ValueError(
            f"collector.frames_per_batch={col.frames_per_batch} must be a multiple of "
            f"collector.num_workers={col.num_workers}"
        )
    check_int(col.total_frames, "collector.total_frames")
    loss = cfg.loss
    check_number(loss.gamma, "loss.gamma", at_least=0.0, at_most=1.0)
    check_number(loss.lmbda, "loss.lmbda", at_least=0.0, at_most=1.0)
    check_number(loss.clip_epsilon, "loss.clip_epsilon", greater_than=0.0)
    check_number(loss.entropy_coeff, "loss.entropy_coeff", at_least=0.0)
    check_number(loss.critic_coeff, "loss.critic_coeff", at_least=0.0)
    if loss.loss_critic_type not in LOSS_CRITIC_TYPES:
        raise ValueError(
            f"loss.loss_critic_type={loss.loss_critic_type!r}: expected one of {LOSS_CRITIC_TYPES}"
        )
    check_number(cfg.optim.lr, "optim.lr", greater_than=0.0)
    check_int(cfg.optim.epochs, "optim.epochs")
    check_int(cfg.optim.minibatch_size, "optim.minibatch_size")
    check_number(cfg.optim.max_grad_norm, "optim.max_grad_norm", greater_than=0.0)
    if cfg.optim.autocast_dtype is not None and cfg.optim.autocast_dtype not in PPO_AUTOCAST_DTYPES:
        raise ValueError(
            f"optim.autocast_dtype={cfg.optim.autocast_dtype!r}: expected null or one of "
            f"{PPO_AUTOCAST_DTYPES} (float16 would need loss scaling)"
        )
    check_int(cfg.eval.interval, "eval.interval", minimum=0)
    check_int(cfg.eval.episodes, "eval.episodes")
    check_int(cfg.eval.n_robots, "eval.n_robots")
    check_int(cfg.eval.max_steps, "eval.max_steps")
    check_seed(cfg.eval.seed, "eval.seed")
    check_int(cfg.checkpoint.interval, "checkpoint.interval")
    check_int(cfg.checkpoint.keep_last, "checkpoint.keep_last", minimum=0)


# ---------------------------------------------------------------------- reading
_SCALARS: dict[Any, tuple[type, ...]] = {int: (int,), float: (int, float), bool: (bool,), str: (str,)}


def _check_value(hint: Any, value: Any, key: str) -> Any:
    """``value`` checked against a scalar / ``list[scalar]`` type hint (ValueError naming ``key``)."""
    origin = typing.get_origin(hint)
    if origin is list:
        (item,) = typing.get_args(hint)
        if not isinstance(value, (list, tuple)):
            raise ValueError(f"{key}={value!r}: expected a list of {item.__name__}")
        return [_check_value(item, v, f"{key}[{i}]") for i, v in enumerate(value)]
    options = typing.get_args(hint) if isinstance(hint, types.UnionType) else (hint,)
    if value is None and type(None) in options:
        return None
    allowed = tuple(t for o in options if o in _SCALARS for t in _SCALARS[o])
    if not allowed:
        return value
    if (isinstance(value, bool) and bool not in allowed) or not isinstance(value, allowed):
        expected = " or ".join("null" if o is type(None) else o.__name__ for o in options)
        raise ValueError(f"{key}={value!r}: expected {expected}")
    return float(value) if float in options and not isinstance(value, bool) else value


def _section(cls: type, values: Any, prefix: str) -> Any:
    if values is None:
        values = {}
    if not isinstance(values, Mapping):
        raise ValueError(f"config section {prefix.rstrip('.')!r} must be a mapping, got {values!r}")
    hints = typing.get_type_hints(cls)
    known = {f.name for f in dataclasses.fields(cls)}
    unknown = sorted(set(values) - known)
    if unknown:
        raise ValueError(
            f"unknown keys {[prefix + k for k in unknown]}; "
            f"{prefix.rstrip('.') or 'the config'} accepts {sorted(known)}"
        )
    kwargs = {}
    for name, value in values.items():
        if name in _SECTIONS and cls is PPOConfig:
            kwargs[name] = _section(_SECTIONS[name], value, f"{name}.")
        elif name == "model" and cls is PPOConfig:
            if value is not None and not isinstance(value, Mapping):
                raise ValueError(f"config section 'model' must be a mapping, got {value!r}")
            kwargs[name] = dict(value or {})
        else:
            kwargs[name] = _check_value(hints[name], value, prefix + name)
    return cls(**kwargs)


def ppo_config_from_dict(values: Mapping[str, Any]) -> PPOConfig:
    """A :class:`PPOConfig` from a nested dict (resolved YAML); unknown keys and wrongly typed values raise
    ``ValueError`` naming them; missing keys keep their defaults."""
    return _section(PPOConfig, dict(values), "")


def load_ppo_config(overrides: list[str] | None = None, path: str | os.PathLike | None = None) -> PPOConfig:
    """Read ``ppo.yaml`` (packaged default, or ``path``) and apply hydra-style ``key=value`` overrides
    (OmegaConf dotlist: ``method=matdn``, ``collector.num_workers=2``, ``env.sizes=[7.5]``)."""
    from omegaconf import OmegaConf
    from omegaconf.errors import OmegaConfBaseException

    from navformer_rl.training.config_io import read_config_file

    base = read_config_file(path, default_ppo_config_path())
    try:
        if overrides:
            bad = [item for item in overrides if "=" not in item]
            if bad:
                raise ValueError(f"overrides must look like key=value, got {bad}")
            base = OmegaConf.merge(base, OmegaConf.from_dotlist(list(overrides)))
        container = OmegaConf.to_container(base, resolve=True)
    except OmegaConfBaseException as err:
        key = getattr(err, "full_key", None)
        reason = str(err).splitlines()[0]
        raise ValueError(
            f"bad PPO config override{f' {key!r}' if key else ''}: {reason} (keys: docs/baselines.md)"
        ) from None
    return ppo_config_from_dict(container)  # type: ignore[arg-type]
