"""Occupancy grid of a world and exact shortest paths on it (pure numpy + scipy).

Cell ``(row, col)`` covers ``x in [ox + col*res, ox + (col+1)*res)`` and
``y in [oy + row*res, oy + (row+1)*res)`` with ``(ox, oy) = origin``: rows follow +y, columns follow +x (flip
rows to draw it as an image).

Shortest paths use the grid of free cells of the map inflated by a clearance (a disc robot of that radius
fits at every free cell centre). ``reach=1`` (the default) is the 8-connected grid: a diagonal move is allowed
only when both cells it cuts past are free (no corner cutting). ``reach=k`` adds every straight move to a
cell up to ``k`` rows and ``k`` columns away (:func:`grid_moves`), allowed when every cell whose closed square
the move's segment touches is free - the same rule, generalised. Lengths are exact for the graph (Dijkstra),
in metres. In free space a path is at most :func:`reach_overestimate` longer than the straight line between
the same cell centres: 8.2 % for ``reach=1``, 0.49 % for ``reach=5``; beside obstacles longer moves can also
pass where 8-connected ones cannot, so reach-1 paths can be longer still (on the Table I mazes reach 5 was
within 0.46 % of reach 12, and reach 1 up to 8.1 % longer than reach 5).
"""

from __future__ import annotations

import math
from collections import OrderedDict

import numpy as np
from scipy import ndimage
from scipy.sparse import coo_matrix, csr_matrix
from scipy.sparse.csgraph import dijkstra

from navformer_rl.utils.checks import check_int, check_number

_FIELD_CACHE_SIZE = 16


def grid_moves(reach: int) -> list[tuple[int, int, tuple[tuple[int, int], ...]]]:
    """The moves of the ``reach`` grid graph, one per undirected direction.

    Returns ``[(d_row, d_col, cells)]`` for every primitive offset (``gcd = 1``) with
    ``max(|d_row|, |d_col|) <= reach`` in one half-plane; ``cells`` are the offsets, relative to the start
    cell, of every cell whose closed square the segment between the two cell centres touches (start and end
    included). ``reach=1`` gives the 4 moves of the 8-connected grid; the diagonal's cells are the 2 x 2
    block, i.e. no corner cutting.
    """
    reach = check_int(reach, "reach")
    moves = []
    for d_row in range(0, reach + 1):
        for d_col in range(-reach, reach + 1):
            if (d_row == 0 and d_col <= 0) or math.gcd(d_row, abs(d_col)) != 1:
                continue
            moves.append((d_row, d_col, _touched_cells(d_row, d_col)))
    return moves


def _touched_cells(d_row: int, d_col: int) -> tuple[tuple[int, int], ...]:
    """Offsets of the cells whose closed unit square meets the segment from the centre of cell (0, 0) to
    the centre of cell ``(d_row, d_col)`` (Liang-Barsky clipping; touching a corner counts)."""
    cells = []
    for row in range(min(0, d_row), max(0, d_row) + 1):
        for col in range(min(0, d_col), max(0, d_col) + 1):
            lo, hi = 0.0, 1.0
            # the segment is (0.5, 0.5) + t * (d_col, d_row) in (x = col, y = row) cell units
            for start, delta, low, high in ((0.5, d_col, col, col + 1), (0.5, d_row, row, row + 1)):
                if delta == 0:
                    if not low <= start <= high:
                        lo, hi = 1.0, 0.0
                    continue
                t0, t1 = (low - start) / delta, (high - start) / delta
                lo, hi = max(lo, min(t0, t1)), min(hi, max(t0, t1))
            if lo <= hi + 1e-12:
                cells.append((row, col))
    return tuple(cells)


def reach_overestimate(reach: int) -> float:
    """Largest relative excess, in free space, of a ``reach`` grid path over the straight line between the
    same cell centres: ``1 / cos(gap / 2) - 1`` for the widest angle ``gap`` between two move directions.
    Beside obstacles it is no bound: a long move needs only the cells its segment touches, so it can
    pass where shorter moves cannot (a diagonal staircase of free cells), and reach-k paths can be more
    than this shorter than reach-1 paths; on the Table I mazes reach 5 came within 0.46 % of reach 12."""
    angles = sorted({math.atan2(d_row, abs(d_col)) for d_row, d_col, _ in grid_moves(reach)})
    gap = max(b - a for a, b in zip(angles, angles[1:]))
    return 1.0 / math.cos(gap / 2) - 1.0


