"""Depth images from a scene point cloud: the paper's projection of the EuRoC room scan.

EuRoC's vehicles carry no depth camera; the paper (section "Experimental setup") projects
the room's point cloud into ``cam0`` at every instant to get depth images. This module
does that, vectorised in numpy.

Frames and conventions
----------------------
- World W: z up (``recordings.md``). Body B: x forward, y left, z up; ``q_WB`` (w, x, y, z)
  rotates body vectors into W.
- Camera C is the optical frame of EuRoC ``cam0`` and of :mod:`uavturb.sim.core.render`:
  x right, y down, z forward (the viewing direction). ``T_WC`` (4x4) maps C to W;
  ``cam0/sensor.yaml``'s ``T_BS`` maps the camera (sensor) frame to B, so
  ``T_WC = T_WB @ T_BS`` (:func:`camera_pose_world`).
- Pinhole intrinsics ``K = [[fu, 0, cu], [0, fv, cv], [0, 0, 1]]`` (EuRoC's
  ``intrinsics: [fu, fv, cu, cv]``); pixel ``(row i, col j)`` is centred at ``u = j``,
  ``v = i``. Lens distortion is not applied (images are undistorted/pinhole).
- Depth images hold the **z-depth** (along the optical axis, not along the ray) in metres,
  ``0`` where there is no data.

How a scan becomes a closed surface (:func:`depth_from_points`)
----------------------------------------------------------------
1. *Cull and transform*: points are moved into C and kept inside ``[near, far]`` and the
   image (plus their splat radius).
2. *Splat with a size that grows as points get closer*: a point stands for a disc of
   diameter ``s`` (its local scan spacing, estimated from the cloud's density by
   :func:`prepare_cloud`, or ``point_size``), i.e. ``r = splat_scale * f * s / z``
   pixels. To keep the cost per point constant, a point is drawn into the level ``l`` of
   an image pyramid where its radius is below one pixel (``2^l`` full-resolution pixels
   per level pixel) and covers the level pixels within ``r / 2^l`` of it (at most 3 x 3).
   *Splats lie on their surface's plane* (a point's normal from its neighbours,
   :func:`estimate_normals`): every pixel a splat covers gets the depth of the point's tangent
   plane at the pixel's centre (inverse depth is linear in the pixel on a plane), within the
   splat's own disc radius of its depth. A splat whose plane's depth varies across it by more
   than ``eps / 2`` (``rho sin(theta) / h``: a floor seen from a few centimetres, where one 3 cm
   point spans half the image) is split into up to :data:`MAX_SPLIT` x :data:`MAX_SPLIT` smaller
   splats on that plane, so that it lands in fine pyramid levels. Without this, the nearest
   splats of a floor seen from under ~0.3 m each drew one depth over an eighth of the image and
   hid everything behind it (evaluation depths read 40-60 % short there). Points without a
   clear plane (edges, corners, clutter: normal 0) keep one depth.
3. *Soft z-buffer per level*: every pixel keeps the nearest contribution and averages the
   contributions within ``eps`` (relative) of it, weighted by distance to the splat
   centre. This is the epsilon-z-buffer of surface splatting: it removes hidden surfaces
   and does not bias depth towards the camera on slanted surfaces the way a plain
   minimum over large splats does.
4. *Visibility test per level* (background leaking through gaps of a sparse foreground):
   a pixel is declared hidden when, in at least 3 of the 4 directions (left, right, up,
   down), a pixel within ``window`` is nearer by more than ``occlusion`` (relative).
   A plain comparison with a local minimum filter would also erase the genuine background
   along every foreground silhouette (it has nearer pixels on *one* side); a slanted
   surface has nearer pixels on at most two sides (along its depth gradient) and a
   concave corner differs by far less than ``occlusion``. Only a pixel surrounded by a
   nearer surface, i.e. seen through a gap in it, trips the test (a screen-space
   operator in the spirit of Pintus et al., 2011).
5. *Small-hole filling per level*: connected empty regions of at most ``fill_area``
   pixels are filled from their rim inwards, each pixel with the mean of its filled
   neighbours within ``eps`` of the nearest one (foreground first: no flying pixels
   across depth edges). Larger empty regions (no data, beyond ``far``) are left alone, so
   outlines do not grow into empty space.
6. *Composite*: levels are upsampled (nearest) to full resolution and merged with the
   same soft z-buffer rule; the visibility test and hole filling run once more on the
   composite (holes where levels meet are up to one coarse pixel wide).

Limits: where a surface is seen so obliquely that one pixel spans more than ~10 % of depth (a
floor towards the horizon from a few centimetres above it), the pixel has no single depth and
its nearest points win: a few per cent short (ray casts of a mesh give the pixel centre's).
Hidden surfaces less than ``occlusion`` (5 %) behind the visible one (the back
faces of a small object) are not told apart from it, and within ~2 pixels of a
silhouette a hidden surface can show through where the front surface's splats thin out.
Splat sizes come from one spacing for the whole cloud (the median of the per-voxel
estimate; per-voxel densities are biased at edges and corners where several surfaces
share a voxel), so a scan whose density varies a lot should pass ``point_size`` or a
:class:`PreparedCloud` with its own per-point ``spacing``.

:func:`prepare_cloud` does the per-cloud work (float32 copy, spacing estimate) once; pass
its result instead of the raw array when rendering many frames. ``subset`` lets callers
pass indices of a precomputed subset (e.g. the points of the current room).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from uavturb.errors import InputError
from uavturb.physics import quaternion as quat

__all__ = [
    "PreparedCloud",
    "camera_pose_world",
    "depth_from_points",
    "depth_to_points",
    "estimate_normals",
    "estimate_spacing",
    "intrinsics_matrix",
    "prepare_cloud",
]

@dataclass(frozen=True)
class PreparedCloud:
    """A point cloud ready for repeated projection.

    Attributes
    ----------
    points : (P, 3) float32 array
        Points in W [m].
    spacing : (P,) float32 array
        Local scan spacing per point [m]: the diameter of the disc each point stands for.
    normals : (P, 3) float32 array or None
        Unit normal of the surface at each point in W (:func:`estimate_normals`), zero where the
        neighbourhood is not planar (edges, corners, clutter); ``None``: not estimated (splats
        are then never split, see :func:`depth_from_points`).
    """

    points: np.ndarray
    spacing: np.ndarray
    normals: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.points)


def _check_cloud(points: np.ndarray) -> np.ndarray:
    try:
        p = np.asarray(points)
    except (TypeError, ValueError) as e:
        raise InputError("point cloud", f"not a numeric array ({e})") from None
    if p.ndim != 2 or p.shape[1] != 3 or not np.issubdtype(p.dtype, np.number):
        raise InputError("point cloud", f"expected a numeric array of shape (P, 3), got {p.shape}")
    if len(p) == 0:
        raise InputError("point cloud", "empty: no points")
    if not np.all(np.isfinite(p)):
        raise InputError("point cloud", "NaN or infinite coordinates")
    return p


def estimate_spacing(points: np.ndarray, voxel: float | None = None) -> tuple[np.ndarray, float]:
    """Local point spacing [m] of a surface scan, from the point density per voxel.

    A surface crossing a voxel of side ``v`` covers about ``v^2`` of area, so a voxel
    holding ``n`` points has a spacing ``v / sqrt(n)``. This holds for grid-like and random
    scans alike (a nearest-neighbour distance would differ by a factor ~2 between them).

    Parameters
    ----------
    points : (P, 3) array
        Points [m].
    voxel : float, optional
        Voxel side [m]; default: 12 times the global spacing (at least 0.1 m), so that a
        voxel holds ~100+ points.

    Returns
    -------
    spacing : (P,) float32 array
        Per point, its voxel's spacing, clipped to ``[0.5, 2]`` times the median.
    typical_spacing : float
        The median of ``spacing`` over the points: robust to the voxels at edges and
        corners (partly filled, or shared by several surfaces).
    """
    p = _check_cloud(points)
    p = np.asarray(p, dtype=np.float64)

    def per_voxel(v: float):
        ijk = np.floor((p - p.min(axis=0)) / v).astype(np.int64)
        n = ijk.max(axis=0) + 1
        key = (ijk[:, 0] * n[1] + ijk[:, 1]) * n[2] + ijk[:, 2]
        _, inv, counts = np.unique(key, return_inverse=True, return_counts=True)
        return inv, counts

    if voxel is None:
        v0 = 0.25
        _, counts = per_voxel(v0)
        s0 = v0 * np.sqrt(len(counts) / len(p))
        voxel = max(0.1, 12.0 * s0)
        if abs(voxel - v0) < 1e-12:
            voxel = v0
    inv, counts = per_voxel(float(voxel))
    s = voxel / np.sqrt(counts.astype(np.float64))
    s_pt = s[inv]
    med = float(np.median(s_pt))
    return np.clip(s_pt, 0.5 * med, 2.0 * med).astype(np.float32), med


#: neighbours of a point in the plane fit of :func:`estimate_normals`
NORMAL_NEIGHBOURS = 10
#: a neighbourhood is planar when its smallest principal variance is below this share of the middle one
PLANARITY = 0.1


def estimate_normals(points: np.ndarray, neighbours: int = NORMAL_NEIGHBOURS) -> np.ndarray:
    """Unit surface normals [-] of a scan, by principal components of each point's neighbourhood.

    The normal is the direction of least variance of the ``neighbours`` nearest points (the point
    included); it is set to zero where that variance is not clearly the least (at least
    :data:`PLANARITY` of the middle one: edges, corners, clutter) or where there are fewer than
    three points. Its sign is arbitrary (only the plane is used).

    Parameters
    ----------
    points : (P, 3) array
        Points [m].

    Returns
    -------
    (P, 3) float32 array
    """
    from scipy.spatial import cKDTree

    p = np.asarray(_check_cloud(points), dtype=np.float64)
    out = np.zeros(p.shape, dtype=np.float32)
    k = min(int(neighbours), len(p))
    if k < 3:
        return out
    _, idx = cKDTree(p).query(p, k=k)
    nb = p[idx] - p[idx].mean(axis=1, keepdims=True)  # (P, k, 3)
    lam, vec = np.linalg.eigh(np.einsum("pki,pkj->pij", nb, nb))  # ascending variances
    planar = lam[:, 0] <= PLANARITY * lam[:, 1]
    out[planar] = vec[planar, :, 0]
    return out


def prepare_cloud(points: np.ndarray, point_size: float | None = None) -> PreparedCloud:
    """Per-cloud work of :func:`depth_from_points`, done once.

    Parameters
    ----------
    points : (P, 3) array_like
        Scene points in W [m].
    point_size : float, optional
        Scan spacing [m] for every point; default: the typical spacing of
        :func:`estimate_spacing`.

    Returns
    -------
    PreparedCloud
        With the points' normals (:func:`estimate_normals`), so that near, slanted splats are
        drawn on their surface's plane.
    """
    p = _check_cloud(points)
    pts = np.ascontiguousarray(p, dtype=np.float32)
    if point_size is None:
        _, typical = estimate_spacing(p)
        spacing = np.full(len(pts), typical, dtype=np.float32)
    else:
        if not (np.isfinite(point_size) and point_size > 0):
            raise InputError("point_size", f"must be positive, got {point_size}")
        spacing = np.full(len(pts), point_size, dtype=np.float32)
    return PreparedCloud(pts, spacing, estimate_normals(pts))


def intrinsics_matrix(fu: float, fv: float, cu: float, cv: float) -> np.ndarray:
    """``K`` (3, 3) of EuRoC's ``intrinsics: [fu, fv, cu, cv]`` [px]."""
    return np.array([[fu, 0.0, cu], [0.0, fv, cv], [0.0, 0.0, 1.0]])


