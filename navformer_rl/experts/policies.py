"""Simulator-driven experts: exploration (frontier + A* + DWA), NH-ORCA teams, and the privileged FCA.

All three share one interface: ``reset(world, sim, rng)`` at the start of an episode, then
``act(sim, active) -> float32 [R, 2]`` normalised actions ``(v / v_max, w / w_max)`` for every robot of the
simulator (zero rows for inactive robots). Per-robot flags after each ``act``: ``reached`` (stopped within
``stop_radius`` of its target), ``failed`` (gave up: nothing left to explore, or the 500-step timeout),
``stuck_events``. Everything is deterministic given the ``numpy.random.Generator`` passed to ``reset``.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from navformer_rl.constants import MAX_EPISODE_STEPS, SUCCESS_RADIUS
from navformer_rl.envs.robots import RobotSpec
from navformer_rl.experts.dwa import ClearanceMap, DWAConfig, DWAPlanner
from navformer_rl.experts.grid import descend, nearest_true_cell
from navformer_rl.experts.lidar import StaticLidar
from navformer_rl.experts.navigator import FrontierNavigator, LidarConfig, NavigatorConfig
from navformer_rl.experts.nh_orca import NHORCA, NHORCAConfig
from navformer_rl.experts.visibility import target_visible


def normalise(commands: np.ndarray, specs: list[RobotSpec]) -> np.ndarray:
    """``(v, w)`` float ``[R, 2]`` -> float32 ``[R, 2]`` actions in ``[-1, 1]``."""
    limits = np.array([(s.v_max, s.w_max) for s in specs], dtype=np.float64)
    return np.clip(commands / limits, -1.0, 1.0).astype(np.float32)


def _check_active(active, n: int) -> np.ndarray:
    active = np.ones(n, dtype=bool) if active is None else np.asarray(active, dtype=bool).reshape(-1)
    if active.shape != (n,):
        raise ValueError(f"active must be bool [{n}], got shape {active.shape}")
    return active


@dataclass(frozen=True)
class CameraConfig:
    """When the expert 'sees' its target: camera FOV from the robot spec, this range, line of sight."""

    max_range: float = 5.0


@dataclass(frozen=True)
class ExpertConfig:
    """Shared expert settings."""

    lidar: LidarConfig = field(default_factory=LidarConfig)
    navigator: NavigatorConfig = field(default_factory=NavigatorConfig)
    camera: CameraConfig = field(default_factory=CameraConfig)
    stop_radius: float = 1.2
    """Stop once this close to the target centre (inside the 1.5 m success radius)."""
    max_steps: int = MAX_EPISODE_STEPS

    def __post_init__(self) -> None:
        if not 0 < self.stop_radius < SUCCESS_RADIUS:
            raise ValueError(f"stop_radius must be in (0, {SUCCESS_RADIUS}), got {self.stop_radius}")


class _ExpertBase:
    """Episode bookkeeping shared by the experts."""

    def __init__(self, config: ExpertConfig | None = None) -> None:
        self.config = config or ExpertConfig()
        self.world = None
        self.specs: list[RobotSpec] = []
        self.rng: np.random.Generator | None = None
        self.step_count = 0
        self.reached = np.zeros(0, dtype=bool)
        self.failed = np.zeros(0, dtype=bool)

    def reset(self, world, sim, rng: np.random.Generator) -> None:
        """Start an episode in ``world`` driven through ``sim`` (robot ``i`` looks for
        ``world.targets[i]``)."""
        if not isinstance(rng, np.random.Generator):
            raise ValueError(f"rng must be a numpy.random.Generator, got {type(rng).__name__}")
        if sim.n_robots != world.n_robots:
            raise ValueError(
                f"simulator has {sim.n_robots} robots but the world has {world.n_robots} targets"
            )
        self.world, self.specs, self.rng = world, list(sim.robot_specs), rng
        self.step_count = 0
        self.reached = np.zeros(sim.n_robots, dtype=bool)
        self.failed = np.zeros(sim.n_robots, dtype=bool)
        self.targets = world.target_positions[: sim.n_robots].astype(np.float64)  # robot i's: targets[i]
        self.boxes = world.obstacle_boxes
        self.circles = world.obstacle_circles
        self.lidar = StaticLidar.for_world(world)

    def _scans(self, sim, idx: np.ndarray, poses: np.ndarray) -> np.ndarray:
        """float64 ``[k, n_rays]`` lidar ranges of robots ``idx`` (see :class:`LidarConfig` ``source``)."""
        lidar = self.config.lidar
        if lidar.source == "pybullet":
            return sim.ray_scan_all(idx, lidar.n_rays, 2 * math.pi, lidar.max_range).astype(np.float64)
        return np.stack([self.lidar.scan(poses[i], lidar.angles, lidar.max_range) for i in idx])

    def _update_reached(self, poses: np.ndarray) -> None:
        d = np.hypot(*(poses[:, :2] - self.targets).T)
        self.reached |= d <= self.config.stop_radius

    def _tick(self) -> None:
        self.step_count += 1
        if self.step_count >= self.config.max_steps:
            self.failed |= ~self.reached


class ExplorationExpert(_ExpertBase):
    """Frontier exploration on the robot's own lidar map + A* + DWA; drives to the target once the camera
    sees it (paper §V, D_e). Robots are independent (each has its own map); typically ``R = 1``.
    """

    def __init__(self, config: ExpertConfig | None = None, dwa: DWAConfig | None = None) -> None:
        super().__init__(config)
        self.dwa_config = dwa
        """One DWA config for every robot; default: each robot's from its spec (:func:`dwa_config`)."""
        self.navigators: list[FrontierNavigator] = []
        self.dwas: list[DWAPlanner] = []

    def reset(self, world, sim, rng: np.random.Generator) -> None:
        """Start an episode: one navigator (map radius, camera) and one DWA planner per robot,
        from its spec."""
        super().reset(world, sim, rng)
        self.navigators = [
            FrontierNavigator(
                world.size,
                navigator_config(self.config.navigator, spec),
                self.targets[i],
                camera=(math.radians(spec.camera_fov_deg), self.config.camera.max_range),
            )
            for i, spec in enumerate(self.specs)
        ]
        self.dwas = [DWAPlanner(self.dwa_config or dwa_config(spec, sim.dt)) for spec in self.specs]

    @property
    def stuck_events(self) -> np.ndarray:
        """int64 ``[R]`` times each robot made no progress and re-planned (blacklisting frontier goals)."""
        return np.array([n.stuck_events for n in self.navigators], dtype=np.int64)

    def act(self, sim, active=None) -> np.ndarray:
        """float32 ``[R, 2]`` normalised actions for every robot of ``sim`` (zeros where inactive)."""
        active = _check_active(active, sim.n_robots)
        poses = sim.poses.astype(np.float64)
        vels = sim.velocities.astype(np.float64)
        self._update_reached(poses)
        commands = np.zeros((sim.n_robots, 2))
        run = np.flatnonzero(active & ~self.reached & ~self.failed)
        if len(run):
            scans = self._scans(sim, run, poses)
            for k, i in enumerate(run):
                commands[i] = self._act_one(int(i), poses[i], vels[i], scans[k])
        self._tick()
        return normalise(commands, self.specs)

    def _act_one(self, i: int, pose: np.ndarray, vel: np.ndarray, scan: np.ndarray) -> np.ndarray:
        nav = self.navigators[i]
        spec = self.specs[i]
        nav.observe(pose, scan, self.config.lidar)
        if not nav.target_mode and target_visible(
            pose,
            self.targets[i],
            self.world.walls,
            math.radians(spec.camera_fov_deg),
            self.config.camera.max_range,
            spec.camera_forward,
        ):
            nav.set_target_seen()
        carrot = nav.carrot(pose)
        if carrot is None:
            if nav.exhausted:  # explored everything reachable without seeing the target
                self.failed[i] = True
            return np.zeros(2)
        cfg = self.dwas[i].config
        clearance = ClearanceMap(
            nav.map.occupied(),
            nav.map.resolution,
            tuple(nav.map.origin),
            pose[:2],
            cfg.map_half_size,
            cfg.clearance_range,
        )
        res = self.dwas[i].plan(pose, vel, carrot, clearance)
        return np.array([res.v, res.w])


