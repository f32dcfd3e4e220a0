"""Fixed, versioned evaluation episode sets, saved as JSON, so every method faces the same episodes.

Paper protocol (§VII.A): 60 trials per setup, a new maze every 10 trials, sizes {7.5, 12.5, 17.5} m x
{2, 4, 6} robots (Table I); Table II (§VII.B): 30 trials in each furnished out-of-distribution world kind
(``bookstore``, ``cafe``, ``house``, :mod:`navformer_rl.envs.furnished`) with 3 Jackals and eight
targets (Fig. 4: each robot's own and five that no robot seeks, *distractors*), a new furniture layout every
10 trials (the paper had one fixed world per kind); Table III: 12.5 m, 4 robots, with Jackal
("seen") or TurtleBot3 ("unseen") dynamic obstacles; Table IV: the ablations on 12.5 m, 4 robots. Within one
world every trial draws new targets (shape, colour, position) and new robot starts ("robots were randomly
located ... target object locations were randomly chosen").

File format (``FORMAT`` / ``FORMAT_VERSION``)::

    {"format": "navformer_rl.episode_set", "version": 2, "name": ..., "max_steps": 500,
     "generation": {protocol, seed, trials_per_setup, trials_per_world, package_version},
     "content_sha256": sha256 of the canonical JSON of every other field,
     "episodes": [{"episode_id", "setup", "size", "n_robots", "world_index", "trial",
                   "world": {"config": WorldConfig fields (kind: maze or a furnished kind), "seed",
                             "walls_sha256"},
                   "robots": [style per robot], "measured": [bool per robot],
                   "starts": [[x, y, yaw] per robot],
                   "targets": [{"position": [x, y], "shape", "color"} per robot],
                   "distractors": [{"position", "shape", "color"} per target no robot seeks],  # only if any
                   "shortest_paths": [l_i per robot],            # SPL's l: start -> target, metres
                                                                 # (reach-5 grid, SHORTEST_PATH_REACH)
                   "shortest_paths_to_disc": [per robot],        # start -> 1.5 m success disc (reference)
                   "seed": per-episode seed for stochastic policies}, ...]}

Loading refuses a file that is not JSON, has another ``format``, another ``version``, a content hash that
does not match (edited or truncated), or episodes that do not follow the schema. When an episode is
turned into a world the maze is regenerated from ``(config, seed)`` and its walls are checked against
``walls_sha256``, so a changed world generator cannot silently give different mazes.
"""

from __future__ import annotations

import dataclasses
import gzip
import hashlib
import json
import os
import zlib
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from navformer_rl.constants import (
    EVAL_ROBOT_COUNTS,
    EVAL_SIZES,
    FURNISHED_FOOTPRINTS,
    MAX_EPISODE_STEPS,
    SUCCESS_RADIUS,
    TABLE2_ROBOTS,
    TABLE2_TARGETS,
    TABLE2_TRIALS_PER_KIND,
)
from navformer_rl.utils.durable import atomic_write_text

FORMAT = "navformer_rl.episode_set"
FORMAT_VERSION = 2
"""2: ``shortest_paths`` on the reach-5 grid (version 1 used the 8-connected grid, ~5 % longer)."""
SHORTEST_PATH_REACH = 5
"""The grid graph of SPL's l (``OccupancyMap`` module docstring): straight moves of up to 5 cells in 40
directions; in free space at most 0.49 % longer than the straight line between the same cells (8.2 % for
the 8-connected grid), on Table I mazes within 0.46 % of moves of up to 12 cells."""
PROTOCOLS = ("table1", "table2", "table3", "table4", "smoke")
PAPER_TRIALS_PER_SETUP = 60
PAPER_TRIALS_PER_WORLD = 10
PROTOCOL_TRIALS: dict[str, tuple[int, int]] = {"table2": (TABLE2_TRIALS_PER_KIND, PAPER_TRIALS_PER_WORLD)}
"""``(trials per setup, trials per world)`` of a protocol when not given; the others use
``(PAPER_TRIALS_PER_SETUP, PAPER_TRIALS_PER_WORLD)``."""


