"""Reference trajectories through a scene, and closed-loop flights along them.

The paper (section "Large-scale generation of simulated UAV trajectory data") samples
random points on the scene's navigation mesh, orders them by solving a travelling
salesman problem with the Christofides algorithm, inserts extra points so that no leg
crosses a wall, and follows straight lines between them with the yaw facing forward;
an MPC flies the drone along this reference and collisions are checked. This module
does the same on a :class:`~uavturb.sim.scenes.Scene`:

1. **Navigation map** (:class:`NavGrid`): :meth:`Scene.free_space_grid` at a cruise
   height ``z_c`` (drawn per trajectory) with a clearance margin and a height band, plus
   the height of the surface below every cell (:func:`~uavturb.sim.scenes.height_below`
   from ``z_c``). A cell is *flat* when that surface is level within ``flat_tol`` over a
   window of ``±flat_radius`` around it: the vehicle can then go straight down there to a
   floor cell (surface at floor level) or a *top* cell (furniture top, bed, sofa seat...).
2. **Points**: a floor start point, then random floor, top and free cells of the main
   connected component of the map, at least ``min_spacing`` apart.
3. **Order**: Christofides (:func:`networkx.algorithms.approximation.christofides`) on the
   complete graph whose edge weights are the shortest grid-path lengths between points
   (8-connected Dijkstra on the free cells), then cut into an open path at the start.
4. **Legs**: a straight line when its grid cells are free, else the A* grid path
   (:func:`astar`, octile heuristic) simplified to its corner points (line-of-sight
   string pulling, :func:`simplify_path`). Straight segments at cruise height, stop and go
   (each segment starts and ends at rest, :class:`~uavturb.sim.references.Waypoints`),
   the yaw turned in place at every corner to face the next segment.
5. **Altitude profile** (where ground effect matters): take-off from rest on the floor,
   low hovers and landings at floor and top points (heights drawn log-uniformly in
   ``low_heights``, since the ground effect grows as ``1/d^2``), and *edge passes*: from a
   low hover over a furniture top the vehicle slides sideways at that height past the
   edge, and sometimes back onto the top, so the surface below drops or rises while
   the forward camera cannot see it (the paper's negative measurement delay). The flight
   ends landed.

The output is a :class:`~uavturb.sim.references.Reference` (position, velocity,
acceleration, jerk and yaw as functions of time) that both controllers consume.

Flights: :func:`fly_trajectory` (the one call the dataset generator needs)
--------------------------------------------------------------------------
``fly_trajectory(scene, vehicle, seed, controller="mpc", camera_rate=20.0, ...)`` plans a
reference as above and flies it in closed loop:

- physics every ``1 / physics_rate`` s (default 200 Hz): one RK4 step of the one model of
  :mod:`uavturb.physics.dynamics` with the effects of ``effects.md`` (default: the
  simulator's ground effect, ``mu = 2``) evaluated with the actual rotor speeds and the
  heights ``d_down``/``d_up`` over the scene (exact box queries of :mod:`~uavturb.sim.scenes`,
  refreshed at the control rate and followed by the height change in between);
- control every ``1 / control_rate`` s: ``controller="mpc"`` (:class:`~uavturb.sim.mpc.MPCController`,
  default 25 Hz, a real-time-iteration MPC on the full quaternion model with rotor-speed
  bounds) or ``"geometric"`` (:class:`~uavturb.sim.controller.GeometricController`, default
  200 Hz);
- samples every ``1 / camera_rate`` s (the camera frames);
- collision check of the position at every physics step (:func:`collides`: boxes grown by
  the vehicle's radius ``arm_length + rotor_radius`` horizontally and half the landed
  height vertically), in batches of one second of flight: a flight that hits something is
  truncated one frame before the hit (``info["collided"]``, ``info["collisions"]``).

Returns ``(states (T, 13), rotor_speeds (T, N), t (T,), info)``: states are ``p`` [m] in W,
``q`` (w, x, y, z, body to world), ``v`` [m/s] in W, ``w`` [rad/s] in B; ``rotor_speeds``
[rad/s] the actual speeds applied over the frame's instant; ``t`` [s] from the flight's
start; ``info`` holds ``d_down`` (T,) [m] height of the body over the surface below,
``effect_force`` (T, 3) [N] in W, ``reference`` (a :class:`Setpoint` of K=T samples),
``phases``, the plan, timing figures and the collision report.
"""

from __future__ import annotations

import heapq
import math
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from uavturb.errors import InputError
from uavturb.sim.references import Reference, _Plan
from uavturb.sim.scenes import Scene, height_above, height_below, inside_obstacle

__all__ = ["PlanConfig", "NavGrid", "PlannedTrajectory", "plan_trajectory", "christofides_order", "astar",
           "simplify_path", "collides", "fly_trajectory", "CONTROLLERS"]

CONTROLLERS = ("mpc", "geometric")
_SQRT2 = math.sqrt(2.0)