def nh_orca_config(spec: RobotSpec, dt: float, **overrides) -> NHORCAConfig:
    """NH-ORCA parameters from a robot's radius and limits (``overrides``: any other NHORCAConfig field)."""
    return NHORCAConfig(
        radius=spec.radius,
        v_max=spec.v_max,
        w_max=spec.w_max,
        a_max=spec.a_max,
        alpha_max=spec.alpha_max,
        dt=dt,
        **overrides,
    )


def nh_orca_configs(
    specs: list[RobotSpec], dt: float, given: NHORCAConfig | Sequence[NHORCAConfig] | None, **overrides
) -> list[NHORCAConfig]:
    """One NH-ORCA config per robot: ``given`` (one shared config, or one per robot) when not None, else each
    robot's own from its spec (:func:`nh_orca_config` with ``overrides``). ValueError on a length mismatch."""
    if given is None:
        return [nh_orca_config(spec, dt, **overrides) for spec in specs]
    if isinstance(given, NHORCAConfig):
        return [given] * len(specs)
    configs = list(given)
    if len(configs) != len(specs):
        raise ValueError(f"{len(configs)} NH-ORCA configs given for {len(specs)} robots")
    return configs


def dwa_config(spec: RobotSpec, dt: float) -> DWAConfig:
    """DWA parameters from a robot's radius and limits."""
    return DWAConfig(
        v_max=spec.v_max,
        w_max=spec.w_max,
        a_max=spec.a_max,
        alpha_max=spec.alpha_max,
        dt=dt,
        robot_radius=spec.radius,
    )


