"""Per-step records of evaluated episodes, for diagnosing how a policy fails
(``navformer evaluate diagnose``).

An :class:`EpisodeTrace` holds, for every robot of one episode and every step, what the policy commanded,
what the robot did and what it could see. Step ``t`` (0-based, ``T`` steps) is the policy's action on the
observation taken at ``pose[t]``; the env then moves the robots to ``pose[t + 1]``. Arrays (``R`` robots):

========== ================= ============================================================================
field      dtype / shape     meaning
========== ================= ============================================================================
pose       float32 [T+1,R,3] ``(x, y, yaw)`` after the reset (index 0) and after every step
action     float32 [T, R, 2] commanded ``(linear, angular)``, normalised, clipped to [-1, 1] as the env does
velocity   float32 [T, R, 2] executed ``(v m/s, w rad/s)`` of the step (0 where a contact cut it short)
contact    int8 [T, R]       contact on the step: 0 none, 1 wall or target, 2 robot (``collision_kind``)
distance   float32 [T+1, R]  metres from the robot's centre to its target's centre
geodesic   float32 [T+1, R]  shortest collision-free path to the target on the reach-5 grid (as ℓ)
visible    bool [T+1, R]     the target's centre is in the camera's field of view (90°) and no wall cuts
                             the line of sight from the camera (as the experts test it)
========== ================= ============================================================================

Per robot: ``target`` float32 ``[R, 2]`` (its target's centre), ``success_step`` int64 ``[R]`` (steps
taken when it arrived, -1 if never: it was *active* on steps ``t < success_step``, as in
:class:`~navformer_rl.evaluation.measures.TrialTracker`), ``measured``, ``shortest_path`` (ℓ of the
episode), ``v_max`` / ``w_max``. Per episode: ``distractors`` float32 ``[K, 2]``, the centres of the
targets no robot seeks (``K = 0`` in most episode sets; a trace saved before the field existed loads with
none). Traces are saved as one compressed ``.npz``
per episode (:func:`save_trace`, atomic) with a resume ``key``.

:class:`EpisodeGeometry` answers the geometric questions per world: one Dijkstra per robot from its
target (:meth:`OccupancyMap.distance_field`, the graph ℓ is measured on) and the camera's line of sight
(:func:`~navformer_rl.experts.visibility.target_visible`).
"""

from __future__ import annotations

import json
import math
import os
import zipfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from navformer_rl.utils.durable import atomic_path

TRACE_VERSION = 2
"""Bump when the fields of :class:`EpisodeTrace` change (stored traces of another version are recomputed)."""

ARRAY_FIELDS = ("pose", "action", "velocity", "contact", "distance", "geodesic", "visible")
ROBOT_FIELDS = ("target", "success_step", "measured", "shortest_path", "v_max", "w_max")
OPTIONAL_FIELDS = ("distractors",)
"""Arrays a trace may lack (written before they existed): each loads as empty."""


