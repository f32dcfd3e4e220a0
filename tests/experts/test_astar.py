"""A* known answers on hand-made grids."""

import math

import numpy as np
import pytest

from navformer_rl.experts.astar import astar, octile, path_cost
from navformer_rl.experts.grid import distance_field

SQ2 = math.sqrt(2.0)


def grid(rows: list[str]) -> np.ndarray:
    return np.array([[ch == "#" for ch in row] for row in rows], dtype=bool)


def test_empty_grid_cost_is_octile():
    blocked = np.zeros((6, 9), dtype=bool)
    path = astar(blocked, (0, 0), (5, 8))
    assert path[0] == (0, 0) and path[-1] == (5, 8)
    assert path_cost(path) == pytest.approx(5 * SQ2 + 3)
    assert octile(5, 8) == pytest.approx(5 * SQ2 + 3)


def test_start_equals_goal():
    assert astar(np.zeros((3, 3), dtype=bool), (1, 1), (1, 1)) == [(1, 1)]


def test_wall_with_gap_known_cost():
    blocked = grid(
        [
            ".....",
            "####.",
            ".....",
        ]
    )
    # (0,0) -> (2,0): right along row 0 to (0,3), diagonal is forbidden past the wall corner at (1,3):
    # (0,0)->(0,3): 3, (0,3)->(0,4) 1, (0,4)->(1,4) 1, (1,4)->(2,4) 1, (2,4)->(2,0) 4  = 10.
    path = astar(blocked, (0, 0), (2, 0))
    assert path_cost(path) == pytest.approx(10.0)
    assert all(not blocked[r, c] for r, c in path)


def test_no_corner_cutting_between_diagonal_blocks():
    blocked = grid(
        [
            ".#",
            "#.",
        ]
    )
    assert astar(blocked, (0, 0), (1, 1)) is None


def test_blocked_goal_and_enclosed_goal_return_none():
    blocked = grid(
        [
            ".....",
            ".###.",
            ".#.#.",
            ".###.",
        ]
    )
    assert astar(blocked, (0, 0), (2, 2)) is None
    assert astar(blocked, (0, 0), (1, 1)) is None


def test_matches_dijkstra_distance_on_random_grids():
    rng = np.random.default_rng(0)
    for _ in range(5):
        blocked = rng.random((25, 30)) < 0.25
        blocked[0, 0] = blocked[24, 29] = False
        dist = distance_field(~blocked, [(24, 29)])
        path = astar(blocked, (0, 0), (24, 29))
        if np.isfinite(dist[0, 0]):
            assert path is not None
            assert path_cost(path) == pytest.approx(dist[0, 0])
        else:
            assert path is None


def test_bad_input_raises():
    with pytest.raises(ValueError, match="outside the grid"):
        astar(np.zeros((3, 3), dtype=bool), (0, 0), (3, 0))
    with pytest.raises(ValueError, match="bool"):
        astar(np.zeros((3, 3)), (0, 0), (1, 1))
