"""TorchRL ``MultiRobotNavEnv``: every robot is controlled (paper §VII.A: all robots of a trial run the
policy).

Per-robot entries live under the group key ``"agents"`` with the robot dimension first (TorchRL's
MARL convention); privileged state for experts and metrics lives under ``"privileged"``; the root
``done``/``terminated``/``truncated`` end the episode when every robot found its target or after
``max_steps`` steps.

Keys (A robots):

- ``("agents", "pixels")``, ``("agents", "target_pixels")``: uint8 ``[A, 84, 84, 3]``. A robot that
  has succeeded keeps the frame of the step it arrived (it no longer renders).
- ``("agents", "action")``: float32 ``[A, 2]`` in [-1, 1]; ignored for robots that have succeeded.
- ``("agents", "reward")``: float32 ``[A, 1]``, 1 on the step a robot first reaches its target.
- ``("agents", "terminated")`` bool ``[A, 1]`` (= succeeded), ``("agents", "done")`` bool ``[A, 1]``
  (succeeded, or the episode was truncated). They are observations, not done-spec entries, so TorchRL
  rollouts and collectors do not stop (or partially reset) when a single robot finishes.
- ``("agents", "collision")`` bool ``[A, 1]``, ``("agents", "collision_kind")`` int64 ``[A, 1]`` (0 none,
  1 wall or target, 2 robot), for the last step: the robot was in contact (its motion was cut short, or it
  ends the step touching a wall, a target or another robot, e.g. because it was driven into; see
  :meth:`Simulator.step`). A robot that has succeeded is no longer flagged (nothing more counts for it).
- ``("agents", "step_count")`` int64 ``[A, 1]``: steps since reset (0 right after a reset).
- ``("privileged", k)``: ``pose`` float32 ``[A, 3]``, ``velocity`` ``[A, 2]``, ``target_position``
  ``[A, 2]``, ``success`` bool ``[A, 1]``, ``path_length`` float32 ``[A, 1]`` (metres driven),
  ``shortest_path_length`` float32 ``[A, 1]`` (geodesic from the start to the 1.5 m success region; the
  evaluation harness's SPL uses the paper's start-to-target length, see ``docs/evaluation.md``),
  ``collisions`` int64 ``[A, 1]`` (steps in collision so far).
- root ``done``, ``terminated``, ``truncated``: bool ``[1]``.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import numpy as np
import torch
from tensordict import TensorDict, TensorDictBase
from torchrl.data import Bounded, Categorical, Composite, Unbounded
from torchrl.envs import EnvBase

from navformer_rl.constants import IMAGE_SIZE, MAX_EPISODE_STEPS, SUCCESS_RADIUS
from navformer_rl.envs.robots import get_robot_spec
from navformer_rl.envs.sim import Simulator, simulator_for_world, validate_actions
from navformer_rl.envs.target_image import render_target_image
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
_ACTION_KEY = ("agents", "action")


def _style_list(robots) -> list:
    """``robots`` as a list; ValueError for a single string or something that is not a sequence."""
    try:
        styles = None if isinstance(robots, str) else list(robots)
    except TypeError:
        styles = None
    if styles is None:
        raise ValueError(
            f"robots must be a list of robot style names, e.g. ['jackal', 'turtlebot3'], got {robots!r}"
        )
    return styles


def _check_device(device: str | torch.device | None) -> torch.device | None:
    """``device`` as a ``torch.device``; ValueError for an unknown device string or CUDA without CUDA."""
    if device is None:
        return None
    try:
        dev = torch.device(device)
    except (RuntimeError, TypeError):
        raise ValueError(f"device must be a torch device such as 'cpu' or 'cuda', got {device!r}") from None
    if dev.type == "cuda" and not torch.cuda.is_available():
        raise ValueError(f"device {device!r} needs CUDA, which this torch build/machine does not have")
    return dev


class MultiRobotNavEnv(EnvBase):
    """Multi-robot target-driven navigation; all robots take actions from the tensordict.

    Args:
        size, n_robots, kind: the world (see :class:`WorldConfig`); ignored where ``world_config`` is given.
        robots: optional robot style per robot (e.g. ``["jackal", "turtlebot3", ...]``); sets ``n_robots``.
        robot_style: style of every robot when ``robots`` is not given.
        max_steps: truncation horizon (500 in the paper).
        world_config: full :class:`WorldConfig`.
        episodes_per_world: resets that reuse a world (fresh starts) before a new one is drawn.
        textured: tiled floor and coloured walls in the camera images.
        seed: seed of the env's generator, a non-negative integer (also settable with ``set_seed``).
        device: torch device of the output tensors.

    Bad settings raise ValueError naming the value and what was expected (counts are integers >= 1, robot
    styles a list of names, seeds non-negative integers, a CUDA device needs CUDA). ``step`` needs the action
    at ``("agents", "action")``, float ``[A, 2]`` (linear, angular) per robot in [-1, 1]: finite values
    outside are clipped; a missing action, a wrong shape or NaN/inf raise ValueError.

    ``env.world`` (:class:`WorldSpec`) and ``env.simulator`` (:class:`Simulator`) expose the current
    episode; ``env.set_next_episode(EpisodeSpec | WorldSpec)`` makes the next reset replay a fixed
    world, starts and targets (evaluation); its ``world.config.robot_radius`` must cover every robot
    (ValueError naming both radii otherwise). Robot ``i`` seeks ``world.targets[i]``; targets after the
    robots' (``world.distractors``) stand in the world, seen and collided with, and no robot seeks them.

    ``step`` raises RuntimeError before the first reset, after a reset that failed while building the
    simulator (e.g. starts that overlap a wall), and once the episode has ended (root ``done``: every robot
    succeeded, or ``max_steps`` steps), so ``("agents", "step_count")`` never exceeds ``max_steps``; TorchRL's
    ``rollout(..., break_when_any_done=False)``, ``step_and_maybe_reset``, ``SerialEnv`` and the collectors
    reset ended episodes before stepping.
    """

    batch_locked = True

    def __init__(
        self,
        size: float = 12.5,
        n_robots: int = 2,
        kind: str = "maze",
        robots: Sequence[str] | None = None,
        robot_style: str = "jackal",
        max_steps: int = MAX_EPISODE_STEPS,
        world_config: WorldConfig | None = None,
        episodes_per_world: int = 1,
        textured: bool = True,
        seed: int | None = None,
        device: str | torch.device = "cpu",
    ):
        super().__init__(device=_check_device(device), batch_size=torch.Size([]))
        if robots is not None:
            styles = _style_list(robots)
            if not styles:
                raise ValueError("MultiRobotNavEnv needs at least one robot: robots is empty")
        else:
            styles = [robot_style] * check_int(n_robots, "n_robots")
        self.robot_specs = [get_robot_spec(s) for s in styles]
        n = len(self.robot_specs)
        radius = max(s.radius for s in self.robot_specs)
        if world_config is None:
            world_config = WorldConfig(size=size, kind=kind, n_robots=n, robot_radius=radius)
        check_world_config(world_config, self.robot_specs)
        if world_config.n_robots != n:
            raise ValueError(f"world_config.n_robots={world_config.n_robots} but {n} robot styles were given")
        self.config = world_config
        self.n_agents = n
        self.max_steps = check_int(max_steps, "max_steps")
        self.episodes_per_world = check_int(episodes_per_world, "episodes_per_world")
        self.textured = textured
        self.world: WorldSpec | None = None
        self.simulator: Simulator | None = None
        self._next_episode: EpisodeSpec | WorldSpec | None = None
        self._episodes_in_world = 0
        self._ended = False  # the current episode is over (root done): step() refuses until reset()
        self._rng = np.random.default_rng(None if seed is None else check_seed(seed))
        self._make_specs()

    # ------------------------------------------------------------------ specs
    def _make_specs(self) -> None:
        a = self.n_agents
        image = Bounded(0, 255, (a, IMAGE_SIZE, IMAGE_SIZE, 3), dtype=torch.uint8, device=self.device)
        flag = Categorical(2, shape=(a, 1), dtype=torch.bool, device=self.device)
        self.observation_spec = Composite(
            agents=Composite(
                pixels=image,
                target_pixels=image.clone(),
                collision=flag.clone(),
                collision_kind=Categorical(3, shape=(a, 1), dtype=torch.int64, device=self.device),
                step_count=Bounded(0, self.max_steps, (a, 1), dtype=torch.int64, device=self.device),
                done=flag.clone(),
                terminated=flag.clone(),
                shape=(a,),
                device=self.device,
            ),
            privileged=Composite(
                pose=Unbounded((a, 3), dtype=torch.float32, device=self.device),
                velocity=Unbounded((a, 2), dtype=torch.float32, device=self.device),
                target_position=Unbounded((a, 2), dtype=torch.float32, device=self.device),
                success=flag.clone(),
                path_length=Unbounded((a, 1), dtype=torch.float32, device=self.device),
                shortest_path_length=Unbounded((a, 1), dtype=torch.float32, device=self.device),
                collisions=Unbounded((a, 1), dtype=torch.int64, device=self.device),
                shape=(a,),
                device=self.device,
            ),
            device=self.device,
        )
        self.action_spec = Composite(
            agents=Composite(
                action=Bounded(-1.0, 1.0, (a, 2), dtype=torch.float32, device=self.device),
                shape=(a,),
                device=self.device,
            ),
            device=self.device,
        )
        self.reward_spec = Composite(
            agents=Composite(
                reward=Unbounded((a, 1), dtype=torch.float32, device=self.device),
                shape=(a,),
                device=self.device,
            ),
            device=self.device,
        )
        done = Categorical(2, shape=(1,), dtype=torch.bool, device=self.device)
        self.done_spec = Composite(
            done=done, terminated=done.clone(), truncated=done.clone(), device=self.device
        )

    # ------------------------------------------------------------------ episodes
    def set_next_episode(self, episode: EpisodeSpec | WorldSpec) -> None:
        """Make the next ``reset`` use this fixed episode (world, starts, targets)."""
        if not isinstance(episode, (EpisodeSpec, WorldSpec)):
            raise ValueError(f"expected an EpisodeSpec or WorldSpec, got {type(episode).__name__}")
        self._next_episode = episode

    def _draw_world(self) -> WorldSpec:
        if self._next_episode is not None:
            episode, self._next_episode = self._next_episode, None
            world = episode.build() if isinstance(episode, EpisodeSpec) else episode
            if world.n_robots != self.n_agents:
                raise ValueError(f"the episode has {world.n_robots} robots, this env drives {self.n_agents}")
            check_world_config(world.config, self.robot_specs, name="the episode's world.config")
            self._episodes_in_world = self.episodes_per_world  # a fixed episode is never reused implicitly
            return world
        if self.world is not None and self._episodes_in_world < self.episodes_per_world:
            self._episodes_in_world += 1
            starts = sample_start_poses(self.world, self.n_agents, self._rng)
            return dataclasses.replace(self.world, starts=starts)
        self._episodes_in_world = 1
        return generate_world(self.config, int(self._rng.integers(_SEED_HIGH)))

    def _reset(self, tensordict: TensorDictBase | None = None, **kwargs) -> TensorDictBase:
        world = self._draw_world()
        try:
            self.simulator = simulator_for_world(world, self.robot_specs, self.textured, self.simulator)
        except BaseException:  # the previous simulator may be closed: the env is not reset any more
            if self.simulator is not None:
                self.simulator.close()
            self.simulator, self.world, self._episodes_in_world = None, None, 0
            raise
        self.world = world
        self._ended = False
        a = self.n_agents
        self._target_xy = world.robot_target_positions.astype(np.float64)  # distractors are only seen
        self._target_pixels = torch.from_numpy(
            np.stack([render_target_image(t.shape, t.color) for t in world.targets[:a]])
        )
        self._shortest = np.array(
            [
                world.shortest_path_length(world.starts[i, :2], i, spec.radius, goal_radius=SUCCESS_RADIUS)
                for i, spec in enumerate(self.robot_specs)
            ],
            dtype=np.float32,
        )
        self._success = np.zeros(a, dtype=bool)
        self._collisions = np.zeros(a, dtype=np.int64)
        self._path_length = np.zeros(a, dtype=np.float64)
        self._step_count = 0
        self._pixels = self.simulator.render_all()
        zeros = np.zeros(a, dtype=bool)
        return self._make_tensordict(zeros, np.zeros(a, dtype=np.int8), reward=None, truncated=False)

    def _step(self, tensordict: TensorDictBase) -> TensorDictBase:
        if self.simulator is None:
            raise RuntimeError("call reset() before step()")
        if self._ended:
            raise RuntimeError(
                f"the episode ended (every robot succeeded, or max_steps={self.max_steps} steps were taken; "
                "root 'done' was True); call reset() before stepping again (TorchRL's rollout(..., "
                "break_when_any_done=False), step_and_maybe_reset and the collectors do)"
            )
        action = tensordict.get(_ACTION_KEY, None)
        if action is None:
            keys = sorted(tensordict.keys(True, True), key=str)
            hint = " ('action' at the root is not read: put it under 'agents')" if "action" in keys else ""
            raise ValueError(
                f"step() needs the action at key {_ACTION_KEY}: float [{self.n_agents}, 2] (linear, angular) "
                f"per robot in [-1, 1]{hint}; the tensordict has keys {keys}"
            )
        if isinstance(action, torch.Tensor):
            action = action.detach().cpu().numpy()
        actions = validate_actions(action, self.n_agents)
        active = ~self._success
        contacts = self.simulator.step(actions, active)
        collided = contacts.collided & active  # a parked (succeeded) robot that is driven into is not charged
        kind = np.where(active, contacts.kind, 0)
        after = self.simulator.poses[:, :2].astype(np.float64)
        self._path_length += np.abs(self.simulator.velocities[:, 0]) * self.simulator.dt  # arc length driven
        self._collisions += collided
        arrived = active & (np.hypot(*(after - self._target_xy).T) <= SUCCESS_RADIUS)
        self._success |= arrived
        self._step_count += 1
        if active.all():
            self._pixels = self.simulator.render_all()
        elif active.any():  # a new array (never written in place: the last output may share its memory)
            fresh = self.simulator.render_all(active)
            self._pixels = np.where(active[:, None, None, None], fresh, self._pixels)
        truncated = self._step_count >= self.max_steps and not self._success.all()
        self._ended = truncated or bool(self._success.all())
        return self._make_tensordict(collided, kind, reward=arrived, truncated=truncated)

    def _make_tensordict(
        self, collided: np.ndarray, kind: np.ndarray, reward: np.ndarray | None, truncated: bool
    ) -> TensorDictBase:
        a = self.n_agents
        dev = self.device
        success = torch.from_numpy(self._success.copy()).reshape(a, 1)
        terminated = bool(self._success.all())
        agents = {
            "pixels": torch.from_numpy(self._pixels),
            "target_pixels": self._target_pixels.clone(),
            "collision": torch.from_numpy(np.asarray(collided, dtype=bool)).reshape(a, 1),
            "collision_kind": torch.from_numpy(np.asarray(kind, dtype=np.int64)).reshape(a, 1),
            "step_count": torch.full((a, 1), self._step_count, dtype=torch.int64),
            "terminated": success,
            "done": success | truncated,
        }
        if reward is not None:
            agents["reward"] = torch.from_numpy(np.asarray(reward, dtype=np.float32)).reshape(a, 1)
        poses = self.simulator.poses
        privileged = {
            "pose": torch.from_numpy(poses),
            "velocity": torch.from_numpy(self.simulator.velocities),
            "target_position": torch.from_numpy(self._target_xy.astype(np.float32)),
            "success": success.clone(),
            "path_length": torch.from_numpy(self._path_length.astype(np.float32)).reshape(a, 1),
            "shortest_path_length": torch.from_numpy(self._shortest).reshape(a, 1),
            "collisions": torch.from_numpy(self._collisions.copy()).reshape(a, 1),
        }
        out = TensorDict(
            {
                "agents": TensorDict(agents, batch_size=(a,)),
                "privileged": TensorDict(privileged, batch_size=(a,)),
                "done": torch.tensor([terminated or truncated]),
                "terminated": torch.tensor([terminated]),
                "truncated": torch.tensor([truncated]),
            },
            batch_size=(),
        )
        return out.to(dev) if dev is not None and dev != torch.device("cpu") else out

    def _set_seed(self, seed: int | None) -> None:
        self._rng = np.random.default_rng(None if seed is None else check_seed(seed))
        self.world, self._episodes_in_world = None, 0

    def close(self, *, raise_if_closed: bool = True) -> None:
        if self.simulator is not None:
            self.simulator.close()
            self.simulator = None
        super().close(raise_if_closed=raise_if_closed)