@dataclass
class EpisodeTrace:
    """Per-step record of one episode (module docstring for the fields and their shapes)."""

    episode_id: str
    setup: str
    robots: tuple[str, ...]
    dt: float
    pose: np.ndarray
    action: np.ndarray
    velocity: np.ndarray
    contact: np.ndarray
    distance: np.ndarray
    geodesic: np.ndarray
    visible: np.ndarray
    target: np.ndarray
    success_step: np.ndarray
    measured: np.ndarray
    shortest_path: np.ndarray
    v_max: np.ndarray
    w_max: np.ndarray
    key: str = ""
    distractors: np.ndarray = field(default_factory=lambda: np.zeros((0, 2), np.float32))

    @property
    def steps(self) -> int:
        """``T``, the steps the episode ran."""
        return int(self.action.shape[0])

    @property
    def n_robots(self) -> int:
        return int(self.pose.shape[1])

    def active_steps(self, i: int) -> int:
        """Steps robot ``i`` was active (up to and including its arrival)."""
        return self.steps if self.success_step[i] < 0 else int(self.success_step[i])

    def robot(self, i: int) -> RobotSteps:
        """Robot ``i``'s active steps as a :class:`RobotSteps`."""
        n = self.active_steps(i)
        return RobotSteps(
            pose=self.pose[: n + 1, i].astype(np.float64),
            action=self.action[:n, i].astype(np.float64),
            velocity=self.velocity[:n, i].astype(np.float64),
            contact=self.contact[:n, i] > 0,
            distance=self.distance[: n + 1, i].astype(np.float64),
            geodesic=self.geodesic[: n + 1, i].astype(np.float64),
            visible=self.visible[: n + 1, i].astype(bool),
            success=bool(self.success_step[i] >= 0),
            dt=self.dt,
            robot_contact=self.contact[:n, i] == 2,
            target=self.target[i].astype(np.float64),
            other_targets=np.concatenate([np.delete(self.target, i, axis=0), self.distractors]).astype(
                np.float64
            ),
        )


@dataclass
class RobotSteps:
    """One robot-trial's active steps (``n`` of them): the input of every diagnosis measure.

    ``pose`` float ``[n+1, 3]``, ``action`` ``[n, 2]`` (normalised command), ``velocity`` ``[n, 2]``
    (executed, m/s and rad/s), ``contact`` bool ``[n]`` (any contact on the step), ``distance`` /
    ``geodesic`` ``[n+1]`` (metres to the target), ``visible`` bool ``[n+1]``, ``success`` (it arrived on its
    last step), ``dt`` (seconds per step), ``robot_contact`` bool ``[n]`` (the contact was with a robot;
    default: none was), ``target`` float ``[2]`` (its target's centre; default: unknown, and the measures
    that need it report None), ``other_targets`` float ``[k, 2]`` (every other target in its world: the other
    robots' and the distractors; default: unknown).
    """

    pose: np.ndarray
    action: np.ndarray
    velocity: np.ndarray
    contact: np.ndarray
    distance: np.ndarray
    geodesic: np.ndarray
    visible: np.ndarray
    success: bool
    dt: float
    robot_contact: np.ndarray | None = None
    target: np.ndarray | None = None
    other_targets: np.ndarray | None = None

    @property
    def n(self) -> int:
        return int(self.action.shape[0])

    @property
    def driven(self) -> np.ndarray:
        """float ``[n]``: arc length driven on each step, ``|v| dt`` (as ℘ in the evaluation)."""
        return np.abs(self.velocity[:, 0]) * self.dt


def save_trace(trace: EpisodeTrace, path: str | os.PathLike) -> Path:
    """Write ``trace`` as a compressed ``.npz`` at ``path`` (atomic:
    the file is complete whenever it exists)."""
    path = Path(path)
    meta = {
        "version": TRACE_VERSION,
        "episode_id": trace.episode_id,
        "setup": trace.setup,
        "robots": list(trace.robots),
        "dt": trace.dt,
        "key": trace.key,
    }
    arrays = {name: getattr(trace, name) for name in ARRAY_FIELDS + ROBOT_FIELDS + OPTIONAL_FIELDS}
    with atomic_path(path) as tmp, open(tmp, "wb") as handle:
        np.savez_compressed(handle, meta=np.array(json.dumps(meta)), **arrays)
    return path


def load_trace(path: str | os.PathLike) -> EpisodeTrace:
    """Read a trace written by :func:`save_trace`; ValueError naming the file when it is not one (or of
    another :data:`TRACE_VERSION`)."""
    try:
        with np.load(path, allow_pickle=False) as data:
            meta = json.loads(str(data["meta"]))
            arrays = {name: data[name] for name in ARRAY_FIELDS + ROBOT_FIELDS}
            arrays |= {name: data[name] for name in OPTIONAL_FIELDS if name in data.files}
    except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile) as error:
        raise ValueError(f"{path}: not a diagnosis trace ({error})") from None
    if meta.get("version") != TRACE_VERSION:
        raise ValueError(f"{path}: trace version {meta.get('version')!r}, expected {TRACE_VERSION}")
    return EpisodeTrace(
        episode_id=meta["episode_id"],
        setup=meta["setup"],
        robots=tuple(meta["robots"]),
        dt=float(meta["dt"]),
        key=meta["key"],
        **arrays,
    )


