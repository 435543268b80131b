"""Geometric queries on a :class:`~uavturb.scene.indoor.Scene`: heights straight down and up
(the ``d_down``, ``d_up`` of ``effects.md``), the height of the surface under a point, and
collisions.

Scenes made of boxes (generated scenes, single-room layouts) answer exactly from their boxes,
every height through the one surface query :func:`uavturb.scene.boxes.surface_heights`; external
meshes by vertical ray casts and mesh sections (:mod:`uavturb.scene.mesh_queries`). Point clouds
(a recording's scan) have the same ``d_down`` / ``d_up`` query in
:class:`uavturb.scene.heights.SurfaceIndex`.
"""

from __future__ import annotations

import numpy as np
import trimesh

from uavturb.errors import InputError
from uavturb.scene.boxes import BoxHeights, box_heights, boxes_contain, surface_heights
from uavturb.scene.indoor import Scene
from uavturb.scene.mesh_queries import ray_heights


def _heights(mesh_or_scene, positions, direction: float) -> np.ndarray:
    positions = np.asarray(positions, dtype=float)
    if positions.ndim != 2 or positions.shape[1] != 3:
        raise InputError("positions", f"expected shape (N, 3), got {positions.shape}")
    if isinstance(mesh_or_scene, Scene):
        if mesh_or_scene.has_boxes:
            return box_heights(mesh_or_scene.boxes, positions, direction)
        mesh = mesh_or_scene.mesh
    elif isinstance(mesh_or_scene, trimesh.Trimesh):
        mesh = mesh_or_scene
    else:
        raise InputError("mesh_or_scene", f"expected a Scene or trimesh.Trimesh, got {type(mesh_or_scene).__name__}")
    return ray_heights(mesh, positions, direction)


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


def surface_below(scene: Scene, xy: np.ndarray, margin: float = 0.0) -> np.ndarray:
    """Height [m] of the highest surface under points ``xy`` ``(N, 2)`` [m] of a scene made of boxes:
    the floor's (0) or the top of the furniture there, each footprint grown by ``margin`` [m].

    :func:`~uavturb.scene.boxes.surface_heights` seen from 1 um under the ceiling (the highest
    surface a flight can be over). Returns ``(N,)`` m, ``-inf`` off the floor.

    Raises
    ------
    InputError : a scene without boxes or ceiling (an external mesh).
    """
    if not scene.has_boxes or scene.ceiling_height is None:
        raise InputError("scene", "surface_below needs a scene made of boxes with a ceiling (not an external mesh)")
    xy = np.atleast_2d(np.asarray(xy, dtype=float))
    if xy.ndim != 2 or xy.shape[1] != 2:
        raise InputError("xy", f"expected shape (N, 2), got {xy.shape}")
    top = np.full((len(xy), 1), float(scene.ceiling_height) - 1e-6)
    return surface_heights(scene.boxes, np.hstack([xy, top]), grow=float(margin))[0]


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
    hit = boxes_contain(scene.boxes, p, margin)
    hit |= p[:, 2] < margin
    if scene.ceiling_height is not None:
        hit |= p[:, 2] > scene.ceiling_height - margin
    hit |= ~scene.inside_building(p[:, :2])
    return hit


def collides(scene: Scene, positions: np.ndarray, radius: float, half_height: float = 0.01) -> np.ndarray:
    """Whether a vehicle (a vertical cylinder of ``radius`` [m] and ``half_height`` [m] about its
    body origin) at ``positions (K, 3)`` [m] touches the scene.

    Generated scenes: a box grown by ``radius`` horizontally and ``half_height`` vertically
    contains the point (strictly), or the point is outside the building, under the floor plus
    ``half_height`` or over the ceiling minus ``half_height``. External meshes:
    :func:`inside_obstacle` with margin ``half_height``.

    Returns
    -------
    (K,) bool
    """
    p = np.atleast_2d(np.asarray(positions, float))
    if not scene.has_boxes:
        return inside_obstacle(scene, p, margin=half_height)
    hit = boxes_contain(scene.boxes, p, np.array([radius, radius, half_height]), strict=True, chunk=2048)
    hit |= p[:, 2] < half_height
    if scene.ceiling_height is not None:
        hit |= p[:, 2] > scene.ceiling_height - half_height
    hit |= ~scene.inside_building(p[:, :2])
    return hit


class MeshHeights:
    """``d_down`` / ``d_up`` [m] of positions ``(N, 3)`` [m] by vertical ray casts into a mesh."""

    def __init__(self, mesh: trimesh.Trimesh):
        self.mesh = mesh

    def d_down(self, positions: np.ndarray) -> np.ndarray:
        return ray_heights(self.mesh, positions, -1.0)

    def d_up(self, positions: np.ndarray) -> np.ndarray:
        return ray_heights(self.mesh, positions, 1.0)


def scene_heights(scene: Scene) -> BoxHeights | MeshHeights:
    """The height query of a scene (``d_down(positions)``, ``d_up(positions)``, as
    :func:`height_below` / :func:`height_above` answer): :class:`~uavturb.scene.boxes.BoxHeights`
    on a generated scene's boxes, :class:`MeshHeights` on an external mesh."""
    return BoxHeights(scene.boxes) if scene.has_boxes else MeshHeights(scene.mesh)
