"""Version numbers of the behaviour that makes collected data: a dataset's identity besides its settings.

``collect`` stores the numbers its kind depends on (:func:`data_versions`) in the dataset's settings under
:data:`VERSIONS_KEY`. Resuming an unfinished collection whose numbers differ from the code's is refused
(finishing it would mix data of two behaviours); a complete dataset is used as it is, with a warning.

Bump a number when its code changes the data it makes; moves, renames and comments change nothing.
:data:`DAGGER_VERSIONS` apply only to DAgger collections (a trained policy in the loop), so a plain
collection records exactly the numbers of :data:`KIND_VERSIONS`.
``tests/data/test_data_versions.py`` collects a tiny dataset of each kind and compares its signature (counts
and integer columns exactly, floats and images within tolerances) with
``tests/data/data_versions_signature.json``, recorded next to these numbers, so a change in the data without a
bump fails.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from navformer_rl.data.schema import DatasetKind

VERSIONS_KEY = "data_versions"
"""The settings entry holding ``{name: number}`` of the versions that made the data."""


@dataclass(frozen=True)
class DataVersion:
    """Version ``number`` of ``what`` the package modules ``covers`` (relative to ``navformer_rl/``) make
    for the data."""

    number: int
    what: str
    covers: tuple[str, ...]


def _package_files(folder: str) -> tuple[str, ...]:
    """Every source file (``.py``, ``.c``) under ``navformer_rl/<folder>/``, relative to ``navformer_rl/``."""
    package = Path(__file__).resolve().parents[1]
    files = (p for p in (package / folder).rglob("*") if p.suffix in (".py", ".c"))
    return tuple(sorted(p.relative_to(package).as_posix() for p in files))


_EXPERTS = ("experts/policies.py",)
_EPISODES = (
    "data/collect.py",
    "data/collect_settings.py",
    "data/expert_episodes.py",
    "data/schema.py",
    "tasks.py",
)

DATA_VERSIONS: dict[str, DataVersion] = {
    "world": DataVersion(
        1,
        "mazes, arenas and furnished worlds, start poses, targets (positions, shapes, colours) from a seed",
        ("envs/world.py", "envs/furnished.py", "envs/occupancy.py", "utils/checks.py"),
    ),
    "simulator": DataVersion(
        1,
        "robot dynamics, control period, collisions, success radius",
        ("envs/sim.py", "envs/robots.py", "constants.py"),
    ),
    "renderer": DataVersion(
        1,
        "camera images o_t and target images (scene colours, image size)",
        ("envs/sim.py", "envs/scene.py", "envs/target_image.py", "constants.py"),
    ),
    "exploration_expert": DataVersion(
        1,
        "D_e's expert: frontier exploration, A*, DWA, target visibility",
        (
            *_EXPERTS,
            "experts/navigator.py",
            "experts/frontier.py",
            "experts/astar.py",
            "experts/dwa.py",
            "experts/mapping.py",
            "experts/grid.py",
            "experts/lidar.py",
            "experts/visibility.py",
        ),
    ),
    "collision_avoidance_expert": DataVersion(
        1, "D_ca's expert: NH-ORCA", (*_EXPERTS, "experts/nh_orca.py", "experts/orca.py")
    ),
    "exploration_episodes": DataVersion(
        1, "D_e's units: world and seed draws, episode loop, action noise, rows, counters", _EPISODES
    ),
    "collision_avoidance_episodes": DataVersion(
        1, "D_ca's units: arena and seed draws, episode loop, action noise, rows, counters", _EPISODES
    ),
    "ssl_pairs": DataVersion(
        1, "D_ssl's units: world and robot draws, placement retries, the o^s / o^d pairs", _EPISODES
    ),
    "dagger_policy": DataVersion(
        1,
        "DAgger's policy in the loop: checkpoint loading, the NavFormer / DT model and its KV-cached "
        "decoding, the per-step expert-or-policy mixing",
        (
            "data/dagger.py",
            "training/checkpoint.py",
            "training/pretrained_registry.py",
            "pretrained/__init__.py",
            "utils/lazy.py",
            *_package_files("modules"),
        ),
    ),
}
"""Every version, by the name stored in the settings."""

KIND_VERSIONS: dict[DatasetKind, tuple[str, ...]] = {
    DatasetKind.EXPLORATION: (
        "world",
        "simulator",
        "renderer",
        "exploration_expert",
        "exploration_episodes",
    ),
    DatasetKind.COLLISION_AVOIDANCE: (
        "world",
        "simulator",
        "renderer",
        "collision_avoidance_expert",
        "collision_avoidance_episodes",
    ),
    DatasetKind.SSL: ("world", "simulator", "renderer", "ssl_pairs"),
}
"""The versions each kind's data depends on."""

DAGGER_VERSIONS: tuple[str, ...] = ("dagger_policy",)
"""The versions a DAgger collection (D_e / D_ca with a policy in the loop) depends on besides its kind's."""


def data_versions(kind: DatasetKind | str, dagger: bool = False) -> dict[str, int]:
    """``{name: number}`` of the versions the data of ``kind`` depends on (stored under :data:`VERSIONS_KEY`);
    ``dagger``: a collection with a policy in the loop, which also depends on :data:`DAGGER_VERSIONS`."""
    names = KIND_VERSIONS[DatasetKind.parse(kind)] + (DAGGER_VERSIONS if dagger else ())
    return {name: DATA_VERSIONS[name].number for name in names}
