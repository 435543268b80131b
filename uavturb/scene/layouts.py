"""Single-room layouts: functions that build a :class:`~uavturb.scene.indoor.Scene` of one closed
room with solid boxes standing on its floor.

- :func:`box_room`: any such room (the synthetic data's rooms, :mod:`uavturb.data.synthetic`);
- :func:`table_room`: a room with one table and optionally more furniture (the rooms of
  ``uavturb generate flight``, :mod:`uavturb.sim.flights.plans`);
- :func:`euroc_vicon_room`: the stand-in for EuRoC's Vicon room (V1_01_easy, V1_02_medium).

Conventions (``recordings.md``): world frame W, z up, metres. The room's free floor spans
``±size/2`` about the world origin, the floor is the plane ``z = 0`` and the ceiling the plane
``z = ceiling``. A layout's scene holds one :class:`~uavturb.scene.indoor.SceneRoom` (kind
``'room'``), one :class:`~uavturb.scene.indoor.Furniture` per box in the order given (``parts`` the
box itself, ``surface`` its top), and solid boxes: the floor, the ceiling and four wall slabs
(:data:`SLAB` thick, the walls reaching past floor and ceiling) followed by the furniture boxes,
so the height queries of :mod:`uavturb.scene.queries` answer exactly from them.

Its mesh is the room's inner shell (one box, faces turned inwards) followed by the furniture
boxes (12 triangles each, ``trimesh.creation.box``), as the flight rooms have always been meshed:
their recordings' point clouds are sampled from it (face ``k >= 12`` belongs to furniture
``k // 12 - 1``).
"""

from __future__ import annotations

from typing import Sequence

import numpy as np
import trimesh

from uavturb.errors import InputError
from uavturb.scene.indoor import Furniture, Scene, SceneRoom

#: m, thickness of a layout's floor, ceiling and wall slabs
SLAB = 0.1

#: one box standing on the floor: ``(x_min, x_max, y_min, y_max, top)`` [m]
FloorBox = tuple[float, float, float, float, float]


def _shell_and_furniture_mesh(size: tuple[float, float], ceiling: float, boxes: Sequence[FloorBox]) -> trimesh.Trimesh:
    """The inner shell (normals into the room) and the furniture boxes, in order."""
    walls = trimesh.creation.box(extents=(size[0], size[1], ceiling))
    walls.apply_translation((0.0, 0.0, ceiling / 2))
    walls.invert()  # normals point into the room
    solids = []
    for x0, x1, y0, y1, h in boxes:
        box = trimesh.creation.box(extents=(x1 - x0, y1 - y0, h))
        box.apply_translation(((x0 + x1) / 2, (y0 + y1) / 2, h / 2))
        solids.append(box)
    return trimesh.util.concatenate([walls, *solids])


def _structure(size: tuple[float, float], ceiling: float) -> np.ndarray:
    """``(6, 2, 3)`` m: floor, ceiling and the walls at ``-x``, ``+x``, ``-y``, ``+y``."""
    hx, hy, t = size[0] / 2, size[1] / 2, SLAB
    return np.array([
        [[-hx - t, -hy - t, -t], [hx + t, hy + t, 0.0]],
        [[-hx - t, -hy - t, ceiling], [hx + t, hy + t, ceiling + t]],
        [[-hx - t, -hy - t, -t], [-hx, hy + t, ceiling + t]],
        [[hx, -hy - t, -t], [hx + t, hy + t, ceiling + t]],
        [[-hx, -hy - t, -t], [hx, -hy, ceiling + t]],
        [[-hx, hy, -t], [hx, hy + t, ceiling + t]],
    ])


