"""The flight plans of ``uavturb generate flight`` (all deterministic given a seed) and the room
they are planned in:

- :func:`excitation`: a rich flight for identification around a hover point;
- :func:`low_passes`: take-off, low hovers over the floor and a table, passes over
  the table edge, landing (where ground effect matters);
- :func:`mixed`: heading changes, ceiling approach, excitation and low passes in one
  flight (a steady wind turns with the heading in B, an accelerometer bias does not);
- :func:`euroc_room`: a stand-in for EuRoC's Vicon-room flights (V1_01, V1_02): take-off from
  the floor, flight 0.5-2 m over the floor and the furniture of :data:`EUROC_ROOM`, landing
  (:mod:`uavturb.sim.flights.euroc_standin` makes the rest of the stand-in).

The scene they are planned in is a :func:`~uavturb.scene.layouts.table_room` (floor at ``z = 0``,
a ceiling, one table, optionally more furniture; :data:`TABLE_ROOM` by default), the scene whose
mesh :mod:`uavturb.sim.flights.simulate` turns into a point cloud; heights of the surface below
come from :func:`uavturb.scene.queries.surface_below`. Moves are
:class:`~uavturb.sim.core.waypoint_plan.WaypointPlan` moves (the plan builder of every planned
flight), routed over the table (:class:`TableRouter`) or over any box near a leg (``euroc_room``),
never through them. These rooms have no navigation grid to search:
:func:`uavturb.sim.dataset.planning.plan_trajectory` plans through generated scenes.
"""

from __future__ import annotations

import copy
import math

import numpy as np

from uavturb.errors import InputError
from uavturb.physics.constants import GRAVITY
from uavturb.scene.indoor import Furniture, Scene
from uavturb.scene.layouts import euroc_vicon_room, floor_boxes, room_size, table_room
from uavturb.scene.queries import surface_below
from uavturb.sim.core.signals import Constant, Envelope, Reference, Signal, Sines
from uavturb.sim.core.waypoint_plan import WaypointPlan, wrap_near

# --- the room ------------------------------------------------------------------------

#: the room of ``low_passes`` and ``mixed`` flights: 8 x 6 m, 2.6 m high, one table (:func:`table_room`)
TABLE_ROOM = table_room()

#: the stand-in for EuRoC's Vicon room, the room of ``euroc_room`` flights (:func:`euroc_vicon_room`)
EUROC_ROOM = euroc_vicon_room()


def _table(room: Scene) -> Furniture:
    """The table of a :func:`table_room` (its first furniture)."""
    return room.furniture[0]


def table_bounds(room: Scene) -> tuple[float, float, float, float]:
    """``(x_min, x_max, y_min, y_max)`` [m] of the table top of a :func:`table_room`."""
    t = _table(room)
    return float(t.lo[0]), float(t.hi[0]), float(t.lo[1]), float(t.hi[1])


def over_table(room: Scene, x: np.ndarray, y: np.ndarray, margin: float = 0.0) -> np.ndarray:
    """Whether world points ``(x, y)`` [m] lie over the table top of a :func:`table_room` grown by
    ``margin`` [m]."""
    x0, x1, y0, y1 = table_bounds(room)
    x, y = np.asarray(x, float), np.asarray(y, float)
    return (x >= x0 - margin) & (x <= x1 + margin) & (y >= y0 - margin) & (y <= y1 + margin)


# --- excitation ----------------------------------------------------------------------


def _scaled_sines(rng: np.random.Generator, n: int, omega_range: tuple[float, float], max_amp: float,
                  max_rate: float, max_acc: float) -> Sines:
    """``n`` sines with random frequencies and phases, scaled to stay under the given bounds."""
    if n == 0 or max_amp <= 0:
        return Sines((), (), ())
    w = rng.uniform(*omega_range, size=n)
    A = rng.uniform(0.5, 1.0, size=n)
    A /= A.sum()
    scale = min(max_amp, max_rate / float((A * w).sum()), max_acc / float((A * w**2).sum()))
    ph = rng.uniform(0, 2 * np.pi, size=n)
    return Sines(tuple(A * scale), tuple(w), tuple(ph))