@dataclass(frozen=True)
class PlanConfig:
    """How a reference trajectory is drawn.

    Attributes
    ----------
    n_points : int, random points per trajectory (start included)
    cruise_height : (2,) m, range of the cruise height (above tables, desks, counters and
        sofa backs of generated scenes, below shelves and door lintels)
    height_band : m, half-height of the slab kept free around the cruise height
    clearance : m, horizontal clearance from obstacles of the cruise map
    resolution : m, cell size of the navigation grid
    flat_radius : m, half-side of the window that must be level under a descent point
    flat_tol : m, level tolerance of that window
    min_spacing : m, smallest distance between two random points
    top_share : probability that a point lies over a furniture top (when there are some)
    floor_share : probability that a non-top point is a floor point (descent there)
    land_share : probability of landing (rather than a low hover) at a descent point
    edge_share : probability of an edge pass after a top visit
    edge_back_share : probability that an edge pass comes back onto the top
    low_heights : (2,) m, range (log-uniform) of the low-hover heights over the surface
    rest_height : m, height of the body origin over the surface when landed (the model has no
        contact: "landed" is a hover there); ``None``: ``clip(0.6 rotor radius, 0.02, 0.06)``
    speed : m/s, peak horizontal speed of a cruise segment
    vertical_speed : m/s, peak speed of climbs and descents
    edge_speed : m/s, peak speed of an edge pass
    acc : m/s^2, peak acceleration of a move
    yaw_rate : rad/s, peak yaw rate of a turn
    yaw_acc : rad/s^2, peak yaw acceleration of a turn
    hold : (2,) s, range of hover durations
    """

    n_points: int = 5
    cruise_height: tuple[float, float] = (1.1, 1.35)
    height_band: float = 0.15
    clearance: float = 0.25
    resolution: float = 0.1
    flat_radius: float = 0.12
    flat_tol: float = 0.01
    min_spacing: float = 0.8
    top_share: float = 0.5
    floor_share: float = 0.6
    land_share: float = 0.4
    edge_share: float = 0.7
    edge_back_share: float = 0.5
    low_heights: tuple[float, float] = (0.04, 0.5)
    rest_height: float | None = None
    speed: float = 1.0
    vertical_speed: float = 0.5
    edge_speed: float = 0.6
    acc: float = 1.5
    yaw_rate: float = 1.5
    yaw_acc: float = 3.0
    hold: tuple[float, float] = (0.5, 1.5)

    def rest_for(self, rotor_radius: float) -> float:
        """Landed height [m] of the body origin for a vehicle of this rotor radius [m]."""
        if self.rest_height is not None:
            return float(self.rest_height)
        return float(np.clip(0.6 * rotor_radius, 0.02, 0.06))


# --- navigation grid --------------------------------------------------------------------------


_MOVES = ((1, 0, 1.0), (-1, 0, 1.0), (0, 1, 1.0), (0, -1, 1.0),
          (1, 1, _SQRT2), (1, -1, _SQRT2), (-1, 1, _SQRT2), (-1, -1, _SQRT2))


@dataclass
class NavGrid:
    """The navigation map of one cruise height.

    Attributes
    ----------
    occ : (nx, ny) bool, occupied cells (``True``); cell ``[i, j]`` is centred at ``origin + (i, j) res``
    origin : (2,) m, world x, y of cell ``[0, 0]``
    res : m, cell size
    z : m, cruise height of the map
    surface : (nx, ny) m, height of the surface below each cell seen from ``z`` (``-inf``: none)
    flat : (nx, ny) bool, free cells over a level surface (``±flat_radius`` window)
    """

    occ: np.ndarray
    origin: np.ndarray
    res: float
    z: float
    surface: np.ndarray
    flat: np.ndarray

    @property
    def shape(self) -> tuple[int, int]:
        return self.occ.shape  # type: ignore[return-value]

    def to_cell(self, xy: np.ndarray) -> np.ndarray:
        """Nearest cell indices ``(K, 2)`` int of world points ``xy (K, 2)`` [m] (clipped to the grid)."""
        ij = np.rint((np.atleast_2d(xy) - self.origin) / self.res).astype(int)
        return np.clip(ij, 0, np.array(self.shape) - 1)

    def to_world(self, ij: np.ndarray) -> np.ndarray:
        """World x, y ``(K, 2)`` [m] of cell centres ``ij (K, 2)``."""
        return self.origin + np.atleast_2d(ij) * self.res

    def free_at(self, xy: np.ndarray) -> np.ndarray:
        """Whether world points ``xy (K, 2)`` fall in free cells (outside the grid: occupied)."""
        xy = np.atleast_2d(np.asarray(xy, float))
        ij = np.rint((xy - self.origin) / self.res).astype(int)
        ok = (ij >= 0).all(1) & (ij < np.array(self.shape)).all(1)
        out = np.zeros(len(xy), bool)
        out[ok] = ~self.occ[ij[ok, 0], ij[ok, 1]]
        return out

    def segment_free(self, a: np.ndarray, b: np.ndarray) -> bool:
        """Whether the straight segment ``a → b`` (world x, y [m]) crosses free cells only: every
        cell the segment passes through (exact grid traversal: the cells of the midpoints
        between consecutive crossings of cell boundaries)."""
        u0 = (np.asarray(a, float)[:2] - self.origin) / self.res + 0.5  # cell i spans [i, i + 1)
        u1 = (np.asarray(b, float)[:2] - self.origin) / self.res + 0.5
        d = u1 - u0
        ts = [np.array([0.0, 1.0])]
        for ax in range(2):
            if abs(d[ax]) > 1e-12:
                lo, hi = sorted((u0[ax], u1[ax]))
                k = np.arange(np.floor(lo) + 1, np.ceil(hi))
                ts.append((k - u0[ax]) / d[ax])
        t = np.unique(np.clip(np.concatenate(ts), 0.0, 1.0))
        mid = (t[:-1] + t[1:]) / 2 if len(t) > 1 else np.array([0.0])
        ij = np.floor(u0 + mid[:, None] * d).astype(int)
        if ((ij < 0) | (ij >= np.array(self.shape))).any():
            return False
        ends = np.stack([np.asarray(a, float)[:2], np.asarray(b, float)[:2]])
        return not self.occ[ij[:, 0], ij[:, 1]].any() and bool(self.free_at(ends).all())

    def graph(self) -> tuple[Any, np.ndarray]:
        """Sparse 8-connected graph of the free cells (diagonal moves only where both
        orthogonal neighbours are free), weights in metres; and the node index of every cell
        (``-1`` for occupied ones)."""
        from scipy.sparse import coo_matrix

        free = ~self.occ
        nx, ny = self.shape
        node = np.full((nx, ny), -1, dtype=np.int64)
        node[free] = np.arange(int(free.sum()))
        cells = np.argwhere(free)
        rows, cols, w = [], [], []
        for di, dj, c in ((1, 0, 1.0), (0, 1, 1.0), (1, 1, _SQRT2), (1, -1, _SQRT2)):  # each edge once
            n = cells + (di, dj)
            ok = (n[:, 0] >= 0) & (n[:, 0] < nx) & (n[:, 1] >= 0) & (n[:, 1] < ny)
            a, n = cells[ok], n[ok]
            ok = free[n[:, 0], n[:, 1]]
            if di and dj:  # no corner cutting
                ok &= free[a[:, 0] + di, a[:, 1]] & free[a[:, 0], a[:, 1] + dj]
            rows.append(node[a[ok, 0], a[ok, 1]])
            cols.append(node[n[ok, 0], n[ok, 1]])
            w.append(np.full(int(ok.sum()), c * self.res))
        m = int(free.sum())
        r, c_, ww = np.concatenate(rows), np.concatenate(cols), np.concatenate(w)
        g = coo_matrix((np.r_[ww, ww], (np.r_[r, c_], np.r_[c_, r])), shape=(m, m)).tocsr()
        return g, node


