"""World generator: valid, connected, seeded mazes and arenas; clear errors for bad configurations."""

import dataclasses
import math

import numpy as np
import pytest

from navformer_rl.constants import SUCCESS_RADIUS
from navformer_rl.envs.occupancy import OccupancyMap
from navformer_rl.envs.world import (
    EpisodeSpec,
    TargetSpec,
    WorldConfig,
    generate_world,
    replace_layout,
    sample_start_poses,
    world_from_layout,
)


def disc_box_clearance(xy: np.ndarray, boxes: np.ndarray) -> float:
    """Smallest distance from the point to any box ``(cx, cy, hx, hy)``."""
    dx = np.maximum(np.abs(xy[0] - boxes[:, 0]) - boxes[:, 2], 0.0)
    dy = np.maximum(np.abs(xy[1] - boxes[:, 1]) - boxes[:, 3], 0.0)
    return float(np.hypot(dx, dy).min())


@pytest.mark.parametrize("size", [5.0, 7.5, 12.5, 17.5])
def test_maze_is_valid(size):
    config = WorldConfig(size=size, n_robots=3)
    world = generate_world(config, seed=11)
    n = config.cells_per_side
    assert n == max(2, round(size / 2.5))
    # walls lie on the maze grid lines and inside the (half-thickness padded) square
    cell = size / n
    for cx, cy, hx, hy in world.walls:
        on_line = cx if hx < hy else cy
        assert abs(on_line / cell - round(on_line / cell)) < 1e-4
        assert -0.06 <= cx - hx and cx + hx <= size + 0.06 and -0.06 <= cy - hy and cy + hy <= size + 0.06
    # one connected free space for a robot, even with the solid targets in it
    assert world.occupancy.free_components(config.robot_radius)[1] == 1
    # corridors let two robots pass: a disc twice the robot radius still moves everywhere between walls
    walls_only = OccupancyMap.from_shapes(size, 0.05, world.walls)
    assert walls_only.free_components(2 * config.robot_radius)[1] == 1
    # targets are distinct and reachable from every start; starts are collision-free and far enough
    assert len({(t.shape, t.color) for t in world.targets}) == 3
    boxes = world.obstacle_boxes
    for i, start in enumerate(world.starts):
        assert disc_box_clearance(start[:2], boxes) >= config.robot_radius
        assert (
            np.hypot(*(start[:2] - world.targets[i].position)) > SUCCESS_RADIUS + config.start_target_margin
        )
        for j in range(3):
            assert math.isfinite(world.shortest_path_length(start[:2], j))
    gaps = np.hypot(*(world.starts[:, None, :2] - world.starts[None, :, :2]).transpose(2, 0, 1))
    assert gaps[~np.eye(3, dtype=bool)].min() > 2 * config.robot_radius


def test_same_seed_same_world_and_different_seed_different_world():
    config = WorldConfig(size=7.5, n_robots=2)
    a, b, c = generate_world(config, 5), generate_world(config, 5), generate_world(config, 6)
    assert np.array_equal(a.walls, b.walls) and np.array_equal(a.starts, b.starts)
    assert [(t.shape, t.color, tuple(t.position)) for t in a.targets] == [
        (t.shape, t.color, tuple(t.position)) for t in b.targets
    ]
    assert np.array_equal(a.occupancy.grid, b.occupancy.grid)
    assert not (np.array_equal(a.walls, c.walls) and np.array_equal(a.starts, c.starts))


def test_loops_make_the_maze_imperfect():
    perfect = generate_world(WorldConfig(size=12.5, loop_fraction=0.0), 3)
    braided = generate_world(WorldConfig(size=12.5, loop_fraction=0.5), 3)
    assert braided.walls[:, 2:].sum() < perfect.walls[:, 2:].sum()  # less wall in total


