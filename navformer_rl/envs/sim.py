"""The simulator: kinematic unicycle robots with analytic collisions, pybullet only for cameras and rays.

Motion and contacts are pure numpy (paper §VII.A: 0.2 s per step). pybullet (one ``DIRECT`` client per
:class:`Simulator`) holds a copy of the scene built from primitives and is only asked to render the
84x84 cameras (tiny renderer, no shadows) and to cast rays; moved robots are re-synchronised lazily
right before either. ``step`` never renders.
"""

from __future__ import annotations

import math
import os
import sys
from collections.abc import Sequence
from types import ModuleType
from typing import NamedTuple

import numpy as np

from navformer_rl.constants import CONTROL_DT, IMAGE_SIZE
from navformer_rl.envs.robots import RobotSpec
from navformer_rl.envs.scene import (
    WALL_PALETTE,
    add_box,
    add_floor,
    add_furnished_scene,
    add_robot,
    add_target,
)
from navformer_rl.envs.world import WorldSpec
from navformer_rl.utils.checks import check_int, check_number

COLLISION_NONE, COLLISION_WALL, COLLISION_ROBOT = 0, 1, 2
"""Collision kinds: static obstacles (walls and solid targets) count as walls."""

CONTACT_EPS = 1e-3
"""Metres: after a step, a robot whose disc is within this distance of a wall, a target or another visible
robot is in contact (the blocked motion stops within 0.1 mm of the obstacle, well inside this)."""

CAMERA_NEAR = 0.05
_PATH_SAMPLE = 0.05  # metres between collision checks along a step's arc
_REFINE = 32
_BUCKET = 0.5  # metres, spatial hash of the static boxes
_HIDDEN_Z = -50.0


def import_pybullet() -> ModuleType:
    """The ``pybullet`` module, imported with this process's stdout and stderr silenced at the file-descriptor
    level: its C code prints a "pybullet build time" line on import, once in every worker process."""
    if "pybullet" in sys.modules:
        return sys.modules["pybullet"]
    import ctypes

    sys.stdout.flush()
    sys.stderr.flush()
    saved = os.dup(1), os.dup(2)
    devnull = os.open(os.devnull, os.O_WRONLY)
    try:
        os.dup2(devnull, 1)
        os.dup2(devnull, 2)
        import pybullet

        ctypes.CDLL(None).fflush(None)  # C stdio may hold the line until after the descriptors are back
    finally:
        os.dup2(saved[0], 1)
        os.dup2(saved[1], 2)
        for fd in (*saved, devnull):
            os.close(fd)
    return pybullet


class StepContacts(NamedTuple):
    """Contacts of one step: ``collided`` bool ``[R]``, ``kind`` int8 ``[R]`` (0 none, 1 wall, 2 robot).

    ``collided[i]``: robot ``i``'s motion was cut short, or its disc ends the step in contact (within
    :data:`CONTACT_EPS`) with a wall, a target or another robot, whether or not it moved itself.
    """

    collided: np.ndarray
    kind: np.ndarray


