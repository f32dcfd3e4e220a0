"""What a collection of D_e, D_ca or D_ssl is asked for: its settings, the two scales, the unit seeds.

A dataset is a sequence of deterministic **work units**; item ``k`` of unit ``u`` is seeded from
``(seed, kind, u, k)`` (:func:`unit_seed`), so a unit's content depends on its settings and index alone.
A collection's identity is :func:`settings_record` of its settings (stored in ``metadata.json``).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any

import numpy as np

from navformer_rl.constants import MAX_EPISODE_STEPS, TARGET_COLORS, TARGET_SHAPES
from navformer_rl.data.schema import DatasetKind
from navformer_rl.utils.checks import check_int, check_number

MAZE_SIZES = (5.0, 7.5, 10.0, 12.5, 15.0, 17.5)
"""World sides for D_e and D_ssl: the paper's 5-17.5 m range on the 2.5 m maze-cell grid."""

FURNISHED_WORLDS = ("bookstore", "cafe", "house", "furnished")
"""``worlds`` values that collect in Table II's furnished worlds (``envs/furnished.py``) instead of the
training worlds: one kind, or ``"furnished"`` (each world's kind drawn uniformly from the three). Not in the
paper's training data; for fine-tuning in a new world style (paper §VIII)."""

TRAINING_WORLDS = {"e": "maze", "ca": "arena", "ssl": "maze"}
"""The paper's training worlds of each kind (§V), the default ``worlds``."""

KIND_CODE = {DatasetKind.EXPLORATION: 1, DatasetKind.COLLISION_AVOIDANCE: 2, DatasetKind.SSL: 3}
"""The kind's entry of every unit seed's ``spawn_key`` (:func:`unit_seed`)."""

SEED_DERIVATION = (
    "item k of unit u uses SeedSequence(entropy=seed, spawn_key=(kind_code, u, k)).generate_state(1)[0]"
)
"""How :func:`unit_seed` derives the seeds, as recorded in a dataset's ``metadata.json``."""

DAGGER_MIXING = (
    "at every step each robot executes the expert's action when its draw u < beta, else the policy's; the "
    "stored action is always the expert's; the draws of item k of unit u are "
    "default_rng(SeedSequence([unit_seed(seed, kind, u, k), 0xDA66E2])).random(robots) per step"
)
"""How DAgger mixes expert and policy (:func:`mixing_generator`), as recorded in a DAgger dataset's
``metadata.json``."""


@dataclass(frozen=True)
class DaggerSettings:
    """DAgger (Ross et al. 2011; not in the paper): a trained policy in the collection loop.

    At every step each robot executes the expert's action with probability ``beta``, else the policy's; the
    stored action is always the expert's (the label). ``checkpoint`` is the checkpoint folder the workers
    load (resolved from what the user gave, :func:`navformer_rl.data.dagger.dagger_settings`); the data's
    identity is :meth:`record`: the weights' sha256, ``beta`` and the transformer-step path, not the path.
    """

    checkpoint: str
    weights_sha256: str
    beta: float = 0.5
    transformer_step: str = "torch"
    """``"native"`` (the compiled kernel) or ``"torch"``: every worker decodes the same way."""
    context_steps: int | None = None
    """The timesteps the policy attends to, as deployed: the window the checkpoint was trained on
    (``data.context_steps``); None: the model's whole context (the paper's)."""

    def __post_init__(self) -> None:
        check_number(self.beta, "dagger beta", at_least=0.0, at_most=1.0)
        if self.context_steps is not None:
            check_int(self.context_steps, "dagger context_steps")
        if self.transformer_step not in ("native", "torch"):
            raise ValueError(
                f"dagger transformer_step={self.transformer_step!r}: expected 'native' or 'torch'"
            )

    def record(self) -> dict[str, Any]:
        """What the dataset's settings store (and a resume must match)."""
        return {
            "beta": float(self.beta),
            "weights_sha256": self.weights_sha256,
            "transformer_step": self.transformer_step,
            # recorded only for a policy on shorter windows, so whole-context collections keep their record
            **({} if self.context_steps is None else {"context_steps": int(self.context_steps)}),
        }


