"""Solid axis-aligned boxes ``(M, 2, 3)`` as ``[lo, hi]`` corners [m] in W, z up: their mesh, their
occupancy of a horizontal slab, and the one surface query over boxes (:func:`surface_heights`, behind
:func:`box_heights` and :class:`BoxHeights`).

Generated scenes (:mod:`uavturb.scene.procedural`) are unions of such boxes, which makes their
geometric queries exact.
"""

from __future__ import annotations

import numpy as np
import trimesh

_UNIT_BOX = trimesh.creation.box(extents=(1.0, 1.0, 1.0))
_BOX_VERTS = np.asarray(_UNIT_BOX.vertices, dtype=float)  # (8, 3) in [-0.5, 0.5]
_BOX_FACES = np.asarray(_UNIT_BOX.faces, dtype=np.int64)  # (12, 3), outward winding


def boxes_to_mesh(boxes: np.ndarray) -> trimesh.Trimesh:
    """One mesh of solid boxes (the unit box of ``trimesh.creation.box``, scaled and moved).

    Parameters
    ----------
    boxes : (M, 2, 3) float array, m
        ``[lo, hi]`` corners.

    Returns
    -------
    trimesh.Trimesh with ``8 M`` vertices and ``12 M`` faces (face ``k`` from box ``k // 12``),
    unprocessed (no vertex merging), so a seed fixes the vertices exactly.
    """
    boxes = np.asarray(boxes, dtype=float).reshape(-1, 2, 3)
    centre = (boxes[:, 0] + boxes[:, 1]) / 2
    ext = boxes[:, 1] - boxes[:, 0]
    verts = centre[:, None, :] + _BOX_VERTS[None] * ext[:, None, :]
    faces = _BOX_FACES[None] + 8 * np.arange(len(boxes))[:, None, None]
    return trimesh.Trimesh(verts.reshape(-1, 3), faces.reshape(-1, 3), process=False)


def box_occupancy(boxes, xs, ys, z, res, margin, band) -> np.ndarray:
    """Cells (centres ``xs x ys``) whose square overlaps a box grown by ``margin`` in the z band."""
    zlo, zhi = z - band, z + band
    sel = (boxes[:, 0, 2] <= zhi) & (boxes[:, 1, 2] >= zlo)
    occ = np.zeros((len(xs), len(ys)), dtype=bool)
    grow = margin + res / 2 - 1e-9
    for b in boxes[sel]:
        i0 = np.searchsorted(xs, b[0, 0] - grow, side="left")
        j0 = np.searchsorted(ys, b[0, 1] - grow, side="left")
        i1 = np.searchsorted(xs, b[1, 0] + grow, side="right")
        j1 = np.searchsorted(ys, b[1, 1] + grow, side="right")
        occ[i0:i1, j0:j1] = True
    return occ