def excitation(duration: float = 60.0, seed: int = 0, *, center: tuple[float, float, float] = (0.0, 0.0, 1.25),
               yaw0: float = 0.0, horizontal_amplitude: float = 1.4, vertical_amplitude: float = 0.25,
               max_speed: float = 2.0, max_acc: float = 2.0, tilt_excitation: float = 0.08,
               fast_omega: tuple[float, float] = (3.0, 7.0), max_yaw_rate: float = 0.8, max_yaw_acc: float = 0.5,
               ramp: float | None = None) -> Reference:
    """A rich flight for identification: sums of sines in x, y, z around ``center`` and a yaw
    that sweeps through all headings, smoothly faded in and out.

    Per horizontal axis: three slow sines (0.3-1.8 rad/s) carry the vehicle over up to
    ``horizontal_amplitude`` with per-axis speed under ``max_speed`` (horizontal speeds up to
    about 2 m/s), and two fast ones (``fast_omega``, 3-7 rad/s by default, a few cm) rock it
    in roll and pitch by about ``tilt_excitation`` [rad] while the yaw turns, so that the gyroscopic products
    ``w_y w_z``, ``w_x w_z`` are excited. The yaw is a slow sweep (amplitude up to several rad)
    plus two faster sines, under ``max_yaw_rate`` and ``max_yaw_acc`` (a hexarotor's yaw
    authority is small: about 0.7 rad/s^2 for the Firefly-like built-in ``hex``).

    Parameters
    ----------
    duration : s
    seed : random seed (frequencies, amplitudes, phases)
    center : (3,) m, hover point in W; ``yaw0`` rad, the heading it starts and ends at
    horizontal_amplitude, vertical_amplitude : m, bounds of the slow excursions per axis
    max_speed : m/s per axis; max_acc : m/s^2 per axis (slow part)
    tilt_excitation : rad, roll/pitch amplitude of the fast part
    fast_omega : rad/s, frequency band of the fast part (higher for agile vehicles, whose
        angular accelerations must stand out of rotor-speed quantisation)
    max_yaw_rate : rad/s; max_yaw_acc : rad/s^2
    ramp : s, fade-in and fade-out time (default ``min(5, duration / 6)``)

    Returns
    -------
    Reference starting and ending at rest at ``center`` with yaw ``yaw0``.
    """
    if duration <= 0:
        raise InputError("reference", "duration must be positive")
    rng = np.random.default_rng([int(seed), 1])
    ramp = min(5.0, duration / 6.0) if ramp is None else float(ramp)
    # a short fade would make the faded sines' derivatives large: shrink them with it
    shrink = min(1.0, (ramp / 3.0) ** 2)
    horizontal_amplitude, vertical_amplitude, tilt_excitation = (shrink * horizontal_amplitude,
                                                                 shrink * vertical_amplitude, shrink * tilt_excitation)
    env = Envelope(float(duration), ramp)
    chans: list[Signal] = []
    for axis in range(2):
        slow = _scaled_sines(rng, 3, (0.3, 1.8), horizontal_amplitude, max_speed, max_acc)
        w_fast = rng.uniform(*fast_omega, size=2)
        A_fast = tilt_excitation * GRAVITY / w_fast**2 * rng.uniform(0.35, 0.6, size=2)
        fast = Sines(tuple(A_fast), tuple(w_fast), tuple(rng.uniform(0, 2 * np.pi, size=2)))
        chans.append(Constant(center[axis]) + Sines(slow.amplitude + fast.amplitude, slow.omega + fast.omega,
                                                    slow.phase + fast.phase) * env)
    zs = _scaled_sines(rng, 2, (0.3, 1.5), vertical_amplitude, 0.5, 1.0)
    zf = Sines((0.02 * shrink,), (float(rng.uniform(2.0, 4.0)),), (float(rng.uniform(0, 2 * np.pi)),))
    z_sines = Sines(zs.amplitude + zf.amplitude, zs.omega + zf.omega, zs.phase + zf.phase)
    chans.append(Constant(center[2]) + z_sines * env)
    # yaw: a sweep A (1 - cos(w t)) with a whole number of periods in the flight (it starts and
    # ends at rest, so the fade does not add to its rate), plus two faster sines
    n_sweep = max(1, round(duration * float(rng.uniform(0.12, 0.25)) / (2 * np.pi)))
    w_sweep = 2 * np.pi * n_sweep / duration
    A_sweep = min(0.65 * max_yaw_rate / w_sweep, 0.65 * max_yaw_acc / w_sweep**2, 2.0 * np.pi)
    fast = _scaled_sines(rng, 2, (0.6, 1.6), shrink, max_yaw_rate - A_sweep * w_sweep,
                         max_yaw_acc - A_sweep * w_sweep**2)
    sign = float(rng.choice([-1.0, 1.0]))
    yaw = Constant(yaw0 + sign * A_sweep) + Sines((-sign * A_sweep,), (w_sweep,), (np.pi / 2,)) + fast * env  # cos
    return Reference(chans[0], chans[1], chans[2], yaw, float(duration), "excitation",
                     {"excitation": [(0.0, float(duration))]})



