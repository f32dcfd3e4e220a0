"""OccupancyMap: coordinates, inflation and exact 8-connected shortest paths on hand-made maps."""

import math

import numpy as np
import pytest

from navformer_rl.envs.occupancy import OccupancyMap


def bordered(rows: int, cols: int) -> np.ndarray:
    grid = np.zeros((rows, cols), dtype=bool)
    grid[0] = grid[-1] = grid[:, 0] = grid[:, -1] = True
    return grid


def test_straight_corridor_length_is_exact():
    occ = OccupancyMap(bordered(10, 40), 0.1)
    # cells (5, 5) -> (5, 35): 30 straight moves of 0.1 m
    assert occ.shortest_path_length((0.55, 0.55), (3.55, 0.55), clearance=0.0) == pytest.approx(3.0, abs=1e-9)


def test_u_turn_around_a_wall():
    grid = bordered(20, 40)
    grid[:15, 20] = True  # a wall from the bottom up to row 14: the path must climb to row 15 and back
    occ = OccupancyMap(grid, 0.1)
    length = occ.shortest_path_length((0.55, 0.55), (3.55, 0.55), clearance=0.0)
    # 10 diagonals up, 10 straight moves past the wall, 10 diagonals down
    assert length == pytest.approx(20 * 0.1 * math.sqrt(2) + 1.0, abs=1e-9)


def test_unreachable_goal_is_inf():
    grid = bordered(10, 40)
    grid[:, 20] = True
    occ = OccupancyMap(grid, 0.1)
    assert occ.shortest_path_length((0.55, 0.55), (3.55, 0.55), clearance=0.0) == math.inf


def test_clearance_closes_a_narrow_gap():
    grid = bordered(20, 40)
    grid[:, 20] = True
    grid[9:12, 20] = False  # a 0.3 m gap
    occ = OccupancyMap(grid, 0.1)
    assert math.isfinite(occ.shortest_path_length((0.55, 1.05), (3.55, 1.05), clearance=0.0))
    assert occ.shortest_path_length((0.55, 1.05), (3.55, 1.05), clearance=0.2) == math.inf


def test_no_corner_cutting():
    grid = np.ones((4, 4), dtype=bool)
    grid[1, 1] = grid[2, 2] = False  # free cells touching only at a corner
    occ = OccupancyMap(grid, 1.0)
    assert occ.shortest_path_length((1.5, 1.5), (2.5, 2.5), clearance=0.0) == math.inf
    grid[1, 2] = False  # one side open: still no diagonal, the path goes around the corner
    assert OccupancyMap(grid, 1.0).shortest_path_length((1.5, 1.5), (2.5, 2.5), 0.0) == pytest.approx(2.0)
    grid[2, 1] = False  # both sides open: the diagonal is allowed
    assert OccupancyMap(grid, 1.0).shortest_path_length((1.5, 1.5), (2.5, 2.5), 0.0) == pytest.approx(
        math.sqrt(2)
    )


def test_goal_radius_stops_at_the_success_region():
    occ = OccupancyMap(bordered(10, 40), 0.1)
    # free cell centres within 1.0 m of x = 3.55 start at x = 2.55: 20 moves from x = 0.55
    assert occ.shortest_path_length((0.55, 0.55), (3.55, 0.55), 0.0, goal_radius=1.0) == pytest.approx(2.0)


def test_start_and_goal_snap_to_the_nearest_free_cell():
    grid = bordered(10, 40)
    grid[4:7, 34:37] = True  # a solid 'target' around the goal cell (5, 35)
    occ = OccupancyMap(grid, 0.1)
    assert occ.snap_to_free((3.55, 0.55), 0.0) in {(3, 35), (7, 35), (5, 33), (5, 37)}
    assert occ.shortest_path_length((0.55, 0.55), (3.55, 0.55), 0.0) == pytest.approx(2.8)


def test_distance_field_values():
    occ = OccupancyMap(bordered(10, 10), 0.5)
    field = occ.distance_field((2.25, 2.25), 0.0)  # goal cell (4, 4)
    assert field[4, 4] == 0.0
    assert field[4, 5] == pytest.approx(0.5)
    assert field[5, 5] == pytest.approx(0.5 * math.sqrt(2))
    assert field[0, 0] == math.inf  # a wall


def test_inflate_known_cells():
    grid = np.zeros((5, 5), dtype=bool)
    grid[2, 2] = True
    occ = OccupancyMap(grid, 0.1)
    assert np.array_equal(occ.inflate(0.0), grid)
    # centre distance minus half a cell: 0.05 to the 4 neighbours, 0.091 to the diagonals
    assert occ.inflate(0.05).sum() == 1
    assert occ.inflate(0.06).sum() == 5
    assert occ.inflate(0.1).sum() == 9


def test_world_cell_round_trip():
    occ = OccupancyMap(np.zeros((20, 30), dtype=bool), 0.05)
    cells = np.array([[0, 0], [19, 29], [7, 11]])
    assert np.array_equal(occ.world_to_cell(occ.cell_to_world(cells)), cells)
    assert np.allclose(occ.cell_to_world([3, 4]), [0.225, 0.175])


def test_bad_inputs_raise_value_error():
    with pytest.raises(ValueError, match="bool array"):
        OccupancyMap(np.zeros((3, 3)), 0.1)
    with pytest.raises(ValueError, match="resolution"):
        OccupancyMap(np.zeros((3, 3), dtype=bool), 0.0)
    occ = OccupancyMap(bordered(10, 10), 0.1)
    with pytest.raises(ValueError, match="outside the map"):
        occ.shortest_path_length((5.0, 0.5), (0.5, 0.5), 0.0)
    with pytest.raises(ValueError, match="finite"):
        occ.shortest_path_length((np.nan, 0.5), (0.5, 0.5), 0.0)
    with pytest.raises(ValueError, match=">= 0"):
        occ.inflate(-0.1)
    with pytest.raises(ValueError, match="resolution must be a finite number > 0 \\(metres\\), got 0.0"):
        OccupancyMap.from_shapes(5.0, 0.0, np.zeros((0, 4)))
    with pytest.raises(ValueError, match="size must be a finite number > 0 \\(metres\\), got nan"):
        OccupancyMap.from_shapes(math.nan, 0.05, np.zeros((0, 4)))
    with pytest.raises(ValueError, match="resolution .*got inf"):
        OccupancyMap(np.zeros((3, 3), dtype=bool), math.inf)