def test_arena_has_outer_walls_and_few_inner_walls():
    for seed in range(5):
        world = generate_world(WorldConfig(size=12.5, kind="arena", n_robots=4), seed)
        assert world.kind == "arena"
        assert 4 <= len(world.walls) <= 4 + 3
        assert world.occupancy.free_components(0.3)[1] == 1


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"size": 4.9}, r"4\.9.*\[5\.0, 17\.5\]"),
        ({"size": 17.6}, r"17\.6.*\[5\.0, 17\.5\]"),
        ({"kind": "cave"}, "cave"),
        ({"target_shapes": ("cone",)}, "cone"),
        ({"target_colors": ("pink",)}, "pink"),
        ({"n_robots": 11}, "n_robots=11"),
        ({"n_robots": 0}, "n_robots"),
        ({"n_robots": 2.0}, r"n_robots must be an integer >= 1, got 2\.0"),
        ({"size": "12.5"}, r"world size must be a number.*got '12\.5'"),
        ({"size": math.nan}, r"world size nan m"),
        ({"kind": ["maze"]}, "world kind"),
        ({"target_shapes": "sphere"}, r"target_shapes must be a non-empty tuple.*got 'sphere'"),
        ({"target_colors": ()}, r"target_colors must be a non-empty tuple.*got \(\)"),
        ({"cell_size": 0.0}, r"cell_size must be a finite number > 0 \(metres\), got 0\.0"),
        ({"cell_size": -2.5}, r"cell_size .*got -2\.5"),
        ({"cell_size": math.nan}, r"cell_size .*got nan"),
        ({"loop_fraction": math.nan}, r"loop_fraction must be a finite number >= 0 and <= 1, got nan"),
        ({"loop_fraction": 1.5}, r"loop_fraction .*got 1\.5"),
        ({"wall_thickness": 0.0}, r"wall_thickness must be a finite number > 0 \(metres\), got 0\.0"),
        ({"wall_height": math.nan}, r"wall_height must be a finite number > 0 \(metres\), got nan"),
        ({"wall_height": math.inf}, r"wall_height .*got inf"),
        ({"wall_height": -1.0}, r"wall_height .*got -1\.0"),
        ({"robot_radius": math.nan}, r"robot_radius must be a finite number > 0 \(metres\), got nan"),
        ({"robot_radius": 0.0}, r"robot_radius .*got 0\.0"),
        ({"start_target_margin": -0.5}, r"start_target_margin must be a finite number >= 0.*got -0\.5"),
        ({"start_target_margin": math.inf}, r"start_target_margin .*got inf"),
        ({"min_robot_gap": -0.1}, r"min_robot_gap must be a finite number >= 0.*got -0\.1"),
        ({"min_robot_gap": math.nan}, r"min_robot_gap .*got nan"),
        ({"arena_inner_walls": (3, 1)}, r"arena_inner_walls must be an integer range.*got \(3, 1\)"),
        ({"arena_inner_walls": (0.5, 2.5)}, r"arena_inner_walls .*got \(0\.5, 2\.5\)"),
        ({"arena_inner_walls": 2}, r"arena_inner_walls .*got 2"),
        (
            {"arena_wall_length": (2.5, 1.0)},
            r"arena_wall_length must be a range.*0 < lo <= hi, got \(2\.5, 1\.0\)",
        ),
        ({"arena_wall_length": (0.0, 1.0)}, r"arena_wall_length .*got \(0\.0, 1\.0\)"),
        ({"arena_wall_length": (1.0, math.inf)}, r"arena_wall_length .*got \(1\.0, inf\)"),
        ({"arena_wall_length": (1.0, 2.0, 3.0)}, r"arena_wall_length .*got \(1\.0, 2\.0, 3\.0\)"),
        # a maze whose corridors (cell minus wall) cannot fit the robot's disc
        ({"cell_size": 0.5}, r"corridors would be 0\.4 m wide.*robot_radius=0\.3"),
        ({"robot_radius": 1.3}, r"corridors would be 2\.4 m wide.*robot_radius=1\.3"),
        ({"wall_thickness": 2.0}, r"corridors would be 0\.5 m wide.*wall_thickness=2\.0"),
    ],
)
def test_bad_config_raises_value_error(kwargs, message):
    with pytest.raises(ValueError, match=message):
        WorldConfig(**kwargs)


def test_configs_the_project_uses_are_valid():
    """Defaults, the evaluation sizes, arenas, TurtleBot radii, the JSON form (lists) of stored episode sets,
    a maze without interior walls and configs built with numpy scalars all pass."""
    default = WorldConfig()
    for size in (5.0, 7.5, 12.5, 17.5, 5, 6.25, 8.75):
        for kind in ("maze", "arena"):
            WorldConfig(size=size, kind=kind, n_robots=6, robot_radius=0.2)
            WorldConfig(size=size, kind=kind, n_robots=6)
    as_json = {k: list(v) if isinstance(v, tuple) else v for k, v in dataclasses.asdict(default).items()}
    round_trip = WorldConfig(**as_json)
    assert round_trip == default and hash(round_trip) == hash(default)  # lists are stored as tuples
    assert round_trip.arena_inner_walls == (0, 3) and round_trip.arena_wall_length == (1.0, 2.5)
    WorldConfig(cell_size=0.5, loop_fraction=1.0)  # no interior walls left: any cell size
    WorldConfig(size=np.float32(7.5), n_robots=np.int64(2), arena_inner_walls=(np.int64(0), np.int64(2)))
    WorldConfig(start_target_margin=0, min_robot_gap=0)


