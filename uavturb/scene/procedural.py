"""Procedural indoor scenes (apartments, offices) from a seed, and scene-level dataset splits.

The paper flies a virtual UAV through the scanned Matterport3D homes in Habitat. This module
replaces those scans with procedural scenes built from axis-aligned boxes, so that any number
of distinct scenes can be generated offline, deterministically from a seed
(:func:`generate_scene`): a floor plan (:mod:`uavturb.scene.floor_plans`), doors, walls with
lintels, floor and ceiling slabs, and furniture (:mod:`uavturb.scene.furniture`; a table is a
top and four legs, so there is free space under it). The result is a
:class:`~uavturb.scene.indoor.Scene` whose boxes make the queries of
:mod:`uavturb.scene.queries` exact.
"""

from __future__ import annotations

import numpy as np

from uavturb.errors import InputError
from uavturb.scene.boxes import boxes_to_mesh
from uavturb.scene.furniture import furnish
from uavturb.scene.indoor import Door, Furniture, Scene, SceneRoom
from uavturb.scene.floor_plans import (
    DOOR_CLEAR,
    Cell,
    apartment_cells,
    is_connected,
    merge_intervals,
    office_cells,
    shared_walls,
    snap,
    subtract_intervals,
)

SCENE_KINDS = ("apartment", "office")
SLAB = 0.05  # m, thickness of floor and ceiling slabs
DOOR_KEEPOUT = 0.9  # m, furniture-free depth in front of each side of a door


def generate_scene(seed: int, kind: str | None = None) -> Scene:
    """A procedural indoor scene, fixed exactly by ``seed`` (and ``kind``).

    Apartments are a rectangular footprint split recursively into 2-6 rooms (sometimes an
    L-shaped plan with a corner room removed); offices are a corridor with 1-5 offices,
    meeting or storage rooms on one or both sides. Rooms are joined by doors (0.9-1.2 m
    wide, 2.0-2.1 m high) along a random spanning tree of the rooms sharing a wall, plus
    a few extra doors. Walls are 0.1-0.2 m thick and reach the ceiling (2.4-3.0 m).
    Furniture (tables with legs, desks, beds with headboards, sofas, shelves, counters,
    boxes) is chosen by room type and placed without overlap, clear of doors.

    Parameters
    ----------
    seed : int
        Any integer; the same seed gives bit-identical vertices.
    kind : {'apartment', 'office'} or None
        ``None`` draws the kind from the seed (apartments twice as often as offices).

    Returns
    -------
    Scene
    """
    if kind is not None and kind not in SCENE_KINDS:
        raise InputError("kind", f"expected one of {SCENE_KINDS} or None, got {kind!r}")
    try:
        seed = int(seed)
    except (TypeError, ValueError):
        raise InputError("seed", f"expected an integer, got {seed!r}") from None
    if seed < 0:
        raise InputError("seed", f"must be non-negative, got {seed}")
    rng = np.random.default_rng([seed, 0x5CE2E])
    if kind is None:
        kind = "apartment" if rng.random() < 2 / 3 else "office"
    t = snap(rng.uniform(0.1, 0.2), 0.01)  # m, wall thickness
    ceiling = snap(rng.uniform(2.4, 3.0), 0.01)  # m
    cells, kinds, shared = _floor_plan(rng, kind, t, seed)
    if kinds is None:
        kinds = _apartment_room_kinds(rng, cells)
    rooms = [
        SceneRoom(kinds[k], np.array([c[0] + t / 2, c[1] + t / 2, c[2] - t / 2, c[3] - t / 2]), np.array(c, float))
        for k, c in enumerate(cells)
    ]
    doors = _doors(rng, _door_pairs(rng, shared, len(cells)), shared, t)
    structure, box_kinds = _walls(cells, doors, t, ceiling)
    structure_slabs, slab_kinds = _slabs(cells, ceiling)
    furniture = furnish(rng, rooms, [_door_keepout(d) for d in doors])
    return _assemble(seed, kind, rooms, doors, furniture, structure + structure_slabs, box_kinds + slab_kinds,
                     ceiling, t)


