"""Heights over the surface below and to the surface above, measured on a point cloud.

The physics (``effects.md``) needs, for every vehicle position, ``d_down`` (height of the
body origin over the surface directly below it) and ``d_up`` (distance to the surface
directly above it). The paper measures them on the 3D scan of the EuRoC room; this module
answers both for many positions at once from a scene point cloud in the world frame W
(z up, metres).

Method
------
:class:`SurfaceIndex` bins the points into square columns of side ``cell`` in x, y and
sorts them, once, by one monotone key ``cell_id * span + (z - z_min)`` (``span`` is larger
than the cloud's z range, so the points of one column are contiguous and sorted by z).
A query at ``(x, y, z)`` looks at the columns of its *footprint* (the columns whose
centres lie within ``footprint`` of the centre of the query's column): for each such
column, one :func:`numpy.searchsorted` of the query's key finds the highest point not
above ``z`` and the lowest point above it. ``d_down`` is ``z`` minus the highest of those
below (over all footprint columns), ``d_up`` the lowest of those above minus ``z``.

Everything is vectorised over queries (one ``searchsorted`` call for all queries and all
footprint columns; the queries are sorted first so that the search walks the keys nearly
sequentially). Building on 1M points takes ~0.1 s and 100k queries of each ~0.1 s.

Behaviour worth knowing:

- A vehicle under a table: ``d_down`` is measured to the floor (the table is above), and
  ``d_up`` to the table's underside.
- Holes in a scan (real scans have them) are bridged by the footprint: with the default
  ``footprint = 1.5 * cell`` a query looks at its 3 x 3 columns, so an empty column under
  the vehicle does not make the floor vanish. A hole wider than the footprint gives the
  next surface below (or ``inf`` when there is none).
- Positions with no point below (above) in their footprint get ``np.inf``.
- Vertical surfaces count too: a vehicle whose footprint reaches a wall sees the wall's
  points just below and above it (``d_down``, ``d_up`` near 0). With 5 cm columns that
  means flying with the body origin within ~10 cm of the wall, which no multirotor does.

Sparse and holed floors
-----------------------
A floor given as a grid of points 20 cm apart (a synthetic floor plane, as a flight engineer writes one)
leaves most 5 cm columns empty, and so does a scanner's shadow under the tripod or the vehicle: the footprint
then finds no point below, and half of a Crazyflie's rows had no height (treated as far from every surface).
The index reads the cloud's *floor* (:attr:`SurfaceIndex.floor`): the plane through the lowest layer of its
columns (the top of their lowest :data:`FLOOR_LAYER_M`: a sampled mesh's floor slab has an underside), where at
least :data:`FLOOR_MIN_SHARE` of them lie within :data:`FLOOR_BAND_M` of one plane no steeper than 5 degrees and
at most :data:`FLOOR_MAX_BELOW` under it. A position over the floor's extent whose footprint finds nothing below
gets its height over that plane (:meth:`SurfaceIndex.d_down_filled` says which positions did); everything the
footprint finds is answered as before.

A floor sloping by :data:`TILTED_SCAN_DEG` or more (up to the 5 degrees of a floor) is a scan tilted against
the motion capture's world, whose z is gravity's: 1 degree moves the floor 5 cm over 3 m, and the blind probe's
hexarotor lost its ground effect to it. :meth:`SurfaceIndex.tilt` gives what levels it about the flight's own
centre (the heights there are kept; a constant offset left is what the gap finder's height-offset reading is for).

Noisy scans
-----------
A scanner (lidar, depth camera, photogrammetry) spreads a flat floor over a layer a few
millimetres to centimetres thick, and the highest point of a column sits about three standard
deviations above the true surface, more so the denser the scan: 5 mm of noise on a 5 M-point
scan read the floor 1.6 cm high, and a ground effect's ``mu`` 1.25 where it was 2. The index
therefore reads the scan's noise first (:func:`_scan_noise`: the spread of the largest cluster of
points in each block of :data:`SURFACE_CELLS` x :data:`SURFACE_CELLS` columns, the median over
blocks) and, where it is at least :data:`NOISE_EXACT_M`, answers with *surfaces* rather than
points: the points of one block whose heights follow each other within
:data:`SURFACE_GAP_SIGMAS` standard deviations form one surface, which lies at their median
height; in each column it starts at its lowest point there. A cluster that is no flat layer
(a wall, a table leg or a box's side chains the floor to what stands on it: its spread is many
times the noise, :data:`LAYER_IQR_SIGMAS`) keeps its points. ``d_down`` is then the
height over the median of the highest surface that starts below the query (0 inside its layer),
``d_up`` the distance to the median of the lowest surface that starts above it. A cloud without
measurable noise (a mesh sampled, a synthetic floor) is answered point by point as before, to the
bit. A scan too sparse to read its noise (under :data:`NOISE_MIN_POINTS` points in most blocks'
largest cluster) is read as exact too; the gap finder's height-offset reading
(:func:`uavturb.gap.surface_laws.height_offset`) is what then catches a floor read high.
"""