def test_long_arena_walls_are_shortened_to_fit_small_arenas():
    """An inner wall is at most size - 3 m long (1.5 m from the border at both ends), whatever the range."""
    for seed in range(6):
        world = generate_world(WorldConfig(size=5.0, kind="arena", arena_inner_walls=(3, 3)), seed)
        inner = world.walls[4:]
        assert len(inner) == 3
        assert (2 * inner[:, 2:].max(axis=1) <= 2.0 + 1e-5).all()
    assert (
        len(generate_world(WorldConfig(size=5.5, kind="arena", arena_wall_length=(4.0, 6.0)), 0).walls) >= 4
    )


def test_too_many_robots_for_the_space_raises_value_error():
    with pytest.raises(ValueError, match="could not place"):
        generate_world(WorldConfig(size=5.0, n_robots=10), seed=0)


def test_bad_seed_raises_value_error():
    with pytest.raises(ValueError, match="seed"):
        generate_world(WorldConfig(size=5.0), seed=-1)
    for seed in (1.5, True, "3"):
        with pytest.raises(ValueError, match=f"seed must be a non-negative integer, got {seed!r}"):
            generate_world(WorldConfig(size=5.0), seed=seed)
    with pytest.raises(ValueError, match="config must be a WorldConfig, got dict"):
        generate_world({"size": 5.0}, seed=0)


def test_replace_layout_checks_starts(tiny_maze):
    target = tiny_maze.targets[0]
    wall = tiny_maze.walls[0]
    with pytest.raises(ValueError, match="overlaps"):
        replace_layout(tiny_maze, starts=np.array([[wall[0], wall[1], 0.0]] * 3))
    with pytest.raises(ValueError, match="targets"):
        replace_layout(tiny_maze, targets=[target])
    moved = replace_layout(tiny_maze, starts=tiny_maze.starts[::-1].copy())
    assert np.array_equal(moved.starts, tiny_maze.starts[::-1])


def test_replace_layout_checks_targets_against_bounds_walls_and_each_other(tiny_maze):
    ok = list(tiny_maze.targets)
    inner = next(w for w in tiny_maze.walls if 0.5 < w[0] < 4.5 and 0.5 < w[1] < 4.5)  # an interior wall
    cases = [
        ((0.0, 2.5), "sphere", r"target 0 \(sphere, green\) at \[0\.0, 2\.5\] is outside the world"),
        ((4.9, 1.0), "box", r"is outside the world: its body \(half extent 0\.2 m\)"),
        ((float(inner[0]), float(inner[1])), "sphere", r"target 0 .* overlaps the wall box"),
        ((float("nan"), 1.0), "box", r"target 0 position must be a finite float \[2\]"),
    ]
    for position, shape, message in cases:
        bad = TargetSpec(np.array(position, dtype=np.float32), shape, "green")
        with pytest.raises(ValueError, match=message):
            replace_layout(tiny_maze, targets=[bad] + ok[1:])
        with pytest.raises(ValueError, match=message):  # EpisodeSpec overrides go through the same check
            EpisodeSpec(config=tiny_maze.config, world_seed=tiny_maze.seed, targets=[bad] + ok[1:]).build()
    on_top = TargetSpec(ok[1].position + np.float32(0.3), "sphere", "cyan")  # 0.42 m apart: bodies overlap
    with pytest.raises(ValueError, match="target 2 .* overlaps target 1"):
        replace_layout(tiny_maze, targets=[ok[0], ok[1], on_top])
    walls = np.array([(2.5, 0.0, 2.55, 0.05), (2.5, 5.0, 2.55, 0.05)], dtype=np.float32)
    near = [TargetSpec(np.array([1.0, 0.3], np.float32), "sphere", "red")]  # touches the wall face at 0.05
    assert world_from_layout(5.0, walls, near, [(1.0, 3.0, 0.0)]).targets[0].color == "red"
    with pytest.raises(ValueError, match="overlaps the wall box"):
        world_from_layout(
            5.0, walls, [TargetSpec(np.array([1.0, 0.25], np.float32), "box", "red")], [(1.0, 3.0, 0.0)]
        )


