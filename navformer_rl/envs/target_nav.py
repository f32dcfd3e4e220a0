"""gymnasium env ``navformer_rl/TargetNav-v0``: one camera robot looks for its target among moving robots.

Paper §III/§VII.A: robot 0 gets its 84x84 RGB camera image and the target image; reward 1 when it comes
within 1.5 m of its target (then the episode terminates); truncation at 500 steps of 0.2 s. Robots
1..R-1 are dynamic obstacles driven by a pluggable :class:`ObstaclePolicy`. Privileged state (poses,
targets, collisions, shortest path) is in ``info`` only.
"""

from __future__ import annotations

import copy
import dataclasses
from typing import Any

import cv2
import gymnasium as gym
import numpy as np

from navformer_rl.constants import IMAGE_SIZE, MAX_EPISODE_STEPS, SUCCESS_RADIUS
from navformer_rl.envs.obstacle_policy import GoalSeekingPolicy, ObstaclePolicy
from navformer_rl.envs.robots import RobotSpec, get_robot_spec
from navformer_rl.envs.sim import Simulator, simulator_for_world, validate_actions
from navformer_rl.envs.target_image import render_target_image
from navformer_rl.envs.topdown import draw_topdown
from navformer_rl.envs.world import (
    EpisodeSpec,
    WorldConfig,
    WorldSpec,
    check_world_config,
    generate_world,
    sample_start_poses,
)
from navformer_rl.utils.checks import check_int, check_seed

_SEED_HIGH = 2**31 - 1


def robot_specs_for(n_robots: int, robot_style: str, obstacle_style: str | None) -> list[RobotSpec]:
    """Robot 0 in ``robot_style``, the others in ``obstacle_style`` (default: the same style)."""
    main = get_robot_spec(robot_style)
    other = main if obstacle_style is None else get_robot_spec(obstacle_style)
    return [main] + [other] * (n_robots - 1)