# --- low passes and mixed flights --------------------------------------------------------


class TableRouter:
    """Moves a :class:`WaypointPlan` between points of a :func:`table_room` without flying through the table."""

    def __init__(self, plan: WaypointPlan, room: Scene, clearance: float = 0.1, margin: float = 0.15):
        self.plan, self.room, self.clearance, self.margin = plan, room, clearance, margin

    def _crosses_table(self, a: np.ndarray, b: np.ndarray) -> bool:
        s = np.linspace(0.0, 1.0, 41)[:, None]
        pts = a[None, :2] * (1 - s) + b[None, :2] * s
        return bool(np.any(over_table(self.room, pts[:, 0], pts[:, 1], self.margin)))

    def go(self, p: np.ndarray, yaw: float | None = None, speed: float | None = None, phase: str | None = None) -> None:
        p = np.asarray(p, float)
        a = self.plan.p
        safe = _table(self.room).surface + self.clearance
        if self._crosses_table(a, p) and (a[2] < safe or p[2] < safe):
            z = max(a[2], p[2], safe + 0.1)
            if a[2] < z - 1e-9:
                self.plan.move((a[0], a[1], z), yaw, speed, phase)
                yaw = None
            self.plan.move((p[0], p[1], z), yaw, speed, phase)
            yaw = None
        self.plan.move(p, yaw, speed, phase)


def _height(rng: np.random.Generator, bounds: tuple[float, float]) -> float:
    """A hover height [m] drawn log-uniformly from ``bounds`` (ground effect varies as ``1/d^2``,
    so low heights get their share)."""
    lo, hi = bounds
    return float(np.exp(rng.uniform(np.log(lo), np.log(hi))))


def _floor_point(rng: np.random.Generator, room: Scene, keep_out: float = 0.5, wall: float = 1.0) -> np.ndarray:
    """A random floor point [m] (x, y) at least ``keep_out`` from the table and ``wall`` from the walls."""
    hx, hy = room_size(room)[0] / 2 - wall, room_size(room)[1] / 2 - wall
    for _ in range(1000):
        xy = rng.uniform([-hx, -hy], [hx, hy])
        if not over_table(room, xy[0], xy[1], keep_out):
            return xy
    raise InputError("reference", "the room has no free floor away from the table")


def _table_point(rng: np.random.Generator, room: Scene, inset: float = 0.2) -> np.ndarray:
    """A random point (x, y) [m] over the table top, ``inset`` inside its edges."""
    x0, x1, y0, y1 = table_bounds(room)
    return rng.uniform([x0 + inset, y0 + inset], [x1 - inset, y1 - inset])