def navigator_config(
    base: NavigatorConfig, spec: RobotSpec, inflation_margin: float | None = None
) -> NavigatorConfig:
    """``base`` with the robot's radius (and, when given, ``inflation_margin``) for its A* map inflation."""
    changes = {"robot_radius": spec.radius}
    if inflation_margin is not None:
        changes["inflation_margin"] = inflation_margin
    return dataclasses.replace(base, **changes)


def preferred_velocity(
    field: np.ndarray, free: np.ndarray, occupancy, pose: np.ndarray, v_max: float, lookahead_cells: int
) -> np.ndarray:
    """Holonomic preferred velocity float64 ``[2]``: ``v_max`` toward a point ``lookahead_cells`` down the
    distance ``field`` (so walls do not trap the robot); zero when the field is unreachable here."""
    cell = tuple(int(v) for v in occupancy.world_to_cell(pose[:2]))
    h, w = field.shape
    cell = (min(max(cell[0], 0), h - 1), min(max(cell[1], 0), w - 1))
    if not np.isfinite(field[cell]):
        near = nearest_true_cell(np.isfinite(field), cell, max_radius=20)
        if near is None:
            return np.zeros(2)
        cell = near
    path = descend(field, cell, free, max_steps=lookahead_cells)
    point = occupancy.cell_to_world(np.array(path[-1]))
    delta = point - pose[:2]
    dist = math.hypot(delta[0], delta[1])
    if dist < 1e-6:
        return np.zeros(2)
    return delta / dist * v_max


