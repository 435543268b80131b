"""``uavturb bench scene``: the scene queries (heights over the surface below and above a position,
:class:`uavturb.scene.heights.SurfaceIndex`) and the depth projection on a synthetic room cloud."""

from __future__ import annotations

import time

import numpy as np
import trimesh

from uavturb.scene import projection as proj
from uavturb.scene.camera import R_BC_FORWARD
from uavturb.scene.heights import SurfaceIndex, sample_mesh_points


def _room_cloud(n_points: int, seed: int) -> np.ndarray:
    """A synthetic 10 x 8 x 3 m room (floor, ceiling, walls, tables) of ``n_points`` points."""
    parts = []
    room = trimesh.creation.box(extents=(10.0, 8.0, 3.0))
    room.apply_translation((0.0, 0.0, 1.5))
    parts.append(room)
    rng = np.random.default_rng(seed)
    for _ in range(6):
        h = rng.uniform(0.4, 1.1)
        b = trimesh.creation.box(extents=(rng.uniform(0.5, 2.0), rng.uniform(0.5, 1.5), h))
        b.apply_translation((rng.uniform(-4, 4), rng.uniform(-3, 3), h / 2))
        parts.append(b)
    mesh = trimesh.util.concatenate(parts)
    spacing = float(np.sqrt(mesh.area / n_points))
    return sample_mesh_points(mesh, spacing, seed)[:n_points]


def benchmark(n_points: int = 1_000_000, n_queries: int = 100_000, seed: int = 0,
              projection: bool = True) -> dict[str, float]:
    """Timings of the scene queries on a synthetic room cloud (one core, wall clock).

    Parameters
    ----------
    n_points : int
        Cloud size.
    n_queries : int
        Positions per batch query.
    seed : int
        Seed of the cloud and queries.
    projection : bool
        Also time :func:`uavturb.scene.projection.depth_from_points` (128 x 128 and
        752 x 480 images of the same cloud).

    Returns
    -------
    dict of str to float
        Named timings; the unit is in each name.
    """
    pts = _room_cloud(n_points, seed)
    rng = np.random.default_rng(seed + 1)
    q = np.column_stack([rng.uniform(-4.9, 4.9, n_queries), rng.uniform(-3.9, 3.9, n_queries),
                         rng.uniform(0.05, 2.9, n_queries)])
    out: dict[str, float] = {}
    t = time.perf_counter()
    idx = SurfaceIndex(pts)
    out[f"build, {n_points} points (s)"] = time.perf_counter() - t
    t = time.perf_counter()
    idx.d_down(q)
    out[f"d_down, {n_queries} positions (s)"] = time.perf_counter() - t
    t = time.perf_counter()
    idx.d_up(q)
    out[f"d_up, {n_queries} positions (s)"] = time.perf_counter() - t
    t = time.perf_counter()
    for k in range(200):
        idx.d_down(q[k])
    out["d_down, one position (us)"] = (time.perf_counter() - t) / 200 * 1e6
    if projection:
        prepared = proj.prepare_cloud(pts)
        q_WB = np.array([1.0, 0.0, 0.0, 0.0])
        T_BS = np.eye(4)
        T_BS[:3, :3] = R_BC_FORWARD
        T_WC = proj.camera_pose_world(q_WB, np.array([-3.0, 0.0, 1.2]), T_BS)
        for w, h in ((128, 128), (752, 480)):
            f = 0.6 * w
            K = proj.intrinsics_matrix(f, f, (w - 1) / 2, (h - 1) / 2)
            proj.depth_from_points(prepared, T_WC, K, w, h)
            reps = 5
            t = time.perf_counter()
            for _ in range(reps):
                proj.depth_from_points(prepared, T_WC, K, w, h)
            out[f"depth {w}x{h}, {n_points} points (ms)"] = (time.perf_counter() - t) / reps * 1e3
    return out