def box_room(size: tuple[float, float], ceiling: float, boxes: Sequence[Sequence[float]],
             kinds: Sequence[str] | None = None) -> Scene:
    """A closed room with solid boxes standing on its floor.

    Parameters
    ----------
    size : (2,) m, free floor extent along world x and y (the room spans ``±size/2``)
    ceiling : m, height of the ceiling over the floor
    boxes : (K, 5) ``x_min, x_max, y_min, y_max, top`` [m], bottoms on the floor
    kinds : (K,) furniture kinds (default ``'box'`` each)

    Returns
    -------
    Scene of kind ``'room'`` (see the module's description).

    Raises
    ------
    InputError : a size or ceiling that is not positive, a box that is empty, has no height or
        reaches the ceiling, or ``kinds`` of another length.
    """
    size = (float(size[0]), float(size[1]))
    ceiling = float(ceiling)
    if min(size) <= 0 or ceiling <= 0:
        raise InputError("room", f"size and ceiling must be positive, got {size} and {ceiling}")
    rows: list[FloorBox] = [tuple(float(v) for v in b) for b in boxes]  # type: ignore[misc]
    kinds = ["box"] * len(rows) if kinds is None else [str(k) for k in kinds]
    if len(kinds) != len(rows):
        raise InputError("room", f"{len(rows)} boxes but {len(kinds)} kinds")
    for x0, x1, y0, y1, top in rows:
        if not (x0 < x1 and y0 < y1 and 0 < top < ceiling):
            raise InputError("room", f"box {(x0, x1, y0, y1, top)} must have x_min < x_max, y_min < y_max and "
                                     f"0 < top < ceiling ({ceiling:g} m)")
    furniture = []
    for (x0, x1, y0, y1, top), kind in zip(rows, kinds):
        lo, hi = np.array([x0, y0, 0.0]), np.array([x1, y1, top])
        furniture.append(Furniture(kind=kind, lo=lo, hi=hi, parts=np.array([[lo, hi]]), surface=top, room=0))
    rect = np.array([-size[0] / 2, -size[1] / 2, size[0] / 2, size[1] / 2])
    solids = np.concatenate([_structure(size, ceiling), np.array([[f.lo, f.hi] for f in furniture]).reshape(-1, 2, 3)])
    return Scene(mesh=_shell_and_furniture_mesh(size, ceiling, rows), seed=None, kind="room",
                 rooms=[SceneRoom(kind="room", rect=rect, cell=rect.copy())], furniture=furniture,
                 bounds=np.array([[rect[0], rect[1], 0.0], [rect[2], rect[3], ceiling]]), ceiling_height=ceiling,
                 wall_thickness=SLAB, boxes=solids,
                 box_kinds=np.array(["floor", "ceiling", "wall", "wall", "wall", "wall", *kinds], dtype="<U8"),
                 box_owner=np.r_[np.full(6, -1), np.arange(len(furniture))].astype(np.int64))


def table_room(size: tuple[float, float] = (8.0, 6.0), ceiling: float = 2.6,
               table_center: tuple[float, float] = (1.8, 0.9), table_size: tuple[float, float] = (1.2, 0.8),
               table_height: float = 0.75, furniture: Sequence[FloorBox] = ()) -> Scene:
    """A room with one table (its first furniture, kind ``'table'``) and further ``furniture`` boxes
    (kind ``'box'``), each ``(x_min, x_max, y_min, y_max, height)`` [m].

    Parameters
    ----------
    size : (2,) m, room extent along world x and y; ceiling : m
    table_center, table_size : (2,) m, the table top's centre and extent in world x, y
    table_height : m, height of the table top over the floor
    """
    cx, cy = table_center
    hx, hy = table_size[0] / 2, table_size[1] / 2
    table = (cx - hx, cx + hx, cy - hy, cy + hy, table_height)
    return box_room(size, ceiling, [table, *furniture], ["table"] + ["box"] * len(furniture))


def euroc_vicon_room() -> Scene:
    """A stand-in for EuRoC's Vicon room (V1_01_easy, V1_02_medium): a motion-capture room with a
    table and a few boxes and mats on the floor. Not a scan; sizes and layout are ours."""
    return table_room(size=(8.0, 7.0), ceiling=3.2, table_center=(1.5, 1.0), table_size=(1.2, 0.8), table_height=0.75,
                      furniture=((-2.2, -1.6, 0.8, 1.6, 0.45),  # a stack of boxes
                                 (-1.6, 0.2, -2.2, -1.2, 0.2),  # foam mats
                                 (1.0, 1.6, -2.4, -1.6, 0.6)))  # a crate


def room_size(scene: Scene) -> tuple[float, float]:
    """``(2,)`` m, the free floor extent of a single-room layout along world x and y."""
    r = scene.rooms[0].rect
    return float(r[2] - r[0]), float(r[3] - r[1])


def floor_boxes(scene: Scene) -> list[FloorBox]:
    """The furniture of a layout as ``(x_min, x_max, y_min, y_max, top)`` [m] rows, in order."""
    return [(float(f.lo[0]), float(f.hi[0]), float(f.lo[1]), float(f.hi[1]), float(f.hi[2])) for f in scene.furniture]
