"""A* on an 8-connected grid, without corner cutting, with the octile heuristic.

Unlike PythonRobotics' A*, a search that exhausts the open set returns ``None`` ("no path").
"""

from __future__ import annotations

import heapq
import math

import numpy as np

SQRT2 = math.sqrt(2.0)


def octile(dr: int, dc: int) -> float:
    """Exact 8-connected distance (in cells) on an empty grid: admissible and consistent."""
    dr, dc = abs(dr), abs(dc)
    return max(dr, dc) + (SQRT2 - 1.0) * min(dr, dc)


def astar(blocked: np.ndarray, start: tuple[int, int], goal: tuple[int, int]) -> list[tuple[int, int]] | None:
    """Shortest 8-connected path on a bool ``[H, W]`` grid (True = blocked).

    Moves cost 1 (orthogonal) and sqrt(2) (diagonal, only if both orthogonal cells are free).
    Returns the ``(row, col)`` cells from ``start`` to ``goal`` inclusive (``[start]`` when they are equal),
    or ``None`` when the goal is unreachable or ``start``/``goal`` is blocked.
    """
    grid = np.asarray(blocked)
    if grid.ndim != 2 or grid.dtype != bool:
        raise ValueError(f"blocked must be a bool [H, W] array, got dtype {grid.dtype} shape {grid.shape}")
    h, w = grid.shape
    for name, cell in (("start", start), ("goal", goal)):
        if len(cell) != 2 or not (0 <= cell[0] < h and 0 <= cell[1] < w):
            raise ValueError(f"{name} {cell} is outside the grid of shape {grid.shape}")
    sr, sc = int(start[0]), int(start[1])
    gr, gc = int(goal[0]), int(goal[1])
    if grid[sr, sc] or grid[gr, gc]:
        return None
    if (sr, sc) == (gr, gc):
        return [(sr, sc)]
    # Search only the bounding box of the free cells (paths never leave it), padded with a blocked border
    # that removes bound checks from the inner loop.
    rows, cols = np.nonzero(~grid)
    r0, c0 = int(rows.min()), int(cols.min())
    sub = grid[r0 : int(rows.max()) + 1, c0 : int(cols.max()) + 1]
    hs, ws = sub.shape
    wp = ws + 2
    free = np.zeros((hs + 2, wp), dtype=bool)
    free[1:-1, 1:-1] = ~sub
    free_flat = free.ravel().tolist()
    # Octile heuristic of every padded cell, precomputed with numpy (same float arithmetic as octile()).
    dr = np.abs(np.arange(hs + 2)[:, None] - (gr - r0 + 1))
    dc = np.abs(np.arange(wp)[None, :] - (gc - c0 + 1))
    heur = (np.maximum(dr, dc) + (SQRT2 - 1.0) * np.minimum(dr, dc)).ravel().tolist()
    start_i = (sr - r0 + 1) * wp + sc - c0 + 1
    goal_i = (gr - r0 + 1) * wp + gc - c0 + 1
    straight = (-wp, wp, -1, 1)
    diagonal = ((-wp - 1, -wp, -1), (-wp + 1, -wp, 1), (wp - 1, wp, -1), (wp + 1, wp, 1))
    g_cost = {start_i: 0.0}
    parent = {start_i: -1}
    closed = set()
    heap = [(heur[start_i], 0.0, start_i)]
    while heap:
        _, g, cur = heapq.heappop(heap)
        if cur in closed:
            continue
        if cur == goal_i:
            break
        closed.add(cur)
        for off in straight:
            nxt = cur + off
            if free_flat[nxt] and nxt not in closed:
                ng = g + 1.0
                if ng < g_cost.get(nxt, math.inf):
                    g_cost[nxt] = ng
                    parent[nxt] = cur
                    heapq.heappush(heap, (ng + heur[nxt], ng, nxt))
        for off, side_a, side_b in diagonal:
            nxt = cur + off
            if free_flat[nxt] and free_flat[cur + side_a] and free_flat[cur + side_b] and nxt not in closed:
                ng = g + SQRT2
                if ng < g_cost.get(nxt, math.inf):
                    g_cost[nxt] = ng
                    parent[nxt] = cur
                    heapq.heappush(heap, (ng + heur[nxt], ng, nxt))
    else:
        return None
    path = []
    node = goal_i
    while node != -1:
        r, c = divmod(node, wp)
        path.append((r - 1 + r0, c - 1 + c0))
        node = parent[node]
    path.reverse()
    return path


def path_cost(path: list[tuple[int, int]]) -> float:
    """Length in cells of a cell path (1 per orthogonal, sqrt 2 per diagonal step)."""
    total = 0.0
    for (r0, c0), (r1, c1) in zip(path[:-1], path[1:]):
        dr, dc = abs(r1 - r0), abs(c1 - c0)
        if max(dr, dc) != 1:
            raise ValueError(f"cells {(r0, c0)} and {(r1, c1)} are not 8-neighbours")
        total += SQRT2 if dr and dc else 1.0
    return total