def camera_pose_world(q_WB: np.ndarray, p_WB: np.ndarray, T_BS: np.ndarray) -> np.ndarray:
    """Camera pose ``T_WC = T_WB @ T_BS`` from the body pose and the camera extrinsic.

    Parameters
    ----------
    q_WB : (4,) or (N, 4) array
        Body attitude, quaternion w, x, y, z, body to world.
    p_WB : (3,) or (N, 3) array
        Body origin in W [m].
    T_BS : (4, 4) array
        Camera (sensor, optical frame: x right, y down, z forward) to body, as in
        ``cam0/sensor.yaml``.

    Returns
    -------
    (4, 4) or (N, 4, 4) array
        Camera to world.
    """
    q = np.asarray(q_WB, dtype=float)
    p = np.asarray(p_WB, dtype=float)
    T_BS = np.asarray(T_BS, dtype=float)
    if q.shape[-1:] != (4,) or p.shape[-1:] != (3,) or T_BS.shape != (4, 4):
        raise InputError("camera_pose_world", f"expected q (...,4), p (...,3), T_BS (4,4); got {q.shape}, "
                         f"{p.shape}, {T_BS.shape}")
    shape = np.broadcast_shapes(q.shape[:-1], p.shape[:-1])
    T_WB = np.zeros(shape + (4, 4))
    T_WB[..., :3, :3] = quat.to_rotation_matrix(q)
    T_WB[..., :3, 3] = p
    T_WB[..., 3, 3] = 1.0
    return T_WB @ T_BS