def build_grid(scene: Scene, z: float, config: PlanConfig = PlanConfig()) -> NavGrid:
    """The :class:`NavGrid` of ``scene`` at cruise height ``z`` [m]."""
    occ, origin, res = scene.free_space_grid(z, config.resolution, config.clearance, config.height_band)
    nx, ny = occ.shape
    gi, gj = np.meshgrid(np.arange(nx), np.arange(ny), indexing="ij")
    xy = origin + np.c_[gi.ravel(), gj.ravel()] * res
    d = height_below(scene, np.c_[xy, np.full(len(xy), z)])
    surface = (z - d).reshape(nx, ny)
    surface[~np.isfinite(surface)] = -np.inf
    from scipy import ndimage

    k = int(np.ceil(config.flat_radius / res))
    size = 2 * k + 1
    s_fin = np.where(np.isfinite(surface), surface, -1e3)
    hi = ndimage.maximum_filter(s_fin, size=size, mode="nearest")
    lo = ndimage.minimum_filter(s_fin, size=size, mode="nearest")
    flat = (~occ) & (hi - lo <= config.flat_tol) & np.isfinite(surface)
    return NavGrid(occ, np.asarray(origin, float), float(res), float(z), surface, flat)


def astar(occ: np.ndarray, start: tuple[int, int], goal: tuple[int, int]) -> list[tuple[int, int]]:
    """Shortest 8-connected path between two free cells of an occupancy grid (A*, octile
    heuristic, no corner cutting).

    Parameters
    ----------
    occ : (nx, ny) bool, ``True`` = occupied
    start, goal : cell indices ``(i, j)``

    Returns
    -------
    list of cells from ``start`` to ``goal`` inclusive; empty when the goal is unreachable.
    """
    nx, ny = occ.shape
    start, goal = (int(start[0]), int(start[1])), (int(goal[0]), int(goal[1]))
    if occ[start] or occ[goal]:
        return []

    def h(c: tuple[int, int]) -> float:
        dx, dy = abs(c[0] - goal[0]), abs(c[1] - goal[1])
        return (dx + dy) + (_SQRT2 - 2.0) * min(dx, dy)

    g = {start: 0.0}
    parent: dict[tuple[int, int], tuple[int, int]] = {}
    heap = [(h(start), 0, start)]
    counter = 0
    closed: set[tuple[int, int]] = set()
    while heap:
        _, _, c = heapq.heappop(heap)
        if c == goal:
            path = [c]
            while c in parent:
                c = parent[c]
                path.append(c)
            return path[::-1]
        if c in closed:
            continue
        closed.add(c)
        for di, dj, cost in _MOVES:
            n = (c[0] + di, c[1] + dj)
            if not (0 <= n[0] < nx and 0 <= n[1] < ny) or occ[n]:
                continue
            if di and dj and (occ[c[0] + di, c[1]] or occ[c[0], c[1] + dj]):
                continue
            gn = g[c] + cost
            if gn < g.get(n, np.inf):
                g[n] = gn
                parent[n] = c
                counter += 1
                heapq.heappush(heap, (gn + h(n), counter, n))
    return []


def simplify_path(grid: NavGrid, xy: np.ndarray) -> np.ndarray:
    """Corner points of a grid path: from each kept point, jump to the farthest later point
    in straight free line of sight (string pulling).

    Parameters
    ----------
    grid : NavGrid
    xy : (K, 2) m, the path's points

    Returns
    -------
    (L, 2) m, ``L <= K``, first and last points kept; every segment is free in ``grid``.
    """
    xy = np.asarray(xy, float)
    out = [xy[0]]
    i = 0
    while i < len(xy) - 1:
        j = len(xy) - 1
        while j > i + 1 and not grid.segment_free(xy[i], xy[j]):
            j -= 1
        out.append(xy[j])
        i = j
    return np.asarray(out)