@dataclass(frozen=True)
class Setup:
    """One experiment setup: world size, robot styles (one per robot), which robots are measured, the world
    ``kind`` (``"maze"``, or a furnished kind whose ``size`` is ``max`` of its footprint), and
    ``distractors``, the number of catalogue targets no robot seeks that each episode adds beside the robots'
    own."""

    name: str
    size: float
    robots: tuple[str, ...]
    measured: tuple[bool, ...]
    kind: str = "maze"
    distractors: int = 0

    @property
    def n_robots(self) -> int:
        return len(self.robots)


def table1_setups() -> list[Setup]:
    """Table I: sizes {7.5, 12.5, 17.5} m x {2, 4, 6} Jackal robots, every robot measured."""
    return [
        Setup(f"{size:g}m-{n}r", float(size), ("jackal",) * n, (True,) * n)
        for size in EVAL_SIZES
        for n in EVAL_ROBOT_COUNTS
    ]


def table2_setups() -> list[Setup]:
    """Table II: three Jackal robots, every robot measured, in each furnished world kind (setup = kind), with
    eight targets (Fig. 4): each robot's own and five distractors."""
    return [
        Setup(kind, float(max(FURNISHED_FOOTPRINTS[kind])), ("jackal",) * TABLE2_ROBOTS,
              (True,) * TABLE2_ROBOTS, kind, TABLE2_TARGETS - TABLE2_ROBOTS)
        for kind in FURNISHED_FOOTPRINTS
    ]  # fmt: skip


SEEN_SUFFIX = "-seen"
UNSEEN_SUFFIX = "-unseen"
"""Table III's setup names end in these; an unseen setup replays its seen setup's mazes,
starts and targets."""


def table3_setups() -> list[Setup]:
    """Table III (12.5 m, 4 robots): one Jackal plus three Jackal ("seen") or TurtleBot3 ("unseen")
    dynamic obstacles. Seen: all four Jackals are measured (the paper's seen row equals its Table I
    12.5 m / 4 robots row); unseen: only the Jackal (robot 0) is measured."""
    return [
        Setup(f"12.5m-4r{SEEN_SUFFIX}", 12.5, ("jackal",) * 4, (True,) * 4),
        Setup(
            f"12.5m-4r{UNSEEN_SUFFIX}", 12.5, ("jackal",) + ("turtlebot3",) * 3, (True, False, False, False)
        ),
    ]


def protocol_setups(protocol: str) -> list[Setup]:
    """The setups of a named protocol (``table1``, ``table2``, ``table3``, ``table4``, ``smoke``)."""
    if protocol == "table1":
        return table1_setups()
    if protocol == "table2":
        return table2_setups()
    if protocol == "table3":
        return table3_setups()
    if protocol == "table4":
        return [Setup("12.5m-4r", 12.5, ("jackal",) * 4, (True,) * 4)]
    if protocol == "smoke":
        return [Setup("7.5m-2r", 7.5, ("jackal",) * 2, (True,) * 2)]
    raise ValueError(f"unknown protocol {protocol!r}; expected one of {PROTOCOLS}")


