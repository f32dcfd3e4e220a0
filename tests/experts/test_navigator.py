"""FrontierNavigator pieces: camera-coverage exploration map, minimum goal distance, line-of-sight pursuit."""

import math

import numpy as np

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
