"""Floor plans of generated scenes: rectangular cells (rooms bounded by wall centre lines,
``(x0, y0, x1, y1)`` [m]), the walls they share, and interval helpers for cutting doors."""

from __future__ import annotations

import numpy as np

MIN_SIDE = 2.4  # m, smallest room side of a generated layout (wall centre lines)
DOOR_CLEAR = 0.15  # m, wall kept on each side of a door before a wall junction

Cell = tuple[float, float, float, float]


def snap(v: float, step: float = 0.05) -> float:
    """Round to a grid so shared walls have bit-identical coordinates."""
    return round(round(v / step) * step, 6)


def apartment_cells(rng: np.random.Generator, n: int) -> list[tuple[float, float, float, float]]:
    """Apartment footprint split recursively into up to ``n`` rectangular cells."""
    area = n * rng.uniform(9.0, 20.0)
    aspect = rng.uniform(1.0, 1.8)
    W = snap(max(np.sqrt(area * aspect), 2 * MIN_SIDE + 0.1))
    D = snap(max(area / W, MIN_SIDE))
    cells = [(0.0, 0.0, W, D)]
    while len(cells) < n:
        order = sorted(range(len(cells)), key=lambda k: -(cells[k][2] - cells[k][0]) * (cells[k][3] - cells[k][1]))
        for k in order:
            x0, y0, x1, y1 = cells[k]
            w, d = x1 - x0, y1 - y0
            axis = 0 if w >= d else 1
            if rng.random() < 0.25:
                axis = 1 - axis
            side = w if axis == 0 else d
            if side < 2 * MIN_SIDE:
                axis = 1 - axis
                side = w if axis == 0 else d
                if side < 2 * MIN_SIDE:
                    continue
            lo = (x0, y0)[axis]
            cut = snap(lo + side * rng.uniform(0.35, 0.65))
            cut = min(max(cut, snap(lo + MIN_SIDE + 0.025)), snap(lo + side - MIN_SIDE - 0.025))
            if axis == 0:
                cells[k : k + 1] = [(x0, y0, cut, y1), (cut, y0, x1, y1)]
            else:
                cells[k : k + 1] = [(x0, y0, x1, cut), (x0, cut, x1, y1)]
            break
        else:
            break
    return cells


def office_cells(rng: np.random.Generator, n: int) -> tuple[list[tuple[float, float, float, float]], list[str]]:
    """A corridor along x with ``n - 1`` offices on one or both sides."""
    n_off = n - 1
    two = n_off >= 2 and rng.random() < 0.7
    k_a = int(np.ceil(n_off / 2)) if two else n_off
    k_b = n_off - k_a
    widths_a = [snap(rng.uniform(2.6, 4.5)) for _ in range(k_a)]
    L = snap(sum(widths_a))
    cw = snap(rng.uniform(1.6, 2.4))
    d_a = snap(rng.uniform(3.0, 5.5))
    d_b = snap(rng.uniform(3.0, 5.5)) if k_b else 0.0
    cells, kinds = [], []
    y_c0, y_c1 = d_b, snap(d_b + cw)
    cells.append((0.0, y_c0, L, y_c1))
    kinds.append("corridor")

    def row(widths, ya, yb):
        x = 0.0
        for k, w in enumerate(widths):
            x1 = L if k == len(widths) - 1 else snap(x + w)
            cells.append((x, ya, x1, yb))
            kinds.append(str(rng.choice(["office", "office", "office", "meeting", "storage"])))
            x = x1

    row(widths_a, y_c1, snap(y_c1 + d_a))
    if k_b:
        frac = rng.uniform(0.8, 1.2, k_b)
        widths_b = list(frac / frac.sum() * L)
        row(widths_b, 0.0, y_c0)
    if rng.random() < 0.5:  # corridor along y instead
        cells = [(y0, x0, y1, x1) for (x0, y0, x1, y1) in cells]
    return cells, kinds


def shared_walls(cells, t: float) -> dict[tuple[int, int], tuple[int, float, float, float]]:
    """Pairs of cells sharing a wall long enough for a door: ``(axis, coord, a, b)`` of the overlap.

    ``axis`` 0: the wall runs along x at ``y = coord``; 1: along y at ``x = coord``.
    """
    need = 1.2 + 2 * (t / 2 + DOOR_CLEAR)
    out = {}
    for i, a in enumerate(cells):
        for j, b in enumerate(cells):
            if j <= i:
                continue
            for axis, (ca, cb) in ((1, (a[2], b[0])), (1, (b[2], a[0])), (0, (a[3], b[1])), (0, (b[3], a[1]))):
                if abs(ca - cb) > 1e-9:
                    continue
                if axis == 1:
                    lo, hi = max(a[1], b[1]), min(a[3], b[3])
                else:
                    lo, hi = max(a[0], b[0]), min(a[2], b[2])
                if hi - lo >= need:
                    out[(i, j)] = (axis, ca, lo, hi)
    return out


def is_connected(n: int, edges) -> bool:
    if n == 0:
        return False
    seen, stack = {0}, [0]
    adj = {k: set() for k in range(n)}
    for i, j in edges:
        adj[i].add(j)
        adj[j].add(i)
    while stack:
        k = stack.pop()
        for m in adj[k] - seen:
            seen.add(m)
            stack.append(m)
    return len(seen) == n


def merge_intervals(iv: list[tuple[float, float]]) -> list[tuple[float, float]]:
    iv = sorted(iv)
    out = []
    for a, b in iv:
        if out and a <= out[-1][1] + 1e-9:
            out[-1] = (out[-1][0], max(out[-1][1], b))
        else:
            out.append((a, b))
    return out


def subtract_intervals(iv: list[tuple[float, float]], holes: list[tuple[float, float]]) -> list[tuple[float, float]]:
    out = []
    for a, b in iv:
        pieces = [(a, b)]
        for h0, h1 in holes:
            nxt = []
            for p0, p1 in pieces:
                if h1 <= p0 or h0 >= p1:
                    nxt.append((p0, p1))
                    continue
                if h0 > p0:
                    nxt.append((p0, h0))
                if h1 < p1:
                    nxt.append((h1, p1))
            pieces = nxt
        out += [p for p in pieces if p[1] - p[0] > 1e-6]
    return out