@dataclass(frozen=True)
class Episode:
    """One evaluation trial (see the module docstring for the fields)."""

    episode_id: str
    setup: str
    size: float
    n_robots: int
    world_index: int
    trial: int
    world_config: dict[str, Any]
    world_seed: int
    walls_sha256: str
    robots: tuple[str, ...]
    measured: tuple[bool, ...]
    starts: tuple[tuple[float, float, float], ...]
    targets: tuple[dict[str, Any], ...]
    shortest_paths: tuple[float, ...]
    shortest_paths_to_disc: tuple[float, ...]
    seed: int
    distractors: tuple[dict[str, Any], ...] = ()

    def to_json(self) -> dict[str, Any]:
        row = {
            "episode_id": self.episode_id,
            "setup": self.setup,
            "size": self.size,
            "n_robots": self.n_robots,
            "world_index": self.world_index,
            "trial": self.trial,
            "world": {
                "config": self.world_config,
                "seed": self.world_seed,
                "walls_sha256": self.walls_sha256,
            },
            "robots": list(self.robots),
            "measured": list(self.measured),
            "starts": [list(s) for s in self.starts],
            "targets": [dict(t) for t in self.targets],
            "shortest_paths": list(self.shortest_paths),
            "shortest_paths_to_disc": list(self.shortest_paths_to_disc),
            "seed": self.seed,
        }
        if self.distractors:  # a set without distractors keeps the content hash it had before they existed
            row["distractors"] = [dict(t) for t in self.distractors]
        return row

    @classmethod
    def from_json(cls, row: dict[str, Any]) -> Episode:
        """Parse and validate one episode object (ValueError naming the bad field)."""
        try:
            world = row["world"]
            n = int(row["n_robots"])
            episode = cls(
                episode_id=str(row["episode_id"]),
                setup=str(row["setup"]),
                size=float(row["size"]),
                n_robots=n,
                world_index=int(row["world_index"]),
                trial=int(row["trial"]),
                world_config=dict(world["config"]),
                world_seed=int(world["seed"]),
                walls_sha256=str(world["walls_sha256"]),
                robots=tuple(str(r) for r in row["robots"]),
                measured=tuple(bool(m) for m in row["measured"]),
                starts=tuple(tuple(float(v) for v in s) for s in row["starts"]),
                targets=tuple(_target_json(t) for t in row["targets"]),
                shortest_paths=tuple(float(v) for v in row["shortest_paths"]),
                shortest_paths_to_disc=tuple(float(v) for v in row["shortest_paths_to_disc"]),
                seed=int(row["seed"]),
                distractors=tuple(_target_json(t) for t in row.get("distractors", ())),
            )
        except (KeyError, TypeError, ValueError) as error:
            raise ValueError(f"episode {row.get('episode_id', '?') if isinstance(row, dict) else '?'} "
                             f"does not follow the episode schema: {error!r}") from None  # fmt: skip
        per_robot = {
            "robots": episode.robots, "measured": episode.measured, "starts": episode.starts,
            "targets": episode.targets, "shortest_paths": episode.shortest_paths,
            "shortest_paths_to_disc": episode.shortest_paths_to_disc,
        }  # fmt: skip
        for name, values in per_robot.items():
            if len(values) != n:
                raise ValueError(
                    f"episode {episode.episode_id}: {name} has {len(values)} entries, expected n_robots={n}"
                )
        if any(len(s) != 3 for s in episode.starts) or any(
            len(t["position"]) != 2 for t in episode.targets + episode.distractors
        ):
            raise ValueError(
                f"episode {episode.episode_id}: starts must be [x, y, yaw], target positions [x, y]"
            )
        for name in ("shortest_paths", "shortest_paths_to_disc"):
            values = getattr(episode, name)
            if not all(np.isfinite(values)) or min(values) <= 0:
                raise ValueError(f"episode {episode.episode_id}: {name} must be finite and > 0, got {values}")
        if any(
            disc > path + 1e-6 for disc, path in zip(episode.shortest_paths_to_disc, episode.shortest_paths)
        ):
            raise ValueError(
                f"episode {episode.episode_id}: a path to the success disc is longer than the path to its "
                f"target ({episode.shortest_paths_to_disc} vs {episode.shortest_paths})"
            )
        for key, value in (("n_robots", n), ("size", episode.size)):
            if key in episode.world_config and episode.world_config[key] != value:
                raise ValueError(
                    f"episode {episode.episode_id}: {key}={value} disagrees with its world config "
                    f"({key}={episode.world_config[key]})"
                )
        return episode

    def world_spec(self):
        """The :class:`~navformer_rl.envs.world.EpisodeSpec` to hand to
        ``MultiRobotNavEnv.set_next_episode`` (its targets: the robots' own, then the distractors)."""
        from navformer_rl.envs.world import EpisodeSpec, TargetSpec

        return EpisodeSpec(
            config=_world_config(self.world_config),
            world_seed=self.world_seed,
            starts=np.array(self.starts, dtype=np.float32),
            targets=[
                TargetSpec(
                    position=np.array(t["position"], dtype=np.float32), shape=t["shape"], color=t["color"]
                )
                for t in self.targets + self.distractors
            ],
        )

    def check_world(self, world) -> None:
        """ValueError if the regenerated ``world`` (a ``WorldSpec``) has other walls than when the set was
        made."""
        if walls_digest(world.walls) != self.walls_sha256:
            raise ValueError(
                f"episode {self.episode_id}: the world generator now makes a different maze for seed "
                f"{self.world_seed} than when this episode set was written; regenerate the episode set"
            )