def _check_camera(T_WC, K, width, height):
    T_WC = np.asarray(T_WC, dtype=float)
    K = np.asarray(K, dtype=float)
    if T_WC.shape != (4, 4) or not np.all(np.isfinite(T_WC)):
        raise InputError("T_WC", f"expected a finite (4, 4) pose, got shape {T_WC.shape}")
    if K.shape != (3, 3) or not np.all(np.isfinite(K)) or K[0, 0] <= 0 or K[1, 1] <= 0:
        raise InputError("K", "expected a (3, 3) pinhole matrix with positive focal lengths")
    if int(width) < 1 or int(height) < 1:
        raise InputError("image size", f"width and height must be >= 1, got {width} x {height}")
    return T_WC, K, int(width), int(height)


_PAD = 3


def _soft_zbuffer(idx, z, w, n_pix, eps):
    """Per pixel: mean (weights ``w``) of the contributions within ``eps`` of the nearest."""
    zmin = np.full(n_pix, np.inf, dtype=np.float32)
    np.minimum.at(zmin, idx, z)
    w = w * (z <= zmin[idx] * np.float32(1.0 + eps))
    num = np.bincount(idx, weights=w * z, minlength=n_pix)
    den = np.bincount(idx, weights=w, minlength=n_pix)
    out = np.zeros(n_pix, dtype=np.float32)
    hit = den > 0
    out[hit] = num[hit] / den[hit]
    return out