from __future__ import annotations

import numpy as np

from uavturb.errors import InputError
from uavturb.io.ply import surface_points

__all__ = ["SurfaceIndex", "sample_mesh_points"]

#: queries answered at once: the search holds a few (footprint columns, chunk) arrays, about 570 bytes a query
#: unchunked (570 MB for the million rows of a 200 Hz flight over an hour and a half)
QUERY_CHUNK = 1 << 15
#: m, scan noise (standard deviation of a flat surface's points) under which a cloud is answered point by point
NOISE_EXACT_M = 0.001
#: points a block's largest cluster needs for its spread to be read (fewer: read as no spread)
NOISE_MIN_POINTS = 8
#: standard deviations between consecutive heights of one column that part two surfaces (4: a gap that a
#: Gaussian layer of a few hundred points almost never shows, and two surfaces 2 cm apart stay apart under 5 mm
#: of noise)
SURFACE_GAP_SIGMAS = 4.0
#: m, the smallest such gap, and the one the noise is first read with (a floor's two faces 2 cm apart, a mesh's
#: slab, stay two surfaces)
SURFACE_GAP_MIN_M = 0.01
#: a cluster is a flat layer (answered by its median) where its interquartile range is within this many times a
#: layer's (the scan's noise), and its height range within :data:`LAYER_RANGE_GAPS` gaps (a Gaussian layer of a
#: few thousand points spans about 7.5 standard deviations)
LAYER_IQR_SIGMAS = 2.0
LAYER_RANGE_GAPS = 3.0
#: share of the cloud's columns whose lowest surface must lie on one plane for it to be read as the floor (a
#: sparse room scan's ceiling is the lowest surface of as many columns as its floor), and the most that may lie
#: under it (the floor is the lowest surface)
FLOOR_MIN_SHARE = 0.25
FLOOR_MAX_BELOW = 0.05
#: percentile of the columns' lowest surfaces the floor's plane is first sought at
FLOOR_START_PERCENTILE = 10.0
#: columns a floor needs
FLOOR_MIN_COLUMNS = 20
#: m, the bottom layer of a column whose top is the column's floor (a sampled mesh's 2 cm floor slab has an
#: underside), and how far that may lie from the floor's plane and count as floor, each plus three standard
#: deviations of the scan's noise
FLOOR_LAYER_M = 0.02
FLOOR_BAND_M = 0.01
#: the steepest plane read as a floor (5 degrees)
FLOOR_MAX_SLOPE = float(np.tan(np.radians(5.0)))
#: degrees, the floor slope from which a scan is read as tilted against the world (a built floor is level to a
#: tenth of a degree, and the motion capture's z is gravity's): heights are then levelled (:meth:`SurfaceIndex.tilt`)
TILTED_SCAN_DEG = 0.5
#: columns a side of the blocks whose points the surfaces are read on (3: the default footprint's 3 x 3 columns;
#: a scan of a few points a column still gives a block a median over tens)
SURFACE_CELLS = 3
#: 1.349 standard deviations make a normal distribution's interquartile range
IQR_PER_SIGMA = 1.349


def _check_points(points: np.ndarray, where: str) -> np.ndarray:
    try:
        p = np.asarray(points, dtype=float)
    except (TypeError, ValueError) as e:
        raise InputError(where, f"not a numeric array ({e})") from None
    if p.ndim != 2 or p.shape[1] != 3:
        raise InputError(where, f"expected an array of shape (P, 3), got {p.shape}")
    if len(p) == 0:
        raise InputError(where, "empty: no points")
    if not np.all(np.isfinite(p)):
        raise InputError(where, f"{int(np.sum(~np.all(np.isfinite(p), axis=1)))} point(s) are NaN or infinite")
    return p


