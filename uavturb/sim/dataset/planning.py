"""Reference trajectories through a scene (the plan a flight follows).

The paper (section "Large-scale generation of simulated UAV trajectory data") samples
random points on the scene's navigation mesh, orders them by solving a travelling
salesman problem with the Christofides algorithm, inserts extra points so that no leg
crosses a wall, and follows straight lines between them with the yaw facing forward;
an MPC flies the drone along this reference and collisions are checked. This module
does the same on a :class:`~uavturb.scene.indoor.Scene`:

1. **Navigation map** (:class:`~uavturb.sim.dataset.navigation.NavGrid`, :func:`build_grid`):
   :meth:`Scene.free_space_grid` at a cruise height ``z_c`` (drawn per trajectory) with a clearance margin and a
   height band, plus the height of the surface below every cell (:func:`~uavturb.scene.queries.height_below`
   from ``z_c``). A cell is *flat* when that surface is level within ``flat_tol`` over a
   window of ``±flat_radius`` around it: the vehicle can then go straight down there to a
   floor cell (surface at floor level) or a *top* cell (furniture top, bed, sofa seat...).
2. **Points**: a floor start point, then random floor, top and free cells of the main
   connected component of the map, at least ``min_spacing`` apart.
3. **Order**: Christofides (:func:`networkx.algorithms.approximation.christofides`) on the
   complete graph whose edge weights are the shortest grid-path lengths between points
   (8-connected Dijkstra on the free cells), then cut into an open path at the start.
4. **Legs**: a straight line when its grid cells are free, else the A* grid path
   (:func:`~uavturb.sim.dataset.navigation.astar`, octile heuristic) simplified to its corner points
   (line-of-sight string pulling, :func:`~uavturb.sim.dataset.navigation.simplify_path`). Straight segments at
   cruise height, stop and go (each segment starts and ends at rest, :class:`~uavturb.sim.core.signals.Waypoints`),
   the yaw turned in place at every corner to face the next segment.
5. **Altitude profile** (where ground effect matters): take-off from rest on the floor,
   low hovers and landings at floor and top points (heights drawn log-uniformly in
   ``low_heights``, since the ground effect grows as ``1/d^2``), and *edge passes*: from a
   low hover over a furniture top the vehicle slides sideways at that height past the
   edge, and sometimes back onto the top, so the surface below drops or rises while
   the forward camera cannot see it (the paper's negative measurement delay). The flight
   ends landed.

The output is a :class:`~uavturb.sim.core.signals.Reference` (position, velocity,
acceleration, jerk and yaw as functions of time) that both controllers consume.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

from uavturb.errors import InputError
from uavturb.scene.indoor import Scene
from uavturb.scene.queries import height_below
from uavturb.sim.dataset.navigation import NavGrid, astar, christofides_order, simplify_path
from uavturb.sim.core.signals import Reference
from uavturb.sim.core.waypoint_plan import WaypointPlan, wrap_near

__all__ = ["PlanConfig", "PlannedTrajectory", "build_grid", "plan_trajectory"]


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


class _Builder:
    """Appends moves to a :class:`WaypointPlan`, with yaw facing forward on horizontal moves."""

    def __init__(self, plan: WaypointPlan, config: PlanConfig):
        self.plan, self.c = plan, config

    @property
    def p(self) -> np.ndarray:
        return self.plan.p

    def face(self, target_xy: np.ndarray, phase: str = "turn") -> None:
        d = np.asarray(target_xy, float)[:2] - self.p[:2]
        if np.hypot(*d) < 1e-6:
            return
        yaw = wrap_near(math.atan2(d[1], d[0]), self.plan.yaw)
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
    config = replace(config, clearance=max(config.clearance, vehicle_radius + 0.1),
                     flat_radius=max(config.flat_radius, vehicle_radius + 0.05))
    if config.n_points < 1:
        raise InputError("n_points", f"must be at least 1, got {config.n_points}")
    rng = np.random.default_rng([int(seed), 0x7AA])
    floor_level = float(scene.bounds[0, 2]) if not scene.has_boxes else 0.0
    grid = _cruise_grid(scene, rng, config, floor_level)
    floor, top, free = _point_areas(grid, floor_level)
    P, kinds = _draw_points(rng, grid, config, floor, top, free)
    ij = grid.to_cell(P)
    surf = grid.surface[ij[:, 0], ij[:, 1]]
    lengths = _path_lengths(grid, ij)
    order = christofides_order(lengths, 0)

    rest = config.rest_for(rotor_radius)
    yaw0 = float(rng.uniform(-np.pi, np.pi))
    plan = WaypointPlan(np.r_[P[0], surf[0] + rest], yaw0, speed=config.speed, acc=config.acc,
                 yaw_rate=config.yaw_rate, yaw_acc=config.yaw_acc)
    b = _Builder(plan, config)
    corners = [plan.p.copy()]
    plan.hold(1.0, "rest")
    _visit(b, rng, grid, P, ij, surf, kinds, order, rest, corners)
    if kinds[order[-1]] == "free" or plan.p[2] > grid.z - 1e-6:
        _land_on_nearest_floor(b, grid, floor, rest)
    plan.hold(1.0, "rest")
    corners.append(plan.p.copy())
    ref = plan.reference(name or f"traj-{int(seed)}")
    return PlannedTrajectory(ref, np.c_[P, surf], kinds, order, np.asarray(corners), grid, int(seed), lengths)


def _cruise_grid(scene: Scene, rng: np.random.Generator, config: PlanConfig, floor_level: float) -> NavGrid:
    """The map of a cruise height (drawn in ``config.cruise_height`` over ``floor_level`` [m], up to 8
    times) with a level floor cell to take off from."""
    for _ in range(8):
        z_c = float(rng.uniform(*config.cruise_height)) + floor_level
        grid = build_grid(scene, z_c, config)
        if (grid.flat & (grid.surface < floor_level + 0.02)).any():
            return grid
    raise InputError("scene", "no free floor area to take off from at the cruise height")


def _point_areas(grid: NavGrid, floor_level: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(floor, top, free)`` cell masks of the connected free component holding most level floor:
    level floor cells, level furniture tops (10 cm or more over the floor), any free cell."""
    from scipy import ndimage

    labels, _ = ndimage.label(~grid.occ)  # 4-connected: every cell reachable by the 8-connected paths
    floor = grid.flat & (grid.surface < floor_level + 0.02)
    sizes = np.bincount(labels[floor], minlength=labels.max() + 1)
    sizes[0] = 0
    main = labels == int(np.argmax(sizes))
    floor &= main
    top = grid.flat & main & (grid.surface >= floor_level + 0.1)
    free = main & ~grid.occ
    return floor, top, free


