"""Table II's furnished worlds: seeded, connected, in colours no training world uses, built and drawn."""

import itertools

import numpy as np
import pytest

from navformer_rl.constants import FURNISHED_FOOTPRINTS
from navformer_rl.envs.furnished import (
    FURNISHED_KINDS,
    PALETTES,
    PLANNER_MARGIN,
    floor_texture,
    furnished_size,
)
from navformer_rl.envs.occupancy import OccupancyMap
from navformer_rl.envs.robots import JACKAL
from navformer_rl.envs.scene import _SEAM, _TILE_DARK, _TILE_LIGHT, PLAIN_FLOOR_RGBA, WALL_PALETTE
from navformer_rl.envs.sim import Simulator
from navformer_rl.envs.topdown import draw_topdown
from navformer_rl.envs.world import TARGET_RGBA, WorldConfig, generate_world
from navformer_rl.experts.visibility import segment_hits_boxes


def furnished(kind: str, seed: int, n_robots: int = 3):
    return generate_world(WorldConfig(size=furnished_size(kind), kind=kind, n_robots=n_robots), seed)


@pytest.mark.parametrize("kind", FURNISHED_KINDS)
def test_same_seed_same_world_other_seed_other_layout(kind):
    a, b, c = furnished(kind, 3), furnished(kind, 3), furnished(kind, 4)
    assert a.kind == kind and a.size == max(FURNISHED_FOOTPRINTS[kind])
    assert a.walls.tobytes() == b.walls.tobytes() and a.starts.tobytes() == b.starts.tobytes()
    assert a.style.roles == b.style.roles
    assert np.array_equal(a.style.box_rgba, b.style.box_rgba)
    assert np.array_equal(a.style.box_height, b.style.box_height)
    assert [(t.position.tolist(), t.shape, t.color) for t in a.targets] == [
        (t.position.tolist(), t.shape, t.color) for t in b.targets
    ]
    # another seed moves the furniture (or partitions), the targets and the starts
    assert a.walls.shape != c.walls.shape or not np.array_equal(a.walls, c.walls)
    assert not np.array_equal(a.target_positions, c.target_positions)
    assert not np.array_equal(a.starts, c.starts)


def test_palettes_are_unlike_training_and_unlike_the_targets():
    """Every furnished colour is >= 0.15 (RGB in [0, 1]) from every maze wall / floor colour and >= 0.25 from
    every target colour; a world's boxes and floor use only its palette."""
    training = [*WALL_PALETTE, *(0.92 * WALL_PALETTE)]  # the simulator shades every other wall by 0.92
    training += [np.array(c) / 255 for c in (_TILE_LIGHT, _TILE_DARK, _SEAM)]
    training.append(np.array(PLAIN_FLOOR_RGBA[:3]))
    targets = [np.array(rgba[:3]) for rgba in TARGET_RGBA.values()]
    for kind, palette in PALETTES.items():
        for colour in palette.colours():
            assert min(np.linalg.norm(np.array(colour) - t) for t in training) >= 0.15, (kind, colour)
            assert min(np.linalg.norm(np.array(colour) - t) for t in targets) >= 0.25, (kind, colour)
        world = furnished(kind, 0)
        allowed = {tuple(np.float32(v) for v in c) for c in palette.colours()}
        assert {tuple(rgba[:3]) for rgba in world.style.box_rgba} <= allowed
        floor = {tuple(px) for px in world.style.floor_texture.reshape(-1, 3).tolist()}
        assert floor == {tuple(int(round(255 * v)) for v in c) for c in palette.floor}


def test_floor_texture_known_pixels():
    light, dark, seam = (np.round(255 * np.array(c)).astype(np.uint8) for c in PALETTES["cafe"].floor)
    img = floor_texture(PALETTES["cafe"])  # 0.5 m tiles, a 1 m repeat at 32 px/m
    assert img.shape == (32, 32, 3) and img.dtype == np.uint8
    assert np.array_equal(img[8, 8], light) and np.array_equal(img[8, 24], dark)
    assert np.array_equal(img[0, 5], seam) and np.array_equal(img[16, 5], seam)