def _low_pass_maneuvers(router: TableRouter, rng: np.random.Generator, until: float, *,
                        floor_heights: tuple[float, float], table_heights: tuple[float, float], pass_speed: float,
                        hold: tuple[float, float]) -> None:
    """Append random low hovers (floor, table top) and table-edge passes until ``until`` [s]."""
    plan, room = router.plan, router.room
    top = _table(room).surface
    x0, x1, y0, y1 = table_bounds(room)
    cx, cy = (float(v) for v in _table(room).centre[:2])
    kinds = ["floor", "table", "edge_x", "edge_y"]
    queue = list(rng.permutation(kinds))
    misses = 0
    while misses < len(kinds):
        if not queue:
            queue = list(rng.permutation(kinds))
        kind = queue.pop(0)
        yaw = plan.yaw + float(rng.choice([-1, 1]) * rng.uniform(0.3, 1.6)) if rng.random() < 0.5 else None
        steps: list[tuple] = []
        if kind == "floor":
            xy = _floor_point(rng, room)
            for _ in range(int(rng.integers(1, 4))):
                steps.append(((xy[0], xy[1], _height(rng, floor_heights)), "hover_floor"))
        elif kind == "table":
            xy = _table_point(rng, room)
            for _ in range(int(rng.integers(1, 4))):
                steps.append(((xy[0], xy[1], top + _height(rng, table_heights)), "hover_table"))
        else:
            z = top + _height(rng, table_heights)
            if kind == "edge_x":
                y = rng.uniform(y0 + 0.15, y1 - 0.15)
                a, b = (x0 - 0.7, y, z), (x1 + 0.5 if rng.random() < 0.5 else x0 + 0.4, y, z)
            else:
                x = rng.uniform(x0 + 0.15, x1 - 0.15)
                a, b = (x, y0 - 0.7, z), (x, y1 + 0.5 if rng.random() < 0.5 else y0 + 0.4, z)
            if rng.random() < 0.5:
                a, b = (2 * cx - a[0], 2 * cy - a[1], z), (2 * cx - b[0], 2 * cy - b[1], z)
            steps = [(a, None), (b, "edge_pass"), (a, "edge_pass")]
        # time check: a rough estimate of what this manoeuvre costs
        est = sum(plan.move_time(s[0]) for s in steps) + len(steps) * hold[1] + 4.0
        if plan.t + est > until:
            misses += 1
            continue
        misses = 0
        for i, (pt, phase) in enumerate(steps):
            speed = pass_speed if phase == "edge_pass" else None
            router.go(pt, yaw if i == 0 else None, speed, phase)
            if phase != "edge_pass" or i == len(steps) - 1:
                plan.hold(rng.uniform(*hold), phase if phase != "edge_pass" else None)


def _takeoff(plan: WaypointPlan, rng: np.random.Generator, floor_heights: tuple[float, float]) -> None:
    plan.hold(1.0, "rest")
    plan.move((*plan.p[:2], _height(rng, (floor_heights[0], 0.5 * sum(floor_heights)))), speed=0.3, phase="takeoff")
    plan.hold(2.0, "hover_floor")


def _landing_time(plan: WaypointPlan, rest_height: float) -> float:
    return plan.move_time((*plan.p[:2], 0.3)) + 2.0 + plan.move_time((*plan.p[:2], rest_height), speed=0.3) + 2.0


def _land(router: TableRouter, rng: np.random.Generator, rest_height: float) -> None:
    plan = router.plan
    xy = plan.p[:2] if not over_table(router.room, *plan.p[:2], 0.3) else _floor_point(rng, router.room)
    router.go((xy[0], xy[1], 0.3))
    plan.hold(1.5, "hover_floor")
    plan.move((xy[0], xy[1], rest_height), speed=0.3, phase="landing")
    plan.hold(1.0, "rest")


def low_passes(duration: float = 60.0, seed: int = 0, *, room: Scene = TABLE_ROOM, rest_height: float = 0.06,
               start: tuple[float, float] | None = None, yaw0: float | None = None,
               floor_heights: tuple[float, float] = (0.1, 0.5), table_heights: tuple[float, float] = (0.1, 0.5),
               pass_speed: float = 0.8, hold: tuple[float, float] = (1.5, 3.0), max_yaw_acc: float = 0.5) -> Reference:
    """Take-off from the floor, low hovers over the floor and the table top, passes over
    the table edges, landing: a flight where ground effect matters.

    The vehicle starts at rest with its body origin ``rest_height`` over the floor (on its
    legs; the dynamics have no contact model, so "at rest" is a hover there), and ends the
    same way. Between take-off and landing it draws manoeuvres at random: hovers at
    ``floor_heights`` over the floor or ``table_heights`` over the table top, straight
    passes across one or two table edges at ``pass_speed`` [m/s] and a height of
    ``table_heights`` over the top, with random heading changes; heights are drawn
    log-uniformly (ground effect grows as ``1/d^2``). Moves are routed over the table,
    never through it.

    Parameters
    ----------
    duration : s; the plan ends with a rest at ``duration`` (longer if take-off and landing
        alone need more time)
    seed : random seed
    room : the scene
    rest_height : m, height of the body origin when landed
    start : (2,) m, take-off point (default: random, away from the table)
    yaw0 : rad, initial heading (default random)
    floor_heights, table_heights : m, ranges of hover heights over floor and table top
    pass_speed : m/s, peak speed of the table-edge passes
    hold : s, range of hover durations
    max_yaw_acc : rad/s^2

    Returns
    -------
    Reference; ``notes`` lists the phases (``rest``, ``takeoff``, ``hover_floor``,
    ``hover_table``, ``edge_pass``, ``landing``) as ``(t0, t1)`` intervals.
    """
    rng = np.random.default_rng([int(seed), 2])
    xy = _floor_point(rng, room) if start is None else np.asarray(start, float)
    yaw = float(rng.uniform(-np.pi, np.pi)) if yaw0 is None else float(yaw0)
    plan = WaypointPlan(np.array([xy[0], xy[1], rest_height]), yaw, yaw_acc=max_yaw_acc)
    router = TableRouter(plan, room)
    _takeoff(plan, rng, floor_heights)
    _low_pass_maneuvers(router, rng, duration - _landing_time(plan, rest_height) - 1.0, floor_heights=floor_heights,
                        table_heights=table_heights, pass_speed=pass_speed, hold=hold)
    _land(router, rng, rest_height)
    return plan.reference("low_passes", duration)


