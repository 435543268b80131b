"""Queries on triangle meshes without boxes (external scans): vertical ray casts and the
occupancy of a horizontal slab from mesh cross-sections."""

from __future__ import annotations

import numpy as np
import trimesh


def ray_heights(mesh: trimesh.Trimesh, positions: np.ndarray, direction: float) -> np.ndarray:
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



def mesh_occupancy(mesh, xs, ys, z, res, margin, band) -> np.ndarray:
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
        outside[free] = ~np.isfinite(ray_heights(mesh, p, -1.0)) | ~np.isfinite(ray_heights(mesh, p, 1.0))
    occ |= outside.reshape(occ.shape)
    if margin > 0:
        # grow every occupied cell (walls, furniture and outside) by the margin
        dist = ndimage.distance_transform_edt(~occ) * res
        occ |= dist <= margin + 1e-9
    return occ

