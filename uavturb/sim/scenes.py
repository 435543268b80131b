"""Procedural indoor scenes (apartments, offices) as trimesh meshes, and queries on them.

The paper flies a virtual UAV through the scanned Matterport3D homes in Habitat. This
module replaces those scans with procedural scenes built from axis-aligned boxes, so
that any number of distinct scenes can be generated offline, deterministically from a
seed, and scanned meshes can still be loaded (:func:`load_scene_mesh`).

Conventions (``recordings.md``): world frame W, z up, metres; the floor of a generated
scene is the plane ``z = 0`` and its ceiling the plane ``z = ceiling_height``.

A generated :class:`Scene` is a union of solid boxes (``Scene.boxes``, shape ``(M, 2, 3)``
as ``[lo, hi]`` corners): floor and ceiling slabs, walls with door openings and lintels,
and furniture parts (a table is a top and four legs, so there is free space under it).
Its mesh is the concatenation of those boxes (12 triangles per box, in box order: face
``k`` belongs to box ``k // 12``). The boxes make the geometric queries exact and fast:
:func:`height_below`, :func:`height_above`, :func:`inside_obstacle` and
:meth:`Scene.free_space_grid` use them when present and fall back to ray casting or mesh
sections on the mesh (external meshes) otherwise.

Public API
----------
- :class:`Scene`, :class:`SceneRoom`, :class:`Door`, :class:`Furniture`
- :func:`generate_scene` -- a deterministic procedural scene from a seed
- :func:`split_scenes` -- scene-level train/val/test splits (68 -> 43/9/16)
- :func:`load_scene_mesh` -- an external mesh (.glb/.obj/.ply...) as a :class:`Scene`
- :func:`height_below`, :func:`height_above` -- vertical distance to the nearest surface
- :func:`inside_obstacle` -- collision test with a vehicle radius
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import trimesh

from uavturb.errors import InputError

SCENE_KINDS = ("apartment", "office")

_UNIT_BOX = trimesh.creation.box(extents=(1.0, 1.0, 1.0))
_BOX_VERTS = np.asarray(_UNIT_BOX.vertices, dtype=float)  # (8, 3) in [-0.5, 0.5]
_BOX_FACES = np.asarray(_UNIT_BOX.faces, dtype=np.int64)  # (12, 3), outward winding

_SLAB = 0.05  # m, thickness of floor and ceiling slabs
_MIN_SIDE = 2.4  # m, smallest room side of a generated layout (wall centre lines)
_DOOR_CLEAR = 0.15  # m, wall kept on each side of a door before a wall junction
_DOOR_KEEPOUT = 0.9  # m, furniture-free depth in front of each side of a door
_FURN_GAP = 0.1  # m, smallest gap between two pieces of furniture
_WALL_GAP = 0.02  # m, gap between a wall face and furniture against it


# --- records ---------------------------------------------------------------------------


@dataclass
class SceneRoom:
    """One room of a generated scene.

    Attributes
    ----------
    kind : str
        ``'living'``, ``'bedroom'``, ``'kitchen'``, ``'study'``, ``'hall'`` (apartments),
        ``'corridor'``, ``'office'``, ``'meeting'``, ``'storage'`` (offices).
    rect : (4,) float array, m
        Free floor area inside the wall faces, ``(x_min, y_min, x_max, y_max)``.
    cell : (4,) float array, m
        The same room bounded by the wall centre lines (the layout cell).
    """

    kind: str
    rect: np.ndarray
    cell: np.ndarray

    @property
    def centre(self) -> np.ndarray:
        """``(2,)`` m, centre of the room in world x, y."""
        return np.array([(self.rect[0] + self.rect[2]) / 2, (self.rect[1] + self.rect[3]) / 2])

    @property
    def area(self) -> float:
        """Free floor area [m^2]."""
        return float((self.rect[2] - self.rect[0]) * (self.rect[3] - self.rect[1]))

    def contains(self, xy: np.ndarray) -> np.ndarray:
        """Whether points ``xy`` of shape ``(N, 2)`` [m] lie inside the free floor area, ``(N,)`` bool."""
        xy = np.atleast_2d(np.asarray(xy, dtype=float))
        r = self.rect
        return (xy[:, 0] >= r[0]) & (xy[:, 0] <= r[2]) & (xy[:, 1] >= r[1]) & (xy[:, 1] <= r[3])


@dataclass
class Door:
    """A door opening through a wall.

    Attributes
    ----------
    rooms : (int, int)
        Indices into ``Scene.rooms`` of the two rooms the door joins.
    lo, hi : (3,) float arrays, m
        Corners of the opening (through the full wall thickness, floor to door top).
    width : float, m
        Clear width of the opening along the wall.
    height : float, m
        Height of the opening (the lintel's underside).
    axis : int
        0 if the wall runs along world x (the door is crossed along y), 1 if along y.
    """

    rooms: tuple[int, int]
    lo: np.ndarray
    hi: np.ndarray
    width: float
    height: float
    axis: int

    @property
    def centre(self) -> np.ndarray:
        """``(3,)`` m, centre of the opening."""
        return (self.lo + self.hi) / 2


@dataclass
class Furniture:
    """One piece of furniture.

    Attributes
    ----------
    kind : str
        ``'table'``, ``'desk'``, ``'bed'``, ``'sofa'``, ``'shelf'``, ``'counter'`` or ``'box'``.
    lo, hi : (3,) float arrays, m
        Bounding box of the piece (``lo[2] == 0``: it stands on the floor).
    parts : (K, 2, 3) float array, m
        The solid boxes it is made of, ``[lo, hi]`` each (a table: top and four legs).
    surface : float, m
        Height of its main horizontal surface (table or desk top, mattress, sofa seat,
        shelf/counter/box top).
    room : int
        Index into ``Scene.rooms`` of the room it stands in.
    """

    kind: str
    lo: np.ndarray
    hi: np.ndarray
    parts: np.ndarray
    surface: float
    room: int

    @property
    def centre(self) -> np.ndarray:
        """``(3,)`` m, centre of the bounding box."""
        return (self.lo + self.hi) / 2

    @property
    def top(self) -> float:
        """Height [m] of the highest point of the piece."""
        return float(self.hi[2])


@dataclass
class Scene:
    """An indoor scene: its mesh and, for generated scenes, its layout.

    Attributes
    ----------
    mesh : trimesh.Trimesh
        Triangle mesh in the world frame [m] (z up; floor at ``z = 0`` for generated scenes).
        Not necessarily watertight.
    seed : int or None
        The seed of :func:`generate_scene`; ``None`` for external meshes.
    kind : str
        ``'apartment'``, ``'office'`` or ``'external'``.
    rooms : list of SceneRoom
        Axis-aligned rooms (empty for external meshes).
    doors : list of Door
    furniture : list of Furniture
    bounds : (2, 3) float array, m
        Axis-aligned bounds of the mesh, ``[lo, hi]``.
    ceiling_height : float or None, m
        Height of the ceiling plane (``None`` for external meshes).
    wall_thickness : float or None, m
    boxes : (M, 2, 3) float array, m
        Solid boxes the scene is made of (empty for external meshes); ``mesh`` face ``k``
        belongs to box ``k // 12``.
    box_kinds : (M,) str array
        ``'floor'``, ``'ceiling'``, ``'wall'``, ``'lintel'`` or the furniture kind, per box.
    box_owner : (M,) int array
        Index into ``furniture`` of each box, ``-1`` for structure.
    """

    mesh: trimesh.Trimesh
    seed: int | None
    kind: str
    rooms: list[SceneRoom] = field(default_factory=list)
    doors: list[Door] = field(default_factory=list)
    furniture: list[Furniture] = field(default_factory=list)
    bounds: np.ndarray = field(default_factory=lambda: np.zeros((2, 3)))
    ceiling_height: float | None = None
    wall_thickness: float | None = None
    boxes: np.ndarray = field(default_factory=lambda: np.zeros((0, 2, 3)))
    box_kinds: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype="<U8"))
    box_owner: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))

    @property
    def has_boxes(self) -> bool:
        """Whether the scene is described by solid boxes (generated scenes)."""
        return len(self.boxes) > 0 and len(self.rooms) > 0

    def inside_building(self, xy: np.ndarray) -> np.ndarray:
        """Whether points ``xy`` ``(N, 2)`` [m] are inside a room or a door opening, ``(N,)`` bool.

        Only defined for generated scenes (external meshes: all ``True``).
        """
        xy = np.atleast_2d(np.asarray(xy, dtype=float))
        if not self.rooms:
            return np.ones(len(xy), dtype=bool)
        rects = [r.rect for r in self.rooms] + [np.r_[d.lo[:2], d.hi[:2]] for d in self.doors]
        rects = np.asarray(rects)
        x, y = xy[:, :1], xy[:, 1:2]
        inside = (x >= rects[:, 0]) & (x <= rects[:, 2]) & (y >= rects[:, 1]) & (y <= rects[:, 3])
        return inside.any(axis=1)

    def free_space_grid(
        self, z: float, resolution: float = 0.1, margin: float = 0.3, height_band: float = 0.0
    ) -> tuple[np.ndarray, np.ndarray, float]:
        """Occupancy grid of a horizontal slice: the simulator's navigation map.

        A cell is occupied when an obstacle lies within ``margin`` of it (horizontally) at
        a height in ``[z - height_band, z + height_band]``, or when the cell is outside the
        building. Generated scenes use their boxes (exact up to the cell size); external
        meshes use mesh cross-sections rasterised on the grid, with cells that have no
        surface straight above or straight below counted as outside.

        Parameters
        ----------
        z : float, m
            Height of the slice.
        resolution : float, m
            Cell size.
        margin : float, m
            Clearance kept from obstacles (the vehicle radius plus a safety distance).
        height_band : float, m
            Half-height of the slab of space checked around ``z`` (0: the plane only).

        Returns
        -------
        occupancy : (nx, ny) bool array
            ``True`` where occupied; index ``[i, j]`` is the cell centred at
            ``origin + (i, j) * resolution``.
        origin : (2,) float array, m
            World x, y of the centre of cell ``[0, 0]``.
        resolution : float, m
        """
        if resolution <= 0:
            raise InputError("resolution", f"must be positive, got {resolution}")
        if margin < 0 or height_band < 0:
            raise InputError("margin", "margin and height_band must be non-negative")
        lo, hi = self.bounds[0, :2], self.bounds[1, :2]
        origin = lo + resolution / 2
        n = np.maximum(np.ceil((hi - lo) / resolution).astype(int), 1)
        xs = origin[0] + resolution * np.arange(n[0])
        ys = origin[1] + resolution * np.arange(n[1])
        if self.has_boxes:
            occ = _box_occupancy(self.boxes, xs, ys, z, resolution, margin, height_band)
            gx, gy = np.meshgrid(xs, ys, indexing="ij")
            occ |= ~self.inside_building(np.c_[gx.ravel(), gy.ravel()]).reshape(occ.shape)
        else:
            occ = _mesh_occupancy(self.mesh, xs, ys, z, resolution, margin, height_band)
        return occ, origin, float(resolution)


# --- geometry helpers -------------------------------------------------------------------


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


def _box_occupancy(boxes, xs, ys, z, res, margin, band) -> np.ndarray:
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


def _mesh_occupancy(mesh, xs, ys, z, res, margin, band) -> np.ndarray:
    """Occupancy from mesh cross-sections (rasterised segments) and a floor/ceiling test."""
    from scipy import ndimage

    nx, ny = len(xs), len(ys)
    occ = np.zeros((nx, ny), dtype=bool)
    levels = [z] if band <= 0 else np.linspace(z - band, z + band, max(2, int(np.ceil(2 * band / res)) + 1))
    x0, y0 = xs[0], ys[0]
    for level in levels:
        segs = trimesh.intersections.mesh_plane(mesh, plane_normal=[0, 0, 1], plane_origin=[0, 0, level])
        if len(segs) == 0:
            continue
        segs = np.asarray(segs)[:, :, :2]
        length = np.linalg.norm(segs[:, 1] - segs[:, 0], axis=1)
        k = np.maximum(np.ceil(length / (res / 2)).astype(int), 1)
        idx = np.repeat(np.arange(len(segs)), k + 1)
        t = np.concatenate([np.linspace(0, 1, kk + 1) for kk in k])
        pts = segs[idx, 0] + t[:, None] * (segs[idx, 1] - segs[idx, 0])
        i = np.rint((pts[:, 0] - x0) / res).astype(int)
        j = np.rint((pts[:, 1] - y0) / res).astype(int)
        ok = (i >= 0) & (i < nx) & (j >= 0) & (j < ny)
        occ[i[ok], j[ok]] = True
    # outside: no surface below or no surface above the cell centre
    gx, gy = np.meshgrid(xs, ys, indexing="ij")
    pts = np.c_[gx.ravel(), gy.ravel(), np.full(gx.size, z)]
    free = ~occ.ravel()
    outside = np.zeros(gx.size, dtype=bool)
    if free.any():
        p = pts[free]
        outside[free] = ~np.isfinite(_ray_heights(mesh, p, -1.0)) | ~np.isfinite(_ray_heights(mesh, p, 1.0))
    occ |= outside.reshape(occ.shape)
    if margin > 0:
        # grow every occupied cell (walls, furniture and outside) by the margin
        dist = ndimage.distance_transform_edt(~occ) * res
        occ |= dist <= margin + 1e-9
    return occ


def _ray_heights(mesh: trimesh.Trimesh, positions: np.ndarray, direction: float) -> np.ndarray:
    """Distance [m] along ``(0, 0, direction)`` to the first triangle hit (``inf`` if none)."""
    positions = np.asarray(positions, dtype=float).reshape(-1, 3)
    out = np.full(len(positions), np.inf)
    if len(positions) == 0 or len(mesh.faces) == 0:
        return out
    dirs = np.tile([0.0, 0.0, float(np.sign(direction))], (len(positions), 1))
    intersector = mesh.ray  # cached on the mesh; ray_triangle.RayMeshIntersector without embree
    locs, index_ray, _ = intersector.intersects_location(positions, dirs, multiple_hits=True)
    if len(index_ray):
        d = (locs[:, 2] - positions[index_ray, 2]) * np.sign(direction)
        ok = d >= -1e-9
        np.minimum.at(out, index_ray[ok], np.maximum(d[ok], 0.0))
    return out


def _box_heights(boxes: np.ndarray, positions: np.ndarray, direction: float) -> np.ndarray:
    """Vertical distance from points to the nearest box face below (``-1``) or above (``+1``)."""
    p = np.asarray(positions, dtype=float).reshape(-1, 3)
    out = np.full(len(p), np.inf)
    x, y, z = p[:, :1], p[:, 1:2], p[:, 2:3]
    lo, hi = boxes[:, 0], boxes[:, 1]
    over = (x >= lo[:, 0]) & (x <= hi[:, 0]) & (y >= lo[:, 1]) & (y <= hi[:, 1])  # (N, M)
    if direction < 0:
        d = np.where(over & (hi[:, 2] <= z + 1e-12), z - hi[:, 2], np.inf)
    else:
        d = np.where(over & (lo[:, 2] >= z - 1e-12), lo[:, 2] - z, np.inf)
    if d.shape[1]:
        out = np.maximum(d.min(axis=1), 0.0)
    return out


def _heights(mesh_or_scene, positions, direction: float) -> np.ndarray:
    positions = np.asarray(positions, dtype=float)
    if positions.ndim != 2 or positions.shape[1] != 3:
        raise InputError("positions", f"expected shape (N, 3), got {positions.shape}")
    if isinstance(mesh_or_scene, Scene):
        if mesh_or_scene.has_boxes:
            return _box_heights(mesh_or_scene.boxes, positions, direction)
        mesh = mesh_or_scene.mesh
    elif isinstance(mesh_or_scene, trimesh.Trimesh):
        mesh = mesh_or_scene
    else:
        raise InputError("mesh_or_scene", f"expected a Scene or trimesh.Trimesh, got {type(mesh_or_scene).__name__}")
    return _ray_heights(mesh, positions, direction)


def height_below(mesh_or_scene: Scene | trimesh.Trimesh, positions: np.ndarray) -> np.ndarray:
    """Distance straight down to the first surface (the ``d`` of the ground-effect law).

    Generated scenes answer exactly from their boxes; meshes (and external scenes) by
    casting one vertical ray per point (trimesh's pure-python intersector, vectorised).

    Parameters
    ----------
    mesh_or_scene : Scene or trimesh.Trimesh
    positions : (N, 3) float array, m, world frame

    Returns
    -------
    (N,) float array, m; ``inf`` where nothing is below.
    """
    return _heights(mesh_or_scene, positions, -1.0)


def height_above(mesh_or_scene: Scene | trimesh.Trimesh, positions: np.ndarray) -> np.ndarray:
    """Distance straight up to the first surface (ceiling, table underside...).

    Parameters
    ----------
    mesh_or_scene : Scene or trimesh.Trimesh
    positions : (N, 3) float array, m, world frame

    Returns
    -------
    (N,) float array, m; ``inf`` where nothing is above.
    """
    return _heights(mesh_or_scene, positions, 1.0)


def inside_obstacle(scene: Scene, positions: np.ndarray, margin: float = 0.0) -> np.ndarray:
    """Collision test: whether points come within ``margin`` of a solid.

    For generated scenes a point collides when it lies in a box (wall, lintel, floor or
    ceiling slab, furniture part) grown by ``margin`` on every side, below the floor plus
    ``margin``, above the ceiling minus ``margin``, or outside the building. External
    meshes are tested with :func:`height_below`/:func:`height_above` only (closer than
    ``margin`` to a surface below or above, or nothing below).

    Parameters
    ----------
    scene : Scene
    positions : (N, 3) float array, m, world frame
    margin : float, m
        Vehicle radius (plus safety distance).

    Returns
    -------
    (N,) bool array
    """
    p = np.asarray(positions, dtype=float)
    if p.ndim != 2 or p.shape[1] != 3:
        raise InputError("positions", f"expected shape (N, 3), got {p.shape}")
    if not isinstance(scene, Scene):
        raise InputError("scene", f"expected a Scene, got {type(scene).__name__}")
    if not scene.has_boxes:
        below, above = height_below(scene, p), height_above(scene, p)
        return (below < margin) | (above < margin) | ~np.isfinite(below)
    lo = scene.boxes[:, 0] - margin
    hi = scene.boxes[:, 1] + margin
    hit = np.zeros(len(p), dtype=bool)
    for start in range(0, len(p), 4096):  # bounded (chunk, M) temporaries
        q = p[start : start + 4096, None, :]
        hit[start : start + 4096] = ((q >= lo) & (q <= hi)).all(axis=2).any(axis=1)
    hit |= p[:, 2] < margin
    if scene.ceiling_height is not None:
        hit |= p[:, 2] > scene.ceiling_height - margin
    hit |= ~scene.inside_building(p[:, :2])
    return hit


# --- layouts ------------------------------------------------------------------------------


def _r(v: float, step: float = 0.05) -> float:
    """Round to a grid so shared walls have bit-identical coordinates."""
    return round(round(v / step) * step, 6)


def _bsp_layout(rng: np.random.Generator, n: int) -> list[tuple[float, float, float, float]]:
    """Apartment footprint split recursively into up to ``n`` rectangular cells."""
    area = n * rng.uniform(9.0, 20.0)
    aspect = rng.uniform(1.0, 1.8)
    W = _r(max(np.sqrt(area * aspect), 2 * _MIN_SIDE + 0.1))
    D = _r(max(area / W, _MIN_SIDE))
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
            if side < 2 * _MIN_SIDE:
                axis = 1 - axis
                side = w if axis == 0 else d
                if side < 2 * _MIN_SIDE:
                    continue
            lo = (x0, y0)[axis]
            cut = _r(lo + side * rng.uniform(0.35, 0.65))
            cut = min(max(cut, _r(lo + _MIN_SIDE + 0.025)), _r(lo + side - _MIN_SIDE - 0.025))
            if axis == 0:
                cells[k : k + 1] = [(x0, y0, cut, y1), (cut, y0, x1, y1)]
            else:
                cells[k : k + 1] = [(x0, y0, x1, cut), (x0, cut, x1, y1)]
            break
        else:
            break
    return cells


def _office_layout(rng: np.random.Generator, n: int) -> tuple[list[tuple[float, float, float, float]], list[str]]:
    """A corridor along x with ``n - 1`` offices on one or both sides."""
    n_off = n - 1
    two = n_off >= 2 and rng.random() < 0.7
    k_a = int(np.ceil(n_off / 2)) if two else n_off
    k_b = n_off - k_a
    widths_a = [_r(rng.uniform(2.6, 4.5)) for _ in range(k_a)]
    L = _r(sum(widths_a))
    cw = _r(rng.uniform(1.6, 2.4))
    d_a = _r(rng.uniform(3.0, 5.5))
    d_b = _r(rng.uniform(3.0, 5.5)) if k_b else 0.0
    cells, kinds = [], []
    y_c0, y_c1 = d_b, _r(d_b + cw)
    cells.append((0.0, y_c0, L, y_c1))
    kinds.append("corridor")

    def row(widths, ya, yb):
        x = 0.0
        for k, w in enumerate(widths):
            x1 = L if k == len(widths) - 1 else _r(x + w)
            cells.append((x, ya, x1, yb))
            kinds.append(str(rng.choice(["office", "office", "office", "meeting", "storage"])))
            x = x1

    row(widths_a, y_c1, _r(y_c1 + d_a))
    if k_b:
        frac = rng.uniform(0.8, 1.2, k_b)
        widths_b = list(frac / frac.sum() * L)
        row(widths_b, 0.0, y_c0)
    if rng.random() < 0.5:  # corridor along y instead
        cells = [(y0, x0, y1, x1) for (x0, y0, x1, y1) in cells]
    return cells, kinds


def _shared_edges(cells, t: float) -> dict[tuple[int, int], tuple[int, float, float, float]]:
    """Pairs of cells sharing a wall long enough for a door: ``(axis, coord, a, b)`` of the overlap.

    ``axis`` 0: the wall runs along x at ``y = coord``; 1: along y at ``x = coord``.
    """
    need = 1.2 + 2 * (t / 2 + _DOOR_CLEAR)
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


def _connected(n: int, edges) -> bool:
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


def _merge_intervals(iv: list[tuple[float, float]]) -> list[tuple[float, float]]:
    iv = sorted(iv)
    out = []
    for a, b in iv:
        if out and a <= out[-1][1] + 1e-9:
            out[-1] = (out[-1][0], max(out[-1][1], b))
        else:
            out.append((a, b))
    return out


def _subtract(iv: list[tuple[float, float]], holes: list[tuple[float, float]]) -> list[tuple[float, float]]:
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


# --- furniture ------------------------------------------------------------------------------

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


def _furnish(rng, rooms: list[SceneRoom], keepouts: list) -> list[Furniture]:
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
                    if sx > rx1 - rx0 - 2 * _WALL_GAP or sy > ry1 - ry0 - 2 * _WALL_GAP:
                        continue
                    if back == 0:
                        x0 = rx0 + _WALL_GAP
                    elif back == 1:
                        x0 = rx1 - _WALL_GAP - sx
                    else:
                        x0 = rng.uniform(rx0 + _WALL_GAP, rx1 - _WALL_GAP - sx)
                    if back == 2:
                        y0 = ry0 + _WALL_GAP
                    elif back == 3:
                        y0 = ry1 - _WALL_GAP - sy
                    else:
                        y0 = rng.uniform(ry0 + _WALL_GAP, ry1 - _WALL_GAP - sy)
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
                if _overlaps(rect, placed, _FURN_GAP) or _overlaps(rect, keepouts, 0.0):
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


# --- generation ---------------------------------------------------------------------------


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
    t = _r(rng.uniform(0.1, 0.2), 0.01)
    ceiling = _r(rng.uniform(2.4, 3.0), 0.01)

    for _attempt in range(50):
        n = int(rng.integers(2, 7))
        if kind == "apartment":
            cells = _bsp_layout(rng, n)
            kinds = None
        else:
            cells, kinds = _office_layout(rng, n)
        shared = _shared_edges(cells, t)
        if len(cells) < 2 or not _connected(len(cells), shared):
            continue
        if kind == "apartment" and len(cells) >= 4 and rng.random() < 0.4:
            # L-shaped plan: drop a corner cell if the rest stays connected
            W = max(c[2] for c in cells)
            D = max(c[3] for c in cells)
            corner = [k for k, c in enumerate(cells) if (c[0] == 0 or c[2] == W) and (c[1] == 0 or c[3] == D)]
            for k in rng.permutation(corner):
                rest = [c for m, c in enumerate(cells) if m != k]
                sh = _shared_edges(rest, t)
                if _connected(len(rest), sh):
                    cells, shared = rest, sh
                    break
        break
    else:  # pragma: no cover - layouts above always connect in practice
        raise RuntimeError(f"no connected layout for seed {seed}")

    n = len(cells)
    if kinds is None:
        areas = [(c[2] - c[0]) * (c[3] - c[1]) for c in cells]
        kinds = []
        pool = ["bedroom", "bedroom", "kitchen", "study", "hall"]
        for k in range(n):
            if k == int(np.argmax(areas)):
                kinds.append("living")
            else:
                choice = str(rng.choice(pool))
                if choice == "kitchen":
                    pool = [p for p in pool if p != "kitchen"]
                kinds.append(choice)
    rooms = [
        SceneRoom(kinds[k], np.array([c[0] + t / 2, c[1] + t / 2, c[2] - t / 2, c[3] - t / 2]), np.array(c, float))
        for k, c in enumerate(cells)
    ]

    # doors: a random spanning tree over rooms sharing a wall, plus some extra
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
    door_pairs.sort()
    doors: list[Door] = []
    for i, j in door_pairs:
        axis, coord, a, b = shared[(i, j)]
        w = _r(rng.uniform(0.9, 1.2), 0.01)
        dh = _r(rng.uniform(2.0, 2.1), 0.01)
        lo_c, hi_c = a + t / 2 + _DOOR_CLEAR + w / 2, b - t / 2 - _DOOR_CLEAR - w / 2
        c = _r(rng.uniform(lo_c, hi_c), 0.01)
        c = min(max(c, lo_c), hi_c)
        if axis == 0:  # wall along x at y = coord
            lo = np.array([c - w / 2, coord - t / 2, 0.0])
            hi = np.array([c + w / 2, coord + t / 2, dh])
        else:
            lo = np.array([coord - t / 2, c - w / 2, 0.0])
            hi = np.array([coord + t / 2, c + w / 2, dh])
        doors.append(Door((i, j), np.round(lo, 6), np.round(hi, 6), w, dh, axis))

    # walls: union of cell edges per line, extended by t/2 to close corners, minus doors
    lines: dict[tuple[int, float], list] = {}
    for c in cells:
        x0, y0, x1, y1 = c
        lines.setdefault((0, y0), []).append((x0, x1))
        lines.setdefault((0, y1), []).append((x0, x1))
        lines.setdefault((1, x0), []).append((y0, y1))
        lines.setdefault((1, x1), []).append((y0, y1))
    structure: list[np.ndarray] = []
    kinds_b: list[str] = []
    for (axis, coord) in sorted(lines):
        iv = [(a - t / 2, b + t / 2) for a, b in _merge_intervals(lines[(axis, coord)])]
        iv = _merge_intervals(iv)
        holes = []
        for d in doors:
            if d.axis == axis and abs((d.lo[1 - axis] + d.hi[1 - axis]) / 2 - coord) < 1e-6:
                holes.append((d.lo[axis], d.hi[axis]))
                lint = np.array([d.lo, d.hi])
                lint[0, 2], lint[1, 2] = d.height, ceiling
                structure.append(lint)
                kinds_b.append("lintel")
        for a, b in _subtract(iv, holes):
            if axis == 0:
                structure.append(np.array([[a, coord - t / 2, 0.0], [b, coord + t / 2, ceiling]]))
            else:
                structure.append(np.array([[coord - t / 2, a, 0.0], [coord + t / 2, b, ceiling]]))
            kinds_b.append("wall")
    for c in cells:
        structure.append(np.array([[c[0], c[1], -_SLAB], [c[2], c[3], 0.0]]))
        kinds_b.append("floor")
        structure.append(np.array([[c[0], c[1], ceiling], [c[2], c[3], ceiling + _SLAB]]))
        kinds_b.append("ceiling")

    # furniture, clear of a keep-out zone in front of each door
    keepouts = []
    for d in doors:
        lo, hi = d.lo[:2].copy(), d.hi[:2].copy()
        across = 1 - d.axis
        lo[d.axis] -= _DOOR_CLEAR
        hi[d.axis] += _DOOR_CLEAR
        lo[across] -= _DOOR_KEEPOUT
        hi[across] += _DOOR_KEEPOUT
        keepouts.append((lo[0], lo[1], hi[0], hi[1]))
    furniture = _furnish(rng, rooms, keepouts)

    boxes = list(structure)
    owner = [-1] * len(structure)
    for fi, f in enumerate(furniture):
        boxes += list(f.parts)
        kinds_b += [f.kind] * len(f.parts)
        owner += [fi] * len(f.parts)
    boxes_arr = np.round(np.asarray(boxes, dtype=float), 6)
    mesh = boxes_to_mesh(boxes_arr)
    return Scene(
        mesh=mesh,
        seed=seed,
        kind=kind,
        rooms=rooms,
        doors=doors,
        furniture=furniture,
        bounds=np.asarray(mesh.bounds, dtype=float),
        ceiling_height=float(ceiling),
        wall_thickness=float(t),
        boxes=boxes_arr,
        box_kinds=np.asarray(kinds_b),
        box_owner=np.asarray(owner, dtype=np.int64),
    )


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
        raise InputError("split_scenes", f"n_train + n_val + n_test = {n_train + n_val + n_test} != n_scenes = {n_scenes}")
    perm = np.random.default_rng(seed).permutation(n_scenes)
    return {
        "train": sorted(int(k) for k in perm[:n_train]),
        "val": sorted(int(k) for k in perm[n_train : n_train + n_val]),
        "test": sorted(int(k) for k in perm[n_train + n_val :]),
    }


def load_scene_mesh(path: str | Path, up_axis: str = "z") -> Scene:
    """An external mesh (.glb, .gltf, .obj, .ply, .stl, ...) as a :class:`Scene`.

    A file holding several geometries is concatenated into one mesh (world transforms
    applied). The scene has no rooms, doors, furniture or boxes; the queries fall back to
    the mesh (ray casting, cross-sections).

    Parameters
    ----------
    path : str or Path
    up_axis : {'z', 'y'}
        The file's up axis. Matterport/Habitat ``.glb`` files are y-up: ``'y'`` rotates
        them by +90 deg about x (``(x, y, z) -> (x, -z, y)``) so that z is up.

    Returns
    -------
    Scene with ``kind='external'`` and ``seed=None``.

    Raises
    ------
    InputError
        The file is missing, unreadable or holds no triangles, or ``up_axis`` is invalid.
    """
    path = Path(path)
    if up_axis not in ("z", "y"):
        raise InputError("up_axis", f"expected 'z' or 'y', got {up_axis!r}")
    if not path.is_file():
        raise InputError(path, "no such mesh file")
    try:
        loaded = trimesh.load(str(path), force="mesh")
    except Exception as exc:  # trimesh raises many kinds
        raise InputError(path, f"cannot read mesh: {exc}") from None
    if isinstance(loaded, trimesh.Scene):  # older trimesh: force='mesh' may still give a Scene
        geoms = loaded.dump() if hasattr(loaded, "dump") else list(loaded.geometry.values())
        loaded = trimesh.util.concatenate([g for g in geoms if isinstance(g, trimesh.Trimesh)])
    if not isinstance(loaded, trimesh.Trimesh) or len(loaded.faces) == 0:
        raise InputError(path, "holds no triangles")
    mesh = loaded
    if up_axis == "y":
        mesh = mesh.copy()
        mesh.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, [1, 0, 0]))
    return Scene(mesh=mesh, seed=None, kind="external", bounds=np.asarray(mesh.bounds, dtype=float))