class OccupancyMap:
    """A boolean occupancy grid (True = wall or solid object) with path queries.

    Args:
        grid: bool ``[H, W]``, ``grid[row, col]`` True where the cell is occupied. Stored read-only.
        resolution: cell side in metres.
        origin: world ``(x, y)`` of the lower-left corner of cell ``(0, 0)``.
    """

    def __init__(self, grid: np.ndarray, resolution: float, origin: tuple[float, float] = (0.0, 0.0)):
        grid = np.asarray(grid)
        if grid.ndim != 2 or grid.dtype != np.bool_:
            raise ValueError(f"grid must be a bool array [H, W], got dtype {grid.dtype} shape {grid.shape}")
        check_number(resolution, "resolution", greater_than=0.0, unit="metres")
        self.grid = grid.copy()
        self.grid.flags.writeable = False
        self.resolution = float(resolution)
        self.origin = (float(origin[0]), float(origin[1]))
        self._inflated: dict[float, np.ndarray] = {}
        self._graphs: dict[tuple[float, int], tuple[csr_matrix, np.ndarray, np.ndarray]] = {}
        self._nearest_free: dict[float, np.ndarray] = {}
        self._fields: OrderedDict[tuple, np.ndarray] = OrderedDict()

    # ------------------------------------------------------------------ construction
    @classmethod
    def from_shapes(
        cls,
        size: float,
        resolution: float,
        boxes: np.ndarray,
        circles: np.ndarray | None = None,
    ) -> OccupancyMap:
        """Rasterise a square world ``[0, size]^2``.

        Args:
            size: world side in metres (the grid has ``ceil(size / resolution)`` cells per side).
            resolution: cell side in metres.
            boxes: float ``[N, 4]`` axis-aligned boxes ``(cx, cy, half_x, half_y)``; every cell the box
                overlaps (with positive area) is occupied.
            circles: optional float ``[M, 3]`` discs ``(cx, cy, r)``; every cell whose square comes closer
                than ``r`` to the centre is occupied.
        """
        check_number(size, "size", greater_than=0.0, unit="metres")
        check_number(resolution, "resolution", greater_than=0.0, unit="metres")
        n = int(math.ceil(size / resolution - 1e-9))
        grid = np.zeros((n, n), dtype=bool)
        eps = 1e-6
        for cx, cy, hx, hy in np.asarray(boxes, dtype=np.float64).reshape(-1, 4):
            c0 = max(int(math.floor((cx - hx) / resolution + eps)), 0)
            c1 = min(int(math.ceil((cx + hx) / resolution - eps)), n)
            r0 = max(int(math.floor((cy - hy) / resolution + eps)), 0)
            r1 = min(int(math.ceil((cy + hy) / resolution - eps)), n)
            grid[r0:r1, c0:c1] = True
        if circles is not None:
            for cx, cy, r in np.asarray(circles, dtype=np.float64).reshape(-1, 3):
                c0 = max(int(math.floor((cx - r) / resolution)), 0)
                c1 = min(int(math.ceil((cx + r) / resolution)), n)
                r0 = max(int(math.floor((cy - r) / resolution)), 0)
                r1 = min(int(math.ceil((cy + r) / resolution)), n)
                cols = np.arange(c0, c1)
                rows = np.arange(r0, r1)
                # closest point of each cell square to the centre
                px = np.clip(cx, cols * resolution, (cols + 1) * resolution)
                py = np.clip(cy, rows * resolution, (rows + 1) * resolution)
                inside = (px[None, :] - cx) ** 2 + (py[:, None] - cy) ** 2 < r * r
                grid[r0:r1, c0:c1] |= inside
        return cls(grid, resolution)

    # ------------------------------------------------------------------ coordinates
    @property
    def shape(self) -> tuple[int, int]:
        """``(H, W)`` of the grid."""
        return self.grid.shape

    def world_to_cell(self, xy: np.ndarray) -> np.ndarray:
        """World points ``float [..., 2]`` -> int64 ``[..., 2]`` cells ``(row, col)`` (not clipped)."""
        xy = np.asarray(xy, dtype=np.float64)
        col = np.floor((xy[..., 0] - self.origin[0]) / self.resolution)
        row = np.floor((xy[..., 1] - self.origin[1]) / self.resolution)
        return np.stack([row, col], axis=-1).astype(np.int64)

    def cell_to_world(self, cells: np.ndarray) -> np.ndarray:
        """Cells ``int [..., 2]`` ``(row, col)`` -> float64 ``[..., 2]`` world ``(x, y)`` of the cell
        centres."""
        cells = np.asarray(cells)
        x = self.origin[0] + (cells[..., 1] + 0.5) * self.resolution
        y = self.origin[1] + (cells[..., 0] + 0.5) * self.resolution
        return np.stack([x, y], axis=-1)

    def _checked_cell(self, xy, what: str) -> tuple[int, int]:
        """Cell of a finite point inside the map (boundary points go to the edge cell);
        ValueError otherwise."""
        flat = np.asarray(xy, dtype=np.float64).reshape(-1)
        if flat.shape != (2,):
            raise ValueError(f"{what} must be an (x, y) pair, got {xy!r}")
        x, y = float(flat[0]), float(flat[1])
        h, w = self.grid.shape
        ox, oy = self.origin
        res = self.resolution
        if not (math.isfinite(x) and math.isfinite(y)):
            raise ValueError(f"{what} must be finite, got ({x}, {y})")
        if not (ox - 1e-9 <= x <= ox + w * res + 1e-9 and oy - 1e-9 <= y <= oy + h * res + 1e-9):
            raise ValueError(
                f"{what} ({x}, {y}) lies outside the map [{ox}, {ox + w * res}] x [{oy}, {oy + h * res}]"
            )
        row = min(max(int((y - oy) // res), 0), h - 1)
        col = min(max(int((x - ox) // res), 0), w - 1)
        return row, col

    # ------------------------------------------------------------------ inflation
    def inflate(self, radius: float) -> np.ndarray:
        """Cells a disc of ``radius`` metres centred at the cell centre would overlap a wall: bool ``[H, W]``.

        A cell is blocked when the distance from its centre to the nearest occupied cell's boundary
        (centre distance minus half a cell) is below ``radius``; ``inflate(0)`` is the grid itself.
        The result is cached per radius and read-only.
        """
        if not radius >= 0:
            raise ValueError(f"inflation radius must be >= 0 metres, got {radius}")
        key = round(float(radius), 9)
        if key not in self._inflated:
            if not self.grid.any():
                blocked = np.zeros(self.shape, dtype=bool)
            else:
                dist = ndimage.distance_transform_edt(~self.grid) * self.resolution
                blocked = dist - 0.5 * self.resolution < radius - 1e-9
                blocked |= self.grid
            blocked.flags.writeable = False
            self._inflated[key] = blocked
        return self._inflated[key]

    def free_components(self, clearance: float) -> tuple[np.ndarray, int]:
        """Connected components of free cells of ``inflate(clearance)``.

        Returns ``(labels int32 [H, W]`` (0 = blocked, 1..n = component), ``n)``. 4-connectivity gives the
        same components as the 8-connected graph without corner cutting.
        """
        labels, n = ndimage.label(~self.inflate(clearance))
        return labels, int(n)

    def largest_free_component(self, clearance: float) -> np.ndarray:
        """bool ``[H, W]``: the free cells of the largest connected component of ``inflate(clearance)``."""
        labels, n = self.free_components(clearance)
        if n == 0:
            return np.zeros(self.shape, dtype=bool)
        counts = np.bincount(labels.ravel())
        counts[0] = 0
        return labels == int(np.argmax(counts))

    # ------------------------------------------------------------------ shortest paths
    def _graph(self, clearance: float, reach: int = 1) -> tuple[csr_matrix, np.ndarray, np.ndarray]:
        """(adjacency csr ``[n, n]``, node index int64 ``[H, W]`` (-1 blocked),
        nearest-free indices ``[2, H, W]``)."""
        reach = check_int(reach, "reach")  # 1 = the 8-connected grid
        key = (round(float(clearance), 9), reach)
        if key in self._graphs:
            return self._graphs[key]
        blocked = self.inflate(clearance)
        free = ~blocked
        h, w = self.shape
        node = np.full((h, w), -1, dtype=np.int64)
        node[free] = np.arange(int(free.sum()))
        rows, cols = [np.zeros(0, np.int64)], [np.zeros(0, np.int64)]  # a 1 x 1 map has no moves
        weights = [np.zeros(0)]
        for d_row, d_col, cells in grid_moves(reach):
            # source cells (r, c) whose every touched cell (r + dr, c + dc) lies on the map
            r0, r1 = -min(dr for dr, _ in cells), h - max(dr for dr, _ in cells)
            c0, c1 = -min(dc for _, dc in cells), w - max(dc for _, dc in cells)
            if r0 >= r1 or c0 >= c1:
                continue
            ok = np.ones((r1 - r0, c1 - c0), dtype=bool)
            for dr, dc in cells:
                ok &= free[r0 + dr : r1 + dr, c0 + dc : c1 + dc]
            rows.append(node[r0:r1, c0:c1][ok])
            cols.append(node[r0 + d_row : r1 + d_row, c0 + d_col : c1 + d_col][ok])
            weights.append(np.full(len(rows[-1]), self.resolution * math.hypot(d_row, d_col)))
        n_nodes = int(free.sum())
        adjacency = coo_matrix(
            (np.concatenate(weights), (np.concatenate(rows), np.concatenate(cols))), shape=(n_nodes, n_nodes)
        ).tocsr()
        if blocked.all():
            nearest = np.zeros((2, h, w), dtype=np.int64)
        else:
            _, nearest = ndimage.distance_transform_edt(blocked, return_indices=True)
        self._graphs[key] = (adjacency, node, nearest)
        return self._graphs[key]

    def snap_to_free(self, xy, clearance: float) -> tuple[int, int]:
        """Cell ``(row, col)`` nearest (Euclidean, in cells) to the point ``xy`` that is free in
        ``inflate(clearance)``. ValueError when the point is outside the map or nothing is free."""
        _, node, nearest = self._graph(clearance)  # reach does not change which cells are free
        if node.max() < 0:
            raise ValueError(f"no free cell at clearance {clearance} m: the inflated map is fully blocked")
        row, col = self._checked_cell(xy, "point")
        return int(nearest[0, row, col]), int(nearest[1, row, col])

    def distance_field(
        self, goal_xy, clearance: float, goal_radius: float = 0.0, reach: int = 1
    ) -> np.ndarray:
        """Geodesic distance in metres from every cell to the goal: float64 ``[H, W]`` (read-only).

        The goal is the free cell nearest to ``goal_xy`` on ``inflate(clearance)``; with ``goal_radius > 0``
        it is every free cell whose centre lies within ``goal_radius`` of ``goal_xy`` (plus the snapped cell).
        Blocked and unreachable cells hold ``inf``. ``reach``: the grid graph (module docstring); 1 is the
        8-connected grid, larger values approach the any-angle geodesic at a higher cost (``reach=5``:
        40 moves per cell instead of 4, ~10x the time).
        """
        adjacency, node, _ = self._graph(clearance, reach)
        goal_cell = self.snap_to_free(goal_xy, clearance)
        key = (goal_cell, round(float(clearance), 9), round(float(goal_radius), 9), reach)
        if key in self._fields:
            self._fields.move_to_end(key)
            return self._fields[key]
        sources = [int(node[goal_cell])]
        if goal_radius > 0:
            centres = self.cell_to_world(np.argwhere(node >= 0))
            gx, gy = np.asarray(goal_xy, dtype=np.float64).reshape(2)
            near = (centres[:, 0] - gx) ** 2 + (centres[:, 1] - gy) ** 2 <= goal_radius**2
            sources = np.unique(np.concatenate([sources, node[node >= 0][near]])).tolist()
        dist_nodes = dijkstra(adjacency, directed=False, indices=sources, min_only=True)
        field = np.full(self.shape, np.inf)
        field[node >= 0] = dist_nodes
        field.flags.writeable = False
        self._fields[key] = field
        if len(self._fields) > _FIELD_CACHE_SIZE:
            self._fields.popitem(last=False)
        return field

    def shortest_path_length(
        self, start_xy, goal_xy, clearance: float, goal_radius: float = 0.0, reach: int = 1
    ) -> float:
        """Length in metres of the shortest corner-cut-free path on ``inflate(clearance)`` (8-connected for
        ``reach=1``; see the module docstring for larger ``reach``).

        Start and goal are snapped to their nearest free cells (the snap offsets are not added). With
        ``goal_radius > 0`` the path ends at the first free cell within ``goal_radius`` of the goal.
        Returns ``inf`` when the goal cannot be reached; ValueError for points outside the map.
        """
        field = self.distance_field(goal_xy, clearance, goal_radius, reach)
        return float(field[self.snap_to_free(start_xy, clearance)])
