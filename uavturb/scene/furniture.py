"""Furniture of generated scenes: what each room kind holds, random dimensions, the solid boxes
of each piece, and placement without overlap (:func:`furnish`)."""

from __future__ import annotations

import numpy as np

from uavturb.scene.indoor import Furniture, SceneRoom

FURNITURE_GAP = 0.1  # m, smallest gap between two pieces of furniture
WALL_GAP = 0.02  # m, gap between a wall face and furniture against it

_CONTENTS = {
    "living": [("sofa", 1, 2), ("table", 0, 1), ("shelf", 0, 2), ("box", 0, 3)],
    "bedroom": [("bed", 1, 1), ("desk", 0, 1), ("shelf", 0, 1), ("box", 0, 2)],
    "kitchen": [("counter", 1, 2), ("table", 0, 1), ("box", 0, 2)],
    "study": [("desk", 1, 2), ("table", 0, 1), ("shelf", 1, 2), ("box", 0, 2)],
    "hall": [("shelf", 0, 1), ("box", 0, 2)],
    "corridor": [("shelf", 0, 1), ("box", 0, 2)],
    "office": [("desk", 1, 4), ("table", 0, 1), ("shelf", 0, 2), ("box", 0, 2)],
    "meeting": [("table", 1, 2), ("shelf", 0, 1), ("box", 0, 1)],
    "storage": [("shelf", 2, 5), ("box", 2, 6)],
}
_ORDER = ["bed", "sofa", "counter", "table", "desk", "shelf", "box"]


def _furniture_dims(rng: np.random.Generator, kind: str) -> dict:
    """Random dimensions: ``w`` along the wall (or long side), ``d`` away from it, ``h`` height."""
    u = rng.uniform
    if kind == "table":
        return dict(w=u(0.8, 1.8), d=u(0.6, 1.0), h=u(0.72, 0.78), tt=u(0.03, 0.05), wall=False)
    if kind == "desk":
        return dict(w=u(1.0, 1.6), d=u(0.6, 0.8), h=u(0.72, 0.76), tt=u(0.03, 0.04), wall=True)
    if kind == "bed":
        return dict(w=u(0.9, 1.8), d=u(1.9, 2.1), h=u(0.45, 0.6), head=u(0.85, 1.1), wall=True)
    if kind == "sofa":
        return dict(w=u(1.6, 2.4), d=u(0.8, 0.95), h=u(0.4, 0.46), back=u(0.75, 0.9),
                    bt=u(0.15, 0.2), arms=bool(rng.random() < 0.6), arm_h=u(0.55, 0.65), wall=True)
    if kind == "shelf":
        return dict(w=u(0.6, 1.6), d=u(0.3, 0.45), h=u(1.5, 2.0), wall=True)
    if kind == "counter":
        return dict(w=u(1.2, 3.0), d=u(0.55, 0.65), h=u(0.86, 0.92), wall=True)
    if kind == "box":
        return dict(w=u(0.2, 0.6), d=u(0.2, 0.6), h=u(0.2, 0.6), wall=bool(rng.random() < 0.5))
    raise ValueError(kind)


def _furniture_parts(kind: str, dims: dict, x0, y0, x1, y1, back: int) -> tuple[list, float]:
    """Solid boxes of a piece on footprint ``[x0, x1] x [y0, y1]``; ``back`` is the wall side.

    ``back``: 0 = -x, 1 = +x, 2 = -y, 3 = +y (the side against the wall), -1 = free-standing.
    Returns ``(parts, surface height)``.
    """
    h = dims["h"]

    def box(a0, b0, c0, a1, b1, c1):
        return np.array([[a0, b0, c0], [a1, b1, c1]], dtype=float)

    def strip(side, depth, z1):
        """A slab of ``depth`` along footprint side ``side``, floor to ``z1``."""
        if side == 0:
            return box(x0, y0, 0, x0 + depth, y1, z1)
        if side == 1:
            return box(x1 - depth, y0, 0, x1, y1, z1)
        if side == 2:
            return box(x0, y0, 0, x1, y0 + depth, z1)
        return box(x0, y1 - depth, 0, x1, y1, z1)

    if kind == "table":
        tt, leg, ins = dims["tt"], 0.05, 0.03
        parts = [box(x0, y0, h - tt, x1, y1, h)]
        for lx in (x0 + ins, x1 - ins - leg):
            for ly in (y0 + ins, y1 - ins - leg):
                parts.append(box(lx, ly, 0, lx + leg, ly + leg, h - tt))
        return parts, h
    if kind == "desk":
        tt, pt = dims["tt"], 0.03
        parts = [box(x0, y0, h - tt, x1, y1, h)]
        ends = (2, 3) if back in (0, 1) else (0, 1)  # side panels at the ends along the wall
        for e in ends:
            p = strip(e, pt, h - tt)
            parts.append(p)
        return parts, h
    if kind == "bed":
        head = strip(back, 0.06, dims["head"])
        base = _shrink_side(np.array([[x0, y0, 0], [x1, y1, h]], float), back, 0.06)
        return [base, head], h
    if kind == "sofa":
        bt = dims["bt"]
        back_part = strip(back, bt, dims["back"])
        seat = _shrink_side(np.array([[x0, y0, 0], [x1, y1, h]], float), back, bt)
        parts = [seat, back_part]
        if dims["arms"]:
            ends = (2, 3) if back in (0, 1) else (0, 1)
            seat_lo, seat_hi = seat[0].copy(), seat[1].copy()
            for e in ends:  # arms at both ends, in front of the back; the seat between them
                parts.append(_shrink_side(strip(e, 0.15, dims["arm_h"]), back, bt))
                ax = 0 if e in (0, 1) else 1
                if e in (0, 2):
                    seat_lo[ax] += 0.15
                else:
                    seat_hi[ax] -= 0.15
            parts[0] = np.array([seat_lo, seat_hi])
        return parts, h
    return [box(x0, y0, 0, x1, y1, h)], h