@pytest.mark.parametrize(("kind", "seed"), list(itertools.product(FURNISHED_KINDS, (0, 1))))
def test_free_space_is_one_room_set_and_targets_are_reachable_and_visible(kind, seed):
    world = furnished(kind, seed)
    radius = world.config.robot_radius
    # every free cell is reachable: one component for the robot, with the targets in place ...
    assert world.occupancy.free_components(radius)[1] == 1
    # ... and for the experts' planners (a disc PLANNER_MARGIN larger), on the walls alone
    walls_only = OccupancyMap.from_shapes(world.size, 0.05, world.walls)
    assert walls_only.free_components(radius + PLANNER_MARGIN)[1] == 1
    # the free space is the building: nothing beyond its footprint
    fx, fy = FURNISHED_FOOTPRINTS[kind]
    free = world.occupancy.cell_to_world(np.argwhere(~world.occupancy.grid))
    assert free[:, 0].max() < fx and free[:, 1].max() < fy
    for i, target in enumerate(world.targets):
        assert np.isfinite(world.shortest_path_length(world.starts[i, :2], i))
        # seen from the free cell next to it: no box cuts the line of sight
        cell = world.occupancy.cell_to_world(np.array(world.occupancy.snap_to_free(target.position, radius)))
        assert np.hypot(*(cell - target.position)) < 1.0
        boxes = world.walls.astype(np.float64)
        assert not segment_hits_boxes(cell, target.position.astype(np.float64), boxes)


def test_furnished_config_checks():
    with pytest.raises(ValueError, match=r"a cafe world is 9.3 x 23.1 m .* size must be 23.1, got 12.5"):
        WorldConfig(size=12.5, kind="cafe")
    with pytest.raises(ValueError, match="unknown world kind 'library'"):
        WorldConfig(size=12.5, kind="library")
    assert WorldConfig(size=23.1, kind="cafe").size == 23.1  # above the mazes' 17.5 m


def test_builds_in_pybullet_and_renders_an_84x84_frame():
    world = furnished("cafe", 2)
    sim = Simulator(world, JACKAL)
    try:
        p, c = sim._p, sim._client
        assert p.getNumBodies(physicsClientId=c) == 1 + len(world.walls) + len(world.targets) + 3
        for k in range(len(world.walls)):  # floor first, then one body per box in its style
            (shape,) = p.getVisualShapeData(1 + k, physicsClientId=c)
            np.testing.assert_allclose(shape[7], world.style.box_rgba[k], atol=1e-6)
            np.testing.assert_allclose(shape[3][2], world.style.box_height[k], atol=1e-6)  # full extents
        frame = sim.render(0)
        assert frame.shape == (84, 84, 3) and frame.dtype == np.uint8
        # robot 0 faces a terracotta wall: diffuse light scales its colour (here by about 0.6)
        scale = frame.reshape(-1, 3) / (255 * np.array(PALETTES["cafe"].walls))
        lit_wall = (np.ptp(scale, axis=1) < 0.03) & (scale.mean(axis=1) > 0.3) & (scale.mean(axis=1) < 1.05)
        assert lit_wall.mean() > 0.05
    finally:
        sim.close()


def test_topdown_paints_furniture_in_its_colour():
    world = furnished("house", 0)
    px, margin = 20.0, 5
    img = draw_topdown(world, px_per_m=px, margin_px=margin, show_success_radius=False, labels=False)
    for k in (4, int(np.flatnonzero(np.array(world.style.roles) != "wall")[0])):  # a partition, a furniture
        cx, cy = world.walls[k, :2].astype(float)
        pixel = img[int(round(margin + (world.size - cy) * px)), int(round(margin + cx * px))]
        wall = world.style.roles[k] == "wall"
        expected = (60, 60, 66) if wall else np.round(255 * world.style.box_rgba[k, :3])
        assert np.array_equal(pixel, expected), world.style.roles[k]