@dataclass(frozen=True)
class ExplorationSettings:
    """D_e: ``n_trajectories`` successful episodes (paper: 3,496), one maze per episode."""

    n_trajectories: int = 32
    world_sizes: tuple[float, ...] = MAZE_SIZES
    episodes_per_unit: int = 4
    max_steps: int = MAX_EPISODE_STEPS
    robot: str = "jackal"
    seed: int = 0
    action_noise: float = 0.0
    """Std of the Gaussian noise added to the *executed* normalised actions; the stored labels stay the
    expert's (DART, Laskey et al. 2017; not in the paper). 0 (default) records the plain expert."""
    dagger: DaggerSettings | None = None
    """A policy in the loop (:class:`DaggerSettings`); None (default) records the plain expert."""
    worlds: str = "maze"
    """``"maze"`` (the paper's, sized from ``world_sizes``) or one of :data:`FURNISHED_WORLDS` (each at its
    footprint; ``world_sizes`` unused)."""
    distractors: int = 0
    """Targets the robot does not seek, added to each world beside its own (not in the paper; 0, the
    default, is the paper's one target per maze). The expert detects and drives to its own target only, so
    the data then shows which of the targets in view the target image names."""


@dataclass(frozen=True)
class CollisionAvoidanceSettings:
    """D_ca: ``n_trajectories`` robot trajectories (paper: 7,467) from 12.5 m arena episodes with the ego
    robot plus ``other_robots`` (inclusive range; paper: 2-8) others."""

    n_trajectories: int = 64
    arena_size: float = 12.5
    other_robots: tuple[int, int] = (2, 8)
    max_steps: int = MAX_EPISODE_STEPS
    robot: str = "jackal"
    seed: int = 0
    action_noise: float = 0.0
    """As in :class:`ExplorationSettings` (every robot's executed actions are perturbed)."""
    dagger: DaggerSettings | None = None
    """As in :class:`ExplorationSettings` (every robot mixes its own draws; one policy drives them all)."""
    worlds: str = "arena"
    """``"arena"`` (the paper's, ``arena_size``) or one of :data:`FURNISHED_WORLDS` (each at its footprint;
    the experts follow geodesic fields, so furniture is avoided like walls)."""


@dataclass(frozen=True)
class SSLSettings:
    """D_ssl: ``n_worlds`` worlds (paper: 1,000) x ``pairs_per_world`` pairs (paper: 98,000 in total) with
    ``robots`` (inclusive range; paper: 4-25) robots."""

    n_worlds: int = 8
    pairs_per_world: int = 98
    world_sizes: tuple[float, ...] = MAZE_SIZES
    robots: tuple[int, int] = (4, 25)
    robot: str = "jackal"
    seed: int = 0
    worlds: str = "maze"
    """As in :class:`ExplorationSettings`."""


CollectionSettings = ExplorationSettings | CollisionAvoidanceSettings | SSLSettings
"""The settings of one dataset kind."""

SCALES: dict[str, dict[DatasetKind, CollectionSettings]] = {
    "small": {
        DatasetKind.EXPLORATION: ExplorationSettings(n_trajectories=32),
        DatasetKind.COLLISION_AVOIDANCE: CollisionAvoidanceSettings(n_trajectories=64),
        DatasetKind.SSL: SSLSettings(n_worlds=8),
    },
    "paper": {
        DatasetKind.EXPLORATION: ExplorationSettings(n_trajectories=3496),
        DatasetKind.COLLISION_AVOIDANCE: CollisionAvoidanceSettings(n_trajectories=7467),
        DatasetKind.SSL: SSLSettings(n_worlds=1000),
    },
}
"""``small``: minutes on a laptop; ``paper``: the sizes of paper §V."""


