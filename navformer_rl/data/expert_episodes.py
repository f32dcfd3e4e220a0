"""One work unit of expert episodes -> the rows of a dataset (paper §V).

* D_e: ``episodes_per_unit`` single-robot exploration episodes, each in its own random maze of
  5-17.5 m (frontier exploration + A* + DWA until the target is seen, then driving to it);
* D_ca: one 12.5 m arena episode with the ego robot and 2-8 others, all driven by NH-ORCA to their own
  targets; every robot that reaches its target gives one trajectory (ending at its success step);
* D_ssl: one world of 5-17.5 m with 4-25 robots; robots are placed at random (re-drawn until
  ``pairs_per_world`` pairs exist), each robot's view o^d is rendered with every robot visible, then the
  robots are hidden and o^s is rendered from the same pose.

Failed expert episodes (target not reached within ``max_steps``, or the expert reports failure) are
dropped and counted; they are never stored. With DAgger (``settings.dagger``: a trained policy in the loop,
:mod:`navformer_rl.data.dagger`) every trajectory the mixture drives is stored, successful or not (its
rewards say which), since the states the policy reaches are the point. Every function here depends on its
settings and unit index alone (seeds from :func:`~navformer_rl.data.collect_settings.unit_seed`). A change
to what they produce is a bump of the matching number in :mod:`navformer_rl.data.versions`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from tensordict import TensorDict

from navformer_rl.constants import SUCCESS_RADIUS
from navformer_rl.data.collect_settings import (
    CollisionAvoidanceSettings,
    DaggerSettings,
    ExplorationSettings,
    SSLSettings,
    mixing_generator,
    noise_generator,
    unit_seed,
)
from navformer_rl.data.schema import TASK_ID, DatasetKind, ssl_rows, trajectory_rows
from navformer_rl.envs.sim import COLLISION_ROBOT

if TYPE_CHECKING:
    from navformer_rl.data.dagger import DaggerMixture
    from navformer_rl.envs.world import WorldSpec

SSL_PLACEMENT = (
    "a world whose drawn robot count does not fit (random placement jams) is retried with one robot fewer "
    "per attempt a >= 1, seeded by item index a of its unit; counts.robots_drawn - counts.robots_total "
    "robots were removed in counts.worlds_with_fewer_robots worlds"
)
"""How :func:`ssl_layouts` fits a world's robots, as recorded in a D_ssl ``metadata.json``."""


@dataclass
class RobotTrajectory:
    """One robot's recorded steps: frames uint8 ``[T, 84, 84, 3]``, actions ``[T, 2]``, collisions ``[T]``,
    poses ``[T, 3]``; ``succeeded`` when it ended within ``SUCCESS_RADIUS`` of its target;
    ``policy_steps``: steps that executed the DAgger policy's action instead of the recorded expert's."""

    frames: list[np.ndarray]
    actions: list[np.ndarray]
    collisions: list[bool]
    poses: list[np.ndarray]
    succeeded: bool = False
    robot_collisions: int = 0
    policy_steps: int = 0

    def kept(self, dagger: bool) -> bool:
        """Whether the dataset stores this trajectory: a success, or with DAgger any non-empty one."""
        return self.succeeded or (dagger and len(self.actions) > 0)

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