def christofides_order(lengths: np.ndarray, start: int = 0) -> list[int]:
    """Visiting order of points from a symmetric matrix of path lengths: the Christofides
    tour (networkx) rotated to begin at ``start`` and opened there by dropping the longer of
    its two edges at ``start`` (the tour is walked in the direction that keeps the shorter).

    Parameters
    ----------
    lengths : (n, n) m, finite, symmetric, zero diagonal (a metric: shortest-path lengths)
    start : index of the first point

    Returns
    -------
    list of the ``n`` point indices, each once, beginning with ``start``.
    """
    import networkx as nx
    from networkx.algorithms.approximation import christofides

    n = len(lengths)
    if n <= 2:
        return [start] + [i for i in range(n) if i != start]
    G = nx.Graph()
    for i in range(n):
        for j in range(i + 1, n):
            G.add_edge(i, j, weight=float(lengths[i, j]))
    cycle = christofides(G, weight="weight")[:-1]  # closed tour, first node repeated at the end
    k = cycle.index(start)
    order = cycle[k:] + cycle[:k]
    # open the tour by dropping the longer of the two edges at the start
    if lengths[start, order[1]] > lengths[start, order[-1]]:
        order = [start] + order[1:][::-1]
    return order


# --- plans -------------------------------------------------------------------------------------


@dataclass
class PlannedTrajectory:
    """A reference trajectory and how it was built.

    Attributes
    ----------
    reference : Reference (``notes``: phases as ``(t0, t1)`` intervals, see :func:`plan_trajectory`)
    points : (n, 3) m, the random points (x, y and the surface height below them)
    kinds : list of n str, ``'floor'``, ``'top'`` or ``'free'``
    order : list of n int, Christofides visiting order
    corners : (W, 3) m, the planned waypoints in time order (after A* insertion)
    grid : NavGrid, the cruise map
    seed : int
    """

    reference: Reference
    points: np.ndarray
    kinds: list
    order: list
    corners: np.ndarray
    grid: NavGrid
    seed: int
    lengths: np.ndarray = field(repr=False, default_factory=lambda: np.zeros((0, 0)))


def _log_uniform(rng: np.random.Generator, lo_hi: tuple[float, float]) -> float:
    lo, hi = lo_hi
    return float(np.exp(rng.uniform(np.log(lo), np.log(hi))))


def _wrap_to(yaw: float, near: float) -> float:
    """``yaw`` [rad] shifted by a multiple of 2 pi to lie within pi of ``near``."""
    return near + (yaw - near + np.pi) % (2 * np.pi) - np.pi


class _Builder:
    """Appends moves to a :class:`_Plan`, with yaw facing forward on horizontal moves."""

    def __init__(self, plan: _Plan, config: PlanConfig):
        self.plan, self.c = plan, config

    @property
    def p(self) -> np.ndarray:
        return self.plan.p

    def face(self, target_xy: np.ndarray, phase: str = "turn") -> None:
        d = np.asarray(target_xy, float)[:2] - self.p[:2]
        if np.hypot(*d) < 1e-6:
            return
        yaw = _wrap_to(math.atan2(d[1], d[0]), self.plan.yaw)
        if abs(yaw - self.plan.yaw) > 1e-3:
            self.plan.move(self.p, yaw, phase=phase)

    def horizontal(self, xy: np.ndarray, speed: float, phase: str) -> None:
        self.face(xy)
        self.plan.move(np.r_[np.asarray(xy, float)[:2], self.p[2]], speed=speed, phase=phase)

    def vertical(self, z: float, phase: str) -> None:
        if abs(z - self.p[2]) > 1e-6:
            self.plan.move(np.r_[self.p[:2], z], speed=self.c.vertical_speed, phase=phase)

    def hold(self, rng: np.random.Generator, phase: str) -> None:
        self.plan.hold(float(rng.uniform(*self.c.hold)), phase)


def _edge_pass(b: _Builder, grid: NavGrid, rng: np.random.Generator, surface: float) -> bool:
    """From a low hover over a top of height ``surface``, slide sideways past its edge at the
    same height (the surface below drops), and with probability ``edge_back_share`` back onto
    the top (it rises); returns whether a free pass was found (and appended)."""
    z = b.p[2]
    dirs = [np.array(d, float) for d in ((1, 0), (-1, 0), (0, 1), (0, -1), (1, 1), (1, -1), (-1, 1), (-1, -1))]
    order = rng.permutation(len(dirs))
    S = np.where(np.isfinite(grid.surface), grid.surface, -1e3)
    from scipy import ndimage

    k = int(np.ceil(b.c.flat_radius / grid.res))  # vehicle radius plus margin, in cells
    S_max = ndimage.maximum_filter(S, size=2 * k + 1, mode="nearest")
    for o in order:
        d = dirs[o] / np.linalg.norm(dirs[o])
        for length in (float(rng.uniform(0.4, 0.9)), 0.4):
            end = b.p[:2] + length * d
            n = int(np.ceil(length / (0.25 * grid.res))) + 1
            pts = b.p[:2] + np.linspace(0, 1, n)[:, None] * (end - b.p[:2])
            ij = grid.to_cell(pts)
            inside = ((np.rint((pts - grid.origin) / grid.res) >= 0).all(1)
                      & (np.rint((pts - grid.origin) / grid.res) < np.array(grid.shape)).all(1)).all()
            if not inside:
                continue
            below = S_max[ij[:, 0], ij[:, 1]]
            e = grid.to_cell(end)[0]
            # clear at this height all the way, the surface below changes, and the end is a
            # descent-safe point of the cruise map (to climb back)
            if (below.max() <= surface + 0.005 and grid.surface[e[0], e[1]] < surface - 0.1
                    and grid.flat[e[0], e[1]] and z - grid.surface[e[0], e[1]] > 0):
                start = b.p[:2].copy()
                b.horizontal(end, b.c.edge_speed, "edge_pass")
                if rng.random() < b.c.edge_back_share:  # and back onto the top: the surface rises
                    b.hold(rng, "hover_low")
                    b.horizontal(start, b.c.edge_speed, "edge_pass")
                return True
    return False