def validate_actions(actions, n: int) -> np.ndarray:
    """Check normalised actions and clip them: returns float64 ``[n, 2]`` in ``[-1, 1]``.

    ValueError when the actions are not numbers, the shape is not ``[n, 2]`` (or ``[2]`` for ``n == 1``) or
    a value is NaN/inf. Finite values outside ``[-1, 1]`` are clipped, not refused.
    """
    try:
        a = np.asarray(actions, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(
            f"actions must be numbers (linear, angular) in [-1, 1], shape {_expected_action_shape(n)}; "
            f"got {actions!r}"
        ) from None
    if n == 1 and a.shape == (2,):
        a = a[None]
    if a.shape != (n, 2):
        raise ValueError(
            f"actions must have shape {_expected_action_shape(n)}: (linear, angular) per robot in [-1, 1] "
            f"(out-of-range values are clipped), got shape {a.shape}"
        )
    if not np.isfinite(a).all():
        raise ValueError(
            f"actions must be finite numbers in [-1, 1] (out-of-range values are clipped; NaN and inf are "
            f"refused), got {a.tolist()}"
        )
    return np.clip(a, -1.0, 1.0)


def _expected_action_shape(n: int) -> str:
    return "(1, 2) or (2,)" if n == 1 else f"({n}, 2)"


def _arc_point(x: float, y: float, th: float, v: float, w: float, t: float) -> tuple[float, float]:
    """Position after driving the unicycle ``(v, w)`` for ``t`` seconds from ``(x, y, th)`` (scalar math)."""
    if abs(w) > 1e-9:
        return x + v / w * (math.sin(th + w * t) - math.sin(th)), y - v / w * (
            math.cos(th + w * t) - math.cos(th)
        )
    return x + v * t * math.cos(th), y + v * t * math.sin(th)


def _contact_kind(px: float, py: float, r2: float, boxes: list, discs: list) -> int:
    """Contact kind of a disc (squared radius ``r2``) at ``(px, py)``: 2 robot, 1 wall/target, 0 none."""
    kind = COLLISION_NONE
    for cx, cy, reach, disc_kind in discs:
        if (px - cx) ** 2 + (py - cy) ** 2 < reach * reach:
            if disc_kind == COLLISION_ROBOT:
                return COLLISION_ROBOT
            kind = COLLISION_WALL
    if kind:
        return kind
    for cx, cy, hx, hy in boxes:
        dx = abs(px - cx) - hx
        dy = abs(py - cy) - hy
        if dx < 0.0:
            dx = 0.0
        if dy < 0.0:
            dy = 0.0
        if dx * dx + dy * dy < r2:
            return COLLISION_WALL
    return COLLISION_NONE


def _clearance(px: float, py: float, radius: float, boxes: list, discs: list) -> float:
    """Free distance between a disc of ``radius`` at ``(px, py)`` and the nearest box or disc
    (``inf`` if none)."""
    best = math.inf
    for cx, cy, hx, hy in boxes:
        dx = max(abs(px - cx) - hx, 0.0)
        dy = max(abs(py - cy) - hy, 0.0)
        best = min(best, math.sqrt(dx * dx + dy * dy) - radius)
    for cx, cy, reach, _ in discs:
        best = min(best, math.hypot(px - cx, py - cy) - reach)
    return best


def wrap_angle(angle: float) -> float:
    """Angle in radians wrapped to [-pi, pi)."""
    return (angle + math.pi) % (2 * math.pi) - math.pi


class Simulator:
    """Robots in a :class:`WorldSpec`, with cameras and rays through one pybullet DIRECT client.

    Args:
        world: the world (walls, targets, starts).
        robot_specs: one :class:`RobotSpec` per robot (a single spec is repeated for every start).
        poses: optional float ``[R, 3]`` initial poses; default ``world.starts`` (then ``R`` must match).
        textured: paint the floor with a 1 m tile pattern and give each wall its own colour (spatial cues
            for the cameras); False draws a plain floor and uniform walls.
        dt: seconds per step, > 0 (default 0.2, paper §VII.A).

    ValueError for a world that is not a :class:`WorldSpec`, specs that are not :class:`RobotSpec` (e.g.
    style names), a count mismatch, a non-positive or non-finite ``dt``, or colliding ``poses``.
    """

    def __init__(
        self,
        world: WorldSpec,
        robot_specs: RobotSpec | Sequence[RobotSpec],
        poses: np.ndarray | None = None,
        textured: bool = True,
        dt: float = CONTROL_DT,
    ):
        if not isinstance(world, WorldSpec):
            raise ValueError(f"world must be a WorldSpec (see generate_world), got {type(world).__name__}")
        if isinstance(robot_specs, RobotSpec):
            robot_specs = [robot_specs] * (world.n_robots if poses is None else len(poses))
        try:
            specs = None if isinstance(robot_specs, str) else list(robot_specs)
        except TypeError:
            specs = None
        if specs is None or not all(isinstance(s, RobotSpec) for s in specs):
            raise ValueError(
                "robot_specs must be a RobotSpec or a sequence of them (robots.get_robot_spec(name) turns a "
                f"style name into one), got {robot_specs!r}"
            )
        self.robot_specs = specs
        self.n_robots = len(self.robot_specs)
        if self.n_robots < 1:
            raise ValueError("a Simulator needs at least one robot spec")
        if poses is None and self.n_robots != world.n_robots:
            raise ValueError(
                f"{self.n_robots} robot specs but the world has {world.n_robots} starts; "
                "pass poses explicitly"
            )
        self.world = world
        self.dt = check_number(dt, "dt", greater_than=0.0, unit="seconds per step")
        self._radii = np.array([s.radius for s in self.robot_specs], dtype=np.float64)
        self._limits = np.array([(s.v_max, s.w_max) for s in self.robot_specs], dtype=np.float64)
        self._boxes = world.obstacle_boxes
        self._circles = world.obstacle_circles
        self._poses = np.zeros((self.n_robots, 3), dtype=np.float64)
        self._velocities = np.zeros((self.n_robots, 2), dtype=np.float64)
        self._visible = np.ones(self.n_robots, dtype=bool)
        self._dirty = np.ones(self.n_robots, dtype=bool)
        self._broadphase_stale = True
        self._circle_list = [tuple(float(v) for v in c) for c in self._circles]
        self._build_box_buckets()
        self._textured = textured
        pybullet = import_pybullet()  # lazy: importing this module starts nothing
        self._p = pybullet
        self._client = pybullet.connect(pybullet.DIRECT)
        self._robot_bodies: list[int] = []
        self._projections: dict[float, list[float]] = {}
        self._build_scene()
        self.set_poses(world.starts if poses is None else poses)

    # ------------------------------------------------------------------ scene
    def _build_scene(self) -> None:
        p, c = self._p, self._client
        if self.world.style is not None:  # a furnished world paints itself
            add_furnished_scene(p, c, self.world.size, self.world.walls, self.world.style, self._textured)
        else:
            add_floor(p, c, self.world.size, self._textured)
            rng = np.random.default_rng(self.world.seed)
            height = self.world.wall_height
            for k, (cx, cy, hx, hy) in enumerate(self.world.walls.astype(np.float64)):
                rgb = WALL_PALETTE[rng.integers(len(WALL_PALETTE))] if self._textured else WALL_PALETTE[4]
                shade = 1.0 if k % 2 == 0 else 0.92
                add_box(p, c, (cx, cy, height / 2), (hx, hy, height / 2), (*(rgb * shade), 1.0))
        for target in self.world.targets:
            add_target(p, c, target.shape, target.rgba, target.half_extent, target.position)
        for spec in self.robot_specs:
            self._robot_bodies.append(add_robot(p, c, spec, (0.0, 0.0, _HIDDEN_Z)))

    # ------------------------------------------------------------------ state
    @property
    def poses(self) -> np.ndarray:
        """float32 ``[R, 3]`` ``(x, y, yaw)``, yaw wrapped to ``[-pi, pi)``."""
        return self._poses.astype(np.float32)

    @property
    def velocities(self) -> np.ndarray:
        """float32 ``[R, 2]`` ``(v, w)`` executed during the last step (blocked motion lowers ``v``)."""
        return self._velocities.astype(np.float32)

    @property
    def radii(self) -> np.ndarray:
        """float64 ``[R]`` collision disc radii."""
        return self._radii.copy()

    def set_poses(self, poses, indices: Sequence[int] | None = None) -> None:
        """Teleport robots (all, or ``indices``) to ``poses`` float ``[k, 3]`` and zero their velocities.

        ValueError when a pose is not finite, when the robot's disc leaves the world ``[0, size]^2`` (it
        needs ``radius <= x <= size - radius``, the same for ``y``), or when it overlaps a wall, a target or
        another robot (1 mm tolerance for both).
        """
        idx = np.arange(self.n_robots) if indices is None else np.asarray(indices, dtype=np.int64).reshape(-1)
        poses = np.asarray(poses, dtype=np.float64)
        if poses.shape != (len(idx), 3) or not np.all(np.isfinite(poses)):
            raise ValueError(
                f"poses must be finite float [{len(idx)}, 3] (x, y, yaw), got shape {poses.shape}"
            )
        new = self._poses.copy()
        new[idx] = poses
        new[idx, 2] = (poses[:, 2] + math.pi) % (2 * math.pi) - math.pi
        size = self.world.size
        for i in idx:
            hit = self._static_overlap(new[i : i + 1, :2], self._radii[i] - 1e-3)[0]
            others = self._solid_others(i)
            gaps = np.hypot(*(new[others, :2] - new[i, :2]).T) - self._radii[others] - self._radii[i]
            if hit or (gaps.size and gaps.min() < -1e-3):
                raise ValueError(
                    f"pose {new[i].tolist()} of robot {i} overlaps a wall, a target or another robot"
                )
            r = float(self._radii[i])
            x, y = new[i, :2]
            if not (r - 1e-3 <= x <= size - r + 1e-3 and r - 1e-3 <= y <= size - r + 1e-3):
                raise ValueError(
                    f"pose {new[i].tolist()} of robot {i} is outside the world: its disc (radius {r} m) must "
                    f"lie within [0, {size}]^2, i.e. {r} <= x, y <= {size - r}"
                )
        self._poses = new
        self._velocities[idx] = 0.0
        self._dirty[idx] = True

    def set_robot_visible(self, i: int, visible: bool) -> None:
        """Show or hide robot ``i`` (e.g. for D_ssl static views). A hidden robot is absent from camera
        images and ray scans and does not collide with other robots (walls and targets still block it)."""
        self._check_index(i)
        self._visible[i] = bool(visible)
        self._dirty[i] = True

    def _check_index(self, i: int) -> None:
        if not 0 <= int(i) < self.n_robots:
            raise ValueError(f"robot index {i} out of range [0, {self.n_robots})")

    # ------------------------------------------------------------------ motion
    def _static_overlap(self, points: np.ndarray, radius: float) -> np.ndarray:
        """bool ``[S]``: a disc of ``radius`` at each point ``[S, 2]`` overlaps a wall box or a target."""
        b = self._boxes
        dx = np.maximum(np.abs(points[:, None, 0] - b[None, :, 0]) - b[None, :, 2], 0.0)
        dy = np.maximum(np.abs(points[:, None, 1] - b[None, :, 1]) - b[None, :, 3], 0.0)
        hit = (dx * dx + dy * dy < radius * radius).any(axis=1)
        if len(self._circles):
            cc = self._circles
            d2 = (points[:, None, 0] - cc[None, :, 0]) ** 2 + (points[:, None, 1] - cc[None, :, 1]) ** 2
            hit |= (d2 < (radius + cc[None, :, 2]) ** 2).any(axis=1)
        return hit

    def _solid_others(self, i: int) -> np.ndarray:
        """int64 indices of the visible robots other than ``i`` (none when ``i`` itself is hidden)."""
        if not self._visible[i]:
            return np.zeros(0, dtype=np.int64)
        return np.flatnonzero(self._visible & (np.arange(self.n_robots) != i))

    def _build_box_buckets(self) -> None:
        """Spatial hash of the static boxes: for each 0.5 m bucket, the boxes within reach of any point in it
        (largest robot radius + longest step + margin), so a step only tests a handful of boxes."""
        reach = float(self._radii.max() + self._limits[:, 0].max() * self.dt + 0.05)
        n = int(math.ceil(self.world.size / _BUCKET)) + 2
        centres = (np.arange(n) - 1 + 0.5) * _BUCKET
        cx, cy = np.meshgrid(centres, centres, indexing="ij")
        b = self._boxes
        dx = np.maximum(np.abs(cx.reshape(-1, 1) - b[None, :, 0]) - b[None, :, 2], 0.0)
        dy = np.maximum(np.abs(cy.reshape(-1, 1) - b[None, :, 1]) - b[None, :, 3], 0.0)
        near = np.hypot(dx, dy) < reach + _BUCKET * math.sqrt(0.5)
        self._bucket_boxes = [[tuple(float(v) for v in box) for box in b[row]] for row in near]
        self._n_buckets = n

    def _nearby(self, i: int, reach: float) -> tuple[list, list]:
        """Obstacles robot ``i`` may touch within ``reach`` metres of travel (``reach`` <= the longest step).

        Returns the boxes ``[(cx, cy, hx, hy), ...]`` of its spatial-hash bucket (a superset) and the discs
        ``[(x, y, r_obstacle + r_i, kind), ...]`` in reach (kind 1 sphere target, 2 robot). Plain Python:
        for a handful of obstacles it is several times faster than numpy.
        """
        x, y = self._poses[i, 0], self._poses[i, 1]
        r = self._radii[i]
        bx = min(max(int(x // _BUCKET) + 1, 0), self._n_buckets - 1)
        by = min(max(int(y // _BUCKET) + 1, 0), self._n_buckets - 1)
        boxes = self._bucket_boxes[bx * self._n_buckets + by]
        candidates = [(cx, cy, cr, COLLISION_WALL) for cx, cy, cr in self._circle_list]
        if self._visible[i]:
            poses, radii = self._poses, self._radii
            candidates += [
                (poses[j, 0], poses[j, 1], radii[j], COLLISION_ROBOT)
                for j in range(self.n_robots)
                if j != i and self._visible[j]
            ]
        discs = []
        for cx, cy, cr, kind in candidates:
            reach_ij = cr + r
            if (cx - x) ** 2 + (cy - y) ** 2 < (reach_ij + reach) ** 2:
                discs.append((cx, cy, reach_ij, kind))
        return boxes, discs

    def _free_fraction(self, i: int, v: float, w: float) -> tuple[float, int]:
        """Largest collision-free fraction of robot ``i``'s step along its arc and the contact kind that
        stopped it (0 when the whole step is free). Checked every 5 cm, then refined twice on 32
        sub-fractions (resolution < 0.1 mm of travel)."""
        distance = abs(v) * self.dt
        if distance == 0.0:
            return 1.0, COLLISION_NONE
        boxes, discs = self._nearby(i, distance + 1e-3)
        if not boxes and not discs:
            return 1.0, COLLISION_NONE
        x, y, th = (float(c) for c in self._poses[i])
        if _clearance(x, y, float(self._radii[i]), boxes, discs) > distance:
            return 1.0, COLLISION_NONE  # the arc stays within `distance` of its start: nothing in reach
        r2 = float(self._radii[i]) ** 2
        n = max(1, math.ceil(distance / _PATH_SAMPLE))
        lo, hi, kind = 0.0, 1.0, COLLISION_NONE
        fractions = [k / n for k in range(1, n + 1)]
        for _ in range(3):
            hit_at, hit_kind = -1, COLLISION_NONE
            for k, f in enumerate(fractions):
                px, py = _arc_point(x, y, th, v, w, f * self.dt)
                hit_kind = _contact_kind(px, py, r2, boxes, discs)
                if hit_kind:
                    hit_at = k
                    break
            if hit_at < 0:
                if kind == COLLISION_NONE:
                    return 1.0, COLLISION_NONE
                lo = fractions[-1]
            else:
                lo, hi, kind = (fractions[hit_at - 1] if hit_at else lo), fractions[hit_at], hit_kind
            fractions = [lo + (hi - lo) * k / (_REFINE + 1) for k in range(1, _REFINE + 1)]
        return lo, kind

    def step(self, actions, active=None) -> StepContacts:
        """Drive every active robot with normalised ``actions`` float ``[R, 2]`` for ``dt`` seconds.

        Robots move one after the other in index order (a robot sees the others' updated positions).
        Each follows its unicycle arc up to the largest collision-free fraction of the step (see
        ``_free_fraction``); the heading always turns by the full ``w * dt`` (the footprint is a disc, so
        turning never collides). Inactive robots (``active`` bool ``[R]`` False) do not move.

        A step is a collision for robot ``i`` (steps in contact) when its commanded motion was cut
        short, or when, after every robot moved, its disc is within :data:`CONTACT_EPS` of a wall, a target
        or another visible robot: a robot that is driven into (standing, turning or inactive) is flagged
        too. The kind is 2 if a robot is involved (stopped it or touches it), else 1 (wall or target).

        Returns :class:`StepContacts`. ValueError for a wrong shape or NaN/inf actions (out-of-range
        values are clipped).
        """
        a = validate_actions(actions, self.n_robots)
        if active is None:
            active = np.ones(self.n_robots, dtype=bool)
        active = np.asarray(active, dtype=bool).reshape(-1)
        if active.shape != (self.n_robots,):
            raise ValueError(f"active must be bool [{self.n_robots}], got shape {active.shape}")
        commands = a * self._limits
        kinds = np.zeros(self.n_robots, dtype=np.int8)
        for i in range(self.n_robots):
            if not active[i]:
                self._velocities[i] = 0.0
                continue
            v, w = float(commands[i, 0]), float(commands[i, 1])
            fraction, kind = self._free_fraction(i, v, w)
            th = float(self._poses[i, 2])
            x, y = _arc_point(
                float(self._poses[i, 0]), float(self._poses[i, 1]), th, v, w, fraction * self.dt
            )
            self._poses[i] = (x, y, wrap_angle(th + w * self.dt))
            self._velocities[i] = (v * fraction, w)
            kinds[i] = kind
            self._dirty[i] = True
        for i in range(self.n_robots):
            if kinds[i] != COLLISION_ROBOT:
                kinds[i] = max(int(kinds[i]), self._touching(i))
        return StepContacts(collided=kinds != COLLISION_NONE, kind=kinds)

    def _touching(self, i: int) -> int:
        """Contact kind of robot ``i``'s disc, grown by :data:`CONTACT_EPS`, where it stands now: 2 another
        visible robot, 1 a wall or target, 0 none. Reuses the step's broad phase (``_nearby``) and contact
        test (``_contact_kind``): a handful of boxes and discs, no pybullet query."""
        boxes, discs = self._nearby(i, CONTACT_EPS)
        reach = float(self._radii[i]) + CONTACT_EPS
        grown = [(cx, cy, r + CONTACT_EPS, kind) for cx, cy, r, kind in discs]
        return _contact_kind(float(self._poses[i, 0]), float(self._poses[i, 1]), reach * reach, boxes, grown)

    # ------------------------------------------------------------------ pybullet sync, cameras, rays
    def _sync(self) -> None:
        """Copy moved robots' poses (and visibility) into the pybullet client."""
        if not self._dirty.any():
            return
        p, c = self._p, self._client
        for i in np.flatnonzero(self._dirty):
            x, y, yaw = self._poses[i]
            z = 0.0 if self._visible[i] else _HIDDEN_Z
            orn = (0.0, 0.0, math.sin(yaw / 2), math.cos(yaw / 2))
            p.resetBasePositionAndOrientation(self._robot_bodies[i], (x, y, z), orn, physicsClientId=c)
        self._dirty[:] = False
        self._broadphase_stale = True

    def _projection(self, fov_deg: float) -> list[float]:
        if fov_deg not in self._projections:
            far = self.world.size * 1.5
            self._projections[fov_deg] = self._p.computeProjectionMatrixFOV(fov_deg, 1.0, CAMERA_NEAR, far)
        return self._projections[fov_deg]

    def render_pose(self, pose, spec: RobotSpec) -> np.ndarray:
        """uint8 ``[84, 84, 3]`` RGB view of a camera of robot style ``spec`` at ``pose`` (x, y, yaw)."""
        self._sync()
        x, y, yaw = (float(v) for v in pose)
        cos, sin = math.cos(yaw), math.sin(yaw)
        eye = (x + spec.camera_forward * cos, y + spec.camera_forward * sin, spec.camera_height)
        view = self._p.computeViewMatrix(eye, (eye[0] + cos, eye[1] + sin, eye[2]), (0.0, 0.0, 1.0))
        out = self._p.getCameraImage(
            IMAGE_SIZE,
            IMAGE_SIZE,
            view,
            self._projection(spec.camera_fov_deg),
            renderer=self._p.ER_TINY_RENDERER,
            shadow=0,
            flags=self._p.ER_NO_SEGMENTATION_MASK,
            physicsClientId=self._client,
        )
        return np.asarray(out[2], dtype=np.uint8).reshape(IMAGE_SIZE, IMAGE_SIZE, 4)[:, :, :3].copy()

    def render(self, i: int) -> np.ndarray:
        """uint8 ``[84, 84, 3]`` RGB (HWC) image of robot ``i``'s onboard camera."""
        self._check_index(i)
        return self.render_pose(self._poses[i], self.robot_specs[i])

    def render_all(self, active=None) -> np.ndarray:
        """uint8 ``[R, 84, 84, 3]``: every robot's camera; rows with ``active`` False are left zero."""
        frames = np.zeros((self.n_robots, IMAGE_SIZE, IMAGE_SIZE, 3), dtype=np.uint8)
        active = np.ones(self.n_robots, dtype=bool) if active is None else np.asarray(active, dtype=bool)
        for i in np.flatnonzero(active):
            frames[i] = self.render(int(i))
        return frames

    def ray_scan_all(self, indices: Sequence[int], n_rays: int, fov: float, max_range: float) -> np.ndarray:
        """Planar lidar of several robots in one ``rayTestBatch``: float32 ``[k, n_rays]`` hit distances.

        Rays start at each robot's disc edge, 0.15 m above the floor, spread evenly over ``fov`` radians
        centred on the heading (a full circle for ``fov >= 2 pi``), and return the distance from the robot
        centre to the first wall, target or visible robot, or ``max_range`` when nothing is hit.
        ValueError unless ``n_rays`` is an integer >= 1 and ``fov``, ``max_range`` are finite numbers > 0.
        """
        idx = np.asarray(indices, dtype=np.int64).reshape(-1)
        for i in idx:
            self._check_index(int(i))
        n_rays = check_int(n_rays, "n_rays")
        fov = check_number(fov, "fov", greater_than=0.0, unit="radians")
        max_range = check_number(max_range, "max_range", greater_than=0.0, unit="metres")
        self._sync()
        if self._broadphase_stale:  # moved bodies need fresh AABBs before ray tests (not for rendering)
            self._p.performCollisionDetection(physicsClientId=self._client)
            self._broadphase_stale = False
        if fov >= 2 * math.pi - 1e-9:
            offsets = np.linspace(-math.pi, math.pi, n_rays, endpoint=False)
        else:
            offsets = np.linspace(-fov / 2, fov / 2, n_rays) if n_rays > 1 else np.zeros(1)
        angles = self._poses[idx, 2][:, None] + offsets[None, :]
        dirs = np.stack([np.cos(angles), np.sin(angles)], axis=-1)  # [k, n, 2]
        start_r = (self._radii[idx] + 1e-3)[:, None, None]
        centres = self._poses[idx, None, :2]
        starts = centres + dirs * start_r
        ends = centres + dirs * max_range
        z = np.full(starts.shape[:-1] + (1,), 0.15)
        froms = np.concatenate([starts, z], axis=-1).reshape(-1, 3)
        tos = np.concatenate([ends, z], axis=-1).reshape(-1, 3)
        dist = np.full(len(froms), float(max_range))
        for s in range(0, len(froms), 16000):  # pybullet caps one batch at 16384 rays
            hits = self._p.rayTestBatch(
                froms[s : s + 16000].tolist(),
                tos[s : s + 16000].tolist(),
                numThreads=0,
                physicsClientId=self._client,
            )
            frac = np.array([h[2] if h[0] >= 0 else 1.0 for h in hits])
            seg_start = np.repeat(start_r.reshape(-1), n_rays)[s : s + 16000]
            dist[s : s + 16000] = np.where(frac < 1.0, seg_start + frac * (max_range - seg_start), max_range)
        return dist.reshape(len(idx), n_rays).astype(np.float32)

    def ray_scan(self, i: int, n_rays: int, fov: float, max_range: float) -> np.ndarray:
        """Planar lidar of robot ``i``: float32 ``[n_rays]`` (see :meth:`ray_scan_all`)."""
        return self.ray_scan_all([i], n_rays, fov, max_range)[0]

    def close(self) -> None:
        """Disconnect the pybullet client (idempotent)."""
        if self._client is not None:
            try:
                self._p.disconnect(physicsClientId=self._client)
            except Exception:  # already disconnected  # noqa: BLE001
                pass
            self._client = None

    def __del__(self) -> None:
        if getattr(self, "_client", None) is not None:
            self.close()


def same_scene(a: WorldSpec, b: WorldSpec) -> bool:
    """True when two worlds share walls and targets (only the starts differ)."""
    return (
        a.size == b.size
        and a.walls.shape == b.walls.shape
        and np.array_equal(a.walls, b.walls)
        and len(a.targets) == len(b.targets)
        and all(
            ta.shape == tb.shape and ta.color == tb.color and np.array_equal(ta.position, tb.position)
            for ta, tb in zip(a.targets, b.targets)
        )
    )


def simulator_for_world(
    world: WorldSpec, specs: list[RobotSpec], textured: bool, previous: Simulator | None
) -> Simulator:
    """A simulator showing ``world``: ``previous`` re-posed when it already shows the same walls and targets
    (a new episode in the same maze costs no scene rebuild), otherwise a new one (``previous`` is closed).

    ValueError when ``world.starts`` do not fit (see :meth:`Simulator.set_poses`); ``previous`` may then be
    closed already, so a caller must not keep using it."""
    if previous is not None and same_scene(world, previous.world):
        previous.set_poses(world.starts)
        previous.world = world
        return previous
    if previous is not None:
        previous.close()
    return Simulator(world, specs, textured=textured)