def reached_targets(sim, world) -> np.ndarray:
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
    mixture: DaggerMixture | None = None,
) -> list[RobotTrajectory]:
    """Drive every robot of ``sim`` with ``expert`` until each reached its target or ``max_steps``.

    ``expert`` follows ``navformer_rl.experts.policies``: ``act(sim, active) -> float32 [R, 2]`` and a bool
    ``[R]`` ``failed`` flag. At step t the expert gives a_t for the still-active robots and the simulator
    moves them; a robot that ends the step within ``SUCCESS_RADIUS`` of its target finishes its trajectory
    (reward 1 on that step) and stays in place; one the expert flags ``failed`` ends as a failure.

    With ``action_noise`` > 0 the simulator executes ``clip(a_t + N(0, action_noise^2), -1, 1)`` (drawn from
    ``noise_rng``) while a_t stays the recorded label (DART): the data then holds states off the expert's
    own path, each labelled with the expert's correction.

    With ``mixture`` (DAgger, :class:`~navformer_rl.data.dagger.DaggerMixture`) the simulator executes, per
    robot and step, the expert's a_t or the policy's action on the robot's current frame, a_t again the
    recorded label; every robot's trajectory is then kept (:meth:`RobotTrajectory.kept`).

    The stored cameras run after the episode, and only for the kept robots: every robot is put back at its
    pose of step t and o_t is rendered (the scene is then exactly as it was at t), so failed expert episodes
    cost no rendering. ``record=False`` skips them altogether (to time the planners alone). Returns one
    :class:`RobotTrajectory` per robot.
    """
    if action_noise > 0.0 and noise_rng is None:
        raise ValueError(f"action_noise={action_noise} needs a noise_rng (numpy Generator)")
    R = sim.n_robots
    trajs = [RobotTrajectory([], [], [], []) for _ in range(R)]
    active = ~reached_targets(sim, world)
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
        from_policy = np.zeros(R, dtype=bool)
        if mixture is not None:
            executed, from_policy = mixture.executed(sim, actions, active)
        contacts = sim.step(np.where(active[:, None], executed, 0.0), active)
        reached = reached_targets(sim, world)
        failed = np.asarray(expert.failed, dtype=bool).reshape(R)
        for i in np.flatnonzero(active):
            t = trajs[i]
            t.actions.append(np.clip(actions[i], -1.0, 1.0))
            t.collisions.append(bool(contacts.collided[i]))
            t.robot_collisions += int(contacts.kind[i] == COLLISION_ROBOT)
            t.poses.append(poses[i])
            t.policy_steps += int(from_policy[i])
            if reached[i]:
                t.succeeded = True
        active &= ~reached & ~failed
    if record:
        _render_kept(sim, trajs, history, mixture is not None)
    return trajs


def _render_kept(
    sim, trajs: list[RobotTrajectory], history: list[tuple[np.ndarray, np.ndarray]], dagger: bool
) -> None:
    """Fill ``frames`` of the kept trajectories (:meth:`RobotTrajectory.kept`): for each step, restore every
    robot's pose and render the robots that were active then."""
    keep = np.array([t.kept(dagger) for t in trajs])
    for poses, active in history:
        todo = np.flatnonzero(active & keep)
        if len(todo) == 0:
            continue
        sim.set_poses(poses)
        for i in todo:
            trajs[i].frames.append(sim.render(int(i)))


def world_kind_and_size(worlds: str, sizes: tuple[float, ...], rng: np.random.Generator) -> tuple[str, float]:
    """``(kind, size)`` of one collection world of ``worlds`` (a settings' ``worlds``), drawing from ``rng``:
    a maze's size from ``sizes``; ``"furnished"``'s kind uniformly from the three furnished kinds; a
    furnished world at its footprint. (``"arena"`` is not drawn here: its size is the settings'.)"""
    from navformer_rl.envs.furnished import FURNISHED_KINDS, furnished_size

    if worlds == "maze":
        return "maze", float(sizes[int(rng.integers(len(sizes)))])
    kind = FURNISHED_KINDS[int(rng.integers(len(FURNISHED_KINDS)))] if worlds == "furnished" else worlds
    return kind, furnished_size(kind)


def exploration_world(settings: ExplorationSettings, unit: int, k: int):
    """``(world, rng)`` of episode ``k`` of D_e unit ``unit``: a single-robot world of ``settings.worlds``
    (the paper's: a maze of a size drawn from ``settings.world_sizes``) with ``settings.distractors`` targets
    beside the robot's own, or as many fewer as the maze holds (drawn from a stream of their own: the maze,
    the start and the robot's target are those of the plain collection); ``rng`` (numpy Generator) then
    seeds the expert."""
    from navformer_rl.envs.robots import get_robot_spec
    from navformer_rl.envs.world import WorldConfig, add_distractor_targets, generate_world

    seed = unit_seed(settings.seed, DatasetKind.EXPLORATION, unit, k)
    rng = np.random.default_rng(seed)
    kind, size = world_kind_and_size(settings.worlds, settings.world_sizes, rng)
    radius = get_robot_spec(settings.robot).radius
    world = generate_world(WorldConfig(size=size, kind=kind, n_robots=1, robot_radius=radius), seed)
    for n in range(settings.distractors, 0, -1):  # a small maze that cannot hold them all: one fewer
        try:
            stream = np.random.default_rng(np.random.SeedSequence([seed, 0xD157, n]))
            return add_distractor_targets(world, n, stream), rng
        except ValueError:
            continue
    return world, rng