def other_target_area(episode) -> np.ndarray:
    """float ``[R]``: for each robot of ``episode`` (an evaluation ``Episode``), the share of the free space
    it can stand in (the occupancy map inflated by its radius) that lies within the success radius (1.5 m) of
    a target other than its own, the other robots' and the distractors: where a robot that wandered at random
    would end "near another target" by chance, the reference for the diagnosis's "failures ending there"."""
    from navformer_rl.constants import SUCCESS_RADIUS
    from navformer_rl.envs.robots import get_robot_spec

    world = episode.world_spec().build()
    targets = world.target_positions.astype(np.float64)
    shares = []
    for i, style in enumerate(episode.robots):
        free = np.argwhere(~world.occupancy.inflate(get_robot_spec(style).radius))
        centres = world.occupancy.cell_to_world(free)
        others = np.delete(targets, i, axis=0)
        if not len(others) or not len(centres):
            shares.append(0.0)
            continue
        gaps = np.hypot(centres[:, None, 0] - others[None, :, 0], centres[:, None, 1] - others[None, :, 1])
        shares.append(float((gaps.min(axis=1) <= SUCCESS_RADIUS).mean()))
    return np.array(shares)


class EpisodeGeometry:
    """Geodesic distance and target visibility in one episode's world.

    Args:
        world: the episode's ``WorldSpec`` (``env.world`` after the reset): walls, targets and its
            ``occupancy`` (walls and solid targets).
        specs: one ``RobotSpec`` per robot (radius: the clearance of its paths; camera offset and fov).
        reach: moves of the path grid (5: the grid ℓ of the episode sets is measured on).
    """

    def __init__(self, world, specs, reach: int = 5) -> None:
        self.world = world
        self.specs = list(specs)
        self.targets = np.asarray(world.robot_target_positions, dtype=np.float64)
        self.distractors = np.asarray(world.target_positions[world.n_robots :], dtype=np.float64)  # [K, 2]
        self.fields = [
            world.occupancy.distance_field(self.targets[i], spec.radius, reach=reach)
            for i, spec in enumerate(self.specs)
        ]

    def geodesic(self, i: int, xy: np.ndarray) -> float:
        """Metres along the shortest collision-free path from ``xy`` (snapped to the nearest free cell, as the
        start of ℓ is) to robot ``i``'s target; ``inf`` if cut off."""
        cell = self.world.occupancy.snap_to_free(xy, self.specs[i].radius)
        return float(self.fields[i][cell])

    def visible(self, i: int, pose: np.ndarray) -> bool:
        """Whether robot ``i``'s target centre is in its camera's view at ``pose`` (fov, walls; any range)."""
        from navformer_rl.experts.visibility import target_visible

        spec = self.specs[i]
        return target_visible(
            pose,
            self.targets[i],
            self.world.walls,
            math.radians(spec.camera_fov_deg),
            math.inf,
            spec.camera_forward,
        )

    def measure(self, poses: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(distance, geodesic, visible)`` float ``[R]``, float ``[R]``,
        bool ``[R]`` at ``poses`` ``[R, 3]``."""
        poses = np.asarray(poses, dtype=np.float64)
        distance = np.hypot(*(poses[:, :2] - self.targets).T)
        geodesic = np.array([self.geodesic(i, p[:2]) for i, p in enumerate(poses)])
        visible = np.array([self.visible(i, p) for i, p in enumerate(poses)], dtype=bool)
        return distance, geodesic, visible