class NHORCAExpert(_ExpertBase):
    """Every robot of an arena episode driven by NH-ORCA toward its own target (paper §V, D_ca).

    Preferred velocity: ``v_max`` toward a point 1 m down the geodesic distance field of the robot's target on
    the true occupancy map (privileged, like the paper's expert), slowing near the stop radius, plus a small
    seeded perturbation (magnitude U[0, ``noise``], angle U[0, 2 pi)) that breaks ORCA's symmetric jams.
    Walls and solid targets are static obstacles. A robot that reached its target (or is inactive) stops
    and becomes a non-reciprocal static agent for the others. A robot without ``progress_min`` metres of
    progress along its field for ``progress_window`` steps re-plans its field with the stopped robots drawn
    into the map (ORCA alone cannot leave the local minimum a parked robot creates).
    """

    def __init__(
        self,
        config: ExpertConfig | None = None,
        nh_orca: NHORCAConfig | Sequence[NHORCAConfig] | None = None,
        noise: float = 0.02,
        progress_window: int = 15,
        progress_min: float = 0.3,
    ) -> None:
        super().__init__(config)
        self.nh_config = nh_orca
        """NH-ORCA config (shared, or one per robot); default: each robot's from its spec."""
        self.noise = noise
        self.progress_window = progress_window
        self.progress_min = progress_min

    def reset(self, world, sim, rng: np.random.Generator) -> None:
        """Start an episode: one NH-ORCA config per robot and each robot's field on the true map."""
        super().reset(world, sim, rng)
        self.orca_configs = nh_orca_configs(self.specs, sim.dt, self.nh_config)
        self.planner = NHORCA(self.orca_configs)
        self.planner.reset(sim.poses, sim.velocities)
        # Plan with ORCA's own inflated radius so that planned gaps are gaps ORCA lets the robot through.
        self.clearance = np.array([c.radius + c.tracking_error + c.safety for c in self.orca_configs])
        self.radii = sim.radii
        occ = world.occupancy
        free = {c: ~occ.inflate(c) for c in set(self.clearance.tolist())}
        n = sim.n_robots
        self.maps = [(occ, free[float(self.clearance[i])], self._field(occ, i)) for i in range(n)]
        self.lookahead_cells = int(round(1.0 / occ.resolution))
        self.best = np.full(n, np.inf)
        self.last_progress = np.zeros(n, dtype=np.int64)
        self.replans = np.zeros(n, dtype=np.int64)

    def _field(self, occupancy, i: int) -> np.ndarray:
        return occupancy.distance_field(
            self.targets[i], float(self.clearance[i]), self.config.stop_radius - 0.2
        )

    def _replan_around(self, i: int, poses: np.ndarray, stopped: np.ndarray) -> None:
        """Re-plan robot ``i``'s field on the true map plus the discs of the ``stopped`` robots."""
        from navformer_rl.envs.occupancy import OccupancyMap

        base = self.world.occupancy
        circles = np.array(
            [
                (poses[j, 0], poses[j, 1], self.radii[j] + self.orca_configs[j].safety)
                for j in np.flatnonzero(stopped)
                if j != i
            ]
        ).reshape(-1, 3)
        grid = base.grid.copy()
        if len(circles):
            centres = base.cell_to_world(np.argwhere(np.ones(base.shape, dtype=bool))).reshape(*base.shape, 2)
            for cx, cy, r in circles:
                grid |= (centres[..., 0] - cx) ** 2 + (centres[..., 1] - cy) ** 2 < r * r
        occ = OccupancyMap(grid, base.resolution, base.origin)
        field = self._field(occ, i)
        here = tuple(int(v) for v in occ.world_to_cell(poses[i, :2]))
        if np.isfinite(field[here]) or not np.isfinite(self.maps[i][2][here]):
            self.maps[i] = (occ, ~occ.inflate(float(self.clearance[i])), field)
        self.replans[i] += 1

    def preferred(self, poses: np.ndarray, run: np.ndarray) -> np.ndarray:
        """float64 ``[R, 2]`` holonomic preferred velocities (zero outside ``run``)."""
        pref = np.zeros((len(poses), 2))
        stopped = ~run
        for i in np.flatnonzero(run):
            occ, free, field = self.maps[i]
            cell = tuple(int(v) for v in occ.world_to_cell(poses[i, :2]))
            remaining = float(field[cell]) if np.isfinite(field[cell]) else np.inf
            if remaining < self.best[i] - self.progress_min:
                self.best[i], self.last_progress[i] = remaining, self.step_count
            elif self.step_count - self.last_progress[i] > self.progress_window:
                self._replan_around(i, poses, stopped)
                occ, free, field = self.maps[i]
                self.best[i], self.last_progress[i] = np.inf, self.step_count
            v_max = self.specs[i].v_max
            pref[i] = preferred_velocity(field, free, occ, poses[i], v_max, self.lookahead_cells)
            d = math.hypot(*(poses[i, :2] - self.targets[i])) - self.config.stop_radius
            pref[i] *= min(1.0, max(0.3, d + 0.3))
        angle = self.rng.uniform(0.0, 2 * math.pi, len(poses))
        mag = self.noise * self.rng.uniform(0.0, 1.0, len(poses))
        pref += np.where(run[:, None], mag[:, None] * np.stack([np.cos(angle), np.sin(angle)], 1), 0.0)
        return pref

    def act(self, sim, active=None) -> np.ndarray:
        """float32 ``[R, 2]`` normalised actions for every robot of ``sim`` (zeros where inactive/arrived)."""
        active = _check_active(active, sim.n_robots)
        poses = sim.poses.astype(np.float64)
        vels = sim.velocities.astype(np.float64)
        self._update_reached(poses)
        run = active & ~self.reached & ~self.failed
        commands = self.planner.step(poses, vels, self.preferred(poses, run), run, self.boxes, self.circles)
        self._tick()
        return normalise(commands, self.specs)