def settings_for(kind: DatasetKind | str, scale: str = "small", seed: int = 0, **overrides: Any) -> Any:
    """The settings dataclass of ``kind`` at ``scale`` with ``seed`` and any field ``overrides``."""
    kind = DatasetKind.parse(kind)
    if scale not in SCALES:
        raise ValueError(f"unknown scale {scale!r}; expected one of {sorted(SCALES)}")
    base = SCALES[scale][kind]
    unknown = set(overrides) - {f.name for f in dataclasses.fields(base)}
    if unknown:
        raise ValueError(f"unknown {kind.value} collection setting(s) {sorted(unknown)}")
    if "action_noise" in overrides:
        check_number(overrides["action_noise"], f"{kind.value} action_noise", at_least=0.0, at_most=1.0)
    if "distractors" in overrides:
        most = len(TARGET_SHAPES) * len(TARGET_COLORS) - 1  # the catalogue beside the robot's own target
        check_int(overrides["distractors"], f"{kind.value} distractors", minimum=0)
        if overrides["distractors"] > most:
            raise ValueError(
                f"{kind.value} distractors={overrides['distractors']!r}: expected at most {most}"
            )
    if "worlds" in overrides:
        allowed = (TRAINING_WORLDS[kind.value], *FURNISHED_WORLDS)
        if overrides["worlds"] not in allowed:
            raise ValueError(f"{kind.value} worlds={overrides['worlds']!r}: expected one of {allowed}")
    for key, least in (("other_robots", 0), ("robots", 1)):
        if key in overrides:
            if isinstance(overrides[key], list):  # as a config file gives it
                overrides[key] = tuple(overrides[key])
            _check_range(overrides[key], f"{kind.value} {key}", least)
    settings = dataclasses.replace(base, seed=seed, **overrides)
    dagger = getattr(settings, "dagger", None)
    if dagger is not None:
        if not isinstance(dagger, DaggerSettings):
            raise ValueError(f"{kind.value} dagger={dagger!r}: expected None or a DaggerSettings")
        if settings.action_noise > 0.0:
            raise ValueError(
                f"{kind.value}: dagger and action_noise={settings.action_noise} together; choose one (the "
                "policy in the loop already takes the robots off the expert's path)"
            )
    return settings


def _check_range(value: Any, name: str, least: int) -> None:
    """Refuse a robot-count range that is not ``(lo, hi)`` integers with ``least <= lo <= hi``."""
    ok = (
        isinstance(value, tuple)
        and len(value) == 2
        and all(isinstance(v, int) and not isinstance(v, bool) for v in value)
        and least <= value[0] <= value[1]
    )
    if not ok:
        raise ValueError(f"{name}={value!r}: expected (lo, hi) integers with {least} <= lo <= hi")


def settings_record(settings: CollectionSettings) -> dict[str, Any]:
    """The settings as a dataset records them: ``dataclasses.asdict``, with ``dagger`` as
    :meth:`DaggerSettings.record` and left out when None, and ``worlds`` left out when it is the paper's
    training worlds and ``distractors`` when 0 (so a plain collection records what it always did)."""
    record = dataclasses.asdict(settings)
    record.pop("dagger", None)
    if record.get("worlds") in TRAINING_WORLDS.values():
        record.pop("worlds")
    if record.get("distractors") == 0:
        record.pop("distractors")
    dagger = getattr(settings, "dagger", None)
    if dagger is not None:
        record["dagger"] = dagger.record()
    return record


def target_count(kind: DatasetKind, settings: CollectionSettings) -> int:
    """Items of the finished dataset: trajectories (D_e, D_ca) or pairs (D_ssl)."""
    if kind is DatasetKind.SSL:
        return settings.n_worlds * settings.pairs_per_world
    return settings.n_trajectories


def unit_seed(seed: int, kind: DatasetKind, unit: int, index: int = 0) -> int:
    """Deterministic 32-bit seed of item ``index`` of work unit ``unit`` (:data:`SEED_DERIVATION`)."""
    ss = np.random.SeedSequence(entropy=int(seed), spawn_key=(KIND_CODE[kind], int(unit), int(index)))
    return int(ss.generate_state(1)[0])


def noise_generator(seed: int, kind: DatasetKind, unit: int, index: int = 0) -> np.random.Generator:
    """The generator of the action noise of item ``index`` of unit ``unit`` (apart from the world's and the
    expert's streams, so the noise changes no other draw)."""
    return np.random.default_rng(np.random.SeedSequence([unit_seed(seed, kind, unit, index), 0xDA27]))


def mixing_generator(seed: int, kind: DatasetKind, unit: int, index: int = 0) -> np.random.Generator:
    """The generator of DAgger's per-step expert-or-policy draws of item ``index`` of unit ``unit`` (a stream
    of its own, like :func:`noise_generator`'s)."""
    return np.random.default_rng(np.random.SeedSequence([unit_seed(seed, kind, unit, index), 0xDA66E2]))
