"""Running episodes: the policy drives every robot of a ``MultiRobotNavEnv``; each robot-trial is measured.

:class:`EpisodeTask` is one unit of work (an episode, what to visualise, where, its resume key).
:class:`EpisodeRunner` runs tasks one at a time (one policy, one env per robot line-up, cached) and returns
``{"records": [RobotTrial], "maps": [...], "videos": [...]}``, drawing the top-down map PNG and the
camera + map video frames on the way; :func:`robot_trials` turns a finished episode's
:class:`~navformer_rl.evaluation.measures.TrialTracker` into its rows. ``_init_worker`` / ``_run_in_worker``
are what the harness's spawned worker processes run (they find them by this module's import path).
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from navformer_rl.evaluation.episodes import Episode
from navformer_rl.evaluation.measures import RobotTrial, TrialTracker
from navformer_rl.evaluation.policy_spec import PolicySpec
from navformer_rl.evaluation.video import MAP_PNG_PX, compose_frame, draw_map, save_map_png
from navformer_rl.utils.interrupts import exit_on_sigint
from navformer_rl.utils.mp4 import Mp4Writer


@dataclass(frozen=True)
class EpisodeTask:
    """One unit of work: an episode, what to visualise, where to write visuals."""

    index: int
    episode: dict[str, Any]
    save_map: bool
    save_video: bool
    out_dir: str
    label: str
    key: str
    """Identifies the work (method, checkpoint, seed, episode, visuals): a stored result with this key is
    reused on resume."""


def _timed_run(runner: EpisodeRunner, task: EpisodeTask) -> dict[str, Any]:
    """``runner.run(task)`` with ``seconds``: how long the episode took in this process."""
    started = time.perf_counter()
    output = runner.run(task)
    output["seconds"] = round(time.perf_counter() - started, 3)
    return output


_WORKER_RUNNER: EpisodeRunner | None = None


def _init_worker(spec: PolicySpec, max_steps: int, video_fps: float) -> None:
    """Pool initialiser: build this worker process's :class:`EpisodeRunner` once (one torch thread). Ctrl-C
    ends the worker quietly, from its start-up on (the harness reports the interruption)."""
    global _WORKER_RUNNER
    exit_on_sigint()
    import torch

    torch.set_num_threads(1)
    _WORKER_RUNNER = EpisodeRunner(spec, max_steps, video_fps)


def _run_in_worker(task: EpisodeTask) -> dict[str, Any]:
    """Run ``task`` on this worker's runner; the output dict of :func:`_timed_run`."""
    if _WORKER_RUNNER is None:
        raise RuntimeError("evaluation worker used before its initialiser ran")
    return _timed_run(_WORKER_RUNNER, task)