class FCAController(_ExpertBase):
    """Frontier + NH-ORCA (FCA), the paper's privileged upper bound (§VII.A), for all robots at once.

    Uses, per robot: its own 360-degree lidar map (rays that hit other robots are dropped, using their true
    poses), goal-biased frontier exploration (frontier cost = path length + distance from the frontier to
    its *known target location*), A* paths on that map, and NH-ORCA local control with the other robots'
    true positions and velocities and the true wall geometry as static obstacles. It switches to driving to
    the target once the target is in its camera view (FOV, 5 m, line of sight) or in lidar range (6 m) with
    line of sight. Interface for the evaluation harness: ``reset(world, sim, rng)``, ``act(sim, active)``.
    """

    def __init__(
        self,
        config: ExpertConfig | None = None,
        nh_orca: NHORCAConfig | Sequence[NHORCAConfig] | None = None,
        frontier_bias: float = 1.0,
        noise: float = 0.02,
        tracking_error: float = 0.07,
        safety: float = 0.03,
    ) -> None:
        super().__init__(config)
        self.nh_config = nh_orca
        self.frontier_bias = frontier_bias
        self.noise = noise
        # Tighter NH-ORCA inflation than the arena expert's (0.10 + 0.03): in 2.4 m maze corridors the
        # larger one leaves no gap ORCA accepts beside a parked robot, though 0.9 m are physically free.
        self.tracking_error = tracking_error
        self.safety = safety

    def reset(self, world, sim, rng: np.random.Generator) -> None:
        """Start an episode: per robot, an NH-ORCA config and a navigator from its spec."""
        super().reset(world, sim, rng)
        self.orca_configs = nh_orca_configs(
            self.specs, sim.dt, self.nh_config, tracking_error=self.tracking_error, safety=self.safety
        )
        self.planner = NHORCA(self.orca_configs)
        self.planner.reset(sim.poses, sim.velocities)
        # Plan with at least NH-ORCA's inflation (E + safety): a gap A* uses must be one ORCA lets through.
        # When parked robots (static discs) and the half-cell rounding close every way to the target at
        # that inflation, retry at NH-ORCA's own radius, then at the robot radius + 5 cm: otherwise the
        # robot would wait for the rest of the trial beside a gap it can pass.
        base = self.config.navigator
        self.navigators = []
        for i, (spec, orca) in enumerate(zip(self.specs, self.orca_configs)):
            config = navigator_config(
                base, spec, max(base.inflation_margin, orca.tracking_error + orca.safety)
            )
            full = config.robot_radius + config.inflation_margin + 0.5 * config.resolution
            radii = {spec.radius + orca.tracking_error + orca.safety, spec.radius + 0.05}
            fallback = tuple(sorted((r for r in radii if r < full), reverse=True))
            config = dataclasses.replace(config, fallback_inflation=fallback)
            self.navigators.append(
                FrontierNavigator(world.size, config, self.targets[i], True, self.frontier_bias)
            )

    @property
    def stuck_events(self) -> np.ndarray:
        """int64 ``[R]`` re-plans after no progress."""
        return np.array([n.stuck_events for n in self.navigators], dtype=np.int64)

    @property
    def no_path_plans(self) -> np.ndarray:
        """int64 ``[R]`` plans that found no way to the (known) target at any inflation."""
        return np.array([n.no_path_plans for n in self.navigators], dtype=np.int64)

    def act(self, sim, active=None) -> np.ndarray:
        """float32 ``[R, 2]`` normalised actions for every robot of ``sim`` (zeros where inactive/arrived)."""
        active = _check_active(active, sim.n_robots)
        poses = sim.poses.astype(np.float64)
        vels = sim.velocities.astype(np.float64)
        self._update_reached(poses)
        run = active & ~self.reached & ~self.failed
        pref = np.zeros((sim.n_robots, 2))
        idx = np.flatnonzero(run)
        if len(idx):
            scans = self._scans(sim, idx, poses)
            radii = sim.radii
            # Stopped robots (arrived, failed, or held inactive) are static obstacles for planning, drawn
            # with NH-ORCA's radius for static agents (their radius + safety).
            parked = np.flatnonzero(~run)
            safety = np.array([self.orca_configs[j].safety for j in parked]).reshape(-1, 1)
            discs = np.concatenate([poses[parked, :2], radii[parked, None] + safety], axis=1)
            for k, i in enumerate(idx):
                self.navigators[i].set_static_discs(discs)
                pref[i] = self._preferred_one(int(i), poses, radii, scans[k])
        run &= ~self.failed
        angle = self.rng.uniform(0.0, 2 * math.pi, sim.n_robots)
        mag = self.noise * self.rng.uniform(0.0, 1.0, sim.n_robots)
        pref += np.where(run[:, None], mag[:, None] * np.stack([np.cos(angle), np.sin(angle)], 1), 0.0)
        commands = self.planner.step(poses, vels, pref, run, self.boxes, self.circles)
        self._tick()
        return normalise(commands, self.specs)

    def _preferred_one(self, i: int, poses: np.ndarray, radii: np.ndarray, scan: np.ndarray) -> np.ndarray:
        nav = self.navigators[i]
        spec = self.specs[i]
        pose = poses[i]
        lidar = self.config.lidar
        # Drop rays that end on another robot (its true pose is known; only the pybullet lidar sees robots).
        ends = pose[:2] + scan[:, None] * np.stack(
            [np.cos(pose[2] + lidar.angles), np.sin(pose[2] + lidar.angles)], axis=1
        )
        others = np.arange(len(poses)) != i
        d = np.hypot(ends[:, None, 0] - poses[None, others, 0], ends[:, None, 1] - poses[None, others, 1])
        keep = ~(d < radii[None, others] + 0.1).any(axis=1) if others.any() else None
        nav.observe(pose, scan, lidar, keep)
        if not nav.target_mode:
            fov = math.radians(spec.camera_fov_deg)
            seen = target_visible(
                pose,
                self.targets[i],
                self.world.walls,
                fov,
                self.config.camera.max_range,
                spec.camera_forward,
            ) or target_visible(pose, self.targets[i], self.world.walls, 2 * math.pi, lidar.max_range)
            if seen:
                nav.set_target_seen()
        carrot = nav.carrot(pose)
        if carrot is None:
            if nav.exhausted:
                self.failed[i] = True
            return np.zeros(2)
        delta = carrot - pose[:2]
        dist = math.hypot(delta[0], delta[1])
        if dist < 1e-6:
            return np.zeros(2)
        d_target = math.hypot(*(pose[:2] - self.targets[i])) - self.config.stop_radius
        speed = spec.v_max * min(1.0, max(0.3, d_target + 0.3))
        return delta / dist * speed
