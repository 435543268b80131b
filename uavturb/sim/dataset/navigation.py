"""Grid navigation: the free-space map of one cruise height (:class:`NavGrid`), shortest grid
paths (:func:`astar`), string pulling (:func:`simplify_path`) and the visiting order of points
(:func:`christofides_order`)."""

from __future__ import annotations

import heapq
import math
from dataclasses import dataclass
from typing import Any

import numpy as np

_SQRT2 = math.sqrt(2.0)
_MOVES = ((1, 0, 1.0), (-1, 0, 1.0), (0, 1, 1.0), (0, -1, 1.0),
          (1, 1, _SQRT2), (1, -1, _SQRT2), (-1, 1, _SQRT2), (-1, -1, _SQRT2))



@dataclass
class NavGrid:
    """The navigation map of one cruise height.

    Attributes
    ----------
    occ : (nx, ny) bool, occupied cells (``True``); cell ``[i, j]`` is centred at ``origin + (i, j) res``
    origin : (2,) m, world x, y of cell ``[0, 0]``
    res : m, cell size
    z : m, cruise height of the map
    surface : (nx, ny) m, height of the surface below each cell seen from ``z`` (``-inf``: none)
    flat : (nx, ny) bool, free cells over a level surface (``±flat_radius`` window)
    """

    occ: np.ndarray
    origin: np.ndarray
    res: float
    z: float
    surface: np.ndarray
    flat: np.ndarray

    @property
    def shape(self) -> tuple[int, int]:
        return self.occ.shape  # type: ignore[return-value]

    def to_cell(self, xy: np.ndarray) -> np.ndarray:
        """Nearest cell indices ``(K, 2)`` int of world points ``xy (K, 2)`` [m] (clipped to the grid)."""
        ij = np.rint((np.atleast_2d(xy) - self.origin) / self.res).astype(int)
        return np.clip(ij, 0, np.array(self.shape) - 1)

    def to_world(self, ij: np.ndarray) -> np.ndarray:
        """World x, y ``(K, 2)`` [m] of cell centres ``ij (K, 2)``."""
        return self.origin + np.atleast_2d(ij) * self.res

    def free_at(self, xy: np.ndarray) -> np.ndarray:
        """Whether world points ``xy (K, 2)`` fall in free cells (outside the grid: occupied)."""
        xy = np.atleast_2d(np.asarray(xy, float))
        ij = np.rint((xy - self.origin) / self.res).astype(int)
        ok = (ij >= 0).all(1) & (ij < np.array(self.shape)).all(1)
        out = np.zeros(len(xy), bool)
        out[ok] = ~self.occ[ij[ok, 0], ij[ok, 1]]
        return out

    def segment_free(self, a: np.ndarray, b: np.ndarray) -> bool:
        """Whether the straight segment ``a → b`` (world x, y [m]) crosses free cells only: every
        cell the segment passes through (exact grid traversal: the cells of the midpoints
        between consecutive crossings of cell boundaries)."""
        u0 = (np.asarray(a, float)[:2] - self.origin) / self.res + 0.5  # cell i spans [i, i + 1)
        u1 = (np.asarray(b, float)[:2] - self.origin) / self.res + 0.5
        d = u1 - u0
        ts = [np.array([0.0, 1.0])]
        for ax in range(2):
            if abs(d[ax]) > 1e-12:
                lo, hi = sorted((u0[ax], u1[ax]))
                k = np.arange(np.floor(lo) + 1, np.ceil(hi))
                ts.append((k - u0[ax]) / d[ax])
        t = np.unique(np.clip(np.concatenate(ts), 0.0, 1.0))
        mid = (t[:-1] + t[1:]) / 2 if len(t) > 1 else np.array([0.0])
        ij = np.floor(u0 + mid[:, None] * d).astype(int)
        if ((ij < 0) | (ij >= np.array(self.shape))).any():
            return False
        ends = np.stack([np.asarray(a, float)[:2], np.asarray(b, float)[:2]])
        return not self.occ[ij[:, 0], ij[:, 1]].any() and bool(self.free_at(ends).all())

    def graph(self) -> tuple[Any, np.ndarray]:
        """Sparse 8-connected graph of the free cells (diagonal moves only where both
        orthogonal neighbours are free), weights in metres; and the node index of every cell
        (``-1`` for occupied ones)."""
        from scipy.sparse import coo_matrix

        free = ~self.occ
        nx, ny = self.shape
        node = np.full((nx, ny), -1, dtype=np.int64)
        node[free] = np.arange(int(free.sum()))
        cells = np.argwhere(free)
        rows, cols, w = [], [], []
        for di, dj, c in ((1, 0, 1.0), (0, 1, 1.0), (1, 1, _SQRT2), (1, -1, _SQRT2)):  # each edge once
            n = cells + (di, dj)
            ok = (n[:, 0] >= 0) & (n[:, 0] < nx) & (n[:, 1] >= 0) & (n[:, 1] < ny)
            a, n = cells[ok], n[ok]
            ok = free[n[:, 0], n[:, 1]]
            if di and dj:  # no corner cutting
                ok &= free[a[:, 0] + di, a[:, 1]] & free[a[:, 0], a[:, 1] + dj]
            rows.append(node[a[ok, 0], a[ok, 1]])
            cols.append(node[n[ok, 0], n[ok, 1]])
            w.append(np.full(int(ok.sum()), c * self.res))
        m = int(free.sum())
        r, c_, ww = np.concatenate(rows), np.concatenate(cols), np.concatenate(w)
        g = coo_matrix((np.r_[ww, ww], (np.r_[r, c_], np.r_[c_, r])), shape=(m, m)).tocsr()
        return g, node