def surface_heights(boxes: np.ndarray, positions: np.ndarray, grow: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """The one surface query over solid boxes: heights ``z`` [m] in W of the nearest box top at or
    below each position and of the nearest box bottom at or above it.

    A box counts for a position when the position lies over its footprint (boundary included),
    grown by ``grow`` [m] on every side in x and y, and its top is not above the position (its
    bottom not below, for the surface above; 1e-12 m of tolerance). Every height over boxes
    comes from here: ``d_down = z - below`` and ``d_up = above - z`` (:func:`box_heights`,
    :class:`BoxHeights`), and the height of the surface under a point of a room
    (:func:`uavturb.scene.queries.surface_below`).

    Parameters
    ----------
    boxes : (M, 2, 3) m, ``[lo, hi]`` corners
    positions : (N, 3) m, W
    grow : m, footprint margin

    Returns
    -------
    below : (N,) m, ``-inf`` where no box is below; above : (N,) m, ``inf`` where none is above.
    """
    p = np.asarray(positions, dtype=float).reshape(-1, 3)
    boxes = np.asarray(boxes, dtype=float).reshape(-1, 2, 3)
    x, y, z = p[:, :1], p[:, 1:2], p[:, 2:3]
    lo, hi = boxes[:, 0], boxes[:, 1]
    over = ((x >= lo[:, 0] - grow) & (x <= hi[:, 0] + grow) & (y >= lo[:, 1] - grow)
            & (y <= hi[:, 1] + grow))  # (N, M); x - 0.0 is x: no growth changes nothing
    below = np.where(over & (hi[:, 2] <= z + 1e-12), hi[:, 2], -np.inf).max(axis=1, initial=-np.inf)
    above = np.where(over & (lo[:, 2] >= z - 1e-12), lo[:, 2], np.inf).min(axis=1, initial=np.inf)
    return below, above


def box_heights(boxes: np.ndarray, positions: np.ndarray, direction: float) -> np.ndarray:
    """Vertical distance [m] from points ``(N, 3)`` to the nearest box face below (``direction``
    ``-1``) or above (``+1``) (:func:`surface_heights`); ``inf`` where there is none, ``(N,)``.
    A point inside a box is at distance 0 from it."""
    p = np.asarray(positions, dtype=float).reshape(-1, 3)
    below, above = surface_heights(boxes, p)
    # min_k (z - top_k) is z - max_k top_k exactly (rounding is monotone), as the loop always measured
    d = p[:, 2] - below if direction < 0 else above - p[:, 2]
    return np.maximum(d, 0.0)


class BoxHeights:
    """``d_down`` / ``d_up`` [m] over solid boxes: the one box-height query (same answers as
    :func:`box_heights`, bit for bit).

    Many positions at once go through :func:`box_heights` over all boxes. One position at a
    time (the closed loop of :mod:`uavturb.sim.core.closed_loop`) looks at the boxes binned on a
    ``cell`` [m] grid in x, y over its cell only (a box is in every cell its footprint touches,
    so no box over the position is missed); one pass answers both heights, so ``d_up`` right
    after ``d_down`` of the same position is a cache hit.

    Parameters
    ----------
    boxes : (M, 2, 3) m, ``[lo, hi]`` corners
    cell : m, side of the bins
    """

    def __init__(self, boxes: np.ndarray, cell: float = 0.25):
        self.boxes = np.asarray(boxes, float).reshape(-1, 2, 3)
        self.cell = float(cell)
        self._last: tuple[bytes, float, float] | None = None
        self.origin = self.boxes[:, 0, :2].min(axis=0) if len(self.boxes) else np.zeros(2)
        lo = np.floor((self.boxes[:, 0, :2] - self.origin) / self.cell).astype(int)
        hi = np.floor((self.boxes[:, 1, :2] - self.origin) / self.cell).astype(int)
        bins: dict[tuple[int, int], list[int]] = {}
        for m in range(len(self.boxes)):
            for i in range(lo[m, 0], hi[m, 0] + 1):
                for j in range(lo[m, 1], hi[m, 1] + 1):
                    bins.setdefault((i, j), []).append(m)
        self.bins = {k: np.asarray(v) for k, v in bins.items()}

    def _one(self, p: np.ndarray) -> tuple[float, float]:
        """``(d_down, d_up)`` [m] of one position ``p`` (3,)."""
        key = p.tobytes()
        if self._last is not None and self._last[0] == key:
            return self._last[1], self._last[2]
        idx = self.bins.get(tuple(np.floor((p[:2] - self.origin) / self.cell).astype(int)))
        down = up = np.inf
        if idx is not None:
            below, above = surface_heights(self.boxes[idx], p[None])
            down, up = max(float(p[2] - below[0]), 0.0), max(float(above[0] - p[2]), 0.0)
        self._last = (key, down, up)
        return down, up

    def d_down(self, positions: np.ndarray) -> np.ndarray:
        """(N,) m, height of positions ``(N, 3)`` [m] over the nearest box top below (``inf``: none)."""
        p = np.asarray(positions, float).reshape(-1, 3)
        if len(p) != 1:
            return box_heights(self.boxes, p, -1.0)
        return np.array([self._one(p[0])[0]])

    def d_up(self, positions: np.ndarray) -> np.ndarray:
        """(N,) m, distance of positions ``(N, 3)`` [m] to the nearest box bottom above (``inf``: none)."""
        p = np.asarray(positions, float).reshape(-1, 3)
        if len(p) != 1:
            return box_heights(self.boxes, p, 1.0)
        return np.array([self._one(p[0])[1]])


def boxes_contain(boxes: np.ndarray, positions: np.ndarray, grow: np.ndarray | float,
                  strict: bool = False, chunk: int = 4096) -> np.ndarray:
    """Whether points ``(N, 3)`` [m] lie in a box grown by ``grow`` [m] (scalar or per axis (3,)),
    boundary included unless ``strict``; ``(N,)`` bool, in chunks of ``chunk`` points."""
    p = np.atleast_2d(np.asarray(positions, float))
    lo, hi = boxes[:, 0] - grow, boxes[:, 1] + grow
    hit = np.zeros(len(p), dtype=bool)
    for s in range(0, len(p), chunk):  # bounded (chunk, M) temporaries
        q = p[s: s + chunk, None, :]
        inside = ((q > lo) & (q < hi)) if strict else ((q >= lo) & (q <= hi))
        hit[s: s + chunk] = inside.all(axis=2).any(axis=1)
    return hit