def _shrink_side(b: np.ndarray, side: int, amount: float) -> np.ndarray:
    """Remove ``amount`` from box ``b`` on footprint side ``side`` (0 -x, 1 +x, 2 -y, 3 +y)."""
    b = b.copy()
    if side == 0:
        b[0, 0] += amount
    elif side == 1:
        b[1, 0] -= amount
    elif side == 2:
        b[0, 1] += amount
    elif side == 3:
        b[1, 1] -= amount
    return b


def _overlaps(rect, others, gap: float) -> bool:
    if not len(others):
        return False
    o = np.asarray(others)
    return bool(np.any((rect[0] < o[:, 2] + gap) & (rect[2] > o[:, 0] - gap)
                       & (rect[1] < o[:, 3] + gap) & (rect[3] > o[:, 1] - gap)))


def _corner_along(rng: np.random.Generator, lo: float, hi: float, size: float, back: int, low_side: int,
                  high_side: int) -> float:
    """Lower corner [m] along one room axis ``[lo, hi]`` of a piece of ``size`` [m]: against the
    wall at ``lo`` when ``back == low_side``, at ``hi`` when ``back == high_side``, else drawn."""
    if back == low_side:
        return lo + WALL_GAP
    if back == high_side:
        return hi - WALL_GAP - size
    return rng.uniform(lo + WALL_GAP, hi - WALL_GAP - size)


def furnish(rng, rooms: list[SceneRoom], keepouts: list) -> list[Furniture]:
    furniture: list[Furniture] = []
    for ri, room in enumerate(rooms):
        rx0, ry0, rx1, ry1 = room.rect
        wanted = []
        scale = min(max(room.area / 12.0, 0.6), 2.0)
        for kind, lo, hi in _CONTENTS[room.kind]:
            hi_s = max(lo, int(round(hi * scale)))
            wanted += [kind] * int(rng.integers(lo, hi_s + 1))
        wanted.sort(key=_ORDER.index)
        placed: list[tuple] = []  # footprints in this room
        budget = 0.45 * room.area
        used = 0.0
        for kind in wanted:
            dims = _furniture_dims(rng, kind)
            for _ in range(30):
                w, d = dims["w"], dims["d"]
                if dims["wall"]:
                    back = int(rng.integers(4))
                    if back in (0, 1):  # against an x wall: w runs along y
                        sx, sy = d, w
                    else:
                        sx, sy = w, d
                    if sx > rx1 - rx0 - 2 * WALL_GAP or sy > ry1 - ry0 - 2 * WALL_GAP:
                        continue
                    x0 = _corner_along(rng, rx0, rx1, sx, back, 0, 1)
                    y0 = _corner_along(rng, ry0, ry1, sy, back, 2, 3)
                else:
                    back = -1
                    sx, sy = (w, d) if rng.random() < 0.5 else (d, w)
                    clear = 0.3  # room to fly round free-standing pieces
                    if sx > rx1 - rx0 - 2 * clear or sy > ry1 - ry0 - 2 * clear:
                        continue
                    x0 = rng.uniform(rx0 + clear, rx1 - clear - sx)
                    y0 = rng.uniform(ry0 + clear, ry1 - clear - sy)
                rect = (x0, y0, x0 + sx, y0 + sy)
                if used + sx * sy > budget:
                    break
                if _overlaps(rect, placed, FURNITURE_GAP) or _overlaps(rect, keepouts, 0.0):
                    continue
                parts, surface = _furniture_parts(kind, dims, *rect, back)
                parts = np.round(np.asarray(parts), 6)
                lo = parts[:, 0].min(axis=0)
                hi = parts[:, 1].max(axis=0)
                furniture.append(Furniture(kind, lo, hi, parts, float(surface), ri))
                placed.append(rect)
                used += sx * sy
                break
    return furniture

