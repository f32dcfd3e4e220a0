"""Seeded world generator (pure numpy): mazes and open arenas, targets, collision-free robot starts.

A world is a square ``[0, size]^2`` with axis-aligned wall boxes (paper §VII.A: 3D mazes of 7.5 / 12.5 /
17.5 m; §V: training worlds from 5 to 17.5 m and a 12.5 m collision-avoidance arena; §VII.B: Table II's
furnished bookstore, café and house, see :mod:`navformer_rl.envs.furnished`). Everything a simulator, an
expert or a metric needs is in the frozen :class:`WorldSpec`; the same ``(config, seed)`` always gives the
same world.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from navformer_rl.constants import (
    FURNISHED_FOOTPRINTS,
    MAX_WORLD_SIZE,
    MIN_WORLD_SIZE,
    SUCCESS_RADIUS,
    TARGET_COLORS,
    TARGET_SHAPES,
)
from navformer_rl.envs.occupancy import OccupancyMap
from navformer_rl.envs.robots import JACKAL, RobotSpec
from navformer_rl.utils.checks import check_int, check_number, check_seed, is_integer, is_real

if TYPE_CHECKING:
    from navformer_rl.envs.furnished import SceneStyle

TARGET_RGBA: dict[str, tuple[float, float, float, float]] = {
    "green": (0.10, 0.80, 0.15, 1.0),
    "red": (0.90, 0.08, 0.08, 1.0),
    "white": (0.97, 0.97, 0.97, 1.0),
    "yellow": (0.98, 0.88, 0.05, 1.0),
    "blue": (0.08, 0.25, 0.95, 1.0),
    "orange": (1.00, 0.45, 0.00, 1.0),
    "purple": (0.55, 0.15, 0.80, 1.0),
    "cyan": (0.05, 0.85, 0.90, 1.0),
}
"""Known target colours (the paper's five first, then extras for configurable worlds)."""

TARGET_HALF_EXTENT: dict[str, float] = {"sphere": 0.25, "box": 0.20}
"""Known target shapes: sphere of radius 0.25 m, cube of side 0.40 m (both resting on the floor)."""

WORLD_KINDS = ("maze", "arena", *FURNISHED_FOOTPRINTS)
"""Generated kinds: training mazes and arenas, and Table II's furnished worlds
(``furnished.FURNISHED_KINDS``)."""
OCCUPANCY_RESOLUTION = 0.05


@dataclass(frozen=True, eq=False)  # holds arrays: identity equality, hashable
class TargetSpec:
    """One target object: ``position`` float32 ``[2]`` (x, y) of its centre, ``shape``, ``color``."""

    position: np.ndarray
    shape: str
    color: str

    @property
    def half_extent(self) -> float:
        """Sphere radius or half the cube side, in metres."""
        return TARGET_HALF_EXTENT[self.shape]

    @property
    def rgba(self) -> tuple[float, float, float, float]:
        return TARGET_RGBA[self.color]


@dataclass(frozen=True)
class WorldConfig:
    """What kind of world to generate.

    Attributes:
        size: side of the square world in metres, in [5, 17.5]; for a furnished kind exactly its footprint's
            longer side (``furnished.furnished_size``: bookstore 15.6, cafe 23.1, house 19.0).
        kind: ``"maze"`` (random perfect maze with extra openings), ``"arena"`` (outer walls plus a few
            short inner walls) or a furnished Table II world, ``"bookstore"``, ``"cafe"`` or ``"house"``
            (:mod:`navformer_rl.envs.furnished`; ``cell_size``, ``loop_fraction``, ``wall_thickness``,
            ``wall_height`` and the ``arena_*`` fields do not apply to them).
        n_robots: robots to place (each gets its own distinct target), an integer >= 1.
        target_shapes, target_colors: the catalogue targets are drawn from (shape x colour, without
            replacement), non-empty tuples; known shapes are ``TARGET_HALF_EXTENT``'s keys, colours
            ``TARGET_RGBA``'s.
        cell_size: nominal maze cell in metres (> 0); a side of ``size`` gets
            ``max(2, round(size / cell_size))`` cells of ``size / n`` metres (Python's ``round``: a half goes
            to the even count, e.g. 11.25 m -> 4 cells, 13.75 m -> 6; 2.5 m cells leave 2.4 m corridors:
            two robots pass). A maze's corridors (cell minus ``wall_thickness``) must be wider
            than ``2 * robot_radius`` unless ``loop_fraction`` is 1 (no interior walls left).
        loop_fraction: share of the interior walls left by the perfect maze that are removed again
            (adds loops, so several routes exist), in [0, 1].
        wall_thickness, wall_height: wall boxes in metres (> 0).
        arena_inner_walls: inclusive integer range ``(lo, hi)``, ``0 <= lo <= hi``, of short inner walls in
            an arena.
        arena_wall_length: inclusive range ``(lo, hi)``, ``0 < lo <= hi``, of their lengths in metres; a
            wall is at most ``size - 3`` m long (longer draws are shortened: walls keep 1.5 m from the
            border).
        robot_radius: clearance radius used to place starts and targets (the largest robot's disc), > 0.
        start_target_margin: starts are more than ``SUCCESS_RADIUS + start_target_margin`` metres
            (straight line, hence also geodesically) from their own target; >= 0.
        min_robot_gap: free space in metres between two robot discs at the start; >= 0.

    Every field is checked on construction: a value outside its domain (also NaN or inf) raises
    ``ValueError`` naming the field, the value and what was expected. Lists are stored as tuples.
    """

    size: float = 12.5
    kind: str = "maze"
    n_robots: int = 1
    target_shapes: tuple[str, ...] = TARGET_SHAPES
    target_colors: tuple[str, ...] = TARGET_COLORS
    cell_size: float = 2.5
    loop_fraction: float = 0.15
    wall_thickness: float = 0.10
    wall_height: float = 1.0
    arena_inner_walls: tuple[int, int] = (0, 3)
    arena_wall_length: tuple[float, float] = (1.0, 2.5)
    robot_radius: float = JACKAL.radius
    start_target_margin: float = 1.0
    min_robot_gap: float = 0.2

    def __post_init__(self) -> None:
        for entry in dataclasses.fields(self):  # numpy scalars as Python numbers: the config goes to JSON
            value = getattr(self, entry.name)
            if isinstance(value, np.generic):
                object.__setattr__(self, entry.name, value.item())
            elif isinstance(value, (tuple, list)):
                items = [v.item() if isinstance(v, np.generic) else v for v in value]
                object.__setattr__(self, entry.name, type(value)(items))
        if not is_real(self.size):
            raise ValueError(
                f"world size must be a number of metres in [{MIN_WORLD_SIZE}, {MAX_WORLD_SIZE}], "
                f"got {self.size!r}"
            )
        furnished = isinstance(self.kind, str) and self.kind in FURNISHED_FOOTPRINTS
        side = max(FURNISHED_FOOTPRINTS[self.kind]) if furnished else None
        if side is not None and self.size != side:
            fx, fy = FURNISHED_FOOTPRINTS[self.kind]
            raise ValueError(
                f"a {self.kind} world is {fx:g} x {fy:g} m in a square of its longer side: size must be "
                f"{side:g}, got {self.size!r}"
            )
        if side is None and not MIN_WORLD_SIZE <= self.size <= MAX_WORLD_SIZE:
            raise ValueError(
                f"world size {self.size!r} m is outside the supported range "
                f"[{MIN_WORLD_SIZE}, {MAX_WORLD_SIZE}] m"
            )
        if not isinstance(self.kind, str) or self.kind not in WORLD_KINDS:
            raise ValueError(f"unknown world kind {self.kind!r}; expected one of {WORLD_KINDS}")
        check_int(self.n_robots, "n_robots")
        for name, known in (("target_shapes", TARGET_HALF_EXTENT), ("target_colors", TARGET_RGBA)):
            names = getattr(self, name)
            if isinstance(names, str) or not isinstance(names, (tuple, list)) or not names:
                raise ValueError(
                    f"{name} must be a non-empty tuple of names from {sorted(known)}, got {names!r}"
                )
            object.__setattr__(self, name, tuple(names))
        for shape in self.target_shapes:
            if shape not in TARGET_HALF_EXTENT:
                raise ValueError(
                    f"unknown target shape {shape!r}; expected one of {sorted(TARGET_HALF_EXTENT)}"
                )
        for color in self.target_colors:
            if color not in TARGET_RGBA:
                raise ValueError(f"unknown target colour {color!r}; expected one of {sorted(TARGET_RGBA)}")
        n_targets = len(set(self.target_shapes)) * len(set(self.target_colors))
        if self.n_robots > n_targets:
            raise ValueError(
                f"n_robots={self.n_robots} needs as many distinct targets, but shapes {self.target_shapes} x "
                f"colours {self.target_colors} give only {n_targets}"
            )
        check_number(self.cell_size, "cell_size", greater_than=0.0, unit="metres")
        check_number(self.loop_fraction, "loop_fraction", at_least=0.0, at_most=1.0)
        check_number(self.wall_thickness, "wall_thickness", greater_than=0.0, unit="metres")
        check_number(self.wall_height, "wall_height", greater_than=0.0, unit="metres")
        check_number(self.robot_radius, "robot_radius", greater_than=0.0, unit="metres")
        check_number(self.start_target_margin, "start_target_margin", at_least=0.0, unit="metres")
        check_number(self.min_robot_gap, "min_robot_gap", at_least=0.0, unit="metres")
        walls = self.arena_inner_walls
        if not (
            isinstance(walls, (tuple, list))
            and len(walls) == 2
            and all(is_integer(v) for v in walls)
            and 0 <= walls[0] <= walls[1]
        ):
            raise ValueError(
                f"arena_inner_walls must be an integer range (lo, hi) with 0 <= lo <= hi, got {walls!r}"
            )
        object.__setattr__(self, "arena_inner_walls", tuple(walls))
        lengths = self.arena_wall_length
        if not (
            isinstance(lengths, (tuple, list))
            and len(lengths) == 2
            and all(is_real(v) and math.isfinite(v) for v in lengths)
            and 0 < lengths[0] <= lengths[1]
        ):
            raise ValueError(
                "arena_wall_length must be a range (lo, hi) of finite lengths in metres with 0 < lo <= hi, "
                f"got {lengths!r}"
            )
        object.__setattr__(self, "arena_wall_length", tuple(lengths))
        if self.kind == "maze" and self.loop_fraction < 1.0:
            corridor = self.size / self.cells_per_side - self.wall_thickness
            if corridor <= 2 * self.robot_radius:
                raise ValueError(
                    f"maze corridors would be {corridor:.3g} m wide ({self.cells_per_side} cells of "
                    f"{self.size / self.cells_per_side:.3g} m minus wall_thickness={self.wall_thickness!r}), "
                    f"too narrow for a robot of robot_radius={self.robot_radius!r} m; expected corridors "
                    "wider than 2 * robot_radius: use a larger cell_size or a smaller wall_thickness or "
                    "robot_radius"
                )

    @property
    def cells_per_side(self) -> int:
        """Maze cells per side: ``max(2, round(size / cell_size))``; Python's ``round`` sends a half to the
        even count (6.25 m -> 2 cells, 8.75 m -> 4, 11.25 m -> 4, 13.75 m -> 6 with 2.5 m cells)."""
        return max(2, round(self.size / self.cell_size))


@dataclass(frozen=True, eq=False)  # holds arrays: identity equality, hashable
class WorldSpec:
    """A generated world (read-only). Robot ``i`` starts at ``starts[i]`` and looks for ``targets[i]``.

    Attributes:
        size: side in metres; the world spans ``[0, size]^2``.
        kind: one of :data:`WORLD_KINDS` (``"custom"`` for :func:`world_from_layout`).
        walls: float32 ``[W, 4]`` axis-aligned wall boxes ``(cx, cy, half_x, half_y)`` (furniture included).
        wall_height: metres.
        occupancy: :class:`OccupancyMap` at 0.05 m of walls and (solid) targets.
        starts: float32 ``[R, 3]`` start poses ``(x, y, yaw)``.
        targets: one :class:`TargetSpec` per robot, all distinct (shape, colour) pairs; after them, the
            targets no robot seeks that :func:`add_distractor_targets` adds (none in a generated world).
        seed: the generator seed.
        config: the :class:`WorldConfig` it was generated from.
        style: a furnished world's :class:`~navformer_rl.envs.furnished.SceneStyle` (each box's colour and
            height, the floor); None: the training look.
    """

    size: float
    kind: str
    walls: np.ndarray
    wall_height: float
    occupancy: OccupancyMap
    starts: np.ndarray
    targets: list[TargetSpec]
    seed: int
    config: WorldConfig = field(repr=False)
    style: SceneStyle | None = field(default=None, repr=False)

    @property
    def n_robots(self) -> int:
        return int(self.starts.shape[0])

    @property
    def target_positions(self) -> np.ndarray:
        """float32 ``[T, 2]``: every target's centre, the robots' own first (``T >= R``)."""
        return np.array([t.position for t in self.targets], dtype=np.float32).reshape(-1, 2)

    @property
    def robot_target_positions(self) -> np.ndarray:
        """float32 ``[R, 2]``: robot ``i``'s target centre in row ``i`` (the targets the robots seek)."""
        return self.target_positions[: self.n_robots]

    @property
    def distractors(self) -> list[TargetSpec]:
        """The targets no robot seeks (``targets[R:]``; empty in a generated world)."""
        return self.targets[self.n_robots :]

    @property
    def obstacle_boxes(self) -> np.ndarray:
        """float64 ``[W + B, 4]``: wall boxes plus cube targets, the static boxes robots collide with."""
        boxes = [t.position.tolist() + [t.half_extent] * 2 for t in self.targets if t.shape == "box"]
        return np.concatenate(
            [self.walls.astype(np.float64), np.array(boxes, dtype=np.float64).reshape(-1, 4)]
        )

    @property
    def obstacle_circles(self) -> np.ndarray:
        """float64 ``[S, 3]`` ``(cx, cy, r)``: sphere targets, the static discs robots collide with."""
        circles = [t.position.tolist() + [t.half_extent] for t in self.targets if t.shape == "sphere"]
        return np.array(circles, dtype=np.float64).reshape(-1, 3)

    def shortest_path_length(
        self,
        start_xy,
        target_index: int,
        clearance: float = JACKAL.radius,
        goal_radius: float = 0.0,
        reach: int = 1,
    ) -> float:
        """Shortest collision-free path in metres from ``start_xy`` to ``targets[target_index]`` on the true
        map inflated by ``clearance`` (see :meth:`OccupancyMap.shortest_path_length`); the goal is the free
        cell nearest to the (solid) target, or with ``goal_radius`` the first cell within that radius of it.
        ``reach``: 1 = the 8-connected grid (up to 8.2 % longer than the straight line in free space), 5 =
        what the evaluation's SPL uses (0.49 %)."""
        if not 0 <= target_index < len(self.targets):
            raise ValueError(f"target_index {target_index} is out of range [0, {len(self.targets)})")
        goal = self.targets[target_index].position
        return self.occupancy.shortest_path_length(start_xy, goal, clearance, goal_radius, reach)


@dataclass(frozen=True, eq=False)  # holds arrays: identity equality, hashable
class EpisodeSpec:
    """A fixed episode for evaluation: a world from ``(config, world_seed)`` (or a given ``world``), with
    optional overriding ``starts`` float ``[R, 3]`` and ``targets``.

    ``build()`` returns the :class:`WorldSpec` to use; overrides are checked for collisions.
    """

    config: WorldConfig | None = None
    world_seed: int | None = None
    world: WorldSpec | None = None
    starts: np.ndarray | None = None
    targets: list[TargetSpec] | None = None

    def build(self) -> WorldSpec:
        if self.world is not None:
            world = self.world
        elif self.config is not None and self.world_seed is not None:
            world = generate_world(self.config, self.world_seed)
        else:
            raise ValueError("EpisodeSpec needs either a world or both a config and a world_seed")
        return replace_layout(world, self.starts, self.targets)


def check_world_config(
    config: WorldConfig, robot_specs: Sequence[RobotSpec] = (), name: str = "world_config"
) -> WorldConfig:
    """``config`` itself; ValueError unless it is a :class:`WorldConfig` whose ``robot_radius`` (used to place
    starts and targets) is at least the radius of every robot in ``robot_specs``. The message calls the config
    ``name`` (e.g. ``"the episode's world.config"`` for a fixed episode)."""
    if not isinstance(config, WorldConfig):
        raise ValueError(f"{name} must be a WorldConfig, got {type(config).__name__}")
    largest = max(robot_specs, key=lambda spec: spec.radius, default=None)
    if largest is not None and config.robot_radius < largest.radius:
        raise ValueError(
            f"{name}.robot_radius={config.robot_radius!r} m is smaller than the {largest.name} robot's "
            f"radius {largest.radius} m; expected at least the largest robot's radius (starts and targets "
            "are placed with it)"
        )
    return config


# ---------------------------------------------------------------------------------------------- walls
def _maze_walls(config: WorldConfig, rng: np.random.Generator) -> np.ndarray:
    """Random DFS perfect maze, then ``loop_fraction`` of the remaining interior walls removed; walls merged
    into maximal straight runs. Returns float32 ``[W, 4]`` boxes."""
    n = config.cells_per_side
    cell = config.size / n
    # vertical[r, c]: wall on the line x = c * cell between rows r and r+1 (c in 0..n)
    vertical = np.ones((n, n + 1), dtype=bool)
    horizontal = np.ones((n + 1, n), dtype=bool)  # horizontal[r, c]: wall on y = r * cell, column c
    visited = np.zeros((n, n), dtype=bool)
    start = (int(rng.integers(n)), int(rng.integers(n)))
    stack = [start]
    visited[start] = True
    while stack:
        r, c = stack[-1]
        options = [
            (dr, dc)
            for dr, dc in ((1, 0), (-1, 0), (0, 1), (0, -1))
            if 0 <= r + dr < n and 0 <= c + dc < n and not visited[r + dr, c + dc]
        ]
        if not options:
            stack.pop()
            continue
        dr, dc = options[int(rng.integers(len(options)))]
        if dc == 1:
            vertical[r, c + 1] = False
        elif dc == -1:
            vertical[r, c] = False
        elif dr == 1:
            horizontal[r + 1, c] = False
        else:
            horizontal[r, c] = False
        visited[r + dr, c + dc] = True
        stack.append((r + dr, c + dc))
    interior = [("v", r, c) for r in range(n) for c in range(1, n) if vertical[r, c]]
    interior += [("h", r, c) for r in range(1, n) for c in range(n) if horizontal[r, c]]
    n_remove = int(round(config.loop_fraction * len(interior)))
    for k in rng.permutation(len(interior))[:n_remove]:
        kind, r, c = interior[k]
        (vertical if kind == "v" else horizontal)[r, c] = False
    half_t = config.wall_thickness / 2
    boxes = []
    for c in range(n + 1):  # runs along each vertical line
        for r0, r1 in _runs(vertical[:, c]):
            y0, y1 = r0 * cell - half_t, r1 * cell + half_t
            boxes.append((c * cell, (y0 + y1) / 2, half_t, (y1 - y0) / 2))
    for r in range(n + 1):
        for c0, c1 in _runs(horizontal[r, :]):
            x0, x1 = c0 * cell - half_t, c1 * cell + half_t
            boxes.append(((x0 + x1) / 2, r * cell, (x1 - x0) / 2, half_t))
    return np.array(boxes, dtype=np.float32)


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """Maximal runs ``[start, end)`` of True in a 1-D bool array."""
    padded = np.concatenate([[False], mask, [False]]).astype(np.int8)
    edges = np.flatnonzero(np.diff(padded))
    return list(zip(edges[0::2].tolist(), edges[1::2].tolist()))


def _outer_walls(size: float, thickness: float) -> list[tuple[float, float, float, float]]:
    h = thickness / 2
    half = size / 2 + h
    return [
        (size / 2, 0.0, half, h),
        (size / 2, size, half, h),
        (0.0, size / 2, h, half),
        (size, size / 2, h, half),
    ]


def _arena_walls(config: WorldConfig, rng: np.random.Generator) -> np.ndarray:
    """Outer walls plus ``arena_inner_walls`` short axis-aligned segments kept >= 1.5 m from the border."""
    boxes = _outer_walls(config.size, config.wall_thickness)
    lo, hi = config.arena_inner_walls
    h = config.wall_thickness / 2
    for _ in range(int(rng.integers(lo, hi + 1))):
        # at most size - 3 m: the wall keeps 1.5 m from the border at both ends
        length = min(float(rng.uniform(*config.arena_wall_length)), config.size - 3.0)
        along = rng.uniform(1.5 + length / 2, config.size - 1.5 - length / 2)
        across = rng.uniform(2.0, config.size - 2.0)
        if rng.random() < 0.5:
            boxes.append((along, across, length / 2, h))
        else:
            boxes.append((across, along, h, length / 2))
    return np.array(boxes, dtype=np.float32)


# ---------------------------------------------------------------------------------------------- placement
def _free_cells(occupancy: OccupancyMap, clearance: float) -> np.ndarray:
    """int64 ``[K, 2]`` cells of the largest free component of the map inflated by ``clearance``."""
    return np.argwhere(occupancy.largest_free_component(clearance))


def sample_free_positions(
    occupancy: OccupancyMap,
    n: int,
    clearance: float,
    min_separation: float,
    rng: np.random.Generator,
    avoid: np.ndarray | None = None,
    avoid_separation: float = 0.0,
    max_tries: int = 2000,
    largest_only: bool = True,
) -> np.ndarray:
    """Sample ``n`` positions float64 ``[n, 2]`` (free cell centres) in the largest free component of
    ``inflate(clearance)`` (in any of its components with ``largest_only=False``: for worlds whose free space
    is connected at a smaller clearance, e.g. furnished rooms behind doorways narrower than
    ``2 * clearance``), pairwise more than ``min_separation`` apart and more than ``avoid_separation`` from
    every row of ``avoid`` (float ``[K, 2]``). Raises ValueError when they do not fit (after ``max_tries``
    draws)."""
    cells = _free_cells(occupancy, clearance) if largest_only else np.argwhere(~occupancy.inflate(clearance))
    centres = occupancy.cell_to_world(cells)
    if avoid is not None and len(centres):
        avoid = np.asarray(avoid, dtype=np.float64).reshape(-1, 2)
        gaps = np.hypot(centres[:, None, 0] - avoid[None, :, 0], centres[:, None, 1] - avoid[None, :, 1])
        centres = centres[(gaps > avoid_separation).all(axis=1)]
    if len(centres) == 0:
        raise ValueError(f"no free space with clearance {clearance} m to place {n} objects")
    chosen: list[tuple[float, float]] = []
    for _ in range(max_tries):
        x, y = centres[int(rng.integers(len(centres)))]
        if all((x - cx) ** 2 + (y - cy) ** 2 > min_separation**2 for cx, cy in chosen):
            chosen.append((float(x), float(y)))
            if len(chosen) == n:
                return np.array(chosen, dtype=np.float64)
    raise ValueError(
        f"could not place {n} objects with clearance {clearance} m and separation {min_separation} m "
        f"in this {occupancy.shape[0] * occupancy.resolution:.1f} m world (placed {len(chosen)})"
    )


def sample_start_poses(
    world: WorldSpec,
    n: int,
    rng: np.random.Generator,
    robot_radius: float | None = None,
    min_target_distance: float | None = None,
) -> np.ndarray:
    """Collision-free random poses float32 ``[n, 3]`` for ``n`` robots in ``world`` (e.g. new starts, or the
    D_ssl obstacle layouts). Robot ``i < len(world.targets)`` is kept more than ``min_target_distance``
    (default ``SUCCESS_RADIUS + start_target_margin``) from its own target; all are clear of every target.
    ValueError unless ``n`` is an integer >= 0 (0 gives an empty ``[0, 3]`` array), or when the robots do not
    fit."""
    n = check_int(n, "n", minimum=0)
    cfg = world.config
    radius = cfg.robot_radius if robot_radius is None else robot_radius
    min_dist = (
        SUCCESS_RADIUS + cfg.start_target_margin if min_target_distance is None else min_target_distance
    )
    targets = world.target_positions.astype(np.float64)
    centres = world.occupancy.cell_to_world(_free_cells(world.occupancy, radius + 0.05))
    if len(centres) == 0:
        raise ValueError(f"no free space for a robot of radius {radius} m in this world")
    min_gap2 = (2 * radius + cfg.min_robot_gap) ** 2
    poses: list[tuple[float, float, float]] = []
    for i in range(n):
        for _ in range(4000):
            x, y = centres[int(rng.integers(len(centres)))]
            if any((x - px) ** 2 + (y - py) ** 2 <= min_gap2 for px, py, _ in poses):
                continue
            if i < len(targets) and math.hypot(targets[i, 0] - x, targets[i, 1] - y) <= min_dist:
                continue
            poses.append((float(x), float(y), float(rng.uniform(-math.pi, math.pi))))
            break
        else:
            raise ValueError(
                f"could not place {n} robots (radius {radius} m) in this {world.size} m {world.kind}: "
                f"placed {len(poses)}; use fewer robots or a larger world"
            )
    return np.array(poses, dtype=np.float32).reshape(n, 3)


_Body = tuple[float, float, float, float, bool]
"""A solid body ``(x, y, half_x, half_y, is_disc)``: a wall box, a cube target, or a sphere target (a disc of
radius ``half_x == half_y``)."""


def _bodies_overlap(a: _Body, b: _Body) -> bool:
    """True when two solid bodies overlap (touching is fine)."""
    if a[4] and b[4]:
        return math.hypot(a[0] - b[0], a[1] - b[1]) < a[2] + b[2]
    if a[4] or b[4]:  # a disc against a box
        (cx, cy, r, _, _), (bx, by, hx, hy, _) = (a, b) if a[4] else (b, a)
        dx = max(abs(cx - bx) - hx, 0.0)
        dy = max(abs(cy - by) - hy, 0.0)
        return dx * dx + dy * dy < r * r
    return abs(a[0] - b[0]) < a[2] + b[2] and abs(a[1] - b[1]) < a[3] + b[3]


def check_targets(size: float, walls: np.ndarray, targets: Sequence[TargetSpec]) -> None:
    """ValueError unless every target is a known (shape, colour), the pairs are distinct, each ``position`` is
    a finite ``(x, y)`` whose solid body (sphere or cube, ``half_extent``) lies within ``[0, size]^2`` and
    overlaps no wall box of ``walls`` float ``[W, 4]`` and no other target (touching is fine). Looser than
    :func:`generate_world`'s placement (0.9 m from walls, 2 m apart), which hand-made layouts need not
    meet."""
    for t in targets:
        if t.shape not in TARGET_HALF_EXTENT or t.color not in TARGET_RGBA:
            raise ValueError(
                f"unknown target {t.shape!r}/{t.color!r}; expected a shape from {sorted(TARGET_HALF_EXTENT)} "
                f"and a colour from {sorted(TARGET_RGBA)}"
            )
    if len({(t.shape, t.color) for t in targets}) != len(targets):
        raise ValueError("targets must be distinct (shape, colour) pairs")
    bodies = []
    for i, t in enumerate(targets):
        position = np.asarray(t.position, dtype=np.float64)
        if position.shape != (2,) or not np.all(np.isfinite(position)):
            raise ValueError(f"target {i} position must be a finite float [2] (x, y), got {t.position!r}")
        x, y = position.tolist()
        half = t.half_extent
        if not (half <= x <= size - half and half <= y <= size - half):
            raise ValueError(
                f"target {i} ({t.shape}, {t.color}) at {[x, y]} is outside the world: its body (half extent "
                f"{half} m) must lie within [0, {size}]^2, i.e. {half} <= x, y <= {size - half}"
            )
        body = (x, y, half, half, t.shape == "sphere")
        for cx, cy, hx, hy in np.asarray(walls, dtype=np.float64).reshape(-1, 4).tolist():
            if _bodies_overlap(body, (cx, cy, hx, hy, False)):
                raise ValueError(
                    f"target {i} ({t.shape}, {t.color}) at {[x, y]} overlaps the wall box "
                    f"(cx, cy, half_x, half_y) = {[cx, cy, hx, hy]}"
                )
        for j, other in enumerate(bodies):
            if _bodies_overlap(body, other):
                raise ValueError(f"target {i} at {[x, y]} overlaps target {j} at {list(other[:2])}")
        bodies.append(body)


def replace_layout(world: WorldSpec, starts=None, targets: list[TargetSpec] | None = None) -> WorldSpec:
    """A copy of ``world`` with new ``starts`` float ``[R, 3]`` and/or ``targets`` (occupancy rebuilt): robot
    ``i`` seeks ``targets[i]``; targets after the first ``R`` are distractors no robot seeks.

    ValueError when there are fewer targets than starts, a target fails :func:`check_targets` (unknown or
    repeated, outside the world, overlapping a wall or another target), or a start overlaps a wall, a
    target or another start."""
    targets = world.targets if targets is None else list(targets)
    starts = world.starts if starts is None else np.asarray(starts, dtype=np.float32)
    if starts.ndim != 2 or starts.shape[1] != 3 or not np.all(np.isfinite(starts)):
        raise ValueError(f"starts must be finite float [R, 3] (x, y, yaw), got shape {starts.shape}")
    if len(targets) < len(starts):
        raise ValueError(f"{len(starts)} starts need one target each, got {len(targets)} targets")
    check_targets(world.size, world.walls, targets)
    occupancy = _build_occupancy(world.size, world.walls, targets)
    new = dataclasses.replace(world, starts=starts, targets=targets, occupancy=occupancy)
    blocked = occupancy.inflate(world.config.robot_radius)
    cells = occupancy.world_to_cell(starts[:, :2])
    h, w = occupancy.shape
    for i, (r, c) in enumerate(cells):
        if not (0 <= r < h and 0 <= c < w) or blocked[r, c]:
            raise ValueError(
                f"start {i} at {starts[i, :2].tolist()} overlaps a wall or target (or is outside)"
            )
    gaps = np.hypot(*(starts[:, None, :2] - starts[None, :, :2]).transpose(2, 0, 1))
    np.fill_diagonal(gaps, np.inf)
    if gaps.min(initial=np.inf) < 2 * world.config.robot_radius:
        raise ValueError("two starts overlap (closer than two robot radii)")
    return new


def add_distractor_targets(world: WorldSpec, n: int, rng: np.random.Generator) -> WorldSpec:
    """A copy of ``world`` with ``n`` more targets that no robot seeks, after the robots' own (``targets[i]``
    stays robot ``i``'s; the simulator renders and collides with every target).

    They are catalogue targets (``world.config``'s shapes x colours) none of the world's targets already is,
    placed as :func:`generate_world` places targets: 0.9 m from walls, more than 2 m (1.2 m where that does
    not fit) from one another, from the other targets and from every start, with the free space of a maze
    still one component when it was one (a generated maze's always is; in a furnished world, with its
    cluttered corners, or a maze whose layout already left pockets, every start and target still in one
    component). ``n = 0`` returns ``world`` itself. ValueError for a negative ``n``, more than the
    catalogue has left, or when they do not fit.
    """
    n = check_int(n, "n", minimum=0)
    if n == 0:
        return world
    config = world.config
    used = {(t.shape, t.color) for t in world.targets}
    pairs = [
        (s, c)
        for s in dict.fromkeys(config.target_shapes)
        for c in dict.fromkeys(config.target_colors)
        if (s, c) not in used
    ]
    if n > len(pairs):
        raise ValueError(
            f"n={n} distractor targets: the catalogue has {len(pairs)} targets this world does not use yet"
        )
    chosen = rng.permutation(len(pairs))[:n]
    wall_map = OccupancyMap.from_shapes(world.size, OCCUPANCY_RESOLUTION, world.walls)
    clearance = max(TARGET_HALF_EXTENT.values()) + 2 * config.robot_radius + 0.05
    avoid = np.concatenate([world.target_positions, world.starts[:, :2]]).astype(np.float64)
    strict = world.style is None and world.occupancy.free_components(config.robot_radius)[1] == 1
    for attempt in range(40):
        separation = 2.0 if attempt < 20 else 1.2
        try:
            positions = sample_free_positions(
                wall_map, n, clearance, separation, rng, avoid=avoid, avoid_separation=separation,
                largest_only=world.style is None,
            )  # fmt: skip
        except ValueError:
            continue
        extra = [
            TargetSpec(position=positions[i].astype(np.float32), shape=pairs[k][0], color=pairs[k][1])
            for i, k in enumerate(chosen)
        ]
        targets = [*world.targets, *extra]
        occupancy = _build_occupancy(world.size, world.walls, targets)
        if strict:
            reachable = _targets_reachable(occupancy, targets, config.robot_radius)
        else:
            reachable = _one_component(
                occupancy, [t.position for t in targets], world.starts, config.robot_radius
            )
        if reachable:
            return dataclasses.replace(world, targets=targets, occupancy=occupancy)
    raise ValueError(
        f"could not place {n} distractor targets in this {world.size} m {world.kind} beside its "
        f"{len(world.targets)} targets and {world.n_robots} starts"
    )


def _build_occupancy(size: float, walls: np.ndarray, targets: list[TargetSpec]) -> OccupancyMap:
    boxes = [t.position.tolist() + [t.half_extent] * 2 for t in targets if t.shape == "box"]
    circles = [t.position.tolist() + [t.half_extent] for t in targets if t.shape == "sphere"]
    return OccupancyMap.from_shapes(
        size,
        OCCUPANCY_RESOLUTION,
        np.concatenate([walls, np.array(boxes, dtype=np.float32).reshape(-1, 4)]),
        np.array(circles, dtype=np.float64).reshape(-1, 3),
    )


def world_from_layout(
    size: float,
    walls,
    targets: list[TargetSpec],
    starts,
    seed: int = 0,
    config: WorldConfig | None = None,
) -> WorldSpec:
    """A :class:`WorldSpec` from a hand-made layout: ``walls`` float ``[W, 4]`` boxes ``(cx, cy, hx, hy)``,
    one target and one start ``(x, y, yaw)`` per robot. The occupancy map is rasterised from them; starts
    are checked as in :func:`replace_layout`. ``kind`` is ``"custom"``."""
    config = config or WorldConfig(size=size, n_robots=len(targets))
    walls = np.asarray(walls, dtype=np.float32).reshape(-1, 4)
    placeholder = WorldSpec(
        size=float(size),
        kind="custom",
        walls=walls,
        wall_height=float(config.wall_height),
        occupancy=_build_occupancy(size, walls, []),
        starts=np.zeros((0, 3), dtype=np.float32),
        targets=[],
        seed=int(seed),
        config=config,
    )
    return replace_layout(placeholder, starts, targets)


def _targets_reachable(occupancy: OccupancyMap, targets: list[TargetSpec], clearance: float) -> bool:
    """True when the free space at ``clearance`` is one component and touches every target."""
    labels, n = occupancy.free_components(clearance)
    if n != 1:
        return False
    return all(labels[occupancy.snap_to_free(t.position, clearance)] == 1 for t in targets)


def _one_component(occupancy: OccupancyMap, targets, starts: np.ndarray, clearance: float) -> bool:
    """True when every target ``(x, y)`` and start lies (snapped to free space) in one component of the free
    space at ``clearance``; pockets elsewhere do not count."""
    labels, _ = occupancy.free_components(clearance)
    points = [*targets, *np.asarray(starts)[:, :2]]
    found = {int(labels[occupancy.snap_to_free(np.asarray(p, dtype=np.float64), clearance)]) for p in points}
    return len(found) == 1 and 0 not in found


# ---------------------------------------------------------------------------------------------- generator
def generate_world(config: WorldConfig, seed: int) -> WorldSpec:
    """Generate the world for ``(config, seed)`` (deterministic).

    Walls (maze, arena, or a furnished layout from :func:`~navformer_rl.envs.furnished.furnished_walls` for
    ``config.kind`` bookstore / cafe / house), then ``n_robots`` distinct targets in reachable free space
    (0.9 m from walls, more than 2 m apart, or 1.2 m where that does not fit), then collision-free starts,
    each more than ``SUCCESS_RADIUS + start_target_margin`` from its own target. The free space (inflated by
    ``robot_radius``) is one connected component. ValueError when the robots/targets do not fit.
    """
    if not isinstance(config, WorldConfig):
        raise ValueError(f"config must be a WorldConfig, got {type(config).__name__}")
    seed = check_seed(seed)
    rng = np.random.default_rng(np.random.SeedSequence([seed, 0x5EED]))
    style = None
    if config.kind in FURNISHED_FOOTPRINTS:
        from navformer_rl.envs.furnished import furnished_walls  # imports this module

        walls, wall_map, style = furnished_walls(config.kind, config.robot_radius, rng, OCCUPANCY_RESOLUTION)
    else:
        walls, wall_map = _maze_or_arena(config, seed, rng)
    return _place_targets_and_starts(config, seed, rng, walls, wall_map, style)


def _maze_or_arena(
    config: WorldConfig, seed: int, rng: np.random.Generator
) -> tuple[np.ndarray, OccupancyMap]:
    """The walls float32 ``[W, 4]`` of a maze or arena and their occupancy map; ValueError when the free space
    falls apart (maze) or no connected arena is drawn in 100 tries."""
    for _ in range(100):
        walls = _maze_walls(config, rng) if config.kind == "maze" else _arena_walls(config, rng)
        wall_map = OccupancyMap.from_shapes(config.size, OCCUPANCY_RESOLUTION, walls)
        _, n_components = wall_map.free_components(config.robot_radius)
        if n_components == 1:
            break
        if config.kind == "maze":  # corridors wider than a robot plus the grid's rounding are connected
            raise ValueError(
                f"the maze's free space for robot_radius={config.robot_radius!r} m falls into {n_components} "
                f"components on the {OCCUPANCY_RESOLUTION} m occupancy grid (corridors of "
                f"{config.size / config.cells_per_side - config.wall_thickness:.3g} m, seed {seed}); "
                "expected corridors wider than 2 * robot_radius + 0.1 m: use a larger cell_size or a smaller "
                "wall_thickness or robot_radius"
            )
    else:
        raise ValueError(
            "could not draw an arena whose free space is connected for "
            f"robot_radius={config.robot_radius!r} m in 100 tries (seed {seed}, "
            f"arena_inner_walls={config.arena_inner_walls}, arena_wall_length={config.arena_wall_length}); "
            "use a smaller robot_radius or fewer or shorter inner walls"
        )
    return walls, wall_map


def _place_targets_and_starts(
    config: WorldConfig,
    seed: int,
    rng: np.random.Generator,
    walls: np.ndarray,
    wall_map: OccupancyMap,
    style: SceneStyle | None,
) -> WorldSpec:
    """The :class:`WorldSpec` of ``walls``: reachable distinct targets, then starts (see
    :func:`generate_world`)."""
    furnished = style is not None  # free space connected at robot_radius: every room may hold a target
    pairs = [(s, c) for s in dict.fromkeys(config.target_shapes) for c in dict.fromkeys(config.target_colors)]
    chosen = rng.permutation(len(pairs))[: config.n_robots]
    # a robot must fit between a target and a wall on either side: target + robot diameter + 5 cm
    target_clearance = max(TARGET_HALF_EXTENT.values()) + 2 * config.robot_radius + 0.05
    for attempt in range(40):
        separation = 2.0 if attempt < 20 else 1.2  # targets 2 m apart, closer only where they do not fit
        try:
            positions = sample_free_positions(
                wall_map, config.n_robots, target_clearance, separation, rng, largest_only=not furnished
            )
        except ValueError:
            continue
        targets = [
            TargetSpec(position=positions[i].astype(np.float32), shape=pairs[k][0], color=pairs[k][1])
            for i, k in enumerate(chosen)
        ]
        occupancy = _build_occupancy(config.size, walls, targets)
        if _targets_reachable(occupancy, targets, config.robot_radius):
            break
    else:
        raise ValueError(
            f"could not place {config.n_robots} reachable targets in this {config.size} m {config.kind} "
            f"(each {target_clearance:.2f} m from walls for robot_radius={config.robot_radius!r} m); "
            "use fewer robots, a larger world or a smaller robot_radius"
        )
    world = WorldSpec(
        size=float(config.size),
        kind=config.kind,
        walls=walls,
        wall_height=float(config.wall_height) if style is None else style.wall_height,
        occupancy=occupancy,
        starts=np.zeros((config.n_robots, 3), dtype=np.float32),
        targets=targets,
        seed=int(seed),
        config=config,
        style=style,
    )
    starts = sample_start_poses(world, config.n_robots, rng)
    return dataclasses.replace(world, starts=starts)