def _heading_steps(plan: WaypointPlan, rng: np.random.Generator, center: np.ndarray, n: int = 4, hold: float = 2.0,
                   step: float = 0.5) -> None:
    """Hover at ``n`` headings spread over a full turn, each followed by a short translation;
    ends back at ``center``, one full turn from the initial heading."""
    y0 = plan.yaw
    direction = float(rng.choice([-1.0, 1.0]))
    for k in range(n):
        plan.move(center, y0 + direction * k * 2 * np.pi / n, phase="heading_hover")
        plan.hold(hold, "heading_hover")
        d = rng.normal(size=2)
        d = step * d / np.linalg.norm(d)
        plan.move(center + np.array([d[0], d[1], 0.0]), phase="heading_move")
        plan.hold(0.5, "heading_hover")
    plan.move(center, y0 + direction * 2 * np.pi, phase="heading_hover")


def mixed(duration: float = 60.0, seed: int = 0, *, room: Scene = TABLE_ROOM, rest_height: float = 0.06,
          center: tuple[float, float, float] = (0.0, 0.0, 1.25), excitation_share: float = 0.4,
          ceiling_gap: tuple[float, float] = (0.25, 0.45), floor_heights: tuple[float, float] = (0.1, 0.5),
          table_heights: tuple[float, float] = (0.1, 0.5), max_yaw_acc: float = 0.5,
          **excitation_kw: float) -> Reference:
    """Piecewise flight: take-off, hovers at three (``duration`` < 90 s) or four headings
    spread over a turn (a steady wind turns in B with the heading, an accelerometer bias does
    not), an :func:`excitation` block, hovers close under the ceiling (``ceiling_gap`` [m]
    below it), low passes over the floor and table, landing.

    The fixed parts need about 60 s; a shorter ``duration`` gives a longer plan. From 100 s
    on, the ceiling hovers and low passes fit as well.

    Parameters
    ----------
    duration : s; seed : random seed; room : the scene
    rest_height : m, body origin height when landed
    center : (3,) m, hover point of the heading and excitation blocks
    excitation_share : fraction of ``duration`` spent in the excitation block
    ceiling_gap : m, range of distances to the ceiling during the ceiling hovers
    floor_heights, table_heights : m, ranges of the low hovers (see :func:`low_passes`)
    max_yaw_acc : rad/s^2; excitation_kw : passed on to :func:`excitation`
    """
    rng = np.random.default_rng([int(seed), 3])
    c = np.asarray(center, float)
    start = _floor_point(rng, room)
    a = WaypointPlan(np.array([start[0], start[1], rest_height]), float(rng.uniform(-np.pi, np.pi)),
                     yaw_acc=max_yaw_acc)
    _takeoff(a, rng, floor_heights)
    TableRouter(a, room).go(c)
    _heading_steps(a, rng, c, n=4 if duration >= 90 else 3)
    first = a.reference("headings")
    reserve = 35.0 if duration >= 100.0 else 15.0  # s kept for ceiling hovers, low passes, landing
    t_exc = max(6.0, min(excitation_share * duration, duration - first.duration - reserve))
    exc = excitation(t_exc, seed, center=tuple(c), yaw0=a.yaw, max_yaw_acc=max_yaw_acc, **excitation_kw)
    b = WaypointPlan(c.copy(), a.yaw, yaw_acc=max_yaw_acc)
    router = TableRouter(b, room)
    used = first.duration + exc.duration
    for _ in range(2 if duration - used > 30.0 else 0):
        xy = _floor_point(rng, room)
        router.go((xy[0], xy[1], room.ceiling_height - rng.uniform(*ceiling_gap)), phase=None)
        b.hold(rng.uniform(1.5, 3.0), "hover_ceiling")
    left = duration - used
    _low_pass_maneuvers(router, rng, left - _landing_time(b, rest_height) - 1.0, floor_heights=floor_heights,
                        table_heights=table_heights, pass_speed=0.8, hold=(1.5, 3.0))
    _land(router, rng, rest_height)
    last = b.reference("passes", max(left, 0.0))
    return first.then(exc).then(last)