def _padded_views(a, reach, fill, offsets):
    """Views ``out[k][i, j] = a[i + di_k, j + dj_k]`` (``fill`` outside) for ``offsets``."""
    h, w = a.shape
    p = np.pad(a, reach, constant_values=fill)
    return [p[reach + di:reach + di + h, reach + dj:reach + dj + w] for di, dj in offsets]


def _hide_occluded(d, window, occlusion):
    """Zero the pixels with a nearer pixel within ``window`` in >= 3 of the 4 directions."""
    if window < 1 or not np.any(d > 0):
        return d
    a = np.where(d > 0, d, np.inf).astype(np.float32)
    lim = a * np.float32(1.0 - occlusion)
    votes = np.zeros(d.shape, dtype=np.int8)
    for di, dj in ((0, -1), (0, 1), (-1, 0), (1, 0)):
        views = _padded_views(a, window, np.inf, [(di * k, dj * k) for k in range(1, window + 1)])
        votes += np.minimum.reduce(views) < lim
    return np.where(votes >= 3, np.float32(0.0), d).astype(d.dtype)


_NEIGHBOURS = [(di, dj) for di in (-1, 0, 1) for dj in (-1, 0, 1) if (di, dj) != (0, 0)]


def _fill_small_holes(d, max_area, eps):
    """Fill the connected empty regions of at most ``max_area`` pixels, from their rims inwards.

    Each pass gives the empty pixels of those regions that touch filled ones the mean of
    their filled neighbours within ``eps`` of the nearest (foreground first: no flying
    pixels across depth edges). Larger empty regions (no data, the sky, beyond ``far``)
    are left alone, so outlines do not grow into them.
    """
    from scipy import ndimage

    d = np.array(d, dtype=np.float32)
    empty = d <= 0
    if max_area < 1 or not np.any(empty) or np.all(empty):
        return d
    labels, n = ndimage.label(empty)
    size = np.bincount(labels.ravel(), minlength=n + 1)
    size[0] = max_area + 1
    ti, tj = np.nonzero(size[labels] <= max_area)
    h, w = d.shape
    while len(ti):
        a = np.pad(np.where(d > 0, d, np.float32(np.inf)), 1, constant_values=np.inf)
        vals = np.stack([a[ti + 1 + di, tj + 1 + dj] for di, dj in _NEIGHBOURS])  # (8, T)
        nmin = vals.min(axis=0)
        ready = np.isfinite(nmin)
        if not np.any(ready):
            break
        ok = vals[:, ready] <= nmin[ready] * np.float32(1.0 + eps)
        d[ti[ready], tj[ready]] = np.where(ok, vals[:, ready], 0.0).sum(axis=0) / ok.sum(axis=0)
        ti, tj = ti[~ready], tj[~ready]
    return d