def astar(occ: np.ndarray, start: tuple[int, int], goal: tuple[int, int]) -> list[tuple[int, int]]:
    """Shortest 8-connected path between two free cells of an occupancy grid (A*, octile
    heuristic, no corner cutting).

    Parameters
    ----------
    occ : (nx, ny) bool, ``True`` = occupied
    start, goal : cell indices ``(i, j)``

    Returns
    -------
    list of cells from ``start`` to ``goal`` inclusive; empty when the goal is unreachable.
    """
    nx, ny = occ.shape
    start, goal = (int(start[0]), int(start[1])), (int(goal[0]), int(goal[1]))
    if occ[start] or occ[goal]:
        return []

    def h(c: tuple[int, int]) -> float:
        dx, dy = abs(c[0] - goal[0]), abs(c[1] - goal[1])
        return (dx + dy) + (_SQRT2 - 2.0) * min(dx, dy)

    g = {start: 0.0}
    parent: dict[tuple[int, int], tuple[int, int]] = {}
    heap = [(h(start), 0, start)]
    counter = 0
    closed: set[tuple[int, int]] = set()
    while heap:
        _, _, c = heapq.heappop(heap)
        if c == goal:
            path = [c]
            while c in parent:
                c = parent[c]
                path.append(c)
            return path[::-1]
        if c in closed:
            continue
        closed.add(c)
        for di, dj, cost in _MOVES:
            n = (c[0] + di, c[1] + dj)
            if not (0 <= n[0] < nx and 0 <= n[1] < ny) or occ[n]:
                continue
            if di and dj and (occ[c[0] + di, c[1]] or occ[c[0], c[1] + dj]):
                continue
            gn = g[c] + cost
            if gn < g.get(n, np.inf):
                g[n] = gn
                parent[n] = c
                counter += 1
                heapq.heappush(heap, (gn + h(n), counter, n))
    return []


def simplify_path(grid: NavGrid, xy: np.ndarray) -> np.ndarray:
    """Corner points of a grid path: from each kept point, jump to the farthest later point
    in straight free line of sight (string pulling).

    Parameters
    ----------
    grid : NavGrid
    xy : (K, 2) m, the path's points

    Returns
    -------
    (L, 2) m, ``L <= K``, first and last points kept; every segment is free in ``grid``.
    """
    xy = np.asarray(xy, float)
    out = [xy[0]]
    i = 0
    while i < len(xy) - 1:
        j = len(xy) - 1
        while j > i + 1 and not grid.segment_free(xy[i], xy[j]):
            j -= 1
        out.append(xy[j])
        i = j
    return np.asarray(out)


def christofides_order(lengths: np.ndarray, start: int = 0) -> list[int]:
    """Visiting order of points from a symmetric matrix of path lengths: the Christofides
    tour (networkx) rotated to begin at ``start`` and opened there by dropping the longer of
    its two edges at ``start`` (the tour is walked in the direction that keeps the shorter).

    Parameters
    ----------
    lengths : (n, n) m, finite, symmetric, zero diagonal (a metric: shortest-path lengths)
    start : index of the first point

    Returns
    -------
    list of the ``n`` point indices, each once, beginning with ``start``.
    """
    import networkx as nx
    from networkx.algorithms.approximation import christofides

    n = len(lengths)
    if n <= 2:
        return [start] + [i for i in range(n) if i != start]
    G = nx.Graph()
    for i in range(n):
        for j in range(i + 1, n):
            G.add_edge(i, j, weight=float(lengths[i, j]))
    cycle = christofides(G, weight="weight")[:-1]  # closed tour, first node repeated at the end
    k = cycle.index(start)
    order = cycle[k:] + cycle[:k]
    # open the tour by dropping the longer of the two edges at the start
    if lengths[start, order[1]] > lengths[start, order[-1]]:
        order = [start] + order[1:][::-1]
    return order