# --- a stand-in for EuRoC's Vicon-room flights --------------------------------------------


def _free_floor_point(rng: np.random.Generator, room: Scene, keep_out: float, wall: float) -> np.ndarray:
    """A random floor point (x, y) [m] at least ``keep_out`` from every box and ``wall`` from the walls."""
    hx, hy = room_size(room)[0] / 2 - wall, room_size(room)[1] / 2 - wall
    for _ in range(1000):
        xy = rng.uniform([-hx, -hy], [hx, hy])
        if surface_below(room, xy[None], keep_out)[0] == 0.0:
            return xy
    raise InputError("reference", "the room has no free floor away from its furniture")


def _facing(yaw: float, a: np.ndarray, b: np.ndarray) -> float:
    """The heading [rad] from ``a`` to ``b`` (x, y), unwrapped to within pi of ``yaw``; ``yaw``
    when the two are within 10 cm."""
    d = np.asarray(b[:2], float) - np.asarray(a[:2], float)
    if np.hypot(*d) < 0.1:
        return yaw
    return wrap_near(math.atan2(d[1], d[0]), yaw)


def _leg(plan: WaypointPlan, b: np.ndarray, room: Scene, clearance: float, margin: float, speed: float,
         phase: str) -> None:
    """Fly from the plan's position to ``b`` [m] facing the way, never lower than ``clearance`` over
    a box top within ``margin`` of the path: where the straight leg would be, climb first (and
    descend at the end)."""
    a = plan.p.copy()
    s = np.linspace(0.0, 1.0, 61)
    path = a[None, :] * (1 - s[:, None]) + np.asarray(b, float)[None, :] * s[:, None]
    need = surface_below(room, path[:, :2], margin) + clearance
    yaw = _facing(plan.yaw, a, b)
    if np.all(path[:, 2] >= need - 1e-9):
        plan.move(b, yaw, speed, phase)
        return
    z = max(a[2], b[2], float(need.max()))
    if a[2] < z - 1e-9:
        plan.move((a[0], a[1], z), yaw, speed, phase)
        yaw = None
    plan.move((b[0], b[1], z), yaw, speed, phase)
    if b[2] < z - 1e-9:
        plan.move(b, None, speed, phase)


def _waypoint(rng: np.random.Generator, room: Scene, k: int, heights: tuple[float, float], top: float,
              wall: float, inset: float = 0.15) -> np.ndarray:
    """Cruise point ``k``: every other one over a random box (``inset`` inside its edges), the others
    anywhere ``wall`` from the walls; ``heights`` [m] over the surface below, capped at ``top`` [m]."""
    if k % 2 == 1:
        boxes = floor_boxes(room)
        x0, x1, y0, y1, _ = boxes[int(rng.integers(len(boxes)))]
        xy = rng.uniform([x0 + inset, y0 + inset], [x1 - inset, y1 - inset])
    else:
        hx, hy = room_size(room)[0] / 2 - wall, room_size(room)[1] / 2 - wall
        xy = rng.uniform([-hx, -hy], [hx, hy])
    z = min(float(surface_below(room, xy[None])[0]) + rng.uniform(*heights), top)
    return np.array([xy[0], xy[1], z])


def _descend(plan: WaypointPlan, xy: np.ndarray, rest_height: float, vertical_speed: float) -> None:
    plan.move((xy[0], xy[1], rest_height), speed=vertical_speed, phase="landing")
    plan.hold(1.0, "rest")