def depth_from_points(
    points: np.ndarray | PreparedCloud,
    T_WC: np.ndarray,
    K: np.ndarray,
    width: int,
    height: int,
    *,
    near: float = 0.05,
    far: float = 20.0,
    point_size: float | None = None,
    subset: np.ndarray | None = None,
    splat_scale: float = 1.0,
    eps: float = 0.03,
    occlusion: float = 0.05,
    window: int = 3,
    fill_area: int = 16,
) -> np.ndarray:
    """Z-depth image of a point cloud seen by a pinhole camera.

    See the module docstring for the method (splats that grow as points get closer,
    soft z-buffer, visibility test against background leaking through gaps, small-hole
    filling).

    Parameters
    ----------
    points : (P, 3) array_like or PreparedCloud
        Scene points in W [m]. Pass a :func:`prepare_cloud` result when rendering many
        frames (it skips the spacing estimate and the float32 copy).
    T_WC : (4, 4) array
        Camera (optical frame: x right, y down, z forward) to world.
    K : (3, 3) array
        Pinhole intrinsics [px].
    width, height : int
        Image size [px].
    near, far : float
        Depth range [m]; points outside are ignored.
    point_size : float, optional
        Scan spacing [m] (diameter of the disc a point stands for); overrides the
        estimate (default: the typical spacing of :func:`estimate_spacing`).
    subset : (M,) int or (P,) bool array, optional
        Only these points (e.g. a precomputed, culled subset).
    splat_scale : float
        Splat radius in units of the spacing (1: a disc of radius ``s``, which leaves
        ~4 % of a random scan's surface uncovered; the hole filling closes that).
    eps : float
        Relative depth tolerance of the soft z-buffer and of the hole filling.
    occlusion : float
        Relative depth margin of the visibility test (0 disables nothing; use
        ``window=0`` to switch the test off).
    window : int
        Reach [level px] of the visibility test.
    fill_area : int
        Largest hole [level px] that is filled (0: no filling). On the full-resolution
        composite the limit is ``max(fill_area, 2 * 4**L)`` for the coarsest level ``L``
        used, i.e. two of its pixels.

    Returns
    -------
    (height, width) float32 array
        Z-depth [m], ``0`` where there is no data.

    Raises
    ------
    InputError
        Bad cloud (empty, wrong shape, NaN), pose, intrinsics or image size.
    """
    T_WC, K, W, H = _check_camera(T_WC, K, width, height)
    pts, spacing, point_size, normals = _cloud_and_spacing(points, point_size, subset)
    depth = np.zeros((H, W), dtype=np.float32)
    if len(pts) == 0:
        return depth
    u, v, z, r, keep = _project_splats(pts, spacing, point_size, T_WC, K, W, H, near, far, splat_scale)
    if len(z) == 0:
        return depth
    splats = (u, v, z, r, *_inverse_depth_slopes(pts[keep], None if normals is None else normals[keep], T_WC, K))
    if normals is not None:
        splats = _split_slanted_splats(splats, keep, pts, spacing, point_size, normals, T_WC, K, W, H, near, far,
                                       splat_scale, eps)
    return _splat_and_composite(*splats, 0.5 * float(K[0, 0] + K[1, 1]), W, H, eps, occlusion, window, fill_area)


def _cloud_and_spacing(points: np.ndarray | PreparedCloud, point_size: float | None, subset: np.ndarray | None
                       ) -> tuple[np.ndarray, np.ndarray | None, float | None, np.ndarray | None]:
    """``(points (P, 3) float32, per-point spacing (P,) or None, point_size, normals (P, 3) or None)``
    of a checked cloud: a prepared cloud's own spacing unless ``point_size`` [m] is given, else one
    size for all (estimated when not given); a prepared cloud's normals, estimated for a raw one;
    only the ``subset`` rows when given."""
    if isinstance(points, PreparedCloud):
        pts, spacing, normals = points.points, points.spacing, points.normals
        if point_size is not None:
            spacing = None
    else:
        pts = np.asarray(_check_cloud(points), dtype=np.float32)
        spacing, normals = None, estimate_normals(pts)
        if point_size is None:
            point_size = estimate_spacing(pts)[1]
    if point_size is not None and not (np.isfinite(point_size) and point_size > 0):
        raise InputError("point_size", f"must be positive, got {point_size}")
    if subset is not None:
        pts = pts[subset]
        spacing = None if spacing is None else spacing[subset]
        normals = None if normals is None else normals[subset]
    return pts, spacing, point_size, normals