def test_sample_start_poses_refuses_bad_counts(tiny_maze):
    rng = np.random.default_rng(0)
    for n in (-1, 2.5, True, "2"):
        with pytest.raises(ValueError, match=f"n must be an integer >= 0, got {n!r}"):
            sample_start_poses(tiny_maze, n, rng)
    assert sample_start_poses(tiny_maze, 0, rng).shape == (0, 3)
    poses = sample_start_poses(tiny_maze, np.int64(2), rng)
    assert poses.shape == (2, 3) and poses.dtype == np.float32
    cfg = tiny_maze.config
    radius = cfg.robot_radius
    # the two discs keep min_robot_gap between them
    assert math.dist(poses[0, :2], poses[1, :2]) > 2 * radius + cfg.min_robot_gap
    for i, (x, y, yaw) in enumerate(poses.astype(np.float64)):
        assert -math.pi <= yaw <= math.pi
        assert radius <= x <= tiny_maze.size - radius and radius <= y <= tiny_maze.size - radius
        for cx, cy, hx, hy in tiny_maze.walls.astype(np.float64):  # clear of every wall box
            assert math.hypot(max(abs(x - cx) - hx, 0.0), max(abs(y - cy) - hy, 0.0)) >= radius
        for target in tiny_maze.targets:  # clear of every target's body (sphere or cube)
            tx, ty = np.asarray(target.position, dtype=np.float64)
            half = target.half_extent
            if target.shape == "sphere":
                assert math.hypot(x - tx, y - ty) >= radius + half
            else:
                assert math.hypot(max(abs(x - tx) - half, 0.0), max(abs(y - ty) - half, 0.0)) >= radius
        # robot i starts more than SUCCESS_RADIUS + start_target_margin from its own target
        own = np.asarray(tiny_maze.targets[i].position, dtype=np.float64)
        assert math.hypot(x - own[0], y - own[1]) > SUCCESS_RADIUS + cfg.start_target_margin


def test_episode_spec_rebuilds_the_world_with_overrides(tiny_maze):
    spec = EpisodeSpec(
        config=tiny_maze.config, world_seed=tiny_maze.seed, starts=tiny_maze.starts[::-1].copy()
    )
    world = spec.build()
    assert np.array_equal(world.walls, tiny_maze.walls)
    assert np.array_equal(world.starts, tiny_maze.starts[::-1])
    new_targets = [
        TargetSpec(t.position, "box" if t.shape == "sphere" else "sphere", t.color) for t in tiny_maze.targets
    ]
    assert EpisodeSpec(world=tiny_maze, targets=new_targets).build().targets[0].shape == new_targets[0].shape
    with pytest.raises(ValueError, match="EpisodeSpec needs"):
        EpisodeSpec().build()


def test_numpy_scalars_in_a_config_become_python_numbers():
    import json

    config = WorldConfig(
        size=np.float32(12.5), n_robots=np.int64(2), arena_wall_length=(np.float64(1.0), 2.0)
    )
    assert type(config.size) is float and type(config.n_robots) is int
    assert all(type(v) is float for v in config.arena_wall_length)
    json.dumps(dataclasses.asdict(config))  # episode sets store it as JSON
    assert config == WorldConfig(size=12.5, n_robots=2, arena_wall_length=(1.0, 2.0))


def test_distractor_targets_are_new_kinds_placed_apart_and_leave_the_robots_targets():
    from navformer_rl.envs.world import add_distractor_targets

    world = generate_world(WorldConfig(size=10.0, n_robots=2), seed=4)
    assert add_distractor_targets(world, 0, np.random.default_rng(0)) is world
    more = add_distractor_targets(world, 3, np.random.default_rng(0))
    assert len(more.targets) == 5 and more.n_robots == 2
    assert more.targets[:2] == world.targets  # robot i still seeks targets[i]
    kinds = [(t.shape, t.color) for t in more.targets]
    assert len(set(kinds)) == 5  # none repeats a target already there
    xy = more.target_positions.astype(np.float64)
    gaps = np.hypot(*(xy[:, None] - xy[None]).transpose(2, 0, 1))[np.triu_indices(5, 1)]
    assert gaps.min() > 1.2
    to_starts = np.hypot(*(xy[2:, None] - world.starts[None, :, :2]).transpose(2, 0, 1))
    assert to_starts.min() > 1.2
    for t in more.targets[2:]:  # solid: the occupancy holds them, the old one did not
        cell = more.occupancy.world_to_cell(t.position)
        assert more.occupancy.grid[tuple(cell)] and not world.occupancy.grid[tuple(cell)]
    again = add_distractor_targets(world, 3, np.random.default_rng(0))
    assert [(t.shape, t.color) for t in again.targets] == kinds  # seeded
    with pytest.raises(ValueError, match="n=9 distractor targets: the catalogue has 8"):
        add_distractor_targets(world, 9, np.random.default_rng(0))
    with pytest.raises(ValueError, match="n must be an integer >= 0"):
        add_distractor_targets(world, -1, np.random.default_rng(0))