def collision_avoidance_world(settings: CollisionAvoidanceSettings, unit: int):
    """``(world, rng)`` of D_ca unit ``unit``: a world of ``settings.worlds`` (the paper's: the arena) with
    the ego robot plus a drawn number of others."""
    from navformer_rl.envs.robots import get_robot_spec
    from navformer_rl.envs.world import WorldConfig, generate_world

    seed = unit_seed(settings.seed, DatasetKind.COLLISION_AVOIDANCE, unit)
    rng = np.random.default_rng(seed)
    lo, hi = settings.other_robots
    n_robots = 1 + int(rng.integers(lo, hi + 1))
    if settings.worlds == "arena":
        kind, size = "arena", settings.arena_size
    else:
        kind, size = world_kind_and_size(settings.worlds, (), rng)
    radius = get_robot_spec(settings.robot).radius
    config = WorldConfig(size=size, kind=kind, n_robots=n_robots, robot_radius=radius)
    return generate_world(config, seed), rng


def exploration_unit(settings: ExplorationSettings, unit: int, by_item: dict[str, list[int]] | None = None):
    """D_e unit ``unit``: ``(rows, targets, counters)``, one rows TensorDict and one uint8 ``[84, 84, 3]``
    target image per successful episode, and the unit's ``attempted`` / ``failed`` episodes,
    ``robot_steps`` (of every episode) and ``collision_steps`` (of the stored ones). ``by_item``, when
    given, receives each counter's value through each stored trajectory (failures before it included).
    With ``settings.dagger`` every non-empty trajectory is stored, and ``policy_steps`` counts the robot
    steps that executed the policy's action."""
    from navformer_rl.envs.robots import get_robot_spec
    from navformer_rl.envs.sim import Simulator
    from navformer_rl.envs.target_image import render_target_image
    from navformer_rl.experts.policies import ExplorationExpert

    spec = get_robot_spec(settings.robot)
    dagger = settings.dagger is not None
    rows, targets = [], []
    counters = {"attempted": 0, "failed": 0, "collision_steps": 0, "robot_steps": 0}
    if dagger:
        counters["policy_steps"] = 0
    for k in range(settings.episodes_per_unit):
        world, rng = exploration_world(settings, unit, k)
        sim = Simulator(world, spec)
        try:
            expert = ExplorationExpert()
            expert.reset(world, sim, rng)
            noise = noise_generator(settings.seed, DatasetKind.EXPLORATION, unit, k)
            mixture = _mixture(settings.dagger, world, DatasetKind.EXPLORATION, settings.seed, unit, k)
            (traj,) = run_episode(
                world, sim, expert, settings.max_steps, True, settings.action_noise, noise, mixture
            )
        finally:
            sim.close()
        counters["attempted"] += 1
        counters["robot_steps"] += len(traj.actions)
        if dagger:
            counters["policy_steps"] += traj.policy_steps
        if not traj.succeeded:
            counters["failed"] += 1
        if not traj.kept(dagger):
            continue
        counters["collision_steps"] += int(np.sum(traj.collisions))
        target = world.targets[0]
        rows.append(traj.rows(TASK_ID[DatasetKind.EXPLORATION], len(targets), target.position))
        targets.append(render_target_image(target.shape, target.color))
        _snapshot(by_item, counters, tuple(counters))
    return rows, targets, counters


