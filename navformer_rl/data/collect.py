"""Collection of D_e, D_ca and D_ssl (paper §V): parallel, resumable, sharded.

Each dataset is a sequence of deterministic **work units** (unit ``u`` is seeded from ``(seed, kind, u)``):

* D_e: ``episodes_per_unit`` single-robot exploration episodes, each in its own random maze of
  5-17.5 m (frontier exploration + A* + DWA until the target is seen, then driving to it);
* D_ca: one 12.5 m arena episode with the ego robot and 2-8 others, all driven by NH-ORCA to their own
  targets; every robot that reaches its target gives one trajectory (ending at its success step);
* D_ssl: one world of 5-17.5 m with 4-25 robots; robots are placed at random (re-drawn until
  ``pairs_per_world`` pairs exist), each robot's view o^d is rendered with every robot visible, then the
  robots are hidden and o^s is rendered from the same pose.

Failed expert episodes (target not reached within ``max_steps``, or the expert reports failure) are
dropped and counted in ``metadata.json``; they are never stored. Units run in a ``spawn`` process pool (one
pybullet client per process); each worker writes its own shard atomically. The finished dataset is the
first ``n`` items of units 0, 1, 2, ... (see :mod:`navformer_rl.data.writer`), so it is identical whatever
the number of workers and however often collection was interrupted and resumed.
"""

from __future__ import annotations

import dataclasses
import os
import time
import warnings
from collections.abc import Callable
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import torch
from tensordict import TensorDict

from navformer_rl.checks import check_number
from navformer_rl.constants import MAX_EPISODE_STEPS, SUCCESS_RADIUS
from navformer_rl.data.schema import TASK_ID, DatasetKind, ssl_rows, trajectory_rows
from navformer_rl.data.writer import CODE_KEY, DatasetWriter, folder_lock, write_shard
from navformer_rl.envs.sim import COLLISION_ROBOT

if TYPE_CHECKING:
    from navformer_rl.envs.world import WorldSpec

MAZE_SIZES = (5.0, 7.5, 10.0, 12.5, 15.0, 17.5)
"""World sides for D_e and D_ssl: the paper's 5-17.5 m range on the 2.5 m maze-cell grid."""

_KIND_CODE = {DatasetKind.EXPLORATION: 1, DatasetKind.COLLISION_AVOIDANCE: 2, DatasetKind.SSL: 3}


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


