"""Indoor scenes: the :class:`Scene` record (a mesh and, for generated scenes, rooms, doors,
furniture and the solid boxes they are made of) and external meshes as scenes
(:func:`load_scene_mesh`).

The paper flies a virtual UAV through the scanned Matterport3D homes in Habitat; this project
generates procedural scenes from boxes (:mod:`uavturb.scene.procedural`) and can still load
scanned meshes. Conventions (``recordings.md``): world frame W, z up, metres; the floor of a
generated scene is the plane ``z = 0`` and its ceiling the plane ``z = ceiling_height``.
A generated scene's mesh is the concatenation of its boxes (12 triangles per box, in box
order: face ``k`` belongs to box ``k // 12``). Single-room layouts: :mod:`uavturb.scene.layouts`.
Queries: :mod:`uavturb.scene.queries`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import trimesh

from uavturb.errors import InputError
from uavturb.scene.boxes import box_occupancy
from uavturb.scene.mesh_queries import mesh_occupancy


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


@dataclass(eq=False)
class Scene:
    """An indoor scene: its mesh and, for generated scenes and single-room layouts, its layout.

    The one scene model: generated scenes (:func:`uavturb.scene.procedural.generate_scene`),
    single-room layouts (:mod:`uavturb.scene.layouts`: the flight rooms, the EuRoC stand-in room,
    the synthetic box rooms) and external meshes (:func:`load_scene_mesh`). Scenes compare and
    hash by identity (a scene is one object, as caches of its point cloud need).

    Attributes
    ----------
    mesh : trimesh.Trimesh
        Triangle mesh in the world frame [m] (z up; floor at ``z = 0`` for generated scenes).
        Not necessarily watertight.
    seed : int or None
        The seed of :func:`generate_scene`; ``None`` for external meshes.
    kind : str
        ``'apartment'``, ``'office'`` (generated), ``'room'`` (a single-room layout) or ``'external'``.
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
            occ = box_occupancy(self.boxes, xs, ys, z, resolution, margin, height_band)
            gx, gy = np.meshgrid(xs, ys, indexing="ij")
            occ |= ~self.inside_building(np.c_[gx.ravel(), gy.ravel()]).reshape(occ.shape)
        else:
            occ = mesh_occupancy(self.mesh, xs, ys, z, resolution, margin, height_band)
        return occ, origin, float(resolution)




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