def plan_trajectory(scene: Scene, seed: int, config: PlanConfig = PlanConfig(), rotor_radius: float = 0.01,
                    name: str | None = None, vehicle_radius: float = 0.0) -> PlannedTrajectory:
    """A reference trajectory through ``scene``, fixed by ``seed``.

    Parameters
    ----------
    scene : Scene (generated or external; external meshes use mesh sections and ray casts)
    seed : int
    config : PlanConfig
    rotor_radius : m, sets the landed height (see :meth:`PlanConfig.rest_for`)
    name : the reference's name (default ``traj-<seed>``)
    vehicle_radius : m, centre to rotor tip (``arm_length + rotor_radius``); the clearance and
        the level window under descents grow to at least ``vehicle_radius + 0.1`` and
        ``vehicle_radius + 0.05`` (the defaults fit the 50 g quadrotor, radius 0.056 m)

    Returns
    -------
    PlannedTrajectory. Phases in ``reference.notes``: ``rest``, ``takeoff``, ``landing``,
    ``descent``, ``climb``, ``hover_low`` (floor or top), ``hover_cruise``, ``edge_pass``,
    ``cruise``, ``turn``.

    Raises
    ------
    InputError
        ``scene``: no free floor area to take off from at the cruise height;
        ``n_points``: fewer than one point.
    """
    from dataclasses import replace

    config = replace(config, clearance=max(config.clearance, vehicle_radius + 0.1),
                     flat_radius=max(config.flat_radius, vehicle_radius + 0.05))
    if config.n_points < 1:
        raise InputError("n_points", f"must be at least 1, got {config.n_points}")
    rng = np.random.default_rng([int(seed), 0x7AA])
    floor_level = float(scene.bounds[0, 2]) if not scene.has_boxes else 0.0
    grid = None
    for _ in range(8):  # a cruise height with a usable map
        z_c = float(rng.uniform(*config.cruise_height)) + floor_level
        grid = build_grid(scene, z_c, config)
        floor = grid.flat & (grid.surface < floor_level + 0.02)
        if floor.any():
            break
    else:
        raise InputError("scene", "no free floor area to take off from at the cruise height")
    assert grid is not None
    from scipy import ndimage

    labels, _ = ndimage.label(~grid.occ)  # 4-connected: every cell reachable by the 8-connected paths
    floor = grid.flat & (grid.surface < floor_level + 0.02)
    sizes = np.bincount(labels[floor], minlength=labels.max() + 1)
    sizes[0] = 0
    main = labels == int(np.argmax(sizes))
    floor &= main
    top = grid.flat & main & (grid.surface >= floor_level + 0.1)
    free = main & ~grid.occ

    def draw(mask: np.ndarray, taken: list[np.ndarray]) -> np.ndarray | None:
        cells = np.argwhere(mask)
        if len(cells) == 0:
            return None
        for _ in range(50):
            xy = grid.to_world(cells[rng.integers(len(cells))])[0]
            if all(np.linalg.norm(xy - t) >= config.min_spacing for t in taken):
                return xy
        return None

    pts: list[np.ndarray] = []
    kinds: list[str] = []
    start = draw(floor, pts)
    assert start is not None
    pts.append(start)
    kinds.append("floor")
    for _ in range(config.n_points - 1):
        kind = "top" if (top.any() and rng.random() < config.top_share) else (
            "floor" if rng.random() < config.floor_share else "free")
        xy = draw({"top": top, "floor": floor, "free": free}[kind], pts)
        if xy is None:
            continue
        pts.append(xy)
        kinds.append(kind)
    P = np.asarray(pts)
    ij = grid.to_cell(P)
    surf = grid.surface[ij[:, 0], ij[:, 1]]

    # path lengths between all points (Dijkstra on the 8-connected free cells)
    from scipy.sparse.csgraph import dijkstra

    g, node = grid.graph()
    src = node[ij[:, 0], ij[:, 1]]
    lengths = dijkstra(g, directed=False, indices=src)[:, src]
    if not np.all(np.isfinite(lengths)):  # cannot happen: all points in the main component
        raise InputError("scene", "random points in disconnected free space")
    order = christofides_order(lengths, 0)

    rest = config.rest_for(rotor_radius)
    yaw0 = float(rng.uniform(-np.pi, np.pi))
    plan = _Plan(np.r_[P[0], surf[0] + rest], yaw0, speed=config.speed, acc=config.acc,
                 yaw_rate=config.yaw_rate, yaw_acc=config.yaw_acc)
    b = _Builder(plan, config)
    corners = [plan.p.copy()]

    plan.hold(1.0, "rest")
    first = True
    for n_visit, k in enumerate(order):
        last = n_visit == len(order) - 1
        if not first:
            # leg at cruise height: straight if free, else A* and corner points
            a = plan.p[:2].copy()
            if grid.segment_free(a, P[k]):
                way = np.asarray([a, P[k]])
            else:
                path = astar(grid.occ, tuple(grid.to_cell(a)[0]), tuple(ij[k]))
                if not path:
                    continue
                cells = grid.to_world(np.asarray(path))
                cells[0], cells[-1] = a, P[k]
                way = simplify_path(grid, cells)
            for xy in way[1:]:
                b.horizontal(xy, config.speed, "cruise")
                corners.append(plan.p.copy())
        kind = kinds[k]
        s = float(surf[k])
        if kind == "free" and not last:
            b.hold(rng, "hover_cruise")
            first = False
            continue
        if kind == "free":  # the flight ends landed: find the floor
            continue
        # descent point (floor or top); low heights stay under the cruise slab
        top_h = grid.z - config.height_band - s

        def low() -> float:
            return min(_log_uniform(rng, config.low_heights), top_h)

        if first:
            b.vertical(s + low(), "takeoff")
            b.hold(rng, "hover_low")
        else:
            land = last or rng.random() < config.land_share
            h = low()
            b.vertical(s + min(max(h, 0.3), top_h), "descent")
            b.vertical(s + (rest if land else h), "landing" if land else "descent")
            b.hold(rng, "rest" if land else "hover_low")
            if last:
                break
            if land:
                b.vertical(s + low(), "takeoff")
                b.hold(rng, "hover_low")
        corners.append(plan.p.copy())
        if kind == "top" and rng.random() < config.edge_share:
            if _edge_pass(b, grid, rng, s):
                b.hold(rng, "hover_low")
                corners.append(plan.p.copy())
        b.vertical(grid.z, "climb")
        first = False
    if kinds[order[-1]] == "free" or plan.p[2] > grid.z - 1e-6:
        # ended at cruise height: land on the floor at the start point's nearest floor cell
        cells = np.argwhere(floor)
        dist = np.linalg.norm(grid.to_world(cells) - plan.p[:2], axis=1)
        for c in cells[np.argsort(dist)[:200]]:
            xy = grid.to_world(c)[0]
            if grid.segment_free(plan.p[:2], xy):
                b.horizontal(xy, config.speed, "cruise")
                s = float(grid.surface[c[0], c[1]])
                b.vertical(s + min(0.3, grid.z - s), "descent")
                b.vertical(s + rest, "landing")
                break
    plan.hold(1.0, "rest")
    corners.append(plan.p.copy())
    ref = plan.reference(name or f"traj-{int(seed)}")
    return PlannedTrajectory(ref, np.c_[P, surf], kinds, order, np.asarray(corners), grid, int(seed), lengths)


