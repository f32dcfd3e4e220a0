"""FrontierNavigator pieces: camera-coverage exploration map, minimum goal distance, line-of-sight pursuit."""

import math

import numpy as np
import pytest

from navformer_rl.experts.frontier import select_frontier
from navformer_rl.experts.mapping import FREE, UNKNOWN
from navformer_rl.experts.navigator import FrontierNavigator, LidarConfig, NavigatorConfig


def scan_room(nav: FrontierNavigator, pose: np.ndarray, size: float) -> None:
    """Exact ranges of a 360-degree scan inside an empty square room [0, size]^2."""
    lidar = LidarConfig(n_rays=360, max_range=20.0)
    a = pose[2] + lidar.angles
    c, s = np.cos(a), np.sin(a)
    with np.errstate(divide="ignore"):
        tx = np.where(c > 0, (size - pose[0]) / c, np.where(c < 0, -pose[0] / c, np.inf))
        ty = np.where(s > 0, (size - pose[1]) / s, np.where(s < 0, -pose[1] / s, np.inf))
    for _ in range(2):
        nav.observe(pose, np.minimum(tx, ty), lidar)


def test_camera_coverage_marks_unviewed_free_cells_unknown():
    nav = FrontierNavigator(4.0, NavigatorConfig(), np.zeros(2), camera=(math.radians(90), 5.0))
    pose = np.array([2.0, 2.0, 0.0])  # looking along +x
    scan_room(nav, pose, 4.0)
    lidar_map, explore = nav.map.ternary(), nav.exploration_map()
    ahead = tuple(nav.map.world_to_cell(np.array([3.0, 2.0])))
    behind = tuple(nav.map.world_to_cell(np.array([1.0, 2.0])))
    assert lidar_map[ahead] == FREE and lidar_map[behind] == FREE
    assert explore[ahead] == FREE  # inside the 90-degree camera cone
    assert explore[behind] == UNKNOWN  # mapped by the lidar, never looked at by the camera
    no_camera = FrontierNavigator(4.0, NavigatorConfig(), np.zeros(2))
    scan_room(no_camera, pose, 4.0)
    assert np.array_equal(no_camera.exploration_map(), no_camera.map.ternary())


def test_min_path_skips_the_frontier_under_the_robot():
    t = np.full((3, 12), FREE, dtype=np.int8)
    t[:, 0] = UNKNOWN  # frontier at column 1, right next to the robot
    t[:, 11] = UNKNOWN  # frontier at column 10
    trav = t == FREE
    near = select_frontier(t, trav, (1, 2), min_cells=1)
    far = select_frontier(t, trav, (1, 2), min_cells=1, min_path=3.0)
    assert near.goal[1] == 1 and near.path_length == 1.0
    assert far.goal[1] == 10 and far.path_length == 8.0


def test_pursuit_point_keeps_line_of_sight_around_a_corner():
    nav = FrontierNavigator(4.0, NavigatorConfig(lookahead=2.0), np.zeros(2))
    # An L-shaped path: east along y = 0.55 to x = 1.55, then north; a block fills the inside of the corner.
    east = np.stack([np.arange(0.55, 1.56, 0.1), np.full(11, 0.55)], 1)
    north = np.stack([np.full(15, 1.55), np.arange(0.65, 2.06, 0.1)], 1)
    nav.path = np.concatenate([east, north])
    nav.planning_blocked[:, :] = False
    nav.planning_blocked[10:40, 0:12] = True  # x < 1.2, y > 1.0: the corner's inside
    point = nav._pursuit_point(np.array([0.55, 0.55, 0.0]))
    # Segments from (0.55, 0.55) to (1.55, y) pass the block's corner (1.2, 1.0) for y > 1.24 (grazing,
    # within half-cell sampling), and cross the block for y >= 1.35.
    assert point[0] == np.float64(1.55) and 0.55 <= point[1] < 1.35
    free_nav = FrontierNavigator(4.0, NavigatorConfig(lookahead=2.0), np.zeros(2))
    free_nav.path = nav.path
    far = free_nav._pursuit_point(np.array([0.55, 0.55, 0.0]))
    assert far[1] > 1.35  # without the block the pursuit point is farther up the northern leg


def gap_with_a_parked_robot(fallback: tuple[float, ...]) -> FrontierNavigator:
    """A wall at y = 2.0-2.1 m with a 1.2 m gap (x 1.4-2.6 m); a parked robot's disc (r 0.33 m at x 2.5)
    narrows it to 0.9 m between occupied cell centres. Target beyond the wall, known and seen."""
    config = NavigatorConfig(inflation_margin=0.10, fallback_inflation=fallback)  # full inflation 0.45 m
    nav = FrontierNavigator(4.0, config, np.array([2.0, 3.3]), target_known=True)
    nav.map.logodds[:] = nav.map.l_min  # mapped free
    nav.map.logodds[20, :] = nav.map.l_max  # the wall
    nav.map.logodds[20, 14:26] = nav.map.l_min  # the gap
    nav.target_mode = True
    nav.set_static_discs(np.array([[2.5, 2.05, 0.33]]))
    return nav


def test_target_mode_retries_at_smaller_inflation_when_a_parked_robot_closes_the_gap():
    """At 0.45 m no cell centre of the 0.9 m gap is clear on both sides: without a fallback the robot has
    no path and nothing to do (it would wait out the trial); with FCA's fallback radii it goes through."""
    pose = np.array([2.0, 1.0, 0.0])
    stuck = gap_with_a_parked_robot(())
    assert stuck.carrot(pose) is None and stuck.no_path_plans == 1
    nav = gap_with_a_parked_robot((0.40, 0.35))
    assert nav.carrot(pose) is not None and nav.no_path_plans == 0
    in_gap = nav.path[(nav.path[:, 1] > 1.95) & (nav.path[:, 1] < 2.15)]
    assert len(in_gap) and np.all((in_gap[:, 0] > 1.4) & (in_gap[:, 0] < 2.2))  # between wall end and disc
    assert nav.path[-1, 1] > 2.5  # and on to the target's side
    with pytest.raises(ValueError, match="fallback_inflation"):
        NavigatorConfig(fallback_inflation=(0.30, 0.40))  # must decrease
