"""OccupancyMap: coordinates, inflation and exact 8-connected shortest paths on hand-made maps."""

import math

import numpy as np
import pytest

from navformer_rl.envs.occupancy import OccupancyMap, grid_moves, reach_overestimate


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


def cell_centre(occ: OccupancyMap, row: int, col: int) -> np.ndarray:
    return occ.cell_to_world(np.array([row, col]))


def test_reach_one_is_the_eight_connected_grid_without_corner_cutting():
    moves = {(dr, dc): set(cells) for dr, dc, cells in grid_moves(1)}
    assert moves == {
        (0, 1): {(0, 0), (0, 1)},
        (1, 0): {(0, 0), (1, 0)},
        (1, 1): {(0, 0), (0, 1), (1, 0), (1, 1)},  # a diagonal needs both side cells free
        (1, -1): {(0, -1), (0, 0), (1, -1), (1, 0)},
    }
    # (2, 1) from the centre of (0, 0) to that of (2, 1) crosses row 1 at x = 1.0:
    # it touches (1, 0) and (1, 1)
    assert set(dict((m[:2], m[2]) for m in grid_moves(2))[(2, 1)]) == {(0, 0), (1, 0), (1, 1), (2, 1)}
    assert reach_overestimate(1) == pytest.approx(1 / math.cos(math.pi / 8) - 1)  # 8.24 %
    assert reach_overestimate(5) == pytest.approx(1 / math.cos(math.atan(1 / 5) / 2) - 1)  # 0.49 %


def test_open_floor_reach_gives_the_straight_line_when_the_direction_is_a_move():
    occ = OccupancyMap(np.zeros((12, 12), dtype=bool), 0.1)
    start, goal = cell_centre(occ, 0, 0), cell_centre(occ, 3, 9)  # 3 rows up, 9 columns right
    octile = 0.1 * (6 + 3 * math.sqrt(2))
    assert occ.shortest_path_length(start, goal, 0.0) == pytest.approx(octile)
    assert occ.shortest_path_length(start, goal, 0.0, reach=3) == pytest.approx(0.1 * 3 * math.sqrt(10))
    # (3, 9) = 3 x (1, 3); with reach 2 the best is (1, 2) moves plus straight ones, between the two
    assert 0.1 * 3 * math.sqrt(10) < occ.shortest_path_length(start, goal, 0.0, reach=2) < octile


def test_reach_paths_go_round_a_wall_end_through_cell_centres():
    """A wall in column 5, rows 0-7, on an 11 x 11 grid; from (0, 0) to (0, 10). With every direction
    (reach 10) the shortest polyline through free cell centres that touches no wall square is
    (0, 0) -> (7, 3) -> (8, 5) -> (7, 7) -> (0, 10): 2 sqrt(7^2 + 3^2) + 2 sqrt(1^2 + 2^2) cells (the
    segment (7, 3) -> (8, 5) is at y = 8.25 > 8 where it passes x = 5, the wall's top-left corner); the
    8-connected grid pays 8 sqrt(2) + 10 cells; reach 5 lies between, within its bound."""
    grid = np.zeros((11, 11), dtype=bool)
    grid[0:8, 5] = True
    occ = OccupancyMap(grid, 1.0)
    start, goal = cell_centre(occ, 0, 0), cell_centre(occ, 0, 10)
    exact = 2 * math.sqrt(58) + 2 * math.sqrt(5)
    assert occ.shortest_path_length(start, goal, 0.0, reach=10) == pytest.approx(exact)
    assert occ.shortest_path_length(start, goal, 0.0) == pytest.approx(8 * math.sqrt(2) + 10)
    reach5 = occ.shortest_path_length(start, goal, 0.0, reach=5)
    assert exact <= reach5 <= exact * (1 + reach_overestimate(5))
    with pytest.raises(ValueError, match="reach must be an integer >= 1"):
        occ.shortest_path_length(start, goal, 0.0, reach=0)


def test_reach_edge_cases():
    single = OccupancyMap(np.zeros((1, 1), dtype=bool), 0.1)  # no move fits: the path is the cell itself
    assert single.shortest_path_length((0.05, 0.05), (0.05, 0.05), 0.0, reach=5) == 0.0
    occ = OccupancyMap(np.zeros((6, 6), dtype=bool), 0.1)
    assert occ.shortest_path_length((0.05, 0.05), (0.55, 0.15), 0.0, reach=np.int64(5)) == pytest.approx(
        0.1 * math.hypot(5, 1)
    )  # numpy integers are integers
    with pytest.raises(ValueError, match="reach must be an integer >= 1, got 0"):
        reach_overestimate(0)