@dataclass(frozen=True)
class EpisodeSet:
    """A named, ordered list of :class:`Episode` plus how it was made."""

    name: str
    episodes: tuple[Episode, ...]
    max_steps: int = MAX_EPISODE_STEPS
    generation: dict[str, Any] = dataclasses.field(default_factory=dict)

    def __len__(self) -> int:
        return len(self.episodes)

    @property
    def setups(self) -> list[str]:
        """Setup names in order of first appearance."""
        return list(dict.fromkeys(e.setup for e in self.episodes))

    def content(self) -> dict[str, Any]:
        """Every field the content hash covers."""
        return {
            "format": FORMAT,
            "version": FORMAT_VERSION,
            "name": self.name,
            "max_steps": self.max_steps,
            "generation": self.generation,
            "episodes": [e.to_json() for e in self.episodes],
        }

    def content_hash(self) -> str:
        return hashlib.sha256(_canonical(self.content()).encode()).hexdigest()

    def robots_hash(self) -> str:
        """sha256 of what the robots face, without the distractors: every episode's id, world, robots, starts,
        targets and seed, and ``max_steps``. Two sets with the same ``robots_hash`` differ at most in their
        distractors (and so in ℓ, measured around them): their evaluations pair robot-trial by robot-trial."""
        varying = ("distractors", "shortest_paths", "shortest_paths_to_disc")
        rows = [{k: v for k, v in e.to_json().items() if k not in varying} for e in self.episodes]
        faced = {"max_steps": self.max_steps, "episodes": rows}
        return hashlib.sha256(_canonical(faced).encode()).hexdigest()


def walls_digest(walls: np.ndarray) -> str:
    """sha256 of the float32 wall boxes ``[W, 4]`` (identifies a maze)."""
    return hashlib.sha256(np.ascontiguousarray(walls, dtype=np.float32).tobytes()).hexdigest()