def _mixture(
    dagger: DaggerSettings | None, world, kind: DatasetKind, seed: int, unit: int, index: int = 0
) -> DaggerMixture | None:
    """The DAgger mixture of item ``index`` of unit ``unit`` (None without ``dagger``)."""
    if dagger is None:
        return None
    from navformer_rl.data.dagger import dagger_mixture

    return dagger_mixture(dagger, world, mixing_generator(seed, kind, unit, index))


def _snapshot(by_item: dict[str, list[int]] | None, counters: dict[str, int], names: tuple[str, ...]) -> None:
    """Append the current value of each counter of ``names`` to ``by_item`` (when given): called once per
    stored item, so ``by_item[name][k]`` is the counter through item ``k`` (``write_shard``'s
    ``counters_by_item``)."""
    if by_item is not None:
        for name in names:
            by_item.setdefault(name, []).append(counters[name])


def collision_avoidance_unit(
    settings: CollisionAvoidanceSettings, unit: int, by_item: dict[str, list[int]] | None = None
):
    """D_ca unit ``unit`` (one arena episode): ``(rows, targets, counters)``, one trajectory per robot that
    reached its target, in robot order. ``by_item``, when given, receives ``attempted``, ``failed``,
    ``robot_steps`` and ``collision_steps`` through each stored trajectory's robot (the robots before it
    included); ``episodes`` and ``robot_robot_collision_episodes`` count the whole episode. With
    ``settings.dagger`` every robot's non-empty trajectory is stored, and ``policy_steps`` counts the robot
    steps that executed the policy's action."""
    from navformer_rl.envs.robots import get_robot_spec
    from navformer_rl.envs.sim import Simulator
    from navformer_rl.envs.target_image import render_target_image
    from navformer_rl.experts.policies import NHORCAExpert

    spec = get_robot_spec(settings.robot)
    dagger = settings.dagger is not None
    world, rng = collision_avoidance_world(settings, unit)
    sim = Simulator(world, spec)
    try:
        expert = NHORCAExpert()
        expert.reset(world, sim, rng)
        noise = noise_generator(settings.seed, DatasetKind.COLLISION_AVOIDANCE, unit)
        mixture = _mixture(settings.dagger, world, DatasetKind.COLLISION_AVOIDANCE, settings.seed, unit)
        trajs = run_episode(
            world, sim, expert, settings.max_steps, True, settings.action_noise, noise, mixture
        )
    finally:
        sim.close()
    rows, targets = [], []
    through = {"attempted": 0, "failed": 0, "collision_steps": 0, "robot_steps": 0}  # robots 0..i
    if dagger:
        through["policy_steps"] = 0
    for i, traj in enumerate(trajs):
        through["attempted"] += 1
        through["robot_steps"] += len(traj.actions)
        if dagger:
            through["policy_steps"] += traj.policy_steps
        if not traj.succeeded:
            through["failed"] += 1
        if not traj.kept(dagger):
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
    collections stay byte-identical), and a unit whose first attempt fits draws no other seed.
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
        f"D_ssl unit {unit}: cannot place even one robot in its {world.size} m {world.kind} "
        f"(drawn {n_drawn} robots; last error: {last})"
    )


def ssl_world(settings: SSLSettings, unit: int) -> tuple[WorldSpec, int, np.random.Generator]:
    """``(world, n_drawn, rng)`` of D_ssl unit ``unit``: a world of ``settings.worlds`` (the paper's: a maze
    of a size drawn from ``settings.world_sizes``), the robot count drawn from ``settings.robots`` (before
    :func:`ssl_layouts` fits it to the maze) and the unit's numpy Generator, which then places the robots."""
    from navformer_rl.envs.robots import get_robot_spec
    from navformer_rl.envs.world import WorldConfig, generate_world

    seed = unit_seed(settings.seed, DatasetKind.SSL, unit)
    rng = np.random.default_rng(seed)
    kind, size = world_kind_and_size(settings.worlds, settings.world_sizes, rng)
    lo, hi = settings.robots
    n_drawn = int(rng.integers(lo, hi + 1))
    radius = get_robot_spec(settings.robot).radius
    world = generate_world(WorldConfig(size=size, kind=kind, n_robots=1, robot_radius=radius), seed)
    return world, n_drawn, rng


def ssl_unit(
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
