"""Frontier-based exploration (Yamauchi 1997): detection, clustering, selection by path length.

Definition used (Yamauchi's): a frontier cell is a FREE cell with at least one UNKNOWN 4-neighbour.
Frontier cells are grouped by 8-connectivity; groups smaller than ``min_cells`` are dropped. The chosen
frontier is the one nearest to the robot by *path length* through traversable cells (one Dijkstra from the
robot), skipping unreachable groups and groups near blacklisted goals.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from navformer_rl.experts.grid import distance_field
from navformer_rl.experts.mapping import FREE, UNKNOWN

EIGHT_CONNECTED = np.ones((3, 3), dtype=bool)


def frontier_cells(ternary: np.ndarray) -> np.ndarray:
    """bool ``[H, W]``: FREE cells with an UNKNOWN 4-neighbour (cells outside the grid are not unknown)."""
    t = np.asarray(ternary)
    if t.ndim != 2:
        raise ValueError(f"expected a ternary [H, W] grid, got shape {t.shape}")
    unknown = t == UNKNOWN
    near = np.zeros_like(unknown)
    near[1:, :] |= unknown[:-1, :]
    near[:-1, :] |= unknown[1:, :]
    near[:, 1:] |= unknown[:, :-1]
    near[:, :-1] |= unknown[:, 1:]
    return (t == FREE) & near


def frontier_clusters(ternary: np.ndarray, min_cells: int) -> list[np.ndarray]:
    """8-connected groups of frontier cells with at least ``min_cells`` cells: list of int64 ``[K, 2]``.

    Ordered by label (row-major scan of the first cell), so the result is deterministic.
    """
    labels, n = ndimage.label(frontier_cells(ternary), structure=EIGHT_CONNECTED)
    if n == 0:
        return []
    rows, cols = np.nonzero(labels)
    lab = labels[rows, cols]
    order = np.argsort(lab, kind="stable")
    rows, cols, lab = rows[order], cols[order], lab[order]
    splits = np.flatnonzero(np.diff(lab)) + 1
    groups = np.split(np.stack([rows, cols], axis=1), splits)
    return [g for g in groups if len(g) >= min_cells]


@dataclass(frozen=True)
class Frontier:
    """A selected frontier group.

    ``cells``: int64 ``[K, 2]`` its cells; ``goal``: the reachable cell of the group nearest to the robot by
    path; ``path_length``: that path's length in cells; ``cost``: the ranking cost.
    """

    cells: np.ndarray
    goal: tuple[int, int]
    path_length: float
    cost: float


def select_frontier(
    ternary: np.ndarray,
    traversable: np.ndarray,
    robot_cell: tuple[int, int],
    min_cells: int = 4,
    blacklist: list[tuple[int, int]] | None = None,
    blacklist_radius: float = 5.0,
    bias_cell: tuple[int, int] | None = None,
    bias_weight: float = 0.0,
    min_path: float = 0.0,
) -> Frontier | None:
    """The frontier to explore next, or ``None`` when no reachable, non-blacklisted frontier is left.

    Args:
        ternary: int8 ``[H, W]`` map (UNKNOWN/FREE/OCCUPIED).
        traversable: bool ``[H, W]`` cells the robot centre may occupy (free, outside the inflation).
        robot_cell: ``(row, col)`` start of the path search (must be traversable, else nothing is reachable).
        min_cells: smallest group kept.
        blacklist: goal cells given up on; a group whose reachable cells all lie within ``blacklist_radius``
            cells of a blacklisted cell is skipped, other groups lose those cells.
        bias_cell, bias_weight: optional goal-directed ranking ``cost = path + weight * |goal - bias_cell|``
            (used by the privileged FCA, which knows its target); plain Yamauchi when ``bias_weight == 0``.
        min_path: frontier cells closer than this path length (cells) are not goals (a robot standing on a
            frontier it cannot clear by driving onto it would otherwise re-select it forever).
    """
    groups = frontier_clusters(ternary, min_cells)
    if not groups:
        return None
    dist = distance_field(traversable, [robot_cell])
    banned = np.zeros(traversable.shape, dtype=bool)
    for r, c in blacklist or []:
        rr, cc = np.ogrid[: banned.shape[0], : banned.shape[1]]
        banned |= (rr - r) ** 2 + (cc - c) ** 2 <= blacklist_radius**2
    best: Frontier | None = None
    for cells in groups:
        d = dist[cells[:, 0], cells[:, 1]].copy()
        d[banned[cells[:, 0], cells[:, 1]] | (d < min_path)] = np.inf
        k = int(np.argmin(d))
        if not np.isfinite(d[k]):
            continue
        goal = (int(cells[k, 0]), int(cells[k, 1]))
        cost = float(d[k])
        if bias_cell is not None and bias_weight > 0:
            cost += bias_weight * float(np.hypot(goal[0] - bias_cell[0], goal[1] - bias_cell[1]))
        if best is None or cost < best.cost:
            best = Frontier(cells=cells, goal=goal, path_length=float(d[k]), cost=cost)
    return best