def _floor_plan(rng: np.random.Generator, kind: str, t: float, seed: int
                ) -> tuple[list[Cell], list[str] | None, dict[tuple[int, int], tuple[int, float, float, float]]]:
    """Connected cells of a floor plan (apartments: sometimes L-shaped), their room kinds (offices;
    ``None`` for apartments) and the walls they share (:func:`~uavturb.scene.floor_plans.shared_walls`)."""
    for _attempt in range(50):
        n = int(rng.integers(2, 7))
        if kind == "apartment":
            cells = apartment_cells(rng, n)
            kinds = None
        else:
            cells, kinds = office_cells(rng, n)
        shared = shared_walls(cells, t)
        if len(cells) < 2 or not is_connected(len(cells), shared):
            continue
        if kind == "apartment" and len(cells) >= 4 and rng.random() < 0.4:
            cells, shared = _drop_a_corner(rng, cells, shared, t)
        return cells, kinds, shared
    raise RuntimeError(f"no connected layout for seed {seed}")  # pragma: no cover - layouts always connect


def _drop_a_corner(rng: np.random.Generator, cells: list[Cell], shared: dict, t: float) -> tuple[list[Cell], dict]:
    """L-shaped plan: the cells without one corner cell, when the rest stays connected."""
    W = max(c[2] for c in cells)
    D = max(c[3] for c in cells)
    corner = [k for k, c in enumerate(cells) if (c[0] == 0 or c[2] == W) and (c[1] == 0 or c[3] == D)]
    for k in rng.permutation(corner):
        rest = [c for m, c in enumerate(cells) if m != k]
        sh = shared_walls(rest, t)
        if is_connected(len(rest), sh):
            return rest, sh
    return cells, shared


def _apartment_room_kinds(rng: np.random.Generator, cells: list[Cell]) -> list[str]:
    """The largest cell is the living room; the others bedrooms, a kitchen (at most one), a study, a hall."""
    areas = [(c[2] - c[0]) * (c[3] - c[1]) for c in cells]
    kinds = []
    pool = ["bedroom", "bedroom", "kitchen", "study", "hall"]
    for k in range(len(cells)):
        if k == int(np.argmax(areas)):
            kinds.append("living")
        else:
            choice = str(rng.choice(pool))
            if choice == "kitchen":
                pool = [p for p in pool if p != "kitchen"]
            kinds.append(choice)
    return kinds


def _door_pairs(rng: np.random.Generator, shared: dict, n: int) -> list[tuple[int, int]]:
    """Room pairs joined by a door: a random spanning tree over rooms sharing a wall (union-find),
    plus each other shared wall with probability 0.2; sorted."""
    pairs = sorted(shared)
    order = rng.permutation(len(pairs))
    parent = list(range(n))

    def find(a):
        while parent[a] != a:
            parent[a] = parent[parent[a]]
            a = parent[a]
        return a

    door_pairs = []
    for k in order:
        i, j = pairs[k]
        if find(i) != find(j):
            parent[find(i)] = find(j)
            door_pairs.append((i, j))
        elif rng.random() < 0.2:
            door_pairs.append((i, j))
    return sorted(door_pairs)


def _doors(rng: np.random.Generator, door_pairs: list[tuple[int, int]], shared: dict, t: float) -> list[Door]:
    """Door openings (0.9-1.2 m wide, 2.0-2.1 m high) in the shared walls of ``door_pairs``."""
    doors: list[Door] = []
    for i, j in door_pairs:
        axis, coord, a, b = shared[(i, j)]
        w = snap(rng.uniform(0.9, 1.2), 0.01)
        dh = snap(rng.uniform(2.0, 2.1), 0.01)
        lo_c, hi_c = a + t / 2 + DOOR_CLEAR + w / 2, b - t / 2 - DOOR_CLEAR - w / 2
        c = snap(rng.uniform(lo_c, hi_c), 0.01)
        c = min(max(c, lo_c), hi_c)
        if axis == 0:  # wall along x at y = coord
            lo = np.array([c - w / 2, coord - t / 2, 0.0])
            hi = np.array([c + w / 2, coord + t / 2, dh])
        else:
            lo = np.array([coord - t / 2, c - w / 2, 0.0])
            hi = np.array([coord + t / 2, c + w / 2, dh])
        doors.append(Door((i, j), np.round(lo, 6), np.round(hi, 6), w, dh, axis))
    return doors