def _draw_points(rng: np.random.Generator, grid: NavGrid, config: PlanConfig, floor: np.ndarray, top: np.ndarray,
                 free: np.ndarray) -> tuple[np.ndarray, list[str]]:
    """A floor start point, then up to ``n_points - 1`` top, floor or free points (x, y [m]), at
    least ``min_spacing`` apart; and their kinds."""
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
    return np.asarray(pts), kinds


def _path_lengths(grid: NavGrid, ij: np.ndarray) -> np.ndarray:
    """(n, n) m, shortest 8-connected grid-path lengths between the cells ``ij`` (Dijkstra)."""
    from scipy.sparse.csgraph import dijkstra

    g, node = grid.graph()
    src = node[ij[:, 0], ij[:, 1]]
    lengths = dijkstra(g, directed=False, indices=src)[:, src]
    if not np.all(np.isfinite(lengths)):  # cannot happen: all points in the main component
        raise InputError("scene", "random points in disconnected free space")
    return lengths


def _visit(b: _Builder, rng: np.random.Generator, grid: NavGrid, P: np.ndarray, ij: np.ndarray, surf: np.ndarray,
           kinds: list[str], order: list[int], rest: float, corners: list[np.ndarray]) -> None:
    """Fly to the points in ``order``: a cruise leg to each, a hover at free points, a descent
    (take-off, low hover or landing) at floor and top points, sometimes an edge pass after a top."""
    config = b.c
    first = True
    for n_visit, k in enumerate(order):
        last = n_visit == len(order) - 1
        if not first and not _cruise_leg(b, grid, P[k], ij[k], corners):
            continue
        if kinds[k] == "free":
            if not last:
                b.hold(rng, "hover_cruise")
                first = False
            continue  # the flight ends landed: the floor is found afterwards
        s = float(surf[k])
        if _low_visit(b, rng, grid, s, rest, first, last):
            return
        corners.append(b.p.copy())
        if kinds[k] == "top" and rng.random() < config.edge_share:
            if _edge_pass(b, grid, rng, s):
                b.hold(rng, "hover_low")
                corners.append(b.p.copy())
        b.vertical(grid.z, "climb")
        first = False


def _cruise_leg(b: _Builder, grid: NavGrid, xy: np.ndarray, cell: np.ndarray, corners: list[np.ndarray]) -> bool:
    """A leg at cruise height to ``xy`` [m]: straight if free, else A* and corner points; whether
    one was found (and appended)."""
    a = b.p[:2].copy()
    if grid.segment_free(a, xy):
        way = np.asarray([a, xy])
    else:
        path = astar(grid.occ, tuple(grid.to_cell(a)[0]), tuple(cell))
        if not path:
            return False
        cells = grid.to_world(np.asarray(path))
        cells[0], cells[-1] = a, xy
        way = simplify_path(grid, cells)
    for w in way[1:]:
        b.horizontal(w, b.c.speed, "cruise")
        corners.append(b.p.copy())
    return True


def _low_visit(b: _Builder, rng: np.random.Generator, grid: NavGrid, s: float, rest: float, first: bool,
               last: bool) -> bool:
    """At a descent point over a surface at ``s`` [m]: take off (first point), or descend to a low
    hover or a landing (always at the last point) and take off again; low heights stay under the
    cruise slab. Returns whether the flight ended here (landed at the last point)."""
    config = b.c
    top_h = grid.z - config.height_band - s

    def low() -> float:
        return min(_log_uniform(rng, config.low_heights), top_h)

    if first:
        b.vertical(s + low(), "takeoff")
        b.hold(rng, "hover_low")
        return False
    land = last or rng.random() < config.land_share
    h = low()
    b.vertical(s + min(max(h, 0.3), top_h), "descent")
    b.vertical(s + (rest if land else h), "landing" if land else "descent")
    b.hold(rng, "rest" if land else "hover_low")
    if last:
        return True
    if land:
        b.vertical(s + low(), "takeoff")
        b.hold(rng, "hover_low")
    return False


def _land_on_nearest_floor(b: _Builder, grid: NavGrid, floor: np.ndarray, rest: float) -> None:
    """From cruise height, fly to the nearest floor cell in straight free line and land there."""
    cells = np.argwhere(floor)
    dist = np.linalg.norm(grid.to_world(cells) - b.p[:2], axis=1)
    for c in cells[np.argsort(dist)[:200]]:
        xy = grid.to_world(c)[0]
        if grid.segment_free(b.p[:2], xy):
            b.horizontal(xy, b.c.speed, "cruise")
            s = float(grid.surface[c[0], c[1]])
            b.vertical(s + min(0.3, grid.z - s), "descent")
            b.vertical(s + rest, "landing")
            break
