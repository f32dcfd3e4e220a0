"""Running episodes with per-step recording: :class:`TraceRunner` plays an episode as the evaluation does
(same env, policy recipe and seeds) and returns its
:class:`~navformer_rl.evaluation.diagnose.trace.EpisodeTrace`.

``_init_worker`` / ``_run_in_worker`` are what the diagnosis's spawned worker processes run.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from navformer_rl.evaluation.diagnose.trace import EpisodeGeometry, EpisodeTrace
from navformer_rl.evaluation.episodes import Episode
from navformer_rl.evaluation.policy_spec import PolicySpec
from navformer_rl.evaluation.runner import make_eval_env
from navformer_rl.utils.interrupts import exit_on_sigint


@dataclass(frozen=True)
class TraceTask:
    """One episode to record: its JSON (``Episode.to_json``), where to write the trace, its resume key."""

    episode: dict[str, Any]
    path: str
    key: str


class TraceRunner:
    """Runs episodes one at a time with one policy and one ``MultiRobotNavEnv`` per robot line-up (cached).

    Args:
        spec: the policy recipe (as the evaluation's; ``bind(env, seed)`` gets the episode seed XOR
            ``spec.seed``, so the robots act as in ``navformer evaluate`` with the same ``--seed``).
        max_steps: trial length.
    """

    def __init__(self, spec: PolicySpec, max_steps: int) -> None:
        self.spec = spec
        self.policy, _ = spec.build_with_config()
        self.max_steps = int(max_steps)
        self._envs: dict[tuple[str, ...], Any] = {}

    def close(self) -> None:
        for env in self._envs.values():
            env.close()
        self._envs.clear()

    def run(self, episode_json: dict[str, Any], key: str = "") -> EpisodeTrace:
        """Play one episode (``Episode.to_json``) and record every step (see ``diagnose.trace``)."""
        import torch
        from torchrl.envs.utils import step_mdp

        episode = Episode.from_json(episode_json)
        if episode.robots not in self._envs:
            self._envs[episode.robots] = make_eval_env(episode.robots, self.max_steps)
        env = self._envs[episode.robots]
        env.set_next_episode(episode.world_spec())
        with torch.no_grad():
            td = env.reset()
            episode.check_world(env.world)
            specs = list(env.simulator.robot_specs)
            geometry = EpisodeGeometry(env.world, specs)
            if hasattr(self.policy, "bind"):
                self.policy.bind(env, episode.seed ^ self.spec.seed)
            poses = [td.get(("privileged", "pose")).numpy().astype(np.float64)]
            measured = [geometry.measure(poses[0])]
            actions, velocities, contacts = [], [], []
            n = episode.n_robots
            success_step = np.full(n, -1, dtype=np.int64)
            for t in range(1, self.max_steps + 1):
                td = self.policy(td)
                actions.append(np.clip(td.get(("agents", "action")).numpy().reshape(n, 2), -1.0, 1.0))
                td = env.step(td)
                nxt = td.get("next")
                poses.append(nxt.get(("privileged", "pose")).numpy().astype(np.float64))
                velocities.append(nxt.get(("privileged", "velocity")).numpy().reshape(n, 2))
                contacts.append(nxt.get(("agents", "collision_kind")).numpy().reshape(n))
                success = nxt.get(("privileged", "success")).numpy().reshape(n)
                success_step[(success_step < 0) & success] = t
                measured.append(geometry.measure(poses[-1]))
                if bool(nxt.get("done").any()):
                    break
                td = step_mdp(td, exclude_reward=False)  # NavFormer's R-hat reads the rewards
        distance, geodesic, visible = (np.stack(column) for column in zip(*measured))
        return EpisodeTrace(
            episode_id=episode.episode_id,
            setup=episode.setup,
            robots=episode.robots,
            dt=float(env.simulator.dt),
            pose=np.stack(poses).astype(np.float32),
            action=np.stack(actions).astype(np.float32),
            velocity=np.stack(velocities).astype(np.float32),
            contact=np.stack(contacts).astype(np.int8),
            distance=distance.astype(np.float32),
            geodesic=geodesic.astype(np.float32),
            visible=visible,
            target=geometry.targets[:, :2].astype(np.float32),
            distractors=geometry.distractors.astype(np.float32),
            success_step=success_step,
            measured=np.array(episode.measured, dtype=bool),
            shortest_path=np.array(episode.shortest_paths, dtype=np.float64),
            v_max=np.array([spec.v_max for spec in specs]),
            w_max=np.array([spec.w_max for spec in specs]),
            key=key,
        )


_WORKER_RUNNER: TraceRunner | None = None


def _init_worker(spec: PolicySpec, max_steps: int) -> None:
    """Pool initialiser: this worker's :class:`TraceRunner`, one torch thread (as the evaluation's workers).
    Ctrl-C ends the worker quietly, from its start-up on (the parent reports the interruption)."""
    global _WORKER_RUNNER
    exit_on_sigint()
    import torch

    torch.set_num_threads(1)
    _WORKER_RUNNER = TraceRunner(spec, max_steps)


def _run_in_worker(task: TraceTask) -> str:
    """Record ``task``'s episode and save its trace; returns the trace's path."""
    from navformer_rl.evaluation.diagnose.trace import save_trace

    if _WORKER_RUNNER is None:
        raise RuntimeError("diagnosis worker used before its initialiser ran")
    return str(save_trace(_WORKER_RUNNER.run(task.episode, task.key), task.path))