SCALES: dict[str, dict[DatasetKind, Any]] = {
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


def settings_for(kind: DatasetKind | str, scale: str = "small", seed: int = 0, **overrides) -> Any:
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
    return dataclasses.replace(base, seed=seed, **overrides)


def noise_generator(seed: int, kind: DatasetKind, unit: int, index: int = 0) -> np.random.Generator:
    """The generator of the action noise of item ``index`` of unit ``unit`` (apart from the world's and the
    expert's streams, so noise 0 leaves every other draw as it was)."""
    return np.random.default_rng(np.random.SeedSequence([unit_seed(seed, kind, unit, index), 0xDA27]))


def unit_seed(seed: int, kind: DatasetKind, unit: int, index: int = 0) -> int:
    """Deterministic 32-bit seed of item ``index`` of work unit ``unit``."""
    ss = np.random.SeedSequence(entropy=int(seed), spawn_key=(_KIND_CODE[kind], int(unit), int(index)))
    return int(ss.generate_state(1)[0])


# ----------------------------------------------------------------------------------------- episodes
@dataclass
class RobotTrajectory:
    """One robot's recorded steps: frames uint8 ``[T, 84, 84, 3]``, actions ``[T, 2]``, collisions ``[T]``,
    poses ``[T, 3]``; ``succeeded`` when it ended within ``SUCCESS_RADIUS`` of its target."""

    frames: list[np.ndarray]
    actions: list[np.ndarray]
    collisions: list[bool]
    poses: list[np.ndarray]
    succeeded: bool = False
    robot_collisions: int = 0

    def rows(self, task: int, episode: int, target_position: np.ndarray) -> TensorDict:
        """The trajectory in the schema (``target_id == episode``: one target image per trajectory)."""
        T = len(self.actions)
        reward = np.zeros(T, np.float32)
        reward[-1] = 1.0 if self.succeeded else 0.0
        return trajectory_rows(
            pixels=np.stack(self.frames),
            action=np.stack(self.actions),
            reward=reward,
            collision=np.asarray(self.collisions, dtype=bool),
            pose=np.stack(self.poses),
            target_position=target_position,
            succeeded=self.succeeded,
            task=task,
            episode=episode,
            target_id=episode,
        )


def _reached(sim, world) -> np.ndarray:
    """bool ``[R]``: each robot within ``SUCCESS_RADIUS`` of its own target."""
    d = np.hypot(*(sim.poses[:, :2] - world.target_positions[: sim.n_robots]).T)
    return d <= SUCCESS_RADIUS


def run_episode(
    world,
    sim,
    expert,
    max_steps: int,
    record: bool = True,
    action_noise: float = 0.0,
    noise_rng: np.random.Generator | None = None,
) -> list[RobotTrajectory]:
    """Drive every robot of ``sim`` with ``expert`` until each reached its target or ``max_steps``.

    ``expert`` follows ``navformer_rl.experts.policies``: ``act(sim, active) -> float32 [R, 2]`` and a bool
    ``[R]`` ``failed`` flag. At step t the expert gives a_t for the still-active robots and the simulator
    moves them; a robot that ends the step within ``SUCCESS_RADIUS`` of its target finishes its trajectory
    (reward 1 on that step) and stays in place; one the expert flags ``failed`` ends as a failure.

    With ``action_noise`` > 0 the simulator executes ``clip(a_t + N(0, action_noise^2), -1, 1)`` (drawn from
    ``noise_rng``) while a_t stays the recorded label (DART): the data then holds states off the expert's
    own path, each labelled with the expert's correction.

    The cameras run after the episode, and only for robots that succeeded: every robot is put back at its
    pose of step t and o_t is rendered (the scene is then exactly as it was at t), so failed episodes cost no
    rendering. ``record=False`` skips the cameras altogether (to time the planners alone). Returns one
    :class:`RobotTrajectory` per robot.
    """
    if action_noise > 0.0 and noise_rng is None:
        raise ValueError(f"action_noise={action_noise} needs a noise_rng (numpy Generator)")
    R = sim.n_robots
    trajs = [RobotTrajectory([], [], [], []) for _ in range(R)]
    active = ~_reached(sim, world)
    history: list[tuple[np.ndarray, np.ndarray]] = []  # (poses float32 [R, 3] before step t, active [R])
    for _ in range(max_steps):
        if not active.any():
            break
        poses = sim.poses
        history.append((poses, active.copy()))
        actions = np.asarray(expert.act(sim, active), dtype=np.float32).reshape(R, 2)
        executed = actions
        if action_noise > 0.0:
            noise = noise_rng.normal(0.0, action_noise, size=(R, 2)).astype(np.float32)
            executed = np.clip(actions + noise, -1.0, 1.0)
        contacts = sim.step(np.where(active[:, None], executed, 0.0), active)
        reached = _reached(sim, world)
        failed = np.asarray(expert.failed, dtype=bool).reshape(R)
        for i in np.flatnonzero(active):
            t = trajs[i]
            t.actions.append(np.clip(actions[i], -1.0, 1.0))
            t.collisions.append(bool(contacts.collided[i]))
            t.robot_collisions += int(contacts.kind[i] == COLLISION_ROBOT)
            t.poses.append(poses[i])
            if reached[i]:
                t.succeeded = True
        active &= ~reached & ~failed
    if record:
        _render_successes(sim, trajs, history)
    return trajs


def _render_successes(
    sim, trajs: list[RobotTrajectory], history: list[tuple[np.ndarray, np.ndarray]]
) -> None:
    """Fill ``frames`` of the successful trajectories: for each step, restore every robot's pose and render
    the robots that were active then."""
    keep = np.array([t.succeeded for t in trajs])
    for poses, active in history:
        todo = np.flatnonzero(active & keep)
        if len(todo) == 0:
            continue
        sim.set_poses(poses)
        for i in todo:
            trajs[i].frames.append(sim.render(int(i)))


# ------------------------------------------------------------------------------------------- units
def exploration_world(settings: ExplorationSettings, unit: int, k: int):
    """``(world, rng)`` of episode ``k`` of D_e unit ``unit``: a single-robot maze of a size drawn from
    ``settings.world_sizes``; ``rng`` (numpy Generator) then seeds the expert."""
    from navformer_rl.envs.robots import get_robot_spec
    from navformer_rl.envs.world import WorldConfig, generate_world

    seed = unit_seed(settings.seed, DatasetKind.EXPLORATION, unit, k)
    rng = np.random.default_rng(seed)
    size = float(settings.world_sizes[int(rng.integers(len(settings.world_sizes)))])
    radius = get_robot_spec(settings.robot).radius
    return generate_world(WorldConfig(size=size, kind="maze", n_robots=1, robot_radius=radius), seed), rng


def collision_avoidance_world(settings: CollisionAvoidanceSettings, unit: int):
    """``(world, rng)`` of D_ca unit ``unit``: the arena with the ego robot plus a drawn number of others."""
    from navformer_rl.envs.robots import get_robot_spec
    from navformer_rl.envs.world import WorldConfig, generate_world

    seed = unit_seed(settings.seed, DatasetKind.COLLISION_AVOIDANCE, unit)
    rng = np.random.default_rng(seed)
    lo, hi = settings.other_robots
    n_robots = 1 + int(rng.integers(lo, hi + 1))
    radius = get_robot_spec(settings.robot).radius
    config = WorldConfig(size=settings.arena_size, kind="arena", n_robots=n_robots, robot_radius=radius)
    return generate_world(config, seed), rng


def _exploration_unit(settings: ExplorationSettings, unit: int, by_item: dict[str, list[int]] | None = None):
    """D_e unit ``unit``: ``(rows, targets, counters)``, one rows TensorDict and one uint8 ``[84, 84, 3]``
    target image per successful episode, and the unit's ``attempted`` / ``failed`` episodes,
    ``robot_steps`` (of every episode) and ``collision_steps`` (of the stored ones). ``by_item``, when
    given, receives each counter's value through each stored trajectory (failures before it included)."""
    from navformer_rl.envs.robots import get_robot_spec
    from navformer_rl.envs.sim import Simulator
    from navformer_rl.envs.target_image import render_target_image
    from navformer_rl.experts.policies import ExplorationExpert

    spec = get_robot_spec(settings.robot)
    rows, targets = [], []
    counters = {"attempted": 0, "failed": 0, "collision_steps": 0, "robot_steps": 0}
    for k in range(settings.episodes_per_unit):
        world, rng = exploration_world(settings, unit, k)
        sim = Simulator(world, spec)
        try:
            expert = ExplorationExpert()
            expert.reset(world, sim, rng)
            noise = noise_generator(settings.seed, DatasetKind.EXPLORATION, unit, k)
            (traj,) = run_episode(world, sim, expert, settings.max_steps, True, settings.action_noise, noise)
        finally:
            sim.close()
        counters["attempted"] += 1
        counters["robot_steps"] += len(traj.actions)
        if not traj.succeeded:
            counters["failed"] += 1
            continue
        counters["collision_steps"] += int(np.sum(traj.collisions))
        target = world.targets[0]
        rows.append(traj.rows(TASK_ID[DatasetKind.EXPLORATION], len(targets), target.position))
        targets.append(render_target_image(target.shape, target.color))
        _snapshot(by_item, counters, ("attempted", "failed", "collision_steps", "robot_steps"))
    return rows, targets, counters


def _snapshot(by_item: dict[str, list[int]] | None, counters: dict[str, int], names: tuple[str, ...]) -> None:
    """Append the current value of each counter of ``names`` to ``by_item`` (when given): called once per
    stored item, so ``by_item[name][k]`` is the counter through item ``k`` (``write_shard``'s
    ``counters_by_item``)."""
    if by_item is not None:
        for name in names:
            by_item.setdefault(name, []).append(counters[name])


def _collision_avoidance_unit(
    settings: CollisionAvoidanceSettings, unit: int, by_item: dict[str, list[int]] | None = None
):
    """D_ca unit ``unit`` (one arena episode): ``(rows, targets, counters)``, one trajectory per robot that
    reached its target, in robot order. ``by_item``, when given, receives ``attempted``, ``failed``,
    ``robot_steps`` and ``collision_steps`` through each stored trajectory's robot (the robots before it
    included); ``episodes`` and ``robot_robot_collision_episodes`` count the whole episode."""
    from navformer_rl.envs.robots import get_robot_spec
    from navformer_rl.envs.sim import Simulator
    from navformer_rl.envs.target_image import render_target_image
    from navformer_rl.experts.policies import NHORCAExpert

    spec = get_robot_spec(settings.robot)
    world, rng = collision_avoidance_world(settings, unit)
    sim = Simulator(world, spec)
    try:
        expert = NHORCAExpert()
        expert.reset(world, sim, rng)
        noise = noise_generator(settings.seed, DatasetKind.COLLISION_AVOIDANCE, unit)
        trajs = run_episode(world, sim, expert, settings.max_steps, True, settings.action_noise, noise)
    finally:
        sim.close()
    rows, targets = [], []
    through = {"attempted": 0, "failed": 0, "collision_steps": 0, "robot_steps": 0}  # robots 0..i
    for i, traj in enumerate(trajs):
        through["attempted"] += 1
        through["robot_steps"] += len(traj.actions)
        if not traj.succeeded:
            through["failed"] += 1
            continue
        through["collision_steps"] += int(np.sum(traj.collisions))
        target = world.targets[i]
        rows.append(traj.rows(TASK_ID[DatasetKind.COLLISION_AVOIDANCE], len(targets), target.position))
        targets.append(render_target_image(target.shape, target.color))
        _snapshot(by_item, through, tuple(through))
    counters = {
        "episodes": 1,
        "robot_robot_collision_episodes": int(any(t.robot_collisions for t in trajs)),
        **through,
    }
    return rows, targets, counters


def ssl_layouts(
    settings: SSLSettings, unit: int, world: WorldSpec, n_drawn: int, rng: np.random.Generator
) -> list[np.ndarray]:
    """The robot layouts of D_ssl unit ``unit``: ``ceil(pairs_per_world / n)`` float32 ``[n, 3]`` poses.

    Attempt 0 places the ``n_drawn`` robots of the unit with the unit's ``rng`` (as drawn from the paper's
    4-25 range). Random placement jams when a small maze is nearly full (a 5 m maze holds about 20-23
    robots), and ``sample_start_poses`` then raises. Attempt ``a >= 1`` therefore places ``n_drawn - a``
    robots with ``default_rng(unit_seed(seed, ssl, unit, a))``, until every layout fits. So the robot count
    stays as close to the drawn one as placement allows, the result depends on the unit alone (resumed
    collections stay byte-identical), and units whose first attempt fits are unchanged.
    """
    from navformer_rl.envs.world import sample_start_poses

    last: ValueError | None = None
    for attempt in range(n_drawn):
        n = n_drawn - attempt
        if attempt:
            rng = np.random.default_rng(unit_seed(settings.seed, DatasetKind.SSL, unit, attempt))
        n_layouts = -(-settings.pairs_per_world // n)
        try:
            return [sample_start_poses(world, n, rng, min_target_distance=0.0) for _ in range(n_layouts)]
        except ValueError as err:
            last = err
    raise ValueError(
        f"D_ssl unit {unit}: cannot place even one robot in its {world.size} m maze "
        f"(drawn {n_drawn} robots; last error: {last})"
    )


def ssl_world(settings: SSLSettings, unit: int) -> tuple[WorldSpec, int, np.random.Generator]:
    """``(world, n_drawn, rng)`` of D_ssl unit ``unit``: a maze of a size drawn from
    ``settings.world_sizes``, the robot count drawn from ``settings.robots`` (before :func:`ssl_layouts`
    fits it to the maze) and the unit's numpy Generator, which then places the robots."""
    from navformer_rl.envs.robots import get_robot_spec
    from navformer_rl.envs.world import WorldConfig, generate_world

    seed = unit_seed(settings.seed, DatasetKind.SSL, unit)
    rng = np.random.default_rng(seed)
    size = float(settings.world_sizes[int(rng.integers(len(settings.world_sizes)))])
    lo, hi = settings.robots
    n_drawn = int(rng.integers(lo, hi + 1))
    radius = get_robot_spec(settings.robot).radius
    world = generate_world(WorldConfig(size=size, kind="maze", n_robots=1, robot_radius=radius), seed)
    return world, n_drawn, rng


def _ssl_unit(
    settings: SSLSettings, unit: int, by_item: dict[str, list[int]] | None = None
) -> tuple[TensorDict, dict[str, int]]:
    """D_ssl unit ``unit``: ``pairs_per_world`` rows (``pixels_static`` / ``pixels_dynamic`` uint8
    ``[84, 84, 3]``, ``world``, ``pose`` ``[3]``) and its counters. ``by_item``, when given, receives
    ``pairs_with_visible_robot`` through each pair; the other counters describe the whole world."""
    from navformer_rl.envs.robots import get_robot_spec
    from navformer_rl.envs.sim import Simulator

    spec = get_robot_spec(settings.robot)
    world, n_drawn, rng = ssl_world(settings, unit)
    layouts = ssl_layouts(settings, unit, world, n_drawn, rng)
    n_robots = len(layouts[0])
    statics, dynamics, poses = [], [], []
    sim = Simulator(world, [spec] * n_robots, poses=layouts[0])
    try:
        for k, layout in enumerate(layouts):
            if k:
                sim.set_poses(layout)
            take = min(n_robots, settings.pairs_per_world - len(poses))
            for i in range(n_robots):
                sim.set_robot_visible(i, True)
            dynamics.extend(sim.render(i) for i in range(take))  # o^d: every robot visible
            for i in range(n_robots):
                sim.set_robot_visible(i, False)
            # o^s from the same poses: the cameras sit outside their own bodies, so hiding every robot
            # removes exactly the other (dynamic) robots from each view
            statics.extend(sim.render_pose(layout[i], spec) for i in range(take))
            poses.extend(layout[:take])
    finally:
        sim.close()
    statics, dynamics = np.stack(statics), np.stack(dynamics)
    rows = ssl_rows(pixels_static=statics, pixels_dynamic=dynamics, world=unit, pose=np.stack(poses))
    shows_robot = (statics != dynamics).reshape(len(statics), -1).any(1)
    visible = int(shows_robot.sum())
    if by_item is not None:
        by_item["pairs_with_visible_robot"] = np.cumsum(shows_robot).tolist()
    return rows, {
        "worlds": 1,
        "layouts": len(layouts),
        "robots_total": n_robots,
        "robots_drawn": n_drawn,
        "worlds_with_fewer_robots": int(n_robots < n_drawn),
        "pairs_with_visible_robot": visible,
    }


def run_unit(root: str, kind: str, settings: Any, unit: int) -> dict[str, int]:
    """Collect work unit ``unit`` and write its shard under ``root`` (runs inside a worker process)."""
    torch.set_num_threads(1)
    kind = DatasetKind.parse(kind)
    by_item: dict[str, list[int]] = {}
    if kind is DatasetKind.SSL:
        rows, counters = _ssl_unit(settings, unit, by_item)
        write_shard(root, kind, unit, rows, None, counters, by_item)
        return {"items": int(rows.shape[0]), "rows": int(rows.shape[0]), **counters}
    make = _exploration_unit if kind is DatasetKind.EXPLORATION else _collision_avoidance_unit
    rows, targets, counters = make(settings, unit, by_item)
    td = torch.cat(rows) if rows else None
    tgt = torch.from_numpy(np.stack(targets)) if targets else None
    write_shard(root, kind, unit, td, tgt, counters, by_item)
    return {"items": len(targets), "rows": 0 if td is None else int(td.shape[0]), **counters}


# ------------------------------------------------------------------------------------------ driver
def _target_count(kind: DatasetKind, settings: Any) -> int:
    if kind is DatasetKind.SSL:
        return settings.n_worlds * settings.pairs_per_world
    return settings.n_trajectories


def collect(
    kind: DatasetKind | str,
    out: str | Path,
    settings: Any,
    workers: int = 1,
    progress: bool = True,
    unit_fn: Callable[[str, str, Any, int], dict[str, int]] = run_unit,
) -> Path:
    """Collect (or resume, or just finish) the dataset ``kind`` into ``out``; returns ``out``.

    ``workers`` processes (``spawn``, at most 2 per CPU) run work units; ``workers=1`` runs them in this
    process. Rerunning
    the same call after an interruption continues where it stopped and ends with the same bytes. The
    folder is locked meanwhile (:func:`~navformer_rl.data.writer.folder_lock`): a second collection into
    it raises :class:`~navformer_rl.durable.FolderLockedError` instead of deleting the first one's
    shards in progress.
    """
    kind = DatasetKind.parse(kind)
    if workers < 1:
        raise ValueError(f"workers must be >= 1, got {workers}")
    most = 2 * (os.cpu_count() or 1)  # pybullet workers are CPU-bound: more than this only adds overhead
    if workers > most:
        warnings.warn(f"workers={workers} > 2 x {os.cpu_count()} CPUs: using {most}", stacklevel=2)
        workers = most
    with folder_lock(out):
        return _collect_locked(kind, out, settings, workers, progress, unit_fn)


def _collect_locked(
    kind: DatasetKind,
    out: str | Path,
    settings: Any,
    workers: int,
    progress: bool,
    unit_fn: Callable[[str, str, Any, int], dict[str, int]],
) -> Path:
    """The body of :func:`collect`, run while holding the folder lock."""
    settings_dict = {"kind": kind.value, **dataclasses.asdict(settings), CODE_KEY: code_fingerprint()}
    target = _target_count(kind, settings)
    writer = DatasetWriter(out, kind, settings_dict, target_count=target)
    if writer.is_complete:
        return writer.finalize()
    items: dict[int, int] = {}

    def covered() -> int:
        total, u = 0, 0
        while u in items and total < target:
            total += items[u]
            u += 1
        return total

    unit = 0
    for done in writer.completed_units():  # checked: a damaged shard is a ValueError saying what to do
        items[done] = writer.check_shard(done)["items"]
    bar = _progress_bar(kind, target, progress)
    bar.update(min(covered(), target))
    pool = (
        ProcessPoolExecutor(
            max_workers=workers, mp_context=_spawn(), initializer=_exit_with_parent, initargs=(os.getpid(),)
        )
        if workers > 1
        else None
    )
    pending: dict[Future, int] = {}
    interrupted = False
    try:
        while covered() < target:
            # keep 2 units per worker in flight, in unit order, skipping finished ones
            while len(pending) < 2 * workers:
                while unit in items:
                    unit += 1
                fills_gap = unit < max(items, default=-1)
                if not fills_gap and _enough_in_flight(items, pending, target):
                    break
                if pool is None:
                    _record(items, unit, unit_fn(str(out), kind.value, settings, unit), bar, covered)
                else:
                    pending[pool.submit(unit_fn, str(out), kind.value, settings, unit)] = unit
                unit += 1
                if pool is None:
                    break
            if pool is not None and pending:
                finished, _ = wait(list(pending), return_when=FIRST_COMPLETED)
                for fut in finished:
                    _record(items, pending.pop(fut), fut.result(), bar, covered)
    except KeyboardInterrupt:
        interrupted = True
        raise
    finally:
        if pool is not None:
            for fut in pending:
                fut.cancel()
            if interrupted:  # units in flight are lost anyway: their shards are temp folders until renamed
                _terminate_workers(pool)
            pool.shutdown(wait=True, cancel_futures=True)
        bar.close()
    extra: dict[str, Any] = {"seeds": {"base": settings.seed, "derivation": _SEED_DOC}}
    if kind is DatasetKind.SSL:
        extra["robot_placement"] = _SSL_PLACEMENT_DOC
    return writer.finalize(extra_metadata=extra)


_SEED_DOC = (
    "item k of unit u uses SeedSequence(entropy=seed, spawn_key=(kind_code, u, k)).generate_state(1)[0]"
)
_SSL_PLACEMENT_DOC = (
    "a world whose drawn robot count does not fit (random placement jams) is retried with one robot fewer "
    "per attempt a >= 1, seeded by item index a of its unit; counts.robots_drawn - counts.robots_total "
    "robots were removed in counts.worlds_with_fewer_robots worlds"
)


FINGERPRINT_MODULES = ("data/collect.py", "data/schema.py", "constants.py", "checks.py")
"""Package modules besides ``envs/*.py`` and ``experts/*.py`` whose source determines the data: this
module, the schema, the protocol constants (``SUCCESS_RADIUS``, ``CONTROL_DT``, ``IMAGE_SIZE``,
``TARGET_SHAPES`` / ``TARGET_COLORS``, ...) and the setting checks that convert the values the worlds are
built from. The other package modules this code imports only move bytes or draw (``durable``, ``mp4``,
``data/writer``, whose shard format ``stats.json`` checks itself, and ``__init__``'s version string)."""


def fingerprint_files(package: Path | None = None) -> list[Path]:
    """The files :func:`code_fingerprint` hashes, under the package folder ``package`` (default: this
    installed package): ``envs/*.py``, ``experts/*.py`` and :data:`FINGERPRINT_MODULES`."""
    package = Path(__file__).resolve().parents[1] if package is None else Path(package)
    files = sorted([*package.glob("envs/*.py"), *package.glob("experts/*.py")])
    return files + [package / name for name in FINGERPRINT_MODULES]


def code_fingerprint(package: Path | None = None) -> str:
    """sha256 of the source that determines the data (:func:`fingerprint_files`: ``envs/``, ``experts/``,
    this module, the schema, ``constants.py`` and ``checks.py``), of this package or of the package folder
    ``package``.

    Stored in the settings, so resuming with changed simulator, expert or constants code is refused
    instead of silently mixing two versions of the data in one dataset."""
    import hashlib

    package = Path(__file__).resolve().parents[1] if package is None else Path(package)
    files = fingerprint_files(package)
    digest = hashlib.sha256()
    for file in files:
        digest.update(file.relative_to(package).as_posix().encode())
        digest.update(file.read_bytes())
    return digest.hexdigest()


def _enough_in_flight(items: dict[int, int], pending: dict[Future, int], target: int) -> bool:
    """True when the units finished or running are expected to cover ``target`` items (mean yield, 5 %
    margin); units below the highest finished one are always scheduled (gaps left by an interruption)."""
    if not items:
        return False
    mean = max(sum(items.values()) / len(items), 1e-3)
    return sum(items.values()) + mean * len(pending) >= target * 1.05 + mean


def _record(items: dict[int, int], unit: int, result: dict[str, int], bar, covered) -> None:
    items[unit] = int(result["items"])
    bar.n = min(covered(), bar.total)
    bar.set_postfix(units=len(items), rows=result.get("rows", 0), refresh=False)
    bar.refresh()


def _exit_with_parent(parent_pid: int) -> None:
    """Worker initializer: end this worker when the collecting process dies (e.g. SIGKILL), so no orphan
    keeps running; a shard it was writing stays a temp folder that the next run deletes. Ctrl-C (SIGINT,
    sent to the whole process group) is left to the parent, which stops the workers itself: a worker
    interrupted inside the pool's machinery could otherwise hang the parent's shutdown."""
    import signal
    import threading

    signal.signal(signal.SIGINT, signal.SIG_IGN)

    def watch() -> None:
        while os.getppid() == parent_pid:
            time.sleep(1.0)
        os._exit(1)

    threading.Thread(target=watch, daemon=True).start()


def _terminate_workers(pool: ProcessPoolExecutor) -> None:
    """Stop every worker process of ``pool`` now (on Ctrl-C), instead of waiting for its unit to end."""
    for process in list((getattr(pool, "_processes", None) or {}).values()):
        process.terminate()


def _spawn():
    import multiprocessing

    return multiprocessing.get_context("spawn")


def _progress_bar(kind: DatasetKind, total: int, enabled: bool):
    from tqdm.auto import tqdm

    unit = "pairs" if kind is DatasetKind.SSL else "traj"
    return tqdm(total=total, desc=f"collect {kind.value}", unit=unit, disable=not enabled, dynamic_ncols=True)


def collect_exploration(out: str | Path, settings: ExplorationSettings | None = None, **kw) -> Path:
    """D_e into ``out`` (see :func:`collect`)."""
    return collect(DatasetKind.EXPLORATION, out, settings or ExplorationSettings(), **kw)


def collect_collision_avoidance(
    out: str | Path, settings: CollisionAvoidanceSettings | None = None, **kw
) -> Path:
    """D_ca into ``out`` (see :func:`collect`)."""
    return collect(DatasetKind.COLLISION_AVOIDANCE, out, settings or CollisionAvoidanceSettings(), **kw)


def collect_ssl_pairs(out: str | Path, settings: SSLSettings | None = None, **kw) -> Path:
    """D_ssl into ``out`` (see :func:`collect`)."""
    return collect(DatasetKind.SSL, out, settings or SSLSettings(), **kw)


def collect_all(
    out: str | Path, scale: str = "small", seed: int = 0, workers: int = 1, progress: bool = True
) -> dict[str, Path]:
    """The three datasets under ``out/{e,ca,ssl}`` at ``scale``."""
    out = Path(out)
    return {
        kind.value: collect(
            kind, out / kind.value, settings_for(kind, scale, seed), workers=workers, progress=progress
        )
        for kind in DatasetKind
    }


def default_workers() -> int:
    """All cores this process may use."""
    return max(1, len(os.sched_getaffinity(0)))