def _cluster_starts(new_column: np.ndarray, z: np.ndarray, gap: float) -> np.ndarray:
    """Indices where a surface starts in heights ``z`` sorted within columns (``new_column``: (P,) bool, where a
    column starts): a new column, or a step up of more than ``gap`` [m]."""
    return np.flatnonzero(new_column | np.r_[True, np.diff(z) > gap])


def _scan_noise(new_column: np.ndarray, z: np.ndarray) -> tuple[float, float]:
    """The scan's noise [m] (standard deviation of a flat surface's points) and the gap [m] that parts surfaces.

    ``z``: (P,) heights sorted within columns, ``new_column`` where each column starts. Each column's largest
    cluster of points (its floor, a table top or a wall) gives a spread, its interquartile range over
    :data:`IQR_PER_SIGMA` (0 with under :data:`NOISE_MIN_POINTS` points: too few to tell); the noise is their
    median over columns, read again with the gap it implies until the gap settles (three times at most).
    """
    gap = SURFACE_GAP_MIN_M
    sigma = 0.0
    for _ in range(3):
        starts = _cluster_starts(new_column, z, gap)
        n = np.diff(np.r_[starts, len(z)])
        first = np.flatnonzero(new_column[starts])  # each column's first cluster, in cluster order
        largest = np.maximum.reduceat(n, first)
        col_of = np.cumsum(new_column[starts]) - 1  # each cluster's column
        pick = np.flatnonzero(n == largest[col_of])
        pick = pick[np.r_[True, col_of[pick][1:] != col_of[pick][:-1]]]  # the first of a column's largest
        a, m = starts[pick], n[pick]
        spread = np.where(m >= NOISE_MIN_POINTS, (z[a + 3 * (m - 1) // 4] - z[a + (m - 1) // 4]) / IQR_PER_SIGMA, 0.0)
        sigma = float(np.median(spread))
        new_gap = max(SURFACE_GAP_MIN_M, SURFACE_GAP_SIGMAS * sigma)
        if new_gap == gap:
            break
        gap = new_gap
    return sigma, gap


class SurfaceIndex:
    """Column index on a scene point cloud answering ``d_down`` and ``d_up`` queries.

    Parameters
    ----------
    points : (P, 3) array_like, float
        Scene points in the world frame W [m], z up.
    cell : float, optional
        Side of the square columns [m] (default 0.05).
    footprint : float, optional
        Radius [m] of the vehicle's disc over which "directly below/above" looks,
        resolved to columns: a column counts when its centre is within ``footprint`` of
        the centre of the query's column. Default ``1.5 * cell`` (the 3 x 3 columns
        around the query). ``0`` uses the query's column only.

    Raises
    ------
    InputError
        ``"point cloud"``: empty, not ``(P, 3)``, or NaN/inf values; or a non-positive
        ``cell`` / negative ``footprint``.

    Attributes
    ----------
    cell, footprint : float
        As given [m].
    offsets : (K, 2) int array
        The column offsets (dx, dy) of the footprint.
    n_points : int
        Number of points indexed.
    scan_noise_m : float
        The scan's noise read from the cloud [m] (standard deviation of a flat surface's points; 0 where
        the points of each block's largest cluster lie at one height, or are too few to tell).
    surface_gap_m : float or None
        Where the noise is at least :data:`NOISE_EXACT_M`: the height step [m] that parts two surfaces of a
        column, whose medians then answer the queries; None where points answer them.
    """

    def __init__(self, points: np.ndarray, cell: float = 0.05, footprint: float | None = None):
        p = _check_points(points, "point cloud")
        if not (np.isfinite(cell) and cell > 0):
            raise InputError("point cloud", f"cell size must be positive, got {cell}")
        if footprint is None:
            footprint = 1.5 * cell
        if not (np.isfinite(footprint) and footprint >= 0):
            raise InputError("point cloud", f"footprint must be >= 0, got {footprint}")
        self.cell = float(cell)
        self.footprint = float(footprint)
        self.n_points = len(p)

        k = int(np.floor(self.footprint / self.cell + 1e-9))
        d = np.arange(-k, k + 1)
        dx, dy = np.meshgrid(d, d, indexing="ij")
        keep = np.hypot(dx, dy) * self.cell <= self.footprint + 1e-9
        self.offsets = np.stack([dx[keep], dy[keep]], axis=1)
        self._k = k

        # Padded grid: points occupy columns [2k, n + 2k); queries whose whole footprint
        # stays inside the padded grid have columns in [k, n + 3k); others see no point.
        self._xy0 = p[:, :2].min(axis=0)
        ij = np.floor((p[:, :2] - self._xy0) / self.cell).astype(np.int64)
        n = ij.max(axis=0) + 1
        self._shape = n + 4 * k
        self._z0 = float(p[:, 2].min())
        zr = float(p[:, 2].max()) - self._z0
        self._gap = max(1.0, zr)  # key distance between the z ranges of adjacent columns
        self._span = zr + self._gap
        self._zrange = zr
        cid = (ij[:, 0] + 2 * k) * self._shape[1] + (ij[:, 1] + 2 * k)
        self._col_offsets = self.offsets[:, 0] * self._shape[1] + self.offsets[:, 1]
        z = p[:, 2] - self._z0  # m above z_min
        key = cid * self._span + z
        order = np.argsort(key)
        self._keys = key[order]
        self._surface_z: np.ndarray | None = None  # m above z_min, each key's surface (None: the key's own)
        self.scan_noise_m, self.surface_gap_m = 0.0, None
        self._read_surfaces(ij, z, order)
        #: the floor's plane ``z = c0 + c1 x + c2 y`` [m] (3,) and its extent ``(x_min, y_min, x_max, y_max)`` [m],
        #: or None where no plane holds most columns' lowest surface
        self.floor: tuple[np.ndarray, np.ndarray] | None = self._read_floor()

    def _read_surfaces(self, ij: np.ndarray, z: np.ndarray, order: np.ndarray) -> None:
        """Where the scan is noisy, replace each column's points by its surfaces (keys at their lowest point,
        ``_surface_z`` their median), read on blocks of :data:`SURFACE_CELLS` x :data:`SURFACE_CELLS` columns.

        ``ij`` (P, 2) the points' columns, ``z`` (P,) their heights above ``z_min`` [m], ``order`` the sort of
        the keys."""
        block = ij // SURFACE_CELLS
        bid = block[:, 0] * (int(block[:, 1].max()) + 1) + block[:, 1]
        by_block = np.argsort(bid * self._span + z)
        zb = z[by_block]
        new_block = np.r_[True, bid[by_block][1:] != bid[by_block][:-1]]
        self.scan_noise_m, gap = _scan_noise(new_block, zb)
        if self.scan_noise_m < NOISE_EXACT_M:
            return
        starts = _cluster_starts(new_block, zb, gap)
        n = np.diff(np.r_[starts, len(zb)])
        # a surface is a flat layer: a cluster that also holds a wall, a leg or a table's edge (points chained
        # from the floor up) keeps its points, as an exact scan does
        iqr = zb[starts + 3 * (n - 1) // 4] - zb[starts + (n - 1) // 4]
        flat = (iqr <= LAYER_IQR_SIGMAS * IQR_PER_SIGMA * self.scan_noise_m) \
            & (zb[starts + n - 1] - zb[starts] <= LAYER_RANGE_GAPS * gap)
        median = np.repeat(zb[starts + (n - 1) // 2], n)
        level = np.empty_like(z)
        level[by_block] = np.where(np.repeat(flat, n), median, zb)  # each point's surface: its layer's median
        # within a column the levels rise with the points' heights (a block's surfaces are disjoint height
        # ranges), so the column's surfaces are its runs of one level, each keyed at its lowest point
        level = level[order]
        column = np.floor(self._keys / self._span)
        first = np.flatnonzero(np.r_[True, (column[1:] != column[:-1]) | (level[1:] != level[:-1])])
        self._keys, self._surface_z, self.surface_gap_m = self._keys[first], level[first], gap

    def _read_floor(self) -> tuple[np.ndarray, np.ndarray] | None:
        """The plane through most columns' lowest surface (three rounds of a least-squares fit on the columns
        within the band of the last), and the extent of those columns; None where there is no such plane."""
        column = np.floor(self._keys / self._span)
        first = np.flatnonzero(np.r_[True, column[1:] != column[:-1]])
        if len(first) < FLOOR_MIN_COLUMNS:
            return None
        cid = column[first].astype(np.int64)
        ny = self._shape[1]
        centre = self._xy0 + (np.stack([cid // ny, cid % ny], axis=1) - 2 * self._k + 0.5) * self.cell
        band = FLOOR_BAND_M + 3.0 * self.scan_noise_m
        # each column's lowest layer, at its top (a slab's underside, as a sampled mesh has, is no floor)
        top = np.searchsorted(self._keys, self._keys[first] + FLOOR_LAYER_M + 3.0 * self.scan_noise_m,
                              side="right") - 1
        low = (self._keys[top] - column[first] * self._span if self._surface_z is None
               else self._surface_z[top]) + self._z0
        A = np.c_[np.ones(len(low)), centre]
        on = np.abs(low - np.percentile(low, FLOOR_START_PERCENTILE)) <= band
        for _ in range(3):
            if on.sum() < 3:
                return None
            coef = np.linalg.lstsq(A[on], low[on], rcond=None)[0]
            on = np.abs(low - A @ coef) <= band
        below = np.sum(low < A @ coef - band - FLOOR_LAYER_M)  # a slab's underside, where its top is missing
        if on.sum() < max(FLOOR_MIN_COLUMNS, FLOOR_MIN_SHARE * len(low)) or below > FLOOR_MAX_BELOW * len(low) \
                or np.hypot(*coef[1:]) > FLOOR_MAX_SLOPE:
            return None
        xy = centre[on]
        return coef, np.r_[xy.min(axis=0) - 0.5 * self.cell, xy.max(axis=0) + 0.5 * self.cell]

    # -- queries --------------------------------------------------------------------

    def _search(self, positions: np.ndarray, up: bool) -> np.ndarray:
        q = np.asarray(positions, dtype=float)
        single = q.ndim == 1
        if single:
            q = q[None]
        if q.ndim != 2 or q.shape[1] != 3:
            raise InputError("positions", f"expected an array of shape (N, 3), got {np.shape(positions)}")
        if not np.all(np.isfinite(q)):
            raise InputError("positions", "NaN or infinite positions")
        out = np.full(len(q), np.inf)
        if len(q) == 0:
            return out[0] if single else out
        k, ny = self._k, self._shape[1]
        ij = np.floor((q[:, :2] - self._xy0) / self.cell) + 2 * k
        inside = np.all((ij >= k) & (ij < self._shape - k), axis=1)
        cid = ij[:, 0] * ny + ij[:, 1]  # float, exact for any realistic grid
        zoff = np.clip(q[:, 2] - self._z0, -0.5 * self._gap, self._zrange + 0.5 * self._gap)
        key = np.where(inside, cid * self._span + zoff, -np.inf)
        order = np.argsort(key) if len(q) > 1 else np.zeros(1, dtype=np.intp)
        key_s, cid_s, z_s, zoff_s = key[order], cid[order], q[order, 2], zoff[order]
        d = np.empty(len(q))
        for a in range(0, len(q), QUERY_CHUNK):  # (footprint columns, chunk) arrays: memory bounded
            b = slice(a, a + QUERY_CHUNK)
            d[b] = self._nearest_in_columns(cid_s[b], zoff_s[b], z_s[b], up)
        d = np.where(np.isfinite(key_s), np.maximum(d, 0.0), np.inf)
        out[order] = d
        return out[0] if single else out

    def _nearest_in_columns(self, cid: np.ndarray, zoff: np.ndarray, z: np.ndarray, up: bool) -> np.ndarray:
        """(N,) m, distance from each query (column id ``cid``, height ``z`` and its key offset ``zoff``, sorted
        by key) to the nearest point below (``up`` False) or above it over its footprint's columns."""
        base = (cid[None, :] + self._col_offsets[:, None]) * self._span  # (K, N) column starts
        keys = self._keys
        i = np.searchsorted(keys, (base + zoff[None, :]).ravel(), side="right").reshape(base.shape)
        j = np.minimum(i, len(keys) - 1) if up else np.maximum(i - 1, 0)
        found = keys[j]
        if up:
            ok = (i < len(keys)) & (found <= base + self._zrange + 0.25 * self._gap)
        else:
            ok = (i > 0) & (found >= base - 0.25 * self._gap)
        # the surface's height: the point's own, or the median of the surface that starts there (noisy scans)
        level = found - base + self._z0 if self._surface_z is None else self._surface_z[j] + self._z0
        return np.where(ok, level - z[None, :] if up else z[None, :] - level, np.inf).min(axis=0)

    def d_down(self, positions: np.ndarray) -> np.ndarray:
        """Height [m] of each position over the highest surface point below it.

        Parameters
        ----------
        positions : (N, 3) array_like or (3,)
            Body-origin positions in W [m].

        Returns
        -------
        (N,) float array (a float for a single ``(3,)`` position)
            ``z`` minus the highest cloud point with height ``<= z`` in the footprint (the median of its
            surface, on a noisy scan); where there is none, the height over the floor's plane, within its
            extent (:meth:`d_down_filled`); ``np.inf`` elsewhere.
        """
        d, _ = self.d_down_filled(positions)
        return d[0] if np.ndim(positions) == 1 else d

    def d_down_filled(self, positions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`d_down`, and which positions found no point below in their footprint and were answered by the
        floor's plane (:attr:`floor`).

        Parameters
        ----------
        positions : (N, 3) array_like, positions in W [m]

        Returns
        -------
        d : (N,) m, as :meth:`d_down`
        filled : (N,) bool, the positions whose height is over the floor's plane
        """
        d = np.atleast_1d(self._search(positions, up=False))  # checks the positions' shape and values
        q = np.asarray(positions, dtype=float).reshape(-1, 3)
        filled = np.zeros(len(d), dtype=bool)
        if self.floor is None or len(d) == 0:
            return d, filled
        coef, (x0, y0, x1, y1) = self.floor
        plane = coef[0] + q[:, :2] @ coef[1:]
        filled = np.isinf(d) & (q[:, 0] >= x0) & (q[:, 0] <= x1) & (q[:, 1] >= y0) & (q[:, 1] <= y1) \
            & (q[:, 2] >= plane)
        d = np.where(filled, q[:, 2] - plane, d)
        return d, filled

    def tilt(self, positions: np.ndarray) -> tuple[np.ndarray, float] | None:
        """Where the floor's plane slopes by :data:`TILTED_SCAN_DEG` or more: how much higher the plane lies at
        each position than at the positions' mean (the heights a tilted scan gets wrong: the scan levelled about
        the flight's centre answers at a position what it answers that much higher), and the slope.

        Parameters
        ----------
        positions : (N, 3) array_like, positions in W [m]

        Returns
        -------
        (correction (N,) m, slope degrees), or None where the floor is level (or not read)
        """
        if self.floor is None:
            return None
        coef = self.floor[0]
        slope = float(np.degrees(np.arctan(np.hypot(*coef[1:]))))
        q = np.asarray(positions, dtype=float).reshape(-1, 3)
        if slope < TILTED_SCAN_DEG or len(q) == 0:
            return None
        return (q[:, :2] - q[:, :2].mean(axis=0)) @ coef[1:], slope

    def d_up(self, positions: np.ndarray) -> np.ndarray:
        """Distance [m] from each position up to the lowest surface point above it.

        Parameters
        ----------
        positions : (N, 3) array_like or (3,)
            Body-origin positions in W [m].

        Returns
        -------
        (N,) float array (a float for a single ``(3,)`` position)
            The lowest cloud point with height ``> z`` in the footprint, minus ``z``;
            ``np.inf`` where there is none.
        """
        return self._search(positions, up=True)

    def __repr__(self) -> str:
        return (f"SurfaceIndex({self.n_points} points, cell={self.cell:g} m, footprint={self.footprint:g} m, "
                f"{len(self.offsets)} columns)")


def sample_mesh_points(mesh, spacing: float, seed: int | None = 0) -> np.ndarray:
    """A scan-like point cloud of a mesh: points uniformly distributed over its area.

    Parameters
    ----------
    mesh : trimesh.Trimesh
        Triangle mesh [m].
    spacing : float
        Mean point spacing [m]: ``ceil(area / spacing**2)`` points are drawn.
    seed : int or None, optional
        Seed of the random generator (deterministic for an int).

    Returns
    -------
    (P, 3) float array
        Points on the mesh surface [m], in the mesh's frame (:func:`uavturb.io.ply.surface_points`).

    Raises
    ------
    InputError
        ``"mesh"`` when it has no area; ``"spacing"`` when not positive.
    """
    return surface_points(np.asarray(getattr(mesh, "triangles", np.empty((0, 3, 3))), dtype=float), spacing, seed)