# --- collisions ----------------------------------------------------------------------------------


def collides(scene: Scene, positions: np.ndarray, radius: float, half_height: float = 0.01) -> np.ndarray:
    """Whether a vehicle (a vertical cylinder of ``radius`` [m] and ``half_height`` [m] about its
    body origin) at ``positions (K, 3)`` [m] touches the scene.

    Generated scenes: a box grown by ``radius`` horizontally and ``half_height`` vertically
    contains the point, or the point is outside the building, under the floor plus
    ``half_height`` or over the ceiling minus ``half_height``. External meshes:
    :func:`~uavturb.sim.scenes.inside_obstacle` with margin ``half_height``.

    Returns
    -------
    (K,) bool
    """
    p = np.atleast_2d(np.asarray(positions, float))
    if not scene.has_boxes:
        return inside_obstacle(scene, p, margin=half_height)
    grow = np.array([radius, radius, half_height])
    lo, hi = scene.boxes[:, 0] - grow, scene.boxes[:, 1] + grow
    hit = np.zeros(len(p), bool)
    for s in range(0, len(p), 2048):
        q = p[s: s + 2048, None, :]
        hit[s: s + 2048] = ((q > lo) & (q < hi)).all(axis=2).any(axis=1)
    hit |= p[:, 2] < half_height
    if scene.ceiling_height is not None:
        hit |= p[:, 2] > scene.ceiling_height - half_height
    hit |= ~scene.inside_building(p[:, :2])
    return hit


# --- flights -------------------------------------------------------------------------------------


def _ratio(rate_hi: float, rate_lo: float, what: str) -> int:
    n = int(round(rate_hi / rate_lo))
    if n < 1 or abs(n * rate_lo - rate_hi) > 1e-6 * rate_hi:
        raise InputError(what, f"physics_rate ({rate_hi} Hz) must be a whole multiple of it ({rate_lo} Hz)")
    return n


class _SceneHeightQuery:
    """The scene's exact heights as a :class:`~uavturb.sim.closed_loop.HeightQuery`."""

    def __init__(self, scene: Scene):
        self.scene = scene

    def d_down(self, positions: np.ndarray) -> np.ndarray:
        return height_below(self.scene, positions)

    def d_up(self, positions: np.ndarray) -> np.ndarray:
        return height_above(self.scene, positions)


def make_controller(kind: str, vehicle: Any, reference: Reference, control_rate: float | None = None,
                    **options: Any) -> tuple[Any, float]:
    """A controller for :func:`fly_trajectory` and its rate [Hz] (defaults: MPC 25 Hz,
    geometric 200 Hz)."""
    if kind == "mpc":
        from uavturb.sim.mpc import MPCController

        rate = 25.0 if control_rate is None else float(control_rate)
        return MPCController(vehicle, reference, dt=1.0 / rate, **options), rate
    if kind == "geometric":
        from uavturb.sim.closed_loop import GeometricTracker

        rate = 200.0 if control_rate is None else float(control_rate)
        dt = 1.0 / rate
        return GeometricTracker(vehicle, reference, dt, int(np.ceil(reference.duration / dt)) + 2), rate
    raise InputError("controller", f"unknown controller '{kind}' (known: {', '.join(CONTROLLERS)})")


