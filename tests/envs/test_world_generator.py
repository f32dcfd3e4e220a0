"""World generator: valid, connected, seeded mazes and arenas; clear errors for bad configurations."""

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
    ],
)
def test_bad_config_raises_value_error(kwargs, message):
    with pytest.raises(ValueError, match=message):
        WorldConfig(**kwargs)


def test_too_many_robots_for_the_space_raises_value_error():
    with pytest.raises(ValueError, match="could not place"):
        generate_world(WorldConfig(size=5.0, n_robots=10), seed=0)


def test_bad_seed_raises_value_error():
    with pytest.raises(ValueError, match="seed"):
        generate_world(WorldConfig(size=5.0), seed=-1)


def test_replace_layout_checks_starts(tiny_maze):
    target = tiny_maze.targets[0]
    wall = tiny_maze.walls[0]
    with pytest.raises(ValueError, match="overlaps"):
        replace_layout(tiny_maze, starts=np.array([[wall[0], wall[1], 0.0]] * 3))
    with pytest.raises(ValueError, match="targets"):
        replace_layout(tiny_maze, targets=[target])
    moved = replace_layout(tiny_maze, starts=tiny_maze.starts[::-1].copy())
    assert np.array_equal(moved.starts, tiny_maze.starts[::-1])


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