class EpisodeRunner:
    """Runs episodes one at a time: one policy, one ``MultiRobotNavEnv`` per robot line-up (cached).

    Args:
        spec: the policy recipe.
        max_steps: trial length (500 in the paper).
        video_fps: frames per second of recorded videos.
    """

    def __init__(self, spec: PolicySpec, max_steps: int, video_fps: float = 10.0) -> None:
        self.spec = spec
        self.policy, _ = spec.build_with_config()
        self.max_steps = int(max_steps)
        self.video_fps = float(video_fps)
        self._envs: dict[tuple[str, ...], Any] = {}

    def close(self) -> None:
        for env in self._envs.values():
            env.close()
        self._envs.clear()

    def _env(self, robots: tuple[str, ...]):
        if robots not in self._envs:
            self._envs[robots] = make_eval_env(robots, self.max_steps)
        return self._envs[robots]

    def run(self, task: EpisodeTask) -> dict[str, Any]:
        """Run one episode; returns ``{"records": [RobotTrial], "maps": [...], "videos": [...]}``."""
        import torch

        episode = Episode.from_json(task.episode)
        env = self._env(episode.robots)
        env.set_next_episode(episode.world_spec())
        with torch.no_grad():
            td = env.reset()
            world = env.world
            episode.check_world(world)
            specs = list(env.simulator.robot_specs)
            if hasattr(self.policy, "bind"):
                self.policy.bind(env, episode.seed ^ self.spec.seed)
            poses = td.get(("privileged", "pose")).numpy().astype(np.float64)
            tracker = TrialTracker(poses[:, :2])
            keep_path = task.save_map or task.save_video
            paths = [[p[:2].copy()] for p in poses] if keep_path else None
            name = _file_stem(episode.episode_id)
            video = (
                # one encoder thread: episodes already run in parallel processes
                Mp4Writer(Path(task.out_dir) / "videos" / f"{name}.mp4", self.video_fps, threads=1)
                if task.save_video
                else None
            )
            title = f"{task.label} | {episode.episode_id} | {episode.size:g} m, {episode.n_robots} robots"
            try:
                if video is not None:
                    video.write(self._frame(world, paths, poses, specs, td, tracker, title, 0))
                for t in range(1, self.max_steps + 1):
                    td = self.policy(td)
                    td = env.step(td)
                    nxt = td.get("next")
                    poses = nxt.get(("privileged", "pose")).numpy().astype(np.float64)
                    collided = nxt.get(("agents", "collision")).numpy().reshape(-1)
                    success = nxt.get(("privileged", "success")).numpy().reshape(-1)
                    was_active = tracker.active.copy()
                    # the arc length driven on this step: |executed linear velocity| * dt
                    driven = np.abs(nxt.get(("privileged", "velocity"))[:, 0].numpy()) * env.simulator.dt
                    tracker.update(poses[:, :2], collided, success, driven)
                    if paths is not None:
                        for i in np.flatnonzero(was_active):
                            paths[i].append(poses[i, :2].copy())
                    if video is not None:
                        video.write(self._frame(world, paths, poses, specs, nxt, tracker, title, t))
                    if bool(nxt.get("done").any()):
                        break
                    td = _next_input(td)
            except BaseException:
                if video is not None:
                    video.abort()
                raise
            videos = [str(video.close().relative_to(task.out_dir))] if video is not None else []
        maps = []
        if task.save_map:
            image = draw_map(world, [np.array(p) for p in paths], poses, specs, side=MAP_PNG_PX)
            outcome = ", ".join(
                f"{i}:{'ok' if ok else 'fail'}" + ("" if measured else " (obstacle)")
                for i, (ok, measured) in enumerate(zip(tracker.success, episode.measured))
            )
            path = save_map_png(image, Path(task.out_dir) / "maps" / f"{name}.png", f"{title} | {outcome}")
            maps.append(str(path.relative_to(task.out_dir)))
        final_distance = np.hypot(*(poses[:, :2] - world.robot_target_positions.astype(np.float64)).T)
        records = robot_trials(task.label, episode, tracker, final_distance)
        return {"records": records, "maps": maps, "videos": videos}

    @staticmethod
    def _frame(world, paths, poses, specs, td, tracker, title, t) -> np.ndarray:
        from navformer_rl.envs.topdown import ROBOT_COLORS

        cameras = td.get(("agents", "pixels")).numpy()
        targets = td.get(("agents", "target_pixels")).numpy()
        collided = td.get(("agents", "collision")).numpy().reshape(-1)
        distance = np.hypot(*(poses[:, :2] - world.robot_target_positions).T)
        status = []
        for i in range(len(poses)):
            if tracker.success[i]:
                status.append(f"found target at step {tracker.success_step[i]}")
            else:
                status.append(
                    f"{distance[i]:.1f} m to go, {tracker.collisions[i]} coll."
                    + (" HIT" if collided[i] else "")
                )
        map_image = draw_map(world, [np.array(p) for p in paths], poses, specs)
        if len({spec.name for spec in specs}) > 1:  # mixed line-up (Table III): name each robot's style
            status = [f"{spec.name}, {text}" for spec, text in zip(specs, status)]
        return compose_frame(map_image, cameras, targets, ROBOT_COLORS, status, f"{title} | step {t}")


def robot_trials(
    label: str, episode: Episode, tracker: TrialTracker, final_distance: np.ndarray
) -> list[RobotTrial]:
    """One :class:`RobotTrial` per robot of a finished ``episode`` from its ``tracker`` (p, N_c, N_e,
    success) and ``final_distance`` float ``[R]`` (metres to the target at the end); ℓ comes from the
    episode."""
    return [
        RobotTrial(
            method=label,
            episode_id=episode.episode_id,
            setup=episode.setup,
            size=episode.size,
            n_robots=episode.n_robots,
            world_seed=episode.world_seed,
            trial=episode.trial,
            robot=i,
            robot_style=episode.robots[i],
            measured=episode.measured[i],
            success=bool(tracker.success[i]),
            success_step=int(tracker.success_step[i]) if tracker.success[i] else None,
            steps=int(tracker.steps[i]),
            collisions=int(tracker.collisions[i]),
            path_length=round(float(tracker.path_length[i]), 6),
            shortest_path=episode.shortest_paths[i],
            shortest_path_to_disc=episode.shortest_paths_to_disc[i],
            final_distance=round(float(final_distance[i]), 6),
        )
        for i in range(episode.n_robots)
    ]


def make_eval_env(robots: tuple[str, ...], max_steps: int):
    """A ``MultiRobotNavEnv`` for the robot styles ``robots``
    (one per robot) and trial length ``max_steps``."""
    from navformer_rl.envs.multi_robot import MultiRobotNavEnv

    return MultiRobotNavEnv(robots=list(robots), max_steps=max_steps)


def _next_input(td):
    """The next policy input: ``td["next"]`` with the rewards kept (NavFormer's R-hat reads them)."""
    from torchrl.envs.utils import step_mdp

    return step_mdp(td, exclude_reward=False)


def _file_stem(episode_id: str) -> str:
    """``episode_id`` made safe as a file name (``/`` and spaces become ``_``)."""
    return episode_id.replace("/", "_").replace(" ", "_")