def fly_trajectory(scene: Scene, vehicle: Any = "quad", seed: int = 0, controller: str = "mpc", *,
                   camera_rate: float = 20.0, physics_rate: float = 200.0, control_rate: float | None = None,
                   effects: dict[str, dict[str, float]] | None = None,
                   plan: PlanConfig | PlannedTrajectory = PlanConfig(), duration: float | None = None,
                   controller_options: dict | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray, dict[str, Any]]:
    """Plan a reference trajectory through ``scene`` and fly it in closed loop.

    Parameters
    ----------
    scene : Scene
    vehicle : Vehicle or preset name (``quad``: the paper's 50 g drone; ``hex``)
    seed : fixes the plan (the flight itself is deterministic)
    controller : ``"mpc"`` or ``"geometric"``
    camera_rate : Hz, sample rate of the output (camera frames)
    physics_rate : Hz, integration rate; a whole multiple of ``camera_rate`` and ``control_rate``
    control_rate : Hz (default 25 for the MPC, 200 for the geometric controller)
    effects : ``{name: {param: value}}`` of ``effects.md`` (default: the simulator's
        :data:`~uavturb.physics.sim_config.DEFAULT_EFFECTS`, ground effect ``mu = 2``);
        ``{}`` for none. ``motor_lag`` is not supported here.
    plan : PlanConfig, or an already planned trajectory
    duration : s, flight length (default: the reference's)
    controller_options : passed on to the controller (e.g. ``horizon`` for the MPC)

    Returns
    -------
    states : (T, 13) ``p`` [m] W, ``q`` w, x, y, z (body to world), ``v`` [m/s] W, ``w`` [rad/s] B
    rotor_speeds : (T, N) rad/s, actual rotor speeds at the sample times
    t : (T,) s from the start, ``k / camera_rate``
    info : dict with ``d_down`` (T,) m, ``d_up`` (T,) m, ``effect_force`` (T, 3) N in W,
        ``reference`` (Setpoint of T samples), ``phases`` (dict of ``(t0, t1)`` lists),
        ``plan`` (PlannedTrajectory), ``collided`` (bool), ``collisions`` (0 or 1: the flight is
        truncated at its first hit), ``collision_time`` (s or None), ``tracking_error`` (T,) m,
        ``solve_ms`` (controller update times), ``wall_s``, ``samples_per_s``, ``controller``.
    """
    from uavturb.io.vehicle_file import preset
    from uavturb.physics.effects import DEFAULT_EFFECTS
    from uavturb.sim.closed_loop import CollisionWatch, initial_state, run_closed_loop

    wall0 = time.perf_counter()
    veh = preset(vehicle) if isinstance(vehicle, str) else vehicle
    if controller not in CONTROLLERS:
        raise InputError("controller", f"unknown controller '{controller}' (known: {', '.join(CONTROLLERS)})")
    effects = dict(DEFAULT_EFFECTS if effects is None else effects)
    if "motor_lag" in effects:
        raise InputError("effects", "motor_lag is not supported by fly_trajectory")
    planned = plan if isinstance(plan, PlannedTrajectory) else plan_trajectory(
        scene, seed, plan, rotor_radius=veh.rotor_radius, vehicle_radius=veh.arm_length + veh.rotor_radius)
    ref = planned.reference
    duration = float(ref.duration if duration is None else duration)
    ctrl, rate = make_controller(controller, veh, ref, control_rate, **(controller_options or {}))
    cam_every = _ratio(physics_rate, camera_rate, "camera_rate")
    ctrl_every = _ratio(physics_rate, rate, "control_rate")
    dt = 1.0 / physics_rate
    radius = veh.arm_length + veh.rotor_radius
    rest = float(ref(0.0).p[2] - planned.points[0, 2])  # m, landed height of the start
    half_h = float(np.clip(0.5 * rest, 0.005, 0.02))  # m, vertical half-extent in the collision check

    x = initial_state(ref(0.0))
    ctrl.reset(x)
    # collision check in batches of the positions of every physics step (about 1 s of flight)
    watch = CollisionWatch(lambda p: collides(scene, p, radius, half_h), int(round(physics_rate)), dt)
    loop = run_closed_loop(veh, x, lambda x, t, force: ctrl.update(x, t), _SceneHeightQuery(scene), effects=effects,
                           n_steps=int(round(duration * physics_rate)), physics_dt=dt, control_every=ctrl_every,
                           record_every=cam_every, watch=watch)
    k = loop.count
    collided, t_hit = loop.stop_time is not None, loop.stop_time
    if collided and not loop.diverged:
        k = min(k, int(np.ceil(t_hit * camera_rate - 1e-9)))  # frames strictly before the hit
    if collided:
        k = max(k - 1, 0)  # drop the last frame before the hit too: the vehicle was about to touch
    X, W, F_rec, DD, DU = loop.x[:k], loop.rotor_speeds[:k], loop.force[:k], loop.d_down[:k], loop.d_up[:k]
    t_ctrl, t_phys = loop.control_s, loop.physics_s
    t_out = np.arange(k) / camera_rate
    sp = ref(t_out)
    wall = time.perf_counter() - wall0
    solve = np.asarray(getattr(ctrl, "solve_times", []), float) * 1e3
    info: dict[str, Any] = {
        "d_down": DD, "d_up": DU, "effect_force": F_rec, "reference": sp, "phases": dict(ref.notes),
        "plan": planned, "collided": collided, "collisions": int(collided), "collision_time": t_hit,
        "tracking_error": np.linalg.norm(X[:, 0:3] - sp.p, axis=1) if k else np.zeros(0),
        "solve_ms": solve, "controller": controller, "control_rate": rate, "physics_rate": physics_rate,
        "camera_rate": camera_rate, "wall_s": wall, "control_s": t_ctrl, "physics_s": t_phys,
        "samples_per_s": k / wall if wall > 0 else float("inf"), "effects": effects,
    }
    return X, W, t_out, info