def _walls(cells: list[Cell], doors: list[Door], t: float, ceiling: float) -> tuple[list[np.ndarray], list[str]]:
    """Wall and lintel boxes: the union of cell edges per line, extended by ``t / 2`` to close
    corners, minus the door openings (a lintel over each); and their kinds."""
    lines: dict[tuple[int, float], list] = {}
    for x0, y0, x1, y1 in cells:
        lines.setdefault((0, y0), []).append((x0, x1))
        lines.setdefault((0, y1), []).append((x0, x1))
        lines.setdefault((1, x0), []).append((y0, y1))
        lines.setdefault((1, x1), []).append((y0, y1))
    structure: list[np.ndarray] = []
    kinds: list[str] = []
    for (axis, coord) in sorted(lines):
        iv = merge_intervals([(a - t / 2, b + t / 2) for a, b in merge_intervals(lines[(axis, coord)])])
        holes = []
        for d in doors:
            if d.axis == axis and abs((d.lo[1 - axis] + d.hi[1 - axis]) / 2 - coord) < 1e-6:
                holes.append((d.lo[axis], d.hi[axis]))
                lintel = np.array([d.lo, d.hi])
                lintel[0, 2], lintel[1, 2] = d.height, ceiling
                structure.append(lintel)
                kinds.append("lintel")
        for a, b in subtract_intervals(iv, holes):
            if axis == 0:
                structure.append(np.array([[a, coord - t / 2, 0.0], [b, coord + t / 2, ceiling]]))
            else:
                structure.append(np.array([[coord - t / 2, a, 0.0], [coord + t / 2, b, ceiling]]))
            kinds.append("wall")
    return structure, kinds


def _slabs(cells: list[Cell], ceiling: float) -> tuple[list[np.ndarray], list[str]]:
    """Floor and ceiling slab boxes of every cell, and their kinds."""
    structure: list[np.ndarray] = []
    kinds: list[str] = []
    for c in cells:
        structure.append(np.array([[c[0], c[1], -SLAB], [c[2], c[3], 0.0]]))
        kinds.append("floor")
        structure.append(np.array([[c[0], c[1], ceiling], [c[2], c[3], ceiling + SLAB]]))
        kinds.append("ceiling")
    return structure, kinds


def _door_keepout(d: Door) -> tuple[float, float, float, float]:
    """Furniture-free rectangle ``(x0, y0, x1, y1)`` [m] in front of both sides of a door."""
    lo, hi = d.lo[:2].copy(), d.hi[:2].copy()
    across = 1 - d.axis
    lo[d.axis] -= DOOR_CLEAR
    hi[d.axis] += DOOR_CLEAR
    lo[across] -= DOOR_KEEPOUT
    hi[across] += DOOR_KEEPOUT
    return (lo[0], lo[1], hi[0], hi[1])


def _assemble(seed: int, kind: str, rooms: list[SceneRoom], doors: list[Door], furniture: list[Furniture],
              structure: list[np.ndarray], structure_kinds: list[str], ceiling: float, t: float) -> Scene:
    """The Scene: structure boxes then furniture parts, rounded to 1 um, and their mesh."""
    boxes = list(structure)
    kinds = list(structure_kinds)
    owner = [-1] * len(structure)
    for fi, f in enumerate(furniture):
        boxes += list(f.parts)
        kinds += [f.kind] * len(f.parts)
        owner += [fi] * len(f.parts)
    boxes_arr = np.round(np.asarray(boxes, dtype=float), 6)
    mesh = boxes_to_mesh(boxes_arr)
    return Scene(mesh=mesh, seed=seed, kind=kind, rooms=rooms, doors=doors, furniture=furniture,
                 bounds=np.asarray(mesh.bounds, dtype=float), ceiling_height=float(ceiling), wall_thickness=float(t),
                 boxes=boxes_arr, box_kinds=np.asarray(kinds), box_owner=np.asarray(owner, dtype=np.int64))


def split_scenes(
    n_scenes: int = 68, n_train: int = 43, n_val: int = 9, n_test: int = 16, seed: int = 0
) -> dict[str, list[int]]:
    """Scene-level train/val/test splits (the paper's 68 scenes -> 43/9/16).

    Samples are never split: every trajectory of a scene goes where its scene goes.

    Parameters
    ----------
    n_scenes, n_train, n_val, n_test : int
        ``n_train + n_val + n_test`` must equal ``n_scenes``.
    seed : int
        Seed of the permutation.

    Returns
    -------
    dict with keys ``'train'``, ``'val'``, ``'test'``: sorted scene seeds in ``range(n_scenes)``.
    """
    sizes = (n_scenes, n_train, n_val, n_test)
    if any(int(s) != s or s < 0 for s in sizes):
        raise InputError("split_scenes", f"sizes must be non-negative integers, got {sizes}")
    if n_train + n_val + n_test != n_scenes:
        raise InputError("split_scenes",
                         f"n_train + n_val + n_test = {n_train + n_val + n_test} != n_scenes = {n_scenes}")
    perm = np.random.default_rng(seed).permutation(n_scenes)
    return {
        "train": sorted(int(k) for k in perm[:n_train]),
        "val": sorted(int(k) for k in perm[n_train : n_train + n_val]),
        "test": sorted(int(k) for k in perm[n_train + n_val :]),
    }