def _project_splats(pts: np.ndarray, spacing: np.ndarray | None, point_size: float | None, T_WC: np.ndarray,
                    K: np.ndarray, W: int, H: int, near: float, far: float, splat_scale: float
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Step 1: cull and project. ``(u, v)`` [px], z-depth [m], splat radius [px] and index into
    ``pts`` of the points in front of the camera within ``near``..``far`` whose splat touches the
    image."""
    # p_C = R^T (p_W - t), only the z column first
    R = T_WC[:3, :3].astype(np.float32)
    b = -(T_WC[:3, 3] @ T_WC[:3, :3]).astype(np.float32)
    fx, fy, cx, cy = (np.float32(v) for v in (K[0, 0], K[1, 1], K[0, 2], K[1, 2]))
    f = 0.5 * (fx + fy)
    z = pts @ R[:, 2]
    z += b[2]
    sel = np.flatnonzero((z > near) & (z < far))
    z = z[sel]
    p = pts[sel]
    inv = np.float32(1.0) / z
    u = (p @ R[:, 0] + b[0]) * inv * fx + cx
    v = (p @ R[:, 1] + b[1]) * inv * fy + cy
    if spacing is None:
        r = (np.float32(splat_scale) * f * np.float32(point_size)) * inv
    else:
        r = (np.float32(splat_scale) * f) * spacing[sel] * inv
    r = np.minimum(r, np.float32(1.5 * 2 ** max(0, int(np.floor(np.log2(max(1, min(W, H))))) - 2)))
    ok = np.flatnonzero((u > -0.5 - r) & (u < W - 0.5 + r) & (v > -0.5 - r) & (v < H - 0.5 + r))
    return u[ok], v[ok], z[ok], r[ok], sel[ok]


#: most sub-splats across a split splat's diameter (:func:`_split_slanted_splats`)
MAX_SPLIT = 32


def _inverse_depth_slopes(pts: np.ndarray, normals: np.ndarray | None, T_WC: np.ndarray, K: np.ndarray
                          ) -> tuple[np.ndarray, np.ndarray]:
    """``(d(1/z)/du, d(1/z)/dv)`` [1/(m px)] of each point's tangent plane in the image.

    On a plane ``n . x_C = h`` (camera frame), the inverse z-depth along the ray of pixel ``(u, v)``
    is linear in the pixel: ``1/z = (n_x (u - c_u) / f_u + n_y (v - c_v) / f_v + n_z) / h``. So a
    splat can give every pixel it covers the depth of its surface there (:func:`_stamps`) instead
    of its own. Zero (a splat at one depth) for points without a normal and for planes through
    the camera (seen edge-on).
    """
    gu = np.zeros(len(pts), dtype=np.float32)
    gv = np.zeros(len(pts), dtype=np.float32)
    if normals is None or len(pts) == 0:
        return gu, gv
    R = T_WC[:3, :3]
    n_C = normals.astype(np.float64) @ R  # rows: R^T n
    h = ((pts.astype(np.float64) - T_WC[:3, 3]) @ R * n_C).sum(axis=1)
    ok = np.abs(h) > 1e-9
    gu[ok] = n_C[ok, 0] / (K[0, 0] * h[ok])
    gv[ok] = n_C[ok, 1] / (K[1, 1] * h[ok])
    return gu, gv


def _split_slanted_splats(splats: tuple[np.ndarray, ...], keep: np.ndarray, pts: np.ndarray,
                          spacing: np.ndarray | None, point_size: float | None, normals: np.ndarray,
                          T_WC: np.ndarray, K: np.ndarray, W: int, H: int, near: float, far: float,
                          splat_scale: float, eps: float) -> tuple[np.ndarray, ...]:
    """Step 1b: a splat whose surface's depth varies across it by more than ``eps / 2`` is replaced
    by a grid of smaller splats on its surface's plane.

    A splat is drawn at one depth. Across a disc of radius ``rho`` [m] on a plane at distance
    ``h`` [m] from the camera whose normal leans ``theta`` off the viewing axis, the depth varies
    by a share ``rho sin(theta) / h`` of itself, whatever the disc's distance or the focal
    length: a floor seen from a few centimetres above it, where one 3 cm splat spans half the
    image, would otherwise hide everything behind its single depth. Such a splat becomes ``k x k``
    splats on the point's tangent plane (``k = ceil(2 share / eps)``, at most :data:`MAX_SPLIT`
    and no finer than a pixel), each at its own depth. Points without a normal stay as they are.

    ``splats`` is ``(u, v, z, r, d(1/z)/du, d(1/z)/dv)`` of the points ``keep`` of ``pts``; the same
    is returned with the split splats replaced (sub-splats keep their parent's plane).
    """
    u, v, z, r = splats[:4]
    n = normals[keep].astype(np.float64)
    radius = splat_scale * (spacing[keep] if spacing is not None else np.full(len(keep), point_size))  # m
    p = pts[keep].astype(np.float64)
    h = np.abs(((p - T_WC[:3, 3]) * n).sum(axis=1))  # distance of the camera to the point's plane [m]
    lean = np.sqrt(np.maximum(0.0, (n * n).sum(axis=1) - (n @ T_WC[:3, 2]) ** 2))  # sin(theta); 0: no normal
    share = radius * lean / np.maximum(h, 1e-9)
    k = np.minimum(np.ceil(share / (0.5 * eps)), np.minimum(MAX_SPLIT, np.ceil(2.0 * r))).astype(np.int64)
    split = k >= 2
    if not split.any():
        return splats
    sub_points, sub_size, parent = [], [], []
    for kk in np.unique(k[split]):
        sel = np.flatnonzero(k == kk)
        c = -1.0 + (2.0 * np.arange(kk) + 1.0) / kk  # cell centres across the disc, in disc radii
        a, b = (x.ravel() for x in np.meshgrid(c, c))
        inside = a * a + b * b <= (1.0 + 1.0 / kk) ** 2
        a, b = a[inside], b[inside]
        t1, t2 = _tangent_basis(n[sel])
        off = a[None, :, None] * t1[:, None, :] + b[None, :, None] * t2[:, None, :]  # (S, m, 3)
        sub_points.append((p[sel, None, :] + radius[sel, None, None] * off).reshape(-1, 3))
        # a cell is 2 rho / k wide: sub-splats of radius 1.5 rho / k cover its corners
        sub_size.append(np.repeat(1.5 * radius[sel] / (kk * splat_scale), len(a)))
        parent.append(np.repeat(sel, len(a)))
    *sub, seen = _project_splats(np.concatenate(sub_points).astype(np.float32),
                                 np.concatenate(sub_size).astype(np.float32), None, T_WC, K, W, H, near, far,
                                 splat_scale)
    parent = np.concatenate(parent)[seen]
    rest = ~split
    return tuple(np.concatenate([x[rest], y]) for x, y in zip(splats, (*sub, splats[4][parent], splats[5][parent])))


def _tangent_basis(n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors ``(S, 3)`` spanning the planes of the unit normals ``n (S, 3)``."""
    n = n / np.linalg.norm(n, axis=1, keepdims=True)
    helper = np.where(np.abs(n[:, :1]) < 0.9, np.array([[1.0, 0.0, 0.0]]), np.array([[0.0, 1.0, 0.0]]))
    t1 = np.cross(n, helper)
    t1 /= np.linalg.norm(t1, axis=1, keepdims=True)
    return t1, np.cross(n, t1)


def _splat_and_composite(u: np.ndarray, v: np.ndarray, z: np.ndarray, r: np.ndarray, gu: np.ndarray, gv: np.ndarray,
                         focal: float, W: int, H: int, eps: float, occlusion: float, window: int, fill_area: int
                         ) -> np.ndarray:
    """Steps 2-6: splat every point into its pyramid level (soft z-buffer), clean each level
    (visibility test, hole filling) and composite the levels into one (H, W) depth image."""
    # 2. pyramid level per point: radius below one level pixel (capped at the top level).
    # All levels live in one flat buffer, each level image padded by _PAD pixels so that
    # stamps need no bounds checks.
    top = max(0, int(np.floor(np.log2(max(1, min(W, H))))) - 2)
    scale = np.float32(2.0) ** np.clip(np.floor(np.log2(np.maximum(r, np.float32(0.25)) * 2)), 0, top)
    rl = np.minimum(r / scale, np.float32(1.5))
    fl = np.rint(vl := (v + np.float32(0.5)) / scale - np.float32(0.5))
    fk = np.rint(ul := (u + np.float32(0.5)) / scale - np.float32(0.5))
    levels = [(-(-H // 2**lv), -(-W // 2**lv)) for lv in range(top + 1)]
    strides = np.array([wl + 2 * _PAD for _, wl in levels])
    starts = np.concatenate([[0], np.cumsum([(hl + 2 * _PAD) * (wl + 2 * _PAD) for hl, wl in levels])])
    lvl = np.log2(scale).astype(np.int64)
    stride = strides[lvl]
    base = starts[lvl] + (fl.astype(np.int64) + _PAD) * stride + (fk.astype(np.int64) + _PAD)
    dv, du = vl - fl, ul - fk  # offsets of the point from its pixel centre, in [-0.5, 0.5]
    rho = r * z / np.float32(focal)  # m, the splat's disc radius (r [px] = f rho / z)
    flat = _soft_zbuffer(*_stamps(base, stride, dv, du, z, rl, gu * scale, gv * scale, rho), int(starts[-1]), eps)
    composite = []
    for lv in np.flatnonzero(np.bincount(lvl, minlength=top + 1)):
        hl, wl = levels[lv]
        img = flat[starts[lv]:starts[lv + 1]].reshape(hl + 2 * _PAD, wl + 2 * _PAD)[_PAD:-_PAD, _PAD:-_PAD]
        img = _hide_occluded(img, window, occlusion)
        img = _fill_small_holes(img, fill_area, eps)
        if lv > 0:
            img = img[(np.arange(H) >> int(lv))[:, None], (np.arange(W) >> int(lv))[None, :]]
        composite.append(img)
    if len(composite) == 1:
        return composite[0].astype(np.float32)
    return _composite_levels(composite, int(lvl.max()), eps, occlusion, window, fill_area)


def _stamps(base: np.ndarray, stride: np.ndarray, dv: np.ndarray, du: np.ndarray, z: np.ndarray, rl: np.ndarray,
            gu: np.ndarray, gv: np.ndarray, rho: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(flat pixel index, z, weight)`` of every pixel each splat covers: its own pixel and the
    neighbours within its radius ``rl`` [level px], weight ``1 / (1 + d^2 / r^2)``.

    Each covered pixel gets the depth of the splat's tangent plane at the pixel's centre:
    ``1/z + gu du + gv dv`` with ``(gu, gv)`` the inverse depth's slopes [1/(m level px)]
    (:func:`_inverse_depth_slopes`) and ``(du, dv)`` the pixel centre's offset from the splat's,
    shortened to the splat's radius where the centre lies outside it, and kept within the splat's
    disc radius ``rho`` [m] of its own depth (every point of the disc is that close to its centre):
    a wrong normal, at an edge or a corner, cannot bring a hidden point in front of the surface
    that hides it.
    """
    inv_r2 = np.float32(1.0) / np.maximum(rl, np.float32(0.5)) ** 2
    inv_z = np.float32(1.0) / z

    def plane_depth(inv_z, z, gu, gv, ou, ov, r, rho):
        reach = np.minimum(np.float32(1.0), r / np.maximum(np.sqrt(ou * ou + ov * ov), np.float32(1e-6)))
        w = inv_z + reach * (gu * ou + gv * ov)
        return np.clip(np.float32(1.0) / np.maximum(w, np.float32(1e-12)), np.maximum(z - rho, np.float32(0.5) * z),
                       z + rho)

    idx_parts = [base]
    z_parts = [plane_depth(inv_z, z, gu, gv, -du, -dv, rl, rho)]
    w_parts = [np.float32(1.0) / (np.float32(1.0) + (dv * dv + du * du) * inv_r2)]
    g = np.flatnonzero(rl >= 0.5)  # only these can reach a neighbouring pixel
    base, stride, dv, du, zg, rg, inv_r2 = base[g], stride[g], dv[g], du[g], z[g], rl[g], inv_r2[g]
    inv_z, gu, gv, rho, r2 = inv_z[g], gu[g], gv[g], rho[g], rg**2
    for di, dj in _NEIGHBOURS:
        d2 = (dv - di) ** 2 + (du - dj) ** 2
        k = np.flatnonzero(d2 <= r2)
        idx_parts.append(base[k] + di * stride[k] + dj)
        z_parts.append(plane_depth(inv_z[k], zg[k], gu[k], gv[k], dj - du[k], di - dv[k], rg[k], rho[k]))
        w_parts.append(np.float32(1.0) / (np.float32(1.0) + d2[k] * inv_r2[k]))
    return np.concatenate(idx_parts), np.concatenate(z_parts), np.concatenate(w_parts)


def _composite_levels(composite: list[np.ndarray], top_used: int, eps: float, occlusion: float, window: int,
                      fill_area: int) -> np.ndarray:
    """Step 6: composite full-resolution level images with the soft z-buffer rule, then clean
    where the levels meet."""
    H, W = composite[0].shape
    depth = np.zeros((H, W), dtype=np.float32)
    stack = np.stack(composite)
    a = np.where(stack > 0, stack, np.inf)
    zmin = a.min(axis=0)
    near_enough = np.isfinite(a) & (a <= zmin * (1.0 + eps))
    num = np.where(near_enough, a, 0.0).sum(axis=0)
    den = near_enough.sum(axis=0)
    hit = den > 0
    depth[hit] = num[hit] / den[hit]
    # where levels meet (and where a coarse level left a hole) the composite may have
    # holes up to one coarse pixel wide and leaks of a finer level through them
    depth = _hide_occluded(depth, window, occlusion)
    return _fill_small_holes(depth, max(fill_area, 2 * 4 ** top_used), eps)


def depth_to_points(depth: np.ndarray, K: np.ndarray, T_WC: np.ndarray) -> np.ndarray:
    """Back-project a z-depth image into world points (the inverse of the projection).

    Parameters
    ----------
    depth : (H, W) array
        Z-depth [m], ``0`` (or non-finite) where there is no data.
    K : (3, 3) array
        Pinhole intrinsics [px].
    T_WC : (4, 4) array
        Camera (optical frame) to world.

    Returns
    -------
    (M, 3) float array
        World points [m] of the valid pixels, in row-major pixel order.
    """
    d = np.asarray(depth, dtype=float)
    if d.ndim != 2:
        raise InputError("depth", f"expected an (H, W) image, got shape {d.shape}")
    T_WC, K, _, _ = _check_camera(T_WC, K, d.shape[1], d.shape[0])
    i, j = np.nonzero(np.isfinite(d) & (d > 0))
    z = d[i, j]
    x = (j - K[0, 2]) / K[0, 0] * z
    y = (i - K[1, 2]) / K[1, 1] * z
    pc = np.column_stack([x, y, z])
    return pc @ T_WC[:3, :3].T + T_WC[:3, 3]