def make_episode_set(
    setups: Sequence[Setup],
    trials_per_setup: int = PAPER_TRIALS_PER_SETUP,
    trials_per_world: int = PAPER_TRIALS_PER_WORLD,
    seed: int = 0,
    name: str = "custom",
    max_steps: int = MAX_EPISODE_STEPS,
    protocol: str | None = None,
    workers: int = 1,
) -> EpisodeSet:
    """Generate an episode set (deterministic in all arguments but ``workers``, which does not change it).

    Each setup gets ``ceil(trials_per_setup / trials_per_world)`` worlds; world ``k`` of a maze setup has
    seed drawn from ``SeedSequence([seed, size_cm, n_robots, k])``, so setups with the same size and robot
    count share their episodes across protocols (e.g. Table I 12.5 m / 4 robots = Table IV = Table III
    "seen"); a furnished setup's seed also mixes in its kind.
    Most of the time goes into SPL's shortest paths (~0.5 s per Table I episode); ``workers > 1`` makes the
    worlds in that many spawned processes.
    """
    from navformer_rl import __version__
    from navformer_rl.utils.checks import check_int

    if trials_per_setup < 1 or trials_per_world < 1:
        raise ValueError(
            f"trials_per_setup and trials_per_world must be >= 1, got {trials_per_setup}, {trials_per_world}"
        )
    if max_steps < 1:
        raise ValueError(f"max_steps must be >= 1, got {max_steps}")
    workers = check_int(workers, "workers")
    for setup in setups:
        _check_distractors(setup)
    worlds = []
    for setup in setups:
        for world_index in range((trials_per_setup + trials_per_world - 1) // trials_per_world):
            first = world_index * trials_per_world
            trials = tuple(range(first, min(first + trials_per_world, trials_per_setup)))
            worlds.append((setup, world_index, seed, trials))
    if workers > 1 and len(worlds) > 1:
        from concurrent.futures import ProcessPoolExecutor

        from navformer_rl.utils.interrupts import exit_on_sigint, spawn_context

        context = spawn_context()  # no forked pybullet / torch state; Ctrl-C ends the workers quietly
        with ProcessPoolExecutor(
            min(workers, len(worlds)), mp_context=context, initializer=exit_on_sigint
        ) as pool:
            per_world = list(pool.map(_make_world_episodes, worlds))
    else:
        per_world = [_make_world_episodes(world) for world in worlds]
    episodes = [episode for world_episodes in per_world for episode in world_episodes]
    generation = {
        "protocol": protocol,
        "seed": int(seed),
        "trials_per_setup": int(trials_per_setup),
        "trials_per_world": int(trials_per_world),
        "setups": [_setup_record(s) for s in setups],
        "package_version": __version__,
    }
    generation = json.loads(json.dumps(generation))  # the form it takes after a save / load round trip
    return EpisodeSet(name=name, episodes=tuple(episodes), max_steps=int(max_steps), generation=generation)


def make_protocol_episodes(
    protocol: str,
    trials_per_setup: int | None = None,
    trials_per_world: int | None = None,
    seed: int = 0,
    max_steps: int = MAX_EPISODE_STEPS,
    workers: int = 1,
    setups: Sequence[str] | None = None,
    distractors: int | None = None,
) -> EpisodeSet:
    """:func:`make_episode_set` for a named protocol (see :func:`protocol_setups`), or for only the setups it
    names in ``setups`` (e.g. ``["7.5m-2r", "12.5m-4r"]`` of ``table1``; ValueError for a name the protocol
    lacks). A setup's episodes do not depend on which other setups are made. ``trials_per_setup`` /
    ``trials_per_world`` None: the protocol's (:func:`protocol_trials`: 60 / 10, Table II 30 / 10).
    ``distractors``: targets no robot seeks in every episode (None: the protocol's, Table II 5 (Fig. 4), the
    others 0 (§VII.A: "each robot had a different target object")). The robots' starts and targets do not
    depend on it, so episode sets that differ only in ``distractors`` pair robot-trial by robot-trial."""
    chosen = protocol_setups(protocol)
    if distractors is not None:
        chosen = [dataclasses.replace(s, distractors=distractors) for s in chosen]
    default_setup, default_world = protocol_trials(protocol)
    trials_per_setup = default_setup if trials_per_setup is None else trials_per_setup
    trials_per_world = default_world if trials_per_world is None else trials_per_world
    if setups is not None:
        names = [s.name for s in chosen]
        unknown = [name for name in setups if name not in names]
        if unknown or not setups:
            raise ValueError(
                f"setups {list(setups)!r}: "
                f"expected a non-empty list of setups of protocol {protocol!r}: {names}"
            )
        chosen = [s for s in chosen if s.name in setups]
    return make_episode_set(
        chosen,
        trials_per_setup,
        trials_per_world,
        seed,
        protocol,
        max_steps,
        protocol,
        workers=workers,
    )


def protocol_trials(protocol: str) -> tuple[int, int]:
    """``(trials per setup, trials per world)`` of a protocol: Table II 30 / 10, the others the paper's 60 /
    10. ValueError for an unknown protocol."""
    protocol_setups(protocol)
    return PROTOCOL_TRIALS.get(protocol, (PAPER_TRIALS_PER_SETUP, PAPER_TRIALS_PER_WORLD))


def save_episode_set(episode_set: EpisodeSet, path: str | os.PathLike) -> Path:
    """Write ``episode_set`` as JSON (atomic) with its content hash; returns the path."""
    document = episode_set.content()
    document["content_sha256"] = episode_set.content_hash()
    path = Path(path)
    atomic_write_text(path, json.dumps(document, indent=1, sort_keys=True) + "\n")
    return path


def load_episode_set(path: str | os.PathLike) -> EpisodeSet:
    """Read and verify an episode-set file, or its gzip (``.json.gz``, as the committed records keep them; see
    the module docstring for what is refused)."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"no episode-set file at {str(path)!r}")
    try:
        raw = gzip.decompress(path.read_bytes()) if path.suffix == ".gz" else path.read_bytes()
        document = json.loads(raw.decode("utf-8"))
    except (json.JSONDecodeError, UnicodeDecodeError, gzip.BadGzipFile, EOFError) as error:
        raise ValueError(f"{path} is not a valid episode-set file (not JSON: {error})") from None
    if not isinstance(document, dict) or document.get("format") != FORMAT:
        found = document.get("format") if isinstance(document, dict) else type(document).__name__
        raise ValueError(f"{path} is not an episode-set file: format {found!r}, expected {FORMAT!r}")
    if document.get("version") != FORMAT_VERSION:
        raise ValueError(
            f"{path} has episode-set version {document.get('version')!r}; this navformer_rl reads version "
            f"{FORMAT_VERSION} only (version 1 measured SPL's l on the 8-connected grid, ~5 % too long) - "
            "regenerate it with `navformer evaluate make-episodes`"
        )
    stored_hash = document.get("content_sha256")
    try:
        episode_set = EpisodeSet(
            name=str(document["name"]),
            episodes=tuple(Episode.from_json(e) for e in document["episodes"]),
            max_steps=int(document["max_steps"]),
            generation=dict(document["generation"]),
        )
    except (KeyError, TypeError) as error:
        raise ValueError(f"{path} is missing episode-set field {error}") from None
    if stored_hash != episode_set.content_hash():
        raise ValueError(
            f"{path} is corrupt or was edited: its content hash does not match (stored "
            f"{str(stored_hash)[:12]}..., computed {episode_set.content_hash()[:12]}...)"
        )
    ids = [e.episode_id for e in episode_set.episodes]
    if len(set(ids)) != len(ids):
        raise ValueError(f"{path} has duplicate episode ids")
    return episode_set


# ---------------------------------------------------------------------------------------------- internals
def _canonical(obj: Any) -> str:
    return json.dumps(obj, sort_keys=True, separators=(",", ":"), allow_nan=False)


def _world_config(fields: dict[str, Any]):
    from navformer_rl.envs.world import WorldConfig

    known = {f.name for f in dataclasses.fields(WorldConfig)}
    unknown = sorted(set(fields) - known)
    if unknown:
        raise ValueError(f"episode world config has fields {unknown} that this WorldConfig does not know")
    return WorldConfig(**{k: tuple(v) if isinstance(v, list) else v for k, v in fields.items()})


def _setup_record(setup: Setup) -> dict[str, Any]:
    """A setup's fields for ``generation.setups``; a maze setup's record leaves out its kind, and one without
    distractors their count (such sets keep the content hash they had before these fields existed)."""
    record = dataclasses.asdict(setup)
    if record["kind"] == "maze":
        del record["kind"]
    if record["distractors"] == 0:
        del record["distractors"]
    return record


def _check_distractors(setup: Setup) -> None:
    """ValueError naming the setup unless its ``distractors`` is an integer >= 0 that leaves the target
    catalogue (shapes x colours) enough distinct targets for its robots and distractors."""
    from navformer_rl.constants import TARGET_COLORS, TARGET_SHAPES

    catalogue = len(TARGET_SHAPES) * len(TARGET_COLORS)
    if isinstance(setup.distractors, bool) or not isinstance(setup.distractors, int) or setup.distractors < 0:
        raise ValueError(f"setup {setup.name}: distractors={setup.distractors!r}, expected an integer >= 0")
    if setup.n_robots + setup.distractors > catalogue:
        raise ValueError(
            f"setup {setup.name}: distractors={setup.distractors} with {setup.n_robots} robots needs "
            f"{setup.n_robots + setup.distractors} distinct targets; the catalogue has {catalogue}, so at "
            f"most {catalogue - setup.n_robots} distractors"
        )


def _target_json(target: dict[str, Any]) -> dict[str, Any]:
    """A target object of an episode row, its fields typed (KeyError, TypeError or ValueError if
    malformed)."""
    return {
        "position": [float(v) for v in target["position"]],
        "shape": str(target["shape"]),
        "color": str(target["color"]),
    }


def _jsonable(value: Any) -> Any:
    if isinstance(value, tuple | list):
        return [_jsonable(v) for v in value]
    if isinstance(value, np.generic):
        return value.item()
    return value


def _make_world_episodes(world: tuple[Setup, int, int, tuple[int, ...]]) -> list[Episode]:
    """The episodes of one maze: ``(setup, world_index, seed, trials)`` -> one :class:`Episode` per trial."""
    setup, world_index, seed, trials = world
    base = _make_world(setup, world_index, seed)
    return [_make_episode(setup, base, world_index, trial) for trial in trials]


def _make_world(setup: Setup, world_index: int, seed: int):
    """The world (a ``WorldSpec``: a maze or a furnished kind) of world ``world_index`` of ``setup``."""
    from navformer_rl.envs.robots import get_robot_spec
    from navformer_rl.envs.world import WorldConfig, generate_world

    radius = max(get_robot_spec(style).radius for style in setup.robots)
    config = WorldConfig(size=setup.size, kind=setup.kind, n_robots=setup.n_robots, robot_radius=radius)
    entropy = [seed, round(setup.size * 100), setup.n_robots, world_index]
    if setup.kind != "maze":
        entropy.append(zlib.crc32(setup.kind.encode()))
    world_rng = np.random.default_rng(np.random.SeedSequence(entropy))
    return generate_world(config, int(world_rng.integers(2**31)))


def _make_episode(setup: Setup, base, world_index: int, trial: int) -> Episode:
    """Draw the layout of ``trial`` in the world ``base`` (a ``WorldSpec``): targets, then starts. A furnished
    world's free space is connected for the robots, so its targets may stand in any room (not only in the
    largest open area)."""
    from navformer_rl.envs.occupancy import OccupancyMap
    from navformer_rl.envs.robots import get_robot_spec
    from navformer_rl.envs.world import (
        OCCUPANCY_RESOLUTION,
        TARGET_HALF_EXTENT,
        TargetSpec,
        add_distractor_targets,
        replace_layout,
        sample_free_positions,
        sample_start_poses,
    )

    specs = [get_robot_spec(style) for style in setup.robots]
    config = base.config
    world_seed = base.seed
    rng = np.random.default_rng(np.random.SeedSequence([world_seed, trial, 0xE7A1]))
    pairs = [(s, c) for s in dict.fromkeys(config.target_shapes) for c in dict.fromkeys(config.target_colors)]
    chosen = rng.permutation(len(pairs))[: setup.n_robots]
    wall_map = OccupancyMap.from_shapes(config.size, OCCUPANCY_RESOLUTION, base.walls)
    target_clearance = max(TARGET_HALF_EXTENT.values()) + 2 * config.robot_radius + 0.05
    maze_like = config.kind not in FURNISHED_FOOTPRINTS
    positions = sample_free_positions(
        wall_map, setup.n_robots, target_clearance, 2.0, rng, largest_only=maze_like
    )
    targets = [
        TargetSpec(position=positions[i].astype(np.float32), shape=pairs[k][0], color=pairs[k][1])
        for i, k in enumerate(chosen)
    ]
    # The maze with the new targets as obstacles (its old starts are only placeholders) to draw starts in.
    with_targets = dataclasses.replace(base, targets=targets)
    occupancy = OccupancyMap.from_shapes(
        config.size, OCCUPANCY_RESOLUTION, with_targets.obstacle_boxes, with_targets.obstacle_circles
    )
    starts = sample_start_poses(dataclasses.replace(with_targets, occupancy=occupancy), setup.n_robots, rng)
    world = replace_layout(base, starts=starts, targets=targets)
    # Distractors draw from their own stream: the robots' starts and targets, and the episode seed, are those
    # of the same episode without them. They are obstacles too, so l is measured around them.
    distractor_rng = np.random.default_rng(np.random.SeedSequence([world_seed, trial, 0xD157]))
    world = add_distractor_targets(world, setup.distractors, distractor_rng)
    shortest, to_disc = [], []
    for i, spec in enumerate(specs):
        l_target, l_disc = _shortest_paths(world.occupancy, starts[i, :2], targets[i].position, spec.radius)
        shortest.append(l_target)
        to_disc.append(l_disc)
    if not all(np.isfinite(shortest)):
        raise RuntimeError(f"setup {setup.name} world {world_seed} trial {trial}: a target is unreachable")
    episode_seed = int(rng.integers(2**31))
    return Episode(
        episode_id=f"{setup.name}/w{world_index:02d}t{trial:02d}",
        setup=setup.name,
        size=float(setup.size),
        n_robots=setup.n_robots,
        world_index=world_index,
        trial=trial,
        world_config={k: _jsonable(v) for k, v in dataclasses.asdict(config).items()},
        world_seed=world_seed,
        walls_sha256=walls_digest(base.walls),
        robots=tuple(setup.robots),
        measured=tuple(setup.measured),
        starts=tuple(tuple(round(float(v), 6) for v in s) for s in starts),
        targets=tuple(
            {"position": [round(float(v), 6) for v in t.position], "shape": t.shape, "color": t.color}
            for t in targets
        ),
        shortest_paths=tuple(round(float(v), 6) for v in shortest),
        shortest_paths_to_disc=tuple(round(float(v), 6) for v in to_disc),
        seed=episode_seed,
        distractors=tuple(
            {"position": [round(float(v), 6) for v in t.position], "shape": t.shape, "color": t.color}
            for t in world.distractors
        ),
    )


def _shortest_paths(occupancy, start_xy, target_xy, clearance: float) -> tuple[float, float]:
    """``(l, l_disc)`` in metres from one Dijkstra rooted at the start, on ``occupancy`` inflated by
    ``clearance`` with moves of up to :data:`SHORTEST_PATH_REACH` cells: ``l`` to the free cell nearest the
    target (= ``OccupancyMap.shortest_path_length``, the graph is undirected) and ``l_disc`` to the nearest
    free cell whose centre is within the success radius of the target (or that cell)."""
    field = occupancy.distance_field(start_xy, clearance, reach=SHORTEST_PATH_REACH)
    row, col = occupancy.snap_to_free(target_xy, clearance)
    l_target = float(field[row, col])
    free = np.argwhere(np.isfinite(field))
    centres = occupancy.cell_to_world(free)
    near = np.hypot(centres[:, 0] - target_xy[0], centres[:, 1] - target_xy[1]) <= SUCCESS_RADIUS
    l_disc = min(l_target, float(field[tuple(free[near].T)].min(initial=np.inf)))
    return l_target, l_disc