# --- figures and benchmark -------------------------------------------------------------------


def plot_flight(scene: Scene, plan: PlannedTrajectory, path: str, states: np.ndarray | None = None,
                t: np.ndarray | None = None) -> str:
    """Top view (free-space map, random points in visiting order, planned corners, reference and
    flown paths) and altitude profile (reference, flown, surface below) of one trajectory,
    written to ``path`` (PNG, matplotlib Agg). Returns ``path``."""
    import os

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ref = plan.reference
    tt = np.arange(0.0, ref.duration, 0.05)
    sp = ref(tt)
    g = plan.grid
    fig, (ax, az) = plt.subplots(1, 2, figsize=(14, 5.5), gridspec_kw={"width_ratios": [1.1, 1.4]})
    ext = [g.origin[0] - g.res / 2, g.origin[0] + (g.shape[0] - 0.5) * g.res,
           g.origin[1] - g.res / 2, g.origin[1] + (g.shape[1] - 0.5) * g.res]
    surf = np.where(g.occ, np.nan, g.surface)
    ax.imshow(np.where(g.occ, 1.0, np.nan).T, origin="lower", extent=ext, cmap="Greys", vmin=0, vmax=1.5)
    im = ax.imshow(surf.T, origin="lower", extent=ext, cmap="YlGn", alpha=0.6)
    fig.colorbar(im, ax=ax, fraction=0.04, label="surface below [m]")
    ax.plot(sp.p[:, 0], sp.p[:, 1], "b-", lw=1, label="reference")
    if states is not None:
        ax.plot(states[:, 0], states[:, 1], "r--", lw=0.8, label="flown")
    c = plan.corners
    ax.plot(c[:, 0], c[:, 1], "k.", ms=4, label="corners (A*)")
    marks = {"floor": "s", "top": "^", "free": "o"}
    for rank, k in enumerate(plan.order):
        x, y = plan.points[k, :2]
        ax.plot(x, y, marks[plan.kinds[k]], color="C1", ms=8)
        ax.annotate(str(rank), (x, y), textcoords="offset points", xytext=(5, 5))
    ax.set_aspect("equal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_title(f"scene {scene.seed} ({scene.kind}), trajectory {plan.seed}: Christofides order")
    ax.legend(loc="best", fontsize=7)
    d = height_below(scene, sp.p)
    az.plot(tt, sp.p[:, 2], "b-", lw=1, label="reference z")
    az.plot(tt, sp.p[:, 2] - d, "g-", lw=1, label="surface below")
    if states is not None and t is not None:
        az.plot(t, states[:, 2], "r--", lw=0.8, label="flown z")
    for name, color in (("edge_pass", "C3"), ("landing", "C4"), ("takeoff", "C2"), ("hover_low", "C0")):
        for i, (a, b) in enumerate(ref.notes.get(name, [])):
            az.axvspan(a, b, color=color, alpha=0.15, label=name if i == 0 else None)
    az.set_xlabel("t [s]")
    az.set_ylabel("height [m]")
    az.legend(loc="upper right", fontsize=7)
    az.set_title("altitude profile")
    fig.tight_layout()
    tmp = f"{path}.tmp.png"
    fig.savefig(tmp, dpi=110)
    plt.close(fig)
    os.replace(tmp, path)
    return path


def benchmark(n_trajectories: int = 3, controller: str = "mpc", seed: int = 0, print_fn: Any = print,
              **fly_kw: Any) -> dict[str, float]:
    """Fly ``n_trajectories`` (one per generated scene ``seed + i``) and report the speed.

    Returns and prints samples/s (camera frames per wall second, one process), the share of
    time in the controller and the physics, MPC update times (mean, p95) [ms], tracking error
    (mean, max) [m] and the collision count.
    """
    from uavturb.sim.scenes import generate_scene

    frames = wall = ctrl_s = phys_s = 0.0
    solve, err = [], []
    coll = 0
    vehicle = fly_kw.pop("vehicle", "quad")
    for i in range(n_trajectories):
        sc = generate_scene(seed + i)
        X, _, _, info = fly_trajectory(sc, vehicle, seed + i, controller, **fly_kw)
        frames += len(X)
        wall += info["wall_s"]
        ctrl_s += info["control_s"]
        phys_s += info["physics_s"]
        solve.append(info["solve_ms"])
        err.append(info["tracking_error"])
        coll += info["collisions"]
        print_fn(f"[{i + 1}/{n_trajectories}] scene {seed + i}: {len(X)} frames, "
                 f"{len(X) / info['wall_s']:.0f} samples/s")
    s, e = np.concatenate(solve), np.concatenate(err)
    out = {"samples_per_s": frames / wall, "frames": frames, "wall_s": wall, "control_share": ctrl_s / wall,
           "physics_share": phys_s / wall, "solve_mean_ms": float(s.mean()),
           "solve_p95_ms": float(np.percentile(s, 95)), "solve_median_ms": float(np.median(s)),
           "error_mean_m": float(e.mean()), "error_max_m": float(e.max()), "collisions": coll}
    print_fn(f"{controller}: {out['samples_per_s']:.0f} samples/s (one process), "
             f"control {100 * out['control_share']:.0f}%, physics {100 * out['physics_share']:.0f}%, "
             f"update {out['solve_mean_ms']:.2f} ms mean / "
             f"{out['solve_p95_ms']:.2f} ms p95, tracking error {1000 * out['error_mean_m']:.1f} mm mean / "
             f"{1000 * out['error_max_m']:.1f} mm max, collisions {coll}")
    return out