class TargetNavEnv(gym.Env):
    """Single-robot target-driven navigation in a seeded maze with other moving robots.

    Args:
        size: world side in metres, in [5, 17.5].
        n_robots: robots in the world (robot 0 is controlled; the others are obstacles).
        kind: ``"maze"`` or ``"arena"``.
        robot_style: style of robot 0 (``"jackal"`` or ``"turtlebot3"``).
        obstacle_style: style of the other robots (default: ``robot_style``).
        obstacle_policy: drives robots 1..R-1 (default :class:`GoalSeekingPolicy`). The env keeps its own deep
            copy, so one policy object passed to several envs (e.g. ``gym.make_vec(..., obstacle_policy=p)``)
            is never shared between them; ``env.obstacle_policy`` is that copy.
        max_episode_steps: truncation horizon (500 in the paper) of an env built directly. Through
            ``gym.make`` this argument cannot be given (``gym.make(id, max_episode_steps=N)`` is gymnasium's
            own, registered default 500): gymnasium's ``TimeLimit`` wrapper then truncates, see
            :attr:`max_episode_steps`.
        render_mode: ``None`` or ``"rgb_array"`` (top-down map with trajectories beside the camera view).
        episodes_per_world: resets that reuse the same world with fresh starts before a new world is drawn
            (the paper draws a new world every 10 trials).
        world_config: full :class:`WorldConfig` overriding ``size``/``n_robots``/``kind``.
        textured: tiled floor and coloured walls in the camera images.

    Spaces: observation ``Dict(pixels=Box(0, 255, (84, 84, 3), uint8), target_pixels=Box(same))``;
    action ``Box(-1, 1, (2,), float32)`` = (linear, angular), clipped; a missing action (``None``), NaN/inf or
    a wrong shape raise ValueError.

    Bad settings raise ValueError naming the value and what was expected: counts are integers >= 1,
    ``world_config`` a :class:`WorldConfig` whose ``robot_radius`` covers every robot, ``reset`` seeds
    non-negative integers and ``options`` a dict.

    ``reset(seed=..., options={"episode": EpisodeSpec | WorldSpec})`` replays a fixed episode; its world is
    never reused implicitly (the next plain reset draws a new world, whatever ``episodes_per_world``). Its
    ``world.config.robot_radius`` must cover every robot of this env (ValueError naming both radii otherwise).
    A reset that fails while building the simulator (e.g. starts that overlap a wall) leaves the env not
    reset: ``step`` raises "call reset() before step()" until a reset succeeds.
    ``info`` keys: ``pose`` float32 [3], ``velocity`` [2], ``target_position`` [2], ``distance_to_target``,
    ``success``, ``collision`` (robot 0 was in contact on the last step: blocked, or touching a wall, a
    target or another robot, e.g. because it was driven into), ``collision_kind`` (0/1/2), ``collisions``
    (count), ``path_length``
    (metres driven), ``shortest_path_length`` (geodesic from the start to the 1.5 m success region),
    ``robot_poses`` float32 [R, 3], ``world_seed``, ``step``.
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 5}

    def __init__(
        self,
        size: float = 12.5,
        n_robots: int = 1,
        kind: str = "maze",
        robot_style: str = "jackal",
        obstacle_style: str | None = None,
        obstacle_policy: ObstaclePolicy | None = None,
        max_episode_steps: int = MAX_EPISODE_STEPS,
        render_mode: str | None = None,
        episodes_per_world: int = 1,
        world_config: WorldConfig | None = None,
        textured: bool = True,
    ):
        if render_mode not in (None, "rgb_array"):
            raise ValueError(f"render_mode must be None or 'rgb_array', got {render_mode!r}")
        self._max_episode_steps = check_int(max_episode_steps, "max_episode_steps")
        self.episodes_per_world = check_int(episodes_per_world, "episodes_per_world")
        if world_config is None:
            world_config = WorldConfig(size=size, n_robots=n_robots, kind=kind)
        check_world_config(world_config)
        self.robot_specs = robot_specs_for(world_config.n_robots, robot_style, obstacle_style)
        self.config = check_world_config(world_config, self.robot_specs)
        if obstacle_policy is None:
            obstacle_policy = GoalSeekingPolicy()
        elif not isinstance(obstacle_policy, ObstaclePolicy):
            raise ValueError(
                "obstacle_policy must have reset(world, sim, rng) and act(sim, indices), "
                f"got {obstacle_policy!r}"
            )
        else:  # its own copy: a policy keeps per-episode state (targets, plans) of the env it drives
            obstacle_policy = copy.deepcopy(obstacle_policy)
        self.obstacle_policy = obstacle_policy
        self.render_mode = render_mode
        self.textured = textured
        image = gym.spaces.Box(0, 255, (IMAGE_SIZE, IMAGE_SIZE, 3), dtype=np.uint8)
        self.observation_space = gym.spaces.Dict({"pixels": image, "target_pixels": image})
        self.action_space = gym.spaces.Box(-1.0, 1.0, (2,), dtype=np.float32)
        self.world: WorldSpec | None = None
        self.simulator: Simulator | None = None
        self._episodes_in_world = 0

    @property
    def max_episode_steps(self) -> int | None:
        """The step count at which the env itself truncates an episode (``None``: never by itself).

        Built directly: the ``max_episode_steps`` argument. Made by ``gym.make`` (which sets :attr:`spec`):
        the spec's ``max_episode_steps``, which gymnasium >= 1.0 leaves ``None`` on the unwrapped env because
        its ``TimeLimit`` wrapper truncates (at ``gym.make(id, max_episode_steps=N)``'s ``N``, registered
        default 500, none for ``N = -1``), so the env never cuts a longer horizon short.
        """
        if self.spec is not None:
            return self.spec.max_episode_steps
        return self._max_episode_steps

    # ------------------------------------------------------------------ episode set-up
    def _next_world(self, options: dict[str, Any] | None) -> WorldSpec:
        """The world of the next episode: ``options["episode"]`` when given, else the current world with fresh
        starts while it has served fewer than ``episodes_per_world`` episodes, else a newly drawn one."""
        episode = (options or {}).get("episode")
        if episode is not None:
            world = self._fixed_world(episode)
            self._episodes_in_world = self.episodes_per_world  # a fixed episode is never reused implicitly
            return world
        if self.world is not None and self._episodes_in_world < self.episodes_per_world:
            self._episodes_in_world += 1
            starts = sample_start_poses(self.world, self.world.n_robots, self.np_random)
            return dataclasses.replace(self.world, starts=starts)
        self._episodes_in_world = 1
        return generate_world(self.config, int(self.np_random.integers(_SEED_HIGH)))

    def _fixed_world(self, episode: EpisodeSpec | WorldSpec) -> WorldSpec:
        """The world of a fixed episode (``reset(options={"episode": ...})``), checked against this env."""
        if isinstance(episode, EpisodeSpec):
            world = episode.build()
        elif isinstance(episode, WorldSpec):
            world = episode
        else:
            raise ValueError(
                f"options['episode'] must be an EpisodeSpec or WorldSpec, got {type(episode).__name__}"
            )
        if world.n_robots != len(self.robot_specs):
            raise ValueError(
                f"the episode has {world.n_robots} robots, this env drives {len(self.robot_specs)}"
            )
        check_world_config(world.config, self.robot_specs, name="the episode's world.config")
        return world

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        if seed is not None:
            seed = check_seed(seed)  # a plain int: gymnasium refuses numpy integers
        if options is not None and not isinstance(options, dict):
            raise ValueError(
                f"options must be a dict such as {{'episode': EpisodeSpec | WorldSpec}} or None, "
                f"got {type(options).__name__}"
            )
        super().reset(seed=seed)
        if seed is not None:
            self.world, self._episodes_in_world = None, 0
        world = self._next_world(options)
        try:
            self.simulator = simulator_for_world(world, self.robot_specs, self.textured, self.simulator)
        except BaseException:  # the previous simulator may be closed: the env is not reset any more
            self.close()
            self.world, self._episodes_in_world = None, 0
            raise
        self.world = world
        self.obstacle_policy.reset(world, self.simulator, self.np_random)
        target = world.targets[0]
        self._target_pixels = render_target_image(target.shape, target.color)
        self._target_xy = target.position.astype(np.float64)
        self._shortest = world.shortest_path_length(
            world.starts[0, :2], 0, clearance=self.robot_specs[0].radius, goal_radius=SUCCESS_RADIUS
        )
        self._step = 0
        self._collisions = 0
        self._path_length = 0.0
        self._trajectory = [world.starts[0, :2].astype(np.float64)]
        self._last_contact = (False, 0)
        return self._observation(), self._info()

    # ------------------------------------------------------------------ stepping
    def step(self, action):
        if self.simulator is None:
            raise RuntimeError("call reset() before step()")
        if action is None:
            raise ValueError("step() needs an action: float [2] (linear, angular) in [-1, 1], got None")
        own = validate_actions(action, 1)
        n = len(self.robot_specs)
        actions = np.zeros((n, 2), dtype=np.float64)
        actions[0] = own[0]
        if n > 1:
            try:
                actions[1:] = validate_actions(self.obstacle_policy.act(self.simulator, range(1, n)), n - 1)
            except ValueError as error:
                raise ValueError(
                    f"obstacle_policy.act returned bad actions for robots 1..{n - 1}: {error}"
                ) from None
        contacts = self.simulator.step(actions)
        after = self.simulator.poses[0, :2].astype(np.float64)
        self._path_length += abs(float(self.simulator.velocities[0, 0])) * self.simulator.dt  # arc length
        self._trajectory.append(after)
        self._step += 1
        collided = bool(contacts.collided[0])
        self._collisions += int(collided)
        self._last_contact = (collided, int(contacts.kind[0]))
        success = bool(np.hypot(*(after - self._target_xy)) <= SUCCESS_RADIUS)
        horizon = self.max_episode_steps
        truncated = not success and horizon is not None and self._step >= horizon
        return self._observation(), float(success), success, truncated, self._info(success)

    def _observation(self) -> dict[str, np.ndarray]:
        return {"pixels": self.simulator.render(0), "target_pixels": self._target_pixels.copy()}

    def _info(self, success: bool = False) -> dict[str, Any]:
        poses = self.simulator.poses
        return {
            "pose": poses[0].copy(),
            "velocity": self.simulator.velocities[0].copy(),
            "target_position": self._target_xy.astype(np.float32),
            "distance_to_target": float(np.hypot(*(poses[0, :2] - self._target_xy))),
            "success": success,
            "collision": self._last_contact[0],
            "collision_kind": self._last_contact[1],
            "collisions": self._collisions,
            "path_length": self._path_length,
            "shortest_path_length": self._shortest,
            "robot_poses": poses,
            "world_seed": self.world.seed,
            "step": self._step,
        }

    # ------------------------------------------------------------------ rendering
    def render(self) -> np.ndarray | None:
        """``"rgb_array"``: uint8 ``[H, W, 3]`` top-down map (robot 0's trajectory) beside its camera view."""
        if self.render_mode != "rgb_array" or self.simulator is None:
            return None
        return compose_frame(
            draw_topdown(self.world, [np.array(self._trajectory)], self.simulator.poses, self.robot_specs),
            [self.simulator.render(0), self._target_pixels],
        )

    def close(self) -> None:
        if self.simulator is not None:
            self.simulator.close()
            self.simulator = None


def compose_frame(topdown: np.ndarray, views: list[np.ndarray], view_px: int | None = None) -> np.ndarray:
    """Put camera ``views`` (uint8 ``[84, 84, 3]`` each), scaled up and stacked vertically, to the right of a
    top-down map ``[H, W, 3]``: returns uint8 ``[H, W + view_px, 3]``. ``view_px`` (an integer >= 1) defaults
    to the map height split among the views, clamped to [84, 336]. ValueError for images that are not
    ``[H, W, 3]``."""
    topdown = np.asarray(topdown)
    if topdown.ndim != 3 or topdown.shape[2] != 3:
        raise ValueError(f"topdown must be an RGB image [H, W, 3], got shape {topdown.shape}")
    for k, view in enumerate(views):
        if np.ndim(view) != 3 or np.shape(view)[2] != 3:
            raise ValueError(f"views[{k}] must be an RGB image [h, w, 3], got shape {np.shape(view)}")
    h = topdown.shape[0]
    if view_px is None:
        view_px = max(84, min(h // max(len(views), 1), 336))
    view_px = check_int(view_px, "view_px")
    column = np.full((h, view_px, 3), 255, dtype=np.uint8)
    for k, view in enumerate(views[: max(h // view_px, 1)]):
        column[k * view_px : (k + 1) * view_px] = cv2.resize(
            view, (view_px, view_px), interpolation=cv2.INTER_NEAREST
        )
    return np.concatenate([topdown, column], axis=1)