def euroc_room(duration: float = 60.0, seed: int = 0, *, room: Scene = EUROC_ROOM, rest_height: float = 0.16,
               heights: tuple[float, float] = (0.6, 1.9), top: float = 2.0, clearance: float = 0.5,
               margin: float = 0.35, speed: float = 1.2, vertical_speed: float = 0.4,
               hold: tuple[float, float] = (0.5, 1.5), max_yaw_acc: float = 0.5, wall: float = 1.0,
               keep_out: float = 0.6) -> Reference:
    """A stand-in for EuRoC's Vicon-room flights: take-off from the floor, flight 0.5-2 m over the
    floor and the furniture, landing on the floor.

    1 s at rest on the floor (body origin ``rest_height`` over it; "at rest" is a hover there, the
    dynamics have no contact), a vertical take-off at ``vertical_speed`` to the first cruise
    height, cruise points in turn (every other one over a piece of furniture, at ``heights`` over
    the surface below, at most ``top`` over the floor; a hover of ``hold`` at each, the last one
    longer to end the flight at ``duration``; legs at ``speed``, facing the way, raised to
    ``clearance`` over any box top within ``margin`` of the path), then a leg to a free floor
    point, a vertical descent and 1 s at rest. Take-off and
    landing points are ``keep_out`` from every box and ``wall`` from the walls. With the defaults
    a flight is below 0.3 m for about 2-3 s at each end and 0.5-2 m over the surface below in
    between (EuRoC's V1_01_easy flies 58.6 m in 144 s, 0.4 m/s on average; ``speed`` 0.9 m/s
    peak gives about that).

    Parameters
    ----------
    duration : s, the plan's length (it ends landed, after 1 s at rest)
    seed : random seed
    room : the scene (default :data:`EUROC_ROOM`)
    rest_height : m, body origin over the floor when landed
    heights : (2,) m, range of cruise heights over the surface below (drawn uniformly)
    top : m, highest cruise point over the floor
    clearance, margin : m, least height over a box top near a leg, and how near
    speed, vertical_speed : m/s, peak speeds of legs and of take-off and landing
    hold : (2,) s, range of hovers at the cruise points
    max_yaw_acc : rad/s^2; wall, keep_out : m

    Returns
    -------
    Reference named ``euroc_room``; ``notes`` lists the phases (``rest``, ``takeoff``, ``cruise``,
    ``hover``, ``landing``).

    Raises
    ------
    InputError : ``duration`` too short for take-off, one cruise point and landing (names the least
        of 10 draws).
    """
    rng = np.random.default_rng([int(seed), 5])
    start, land = _free_floor_point(rng, room, keep_out, wall), _free_floor_point(rng, room, keep_out, wall)
    plan = WaypointPlan(np.array([start[0], start[1], rest_height]), float(rng.uniform(-np.pi, np.pi)), speed=speed,
                 yaw_acc=max_yaw_acc)
    plan.hold(1.0, "rest")
    first = min(rng.uniform(*heights), top)
    plan.move((start[0], start[1], first), speed=vertical_speed, phase="takeoff")
    plan.hold(rng.uniform(*hold), "hover")

    def finish(p: WaypointPlan) -> WaypointPlan:
        _leg(p, np.array([land[0], land[1], p.p[2]]), room, clearance, margin, speed, "cruise")
        _descend(p, land, rest_height, vertical_speed)
        return p

    k, misses, least = 0, 0, math.inf
    while misses < 10:  # cruise points while one of 10 draws still fits
        trial = copy.deepcopy(plan)
        _leg(trial, _waypoint(rng, room, k, heights, top, wall), room, clearance, margin, speed, "cruise")
        trial.hold(rng.uniform(*hold), "hover")
        end = finish(copy.deepcopy(trial)).t
        if end > duration:
            misses, least = misses + 1, min(least, end)
            continue
        plan, k, misses = trial, k + 1, 0
    if k == 0:
        least = int(math.ceil(least))
        raise InputError("--duration", f"a euroc_room flight needs at least {least} s (take-off, one cruise "
                                       f"point, landing), got {duration:g}")
    plan.hold(duration - finish(copy.deepcopy(plan)).t, "hover")  # the time left: a longer last hover
    return finish(plan).reference("euroc_room", duration)
