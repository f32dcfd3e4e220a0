"""Occupancy mapping from scans and frontier detection/selection on small known maps."""

import math

import numpy as np
import pytest

from navformer_rl.experts.frontier import frontier_cells, frontier_clusters, select_frontier
from navformer_rl.experts.mapping import FREE, OCCUPIED, UNKNOWN, LogOddsGrid

U, F, OC = UNKNOWN, FREE, OCCUPIED


def test_single_ray_marks_free_then_occupied():
    g = LogOddsGrid((2.0, 1.0), resolution=0.1)
    for _ in range(3):
        g.update(np.array([0.05, 0.55, 0.0]), np.array([1.0]), np.array([0.0]), max_range=1.8)
    t = g.ternary()
    assert np.all(t[5, 0:10] == FREE)  # x in [0, 1.0): along the ray
    assert t[5, 10] == OCCUPIED  # the cell behind the hit at x = 1.05
    assert np.all(t[5, 11:] == UNKNOWN)
    assert np.all(t[4] == UNKNOWN) and np.all(t[6] == UNKNOWN)


def test_max_range_ray_marks_no_obstacle():
    g = LogOddsGrid((2.0, 1.0), resolution=0.1)
    for _ in range(3):
        g.update(np.array([0.05, 0.55, 0.0]), np.array([1.5]), np.array([0.0]), max_range=1.5)
    t = g.ternary()
    assert not np.any(t == OCCUPIED)
    assert np.all(t[5, 0:14] == FREE)


def test_full_scan_of_a_square_room():
    """A 360-degree scan inside a 2 m square room (walls at x, y = 0 and 2) maps the room interior."""
    g = LogOddsGrid((2.0, 2.0), resolution=0.1)
    angles = np.linspace(-math.pi, math.pi, 360, endpoint=False)
    pose = np.array([1.0, 1.0, 0.3])
    world = angles + pose[2]
    # distance to the square's border along each ray
    tx = np.where(
        np.cos(world) > 0,
        (1.95 - 1.0) / np.maximum(np.cos(world), 1e-9),
        (1.0 - 0.05) / np.maximum(-np.cos(world), 1e-9),
    )
    ty = np.where(
        np.sin(world) > 0,
        (1.95 - 1.0) / np.maximum(np.sin(world), 1e-9),
        (1.0 - 0.05) / np.maximum(-np.sin(world), 1e-9),
    )
    ranges = np.minimum(tx, ty)
    for _ in range(2):
        g.update(pose, ranges, angles, max_range=5.0)
    t = g.ternary()
    assert np.all(t[1:19, 1:19] == FREE)
    border = np.concatenate([t[0, 1:19], t[19, 1:19], t[1:19, 0], t[1:19, 19]])
    assert np.mean(border == OCCUPIED) > 0.95
    trav = g.traversable(0.3)
    assert trav[10, 10] and not trav[2, 10] and trav[4, 10]


def test_frontier_cells_yamauchi_definition():
    t = np.array(
        [
            [F, F, F, U],
            [F, OC, F, U],
            [F, F, F, F],
        ],
        dtype=np.int8,
    )
    expected = np.array(
        [
            [0, 0, 1, 0],
            [0, 0, 1, 0],
            [0, 0, 0, 1],
        ],
        dtype=bool,
    )
    assert np.array_equal(frontier_cells(t), expected)


def test_clusters_are_eight_connected_and_filtered_by_size():
    t = np.full((6, 6), F, dtype=np.int8)
    t[0, 5] = U  # frontier: (0,4), (1,5)  -> one 8-connected group of 2
    t[5, 0] = U  # frontier: (4,0), (5,1)  -> one group of 2
    t[3, 3] = U  # frontier: 4 cells around it -> one group of 4
    groups = frontier_clusters(t, min_cells=1)
    sizes = sorted(len(g) for g in groups)
    assert sizes == [2, 2, 4]
    assert [len(g) for g in frontier_clusters(t, min_cells=3)] == [4]


def test_select_nearest_by_path_not_euclid():
    """U-shaped map: the frontier behind the wall is Euclidean-closer but farther by path."""
    rows = [
        "FFFFFFFFFU",
        "FFFFFFFFFU",
        "OOOOOOOOFF",
        "FFFFFFFFFF",
        "UUFFFFFFFF",
    ]
    code = {"F": F, "O": OC, "U": U}
    t = np.array([[code[ch] for ch in r] for r in rows], dtype=np.int8)
    trav = t == F
    robot = (0, 0)
    chosen = select_frontier(t, trav, robot, min_cells=1)
    # Frontier A near (0,8)/(1,8): path 8 cells; frontier B near (3,0)/(3,1): Euclid 3 but path ~ 8+...
    assert chosen is not None
    assert chosen.goal in {(0, 8), (1, 8)}
    assert chosen.path_length == pytest.approx(8.0)


def test_unreachable_and_blacklisted_frontiers_are_skipped_and_none_left():
    t = np.array(
        [
            [F, F, OC, F, U],
            [F, F, OC, F, U],
            [F, F, OC, F, F],
        ],
        dtype=np.int8,
    )
    trav = t == F
    assert select_frontier(t, trav, (0, 0), min_cells=1) is None  # the only frontier is behind a wall
    t2 = t.copy()
    t2[:, 2] = F
    chosen = select_frontier(t2, t2 == F, (0, 0), min_cells=1)
    assert chosen is not None
    assert (
        select_frontier(t2, t2 == F, (0, 0), min_cells=1, blacklist=[chosen.goal], blacklist_radius=3) is None
    )
    assert select_frontier(np.full((4, 4), F, dtype=np.int8), np.ones((4, 4), bool), (0, 0)) is None
