"""8-connected grid graphs without corner cutting, and distance fields over them.

Cells are ``(row, col)``; moves cost 1 (orthogonal) or sqrt(2) (diagonal), in cells. A diagonal move is
allowed only when both orthogonal cells it passes are traversable (no corner cutting). Distance fields use
``scipy.sparse.csgraph.dijkstra`` (one run from many sources); A* (:mod:`astar`) is our own.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import dijkstra

SQRT2 = math.sqrt(2.0)
MOVES: tuple[tuple[int, int, float], ...] = (
    (-1, 0, 1.0),
    (1, 0, 1.0),
    (0, -1, 1.0),
    (0, 1, 1.0),
    (-1, -1, SQRT2),
    (-1, 1, SQRT2),
    (1, -1, SQRT2),
    (1, 1, SQRT2),
)
"""(d_row, d_col, cost) of the 8 moves."""


def _check_grid(traversable: np.ndarray) -> np.ndarray:
    grid = np.asarray(traversable)
    if grid.ndim != 2 or grid.dtype != bool:
        raise ValueError(f"expected a bool [H, W] grid, got dtype {grid.dtype} shape {grid.shape}")
    return grid


def grid_graph(traversable: np.ndarray) -> csr_matrix:
    """Sparse adjacency of the traversable cells of a bool ``[H, W]`` grid (True = traversable).

    Node ``r * W + c``; edge weights in cells (1 or sqrt 2); no corner cutting. Built directly in CSR
    order (row-major nodes, moves in :data:`MOVES` order), without a COO sort.
    """
    free = _check_grid(traversable)
    h, w = free.shape
    padded = np.zeros((h + 2, w + 2), dtype=bool)
    padded[1:-1, 1:-1] = free
    valid = np.empty((h, w, len(MOVES)), dtype=bool)
    target = np.empty((h, w, len(MOVES)), dtype=np.int64)
    node = np.arange(h * w, dtype=np.int64).reshape(h, w)
    for k, (dr, dc, _cost) in enumerate(MOVES):
        ok = free & padded[1 + dr : 1 + dr + h, 1 + dc : 1 + dc + w]
        if dr != 0 and dc != 0:
            ok &= padded[1 + dr : 1 + dr + h, 1 : 1 + w] & padded[1 : 1 + h, 1 + dc : 1 + dc + w]
        valid[:, :, k] = ok
        target[:, :, k] = node + dr * w + dc
    costs = np.array([m[2] for m in MOVES])
    flat_valid = valid.reshape(h * w, len(MOVES))
    indptr = np.zeros(h * w + 1, dtype=np.int64)
    np.cumsum(flat_valid.sum(axis=1), out=indptr[1:])
    indices = target.reshape(h * w, len(MOVES))[flat_valid]
    data = np.broadcast_to(costs, flat_valid.shape)[flat_valid]
    return csr_matrix((data, indices, indptr), shape=(h * w, h * w))


def distance_field(traversable: np.ndarray, sources: list[tuple[int, int]]) -> np.ndarray:
    """Path length in cells from the nearest source to every cell: float64 ``[H, W]``, ``inf`` if unreachable.

    Sources that are not traversable are ignored; with no traversable source every cell is ``inf``.
    """
    free = _check_grid(traversable)
    h, w = free.shape
    out = np.full((h, w), np.inf)
    sources = [(r, c) for r, c in sources if 0 <= r < h and 0 <= c < w and free[r, c]]
    if not sources:
        return out
    # Work on the bounding box of the traversable cells (paths never leave it).
    rows, cols = np.nonzero(free)
    r0, r1, c0, c1 = rows.min(), rows.max() + 1, cols.min(), cols.max() + 1
    crop = free[r0:r1, c0:c1]
    cw = c1 - c0
    idx = [(r - r0) * cw + (c - c0) for r, c in sources]
    dist = dijkstra(grid_graph(crop), directed=True, indices=idx, min_only=True)
    out[r0:r1, c0:c1] = np.asarray(dist).reshape(crop.shape)
    return out


def nearest_true_cell(mask: np.ndarray, cell: tuple[int, int], max_radius: int) -> tuple[int, int] | None:
    """The True cell of ``mask`` closest (Euclidean) to ``cell`` within ``max_radius`` cells, else None."""
    r0, c0 = cell
    h, w = mask.shape
    rlo, rhi = max(0, r0 - max_radius), min(h, r0 + max_radius + 1)
    clo, chi = max(0, c0 - max_radius), min(w, c0 + max_radius + 1)
    rr, cc = np.nonzero(mask[rlo:rhi, clo:chi])
    if rr.size == 0:
        return None
    d2 = (rr + rlo - r0) ** 2 + (cc + clo - c0) ** 2
    k = int(np.argmin(d2))
    if d2[k] > max_radius**2:
        return None
    return int(rr[k] + rlo), int(cc[k] + clo)


def descend(
    field: np.ndarray, start: tuple[int, int], traversable: np.ndarray, max_steps: int | None = None
) -> list[tuple[int, int]]:
    """Follow a distance field downhill from ``start`` to a zero cell (no corner cutting).

    Returns the cell path including ``start``; stops early if no neighbour decreases the field, or after
    ``max_steps`` moves.
    """
    h, w = field.shape
    path = [start]
    r, c = start
    limit = math.inf if max_steps is None else max_steps
    while field[r, c] > 0 and len(path) <= limit:
        best, best_val = None, field[r, c]
        for dr, dc, _cost in MOVES:
            nr, nc = r + dr, c + dc
            if not (0 <= nr < h and 0 <= nc < w) or not traversable[nr, nc]:
                continue
            if dr and dc and not (traversable[r + dr, c] and traversable[r, c + dc]):
                continue
            if field[nr, nc] < best_val:
                best, best_val = (nr, nc), field[nr, nc]
        if best is None:
            break
        r, c = best
        path.append(best)
    return path
