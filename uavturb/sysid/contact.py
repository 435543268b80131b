"""Ground contact: the rows of a recording where the floor carries the vehicle.

Recordings often start and end with the vehicle on its landing gear, rotors spinning, and
may touch down in between (touch-and-go). There the floor pushes up with whatever the rotors
do not carry, a force no aerodynamic law explains, so those rows must be left out of every
fit (``recordings.md``, "Streams that may be missing"; ``gap-report.md``, ``ground_contact``).

Height, stillness, attitude and thrust tell it together. The vehicle rests at its landed
height, within a small tolerance; it is still and level and its attitude steady; and its rotors carry
less than its weight (once they carry more, it lifts off). Thrust guesses from rotor speeds can be
10-20 % off (unknown ``k_T``), so the thrust is first scaled so that it carries the weight in the air,
and height and stillness decide first: a hover a few centimetres above the landed height is
in the air however low its thrust reads (ground effect).

**The landed height needs the floor seen carrying the vehicle** (:func:`landed_height`). It is the lowest
height the recording reaches (or one given), but where a bound on the surface lift is known (``hover_lift``,
``lift``: the strongest law of the effects registry at the top of its range) only where, somewhere within
:attr:`ContactLimits.height_tol_m` of it, the vehicle is still and level with a thrust no hover could need:

- under :attr:`ContactLimits.idle_ratio` of the weight (rotors idling or off: however short);
- under the least share that could hold a hover there in the strongest surface lift, for
  :attr:`ContactLimits.min_s`;
- or moving through :attr:`ContactLimits.ramp_ratio` of the weight within :attr:`ContactLimits.ramp_s` while
  the height stays within :attr:`ContactLimits.ramp_m` (rotors spooling up or down on the gear: a hover's thrust
  follows its height, and a lift-off leaves).

The lowest height alone is no landing: a recording that never lands (a hover cut out of a longer log, a flight
that stays low) hovers there, and its thrust reads under the weight *because of the ground effect itself* (a
hexarotor at d/R 1.2 with Cheeseman-Bennett mu = 2 needs 91 % of it). Taken as a landing, 31.5 s and 18 s of such
hover were left out of two probe flights (the rows where the ground effect is strongest) and pure hovers at 0.15
and 0.25 m were refused whole ("0 samples in flight"). The three readings are what tells the floor on the flights
that do land: real Crazyflies switch their motors off on the floor (0 % of the weight), the simulator's landings
ramp their rotors from 30 to 53 % of the weight in a second at 0.6 rotor radius, where the strongest law has its
pole and no thrust is too low for a hover (without the ramp both ends of such a flight were missed: 4-9 N of floor
reaction fitted as aerodynamics). A still vehicle at a constant thrust there, never idling, is a hover as far as
anything recorded can tell. Where no bound is known (no ``d_down``), the lowest height is taken as it is. Where
the floor is not seen at the lowest height, the still stretches above it are tried, lowest first (up to
:data:`REST_CANDIDATES`): a hover over a box or a platform can bring the rotor plane nearer the surface below than
the landing gear holds it on the floor.

A recording without such a landed height has no rests at its lowest height; its idle rests count (below). Closer
than :attr:`ContactLimits.skim_m` to the landed height a still stretch is a rest (the gear may touch there);
one that stays above that is a rest only where its thrust could not hold a hover there even under the strongest
surface lift (row by row): a hover a centimetre over the landed height in a strong ground effect reads 75-95 % of
the weight, and those are the rows that tell the ground effect best. Rotors off or idling hold no hover, so such a
rest counts however short (on real Crazyflies a drop to the floor with the motors off, 0.15 s still,
then a restart: while the rotors spun up the thrust read off commanded speeds led the real one by the
motor lag, up to 15 % over the weight for 0.2 s with the vehicle still on the floor, which the margins
cover). Still and level with the rotors idling for a second or more (:attr:`ContactLimits.idle_rest_s`), the
vehicle rests at whatever height it reads: a barometer's height drifts (a real PX4 log read its first rest 0.45 m
over the lowest height of the recording), and no aerodynamic lift holds a still vehicle on idling rotors; shorter
such stretches away from the landed height are a motor cut in the air (the commands drop at once, the rotors spin
down by their lag, and the fall starts after it).

A vehicle that skids or bounces along the floor is not still: rows within :attr:`ContactLimits.skim_m` of the
landed height (``skim_top``: the vehicle's over its recordings) where the thrust dips under
:attr:`ContactLimits.thrust_ratio` of the weight are left out too. Where no landing was seen, the lowest height
serves for these alone, and only for a dip moving throughout: a still vehicle there hovers, and so does one
leaving or settling into such a hover. Real random walks never land, but their dips to their lowest set point
(never still, 0.2-0.5 s) held the largest residuals: taken as flight, the held-out error of one June walk rose from
6.5 to 18.7 mN. Stillness is judged on the rows where
the state updated (:func:`uavturb.numerics.stream_updates.update_mask`): held positions must not make a
flying vehicle look still. Each contact interval is widened by a margin on either side so that
the transients of lift-off and touch-down are left out too.

Times are seconds since the recording's first ground-truth row; heights metres; speeds m/s;
forces newtons; angles degrees.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np
from scipy.ndimage import maximum_filter1d, median_filter, minimum_filter1d

from uavturb.errors import InputError
from uavturb.physics.dynamics import GRAVITY
from uavturb.numerics.stream_updates import update_mask


@dataclass
class ContactInterval:
    """A stretch of a recording where the floor carries the vehicle (margins included).

    Attributes
    ----------
    t_start, t_end : s since the recording's first ground-truth row
    why : str, one sentence with the numbers that tell it
    group : int, index of the recording
    """

    t_start: float
    t_end: float
    why: str
    group: int = 0

    def to_report(self, recording: str) -> dict:
        """The entry of ``report.json``'s ``ground_contact`` (``gap-report.md``)."""
        return {"recording": recording, "t_start": round(self.t_start, 3), "t_end": round(self.t_end, 3),
                "why": self.why}


@dataclass(frozen=True)
class ContactLimits:
    """Thresholds of :func:`ground_contact`.

    Attributes
    ----------
    height_tol_m : m, how far above the landed height a resting vehicle may read
    still_mps : m/s, the largest speed (median over ``window_s``) of a resting vehicle
    level_deg : deg, the largest tilt of a resting vehicle
    steady_deg : deg, the largest change of tilt over ``window_s`` of a resting vehicle
    thrust_ratio : a contact interval's median thrust must be below this share of the weight
    air_m : m, rows this far above the landed height are in the air (they scale the thrust)
    window_s : s, the window of the speed median and the tilt range
    margin_s : s, added on each side of a contact interval (lift-off and touch-down transients)
    min_s : s, shortest contact kept (before margins), unless the rotors idle in it
    idle_ratio : share of the weight under which the rotors idle (or are off): no hover, however short
    skim_m : m, rows this close to the landed height, still or not, with the thrust under ``thrust_ratio`` of
        the weight, are left out too: the landing gear may touch there (a skid, a bounce); on real Crazyflie
        random walks whose lowest set points put the rotor plane at its resting height, 0.4 % of the rows,
        these held the largest residuals of all
    skim_margin_s : s, added on each side of such rows
    gear_max_m : m, with ``d_down``: the highest a resting rotor plane sits over the surface (its
        landing gear); a recording whose lowest ``d_down`` is higher never landed
    idle_rest_s : s, the shortest stretch, still and level with the rotors idling (``idle_ratio``), taken as a rest
        at any height (where the height drifts); shorter ones away from the landed height are a motor cut in the air
    ramp_ratio : share of the weight the thrust moves through within ``ramp_s`` while a still, level vehicle stays
        within ``ramp_m`` of one height: the floor carries it (a hover's thrust moves with its height only)
    ramp_s : s, the time over which such a thrust change is read
    ramp_m : m, the most the height (median over ``window_s``) may move meanwhile
    """

    height_tol_m: float = 0.015
    still_mps: float = 0.05
    level_deg: float = 10.0
    steady_deg: float = 2.0
    thrust_ratio: float = 0.95
    air_m: float = 0.1
    window_s: float = 0.3
    margin_s: float = 0.2
    min_s: float = 0.2
    idle_ratio: float = 0.3
    skim_m: float = 0.005
    skim_margin_s: float = 0.1
    gear_max_m: float = 0.5
    idle_rest_s: float = 1.0
    ramp_ratio: float = 0.1
    ramp_s: float = 1.0
    ramp_m: float = 0.003


def ground_contact(t: np.ndarray, z: np.ndarray, v: np.ndarray, tilt_deg: np.ndarray, thrust: np.ndarray,
                   mass: float, *, d_down: np.ndarray | None = None, group: np.ndarray | None = None,
                   update: np.ndarray | None = None, landed_height: float | None = None, calibrate: bool = True,
                   limits: ContactLimits | None = None, skim_top: float | None = None, skim_landed: bool = True,
                   hover_lift: Callable[[np.ndarray], np.ndarray] | None = None, lift: np.ndarray | None = None
                   ) -> tuple[np.ndarray, list[ContactInterval]]:
    """Rows where the floor carries the vehicle, and the contact intervals with why.

    Parameters
    ----------
    t : (K,) s since each recording's first ground-truth row, increasing within a recording
    z : (K,) m, height of the body origin in W (as logged: repeats of held rows included)
    v : (K, 3) m/s, velocity in W
    tilt_deg : (K,) deg, angle between the body's z axis and the vertical
    thrust : (K,) N, modelled thrust along z_B, e.g. ``k_T sum(w^2)`` with a guessed ``k_T``
    mass : kg
    d_down : (K,) m, rotor-plane height over the surface below (``inf``: none); used instead of
        ``z`` for the landed height where given
    group : (K,) int, recording index (each recording has its own landed height)
    update : (K,) bool, rows where the state updated; default where ``z`` or ``v`` changed
    landed_height : m, the resting height (of ``d_down`` where given, else of ``z``); default
        the lowest the recording reaches, where the floor is seen to carry the vehicle there
        (:func:`landed_height`)
    calibrate : scale the thrust so that its vertical part carries the weight in the air
        (median over rows ``air_m`` above the landed height); else use it as given
    limits : ContactLimits, thresholds
    skim_top : m, height (of ``d_down`` where given, else of ``z``) under which rows may skim the floor;
        default ``skim_m`` over the landed height. Give the vehicle's landed height over all its
        recordings plus ``skim_m`` so that a recording that never came down there skims nothing
    skim_landed : whether the floor was seen to carry the vehicle at the height ``skim_top`` is ``skim_m`` over
        (a landed height, :func:`landed_height`); False: it is only the lowest the vehicle came, and only dips
        moving throughout (no still row in them or beside them: a skid or a bounce) skim there, a still vehicle
        being a hover (a rest needs the floor seen). With ``skim_top`` None the recording's own lowest height
        serves, seen or not alike
    hover_lift : with ``d_down``: ``(h) -> lift``, the most a surface could raise the thrust at rotor-plane
        heights ``h`` [m] (e.g. :func:`uavturb.physics.effects.strongest_surface_lift`). A still row more than
        ``skim_m`` above the landed height is then resting only where its thrust times that lift stays under
        the weight, or its rotors idle (else it may be a hover in ground effect); where the lift is infinite
        (inside a law's pole, no bound), and with None, any still row within ``height_tol_m`` with the thrust
        under the weight may rest. With a lift known, the lowest height is a landed height only where the floor
        is seen to carry the vehicle there (:func:`landed_height`)
    lift : (K,) -, the same bound row by row, instead of ``hover_lift`` of ``d_down`` (e.g. read off a point
        cloud's heights while ``z`` finds the rests; 1 where no surface is below)

    Returns
    -------
    mask : (K,) bool, True on rows to leave out (contact, margins included)
    intervals : list of ContactInterval, in recording and time order
    """
    lim = limits or ContactLimits()
    t, z, v = np.asarray(t, float), np.asarray(z, float), np.asarray(v, float)
    k = len(t)
    h = np.asarray(z if d_down is None else d_down, float)
    arrays = dict(z=z, tilt_deg=tilt_deg, thrust=thrust, d_down=d_down, group=group, update=update, lift=lift)
    bad = [n for n, a in arrays.items() if a is not None and len(a) != k] + (["v"] if np.shape(v) != (k, 3) else [])
    if bad:
        raise InputError("ground_contact", f"{', '.join(bad)} must have one row per time ({k} rows)")
    lift = _row_lift(h, d_down, hover_lift, lift)
    group = np.zeros(k, int) if group is None else np.asarray(group)
    mask = np.zeros(k, bool)
    intervals: list[ContactInterval] = []
    for g in np.unique(group):
        rows = np.flatnonzero(group == g)
        rec = _recording(t, z, h, v, tilt_deg, thrust, update, lift, rows)
        m, found = _contact_in(rec, mass, landed_height, calibrate, lim, d_down is not None, skim_top, skim_landed)
        mask[rows] = m
        intervals += [ContactInterval(a, b, why, int(g)) for a, b, why in found]
    return mask, intervals


def landed_height(t: np.ndarray, z: np.ndarray, v: np.ndarray, tilt_deg: np.ndarray, thrust: np.ndarray,
                  mass: float, *, d_down: np.ndarray | None = None, update: np.ndarray | None = None,
                  calibrate: bool = True, limits: ContactLimits | None = None,
                  hover_lift: Callable[[np.ndarray], np.ndarray] | None = None, lift: np.ndarray | None = None
                  ) -> float | None:
    """m, the height (of ``d_down`` where given, else of ``z``) at which the floor carries the vehicle in one
    recording, as :func:`ground_contact` reads it, or None where it never lands.

    It is the lowest height the recording reaches (5-row median), or failing that the lowest height of a still
    stretch above it (a hover over a box can come nearer a surface than the gear holds the rotor plane), where
    somewhere within
    :attr:`ContactLimits.height_tol_m` of it the vehicle is still and level with a thrust no hover could need:
    under :attr:`ContactLimits.idle_ratio` of the weight, or under the least share that could hold a hover there
    under the strongest surface lift (``hover_lift`` or ``lift``), for :attr:`ContactLimits.min_s` or more
    (rotors idling: however short); or a thrust moving through :attr:`ContactLimits.ramp_ratio` of the weight
    within :attr:`ContactLimits.ramp_s` while the height stays within :attr:`ContactLimits.ramp_m` (the module's
    docstring tells why). Without a lift known, the lowest height is taken as it is. None also where
    ``d_down``'s lowest is more than :attr:`ContactLimits.gear_max_m`, or fewer than 5 rows update.

    Parameters
    ----------
    t, z, v, tilt_deg, thrust, mass, d_down, update, calibrate, limits, hover_lift, lift
        as :func:`ground_contact`'s, for one recording

    Returns
    -------
    float or None, m
    """
    lim = limits or ContactLimits()
    t, z, v = np.asarray(t, float), np.asarray(z, float), np.asarray(v, float)
    h = np.asarray(z if d_down is None else d_down, float)
    rec = _recording(t, z, h, v, tilt_deg, thrust, update, _row_lift(h, d_down, hover_lift, lift),
                     np.arange(len(t)))
    reading = _read(rec, mass, None, calibrate, lim, d_down is not None)
    return None if reading is None or not reading.landed else reading.h0


def _row_lift(h: np.ndarray, d_down: np.ndarray | None, hover_lift: Callable[[np.ndarray], np.ndarray] | None,
              lift: np.ndarray | None) -> np.ndarray | None:
    """(K,) -, the strongest surface lift on each row (``lift``, else ``hover_lift`` of ``d_down``), or None."""
    if lift is not None:
        return np.asarray(lift, float)
    if hover_lift is None or d_down is None:
        return None
    out = np.ones(len(h))
    finite = np.isfinite(h)
    out[finite] = np.asarray(hover_lift(h[finite]), float)
    return out


@dataclass
class _Recording:
    """One recording's rows: t [s], h [m], v [m/s] (n, 3), tilt [deg], thrust [N], update (bool), lift (the
    strongest surface lift, or None)."""

    t: np.ndarray
    h: np.ndarray
    v: np.ndarray
    tilt: np.ndarray
    thrust: np.ndarray
    update: np.ndarray
    lift: np.ndarray | None = None


def _recording(t: np.ndarray, z: np.ndarray, h: np.ndarray, v: np.ndarray, tilt_deg: np.ndarray,
               thrust: np.ndarray, update: np.ndarray | None, lift: np.ndarray | None, rows: np.ndarray
               ) -> _Recording:
    """The rows ``rows`` of one recording (updates where ``z`` or ``v`` changed unless ``update`` is given)."""
    upd = (update_mask(np.column_stack([z[rows], v[rows]])) if update is None
           else np.asarray(update, bool)[rows].copy())
    return _Recording(t[rows], h[rows], v[rows], np.asarray(tilt_deg, float)[rows], np.asarray(thrust, float)[rows],
                      upd, None if lift is None else lift[rows])


@dataclass
class _Reading:
    """What one recording says before its rests are cut into intervals.

    Attributes
    ----------
    h0 : m, the landed height: given, or the lowest height the recording reaches where the floor is seen to carry
        the vehicle there, or the lowest still height above it where it is (:func:`_read`)
    landed : whether the floor carries the vehicle at ``h0`` (given, seen, or no lift known to tell)
    resting : (n,) bool, rows still and level at ``h0`` (none where not ``landed``)
    known : (n,) bool, rows that hold an update with a finite height (or follow one)
    still : (n,) bool, rows still and level at any height
    speed : (len(u),) m/s, speed on the updates (median over ``window_s``)
    pos : (n,) int, the update each row holds
    ratio : (n,) -, share of the weight the thrust carries (scaled, median over ``window_s``)
    scale : -, the factor the thrust was scaled by
    hover_at : (n,) -, the least share of the weight that could hold a hover on each row (0: no bound)
    lowest : m, the lowest height the recording reaches, where ``h0`` is a still height above it (else None)
    """

    h0: float
    landed: bool
    resting: np.ndarray
    known: np.ndarray
    still: np.ndarray
    speed: np.ndarray
    pos: np.ndarray
    ratio: np.ndarray
    scale: float
    hover_at: np.ndarray
    lowest: float | None = None


#: other still heights of the rotor plane tried as the landed height where the floor is not seen to carry the
#: vehicle at its lowest, and the share of the least thrust that could hold a hover there under which one counts
#: (a still hover on commanded speeds reads a few percent under the weight as its battery sags: a share of 1 had
#: taken a battery test's still hover at 1.25 m for a landing)
REST_CANDIDATES, REST_CANDIDATE_SHARE = 4, 0.85


def _read(rec: _Recording, mass: float, landed: float | None, calibrate: bool, lim: ContactLimits,
          rotor_plane: bool) -> _Reading | None:
    """One recording's landed height, rests at it, stillness and thrust share (None: too few updates, or a
    rotor plane that never came within landing-gear height of a surface).

    The landed height is ``landed`` where given; else the lowest height the recording reaches where the floor is
    seen to carry the vehicle there, or failing that the lowest height of a still stretch above it
    (:func:`_rest_heights`) where the floor is: a hover over a box or a platform may bring the rotor plane nearer
    a surface than its landing gear holds it (a blind probe's quadrotor hovered 0.148 m over a 25 cm box and rested
    on the floor at 0.170 m: its rests at both ends, 7.5-7.9 N of floor reaction, had been fitted as flight, and
    its ground effect lost). Where none shows the floor, the lowest height, not landed."""
    rec.update[0] = True
    u = np.flatnonzero(rec.update & np.isfinite(rec.h))
    if len(u) < 5:
        return None
    lowest = float(np.min(median_filter(rec.h[u], 5, mode="nearest"))) if landed is None else float(landed)
    if rotor_plane and landed is None and lowest > lim.gear_max_m:
        return None  # never within landing-gear height of a surface
    basis = _basis(rec, u, mass, lowest, lim)
    first = _read_at(rec, basis, lowest, landed is not None, calibrate, lim)
    if first.landed or rec.lift is None or not rotor_plane:
        return first
    for h0 in _rest_heights(rec, first.still, lowest, lim):
        reading = _read_at(rec, basis, h0, False, calibrate, lim, share=REST_CANDIDATE_SHARE)
        if reading.landed:
            reading.lowest = lowest
            return reading
    return first


def _rest_heights(rec: _Recording, still: np.ndarray, lowest: float, lim: ContactLimits) -> list[float]:
    """m, ascending, the rotor-plane heights (median) of the still stretches (``still``, per row) of at least
    ``min_s`` above ``lowest`` by more than ``height_tol_m`` and at most ``gear_max_m`` up, one per
    ``height_tol_m`` band, up to :data:`REST_CANDIDATES` of them."""
    heights = []
    for a, b in _runs(still & np.isfinite(rec.h)):
        if rec.t[b - 1] - rec.t[a] >= lim.min_s:
            heights.append(float(np.median(rec.h[a:b])))
    out: list[float] = []
    for h in sorted(heights):
        if h <= lowest + lim.height_tol_m or h > lim.gear_max_m:
            continue
        if not out or h > out[-1] + lim.height_tol_m:
            out.append(h)
    return out[:REST_CANDIDATES]


@dataclass
class _Basis:
    """What a recording's reading needs whatever landed height it is read at (:func:`_read_at`): the updates
    ``u`` (rows), the update each row holds (``last``: -1 before the first; ``pos``: its index in ``u``), stillness
    and speed on the updates, the thrust's share of the weight unscaled (median over ``window_s``), and the least
    share that could hold a hover on each row (0 inside a law's pole), and the weight [N]."""

    u: np.ndarray
    last: np.ndarray
    pos: np.ndarray
    still_u: np.ndarray
    speed_u: np.ndarray
    ratio: np.ndarray
    hover_at: np.ndarray
    weight: float


def _basis(rec: _Recording, u: np.ndarray, mass: float, h0: float, lim: ContactLimits) -> _Basis:
    n = len(rec.t)
    _, speed_u, still_u = _resting_updates(rec, u, h0, lim)
    is_u = np.zeros(n, bool)
    is_u[u] = True
    last = np.maximum.accumulate(np.where(is_u, np.arange(n), -1))
    pos = np.searchsorted(u, last)  # the update each row holds (rows before the first finite one: none)
    # a held thrust is late by half its update step: read it on its updates; rotors off (zero thrust) are
    # a state, not a stale value, and hold every row (interpolated, a restart would lift a rest off zero)
    fresh = update_mask(rec.thrust) | (rec.thrust <= 0)
    weight = mass * GRAVITY
    ratio = _window_median(rec.t, np.interp(rec.t, rec.t[fresh], rec.thrust[fresh]) / weight, lim.window_s)
    hover_at = np.zeros(n)
    if rec.lift is not None:
        bounded = np.isfinite(rec.lift) & (rec.lift > 0)
        hover_at[bounded] = 1.0 / rec.lift[bounded]
    return _Basis(u, last, pos, still_u, speed_u, ratio, hover_at, weight)


def _read_at(rec: _Recording, basis: _Basis, h0: float, given: bool, calibrate: bool, lim: ContactLimits,
             share: float = 1.0) -> _Reading:
    """One recording's reading with its landed height taken at ``h0`` [m] (``given``: told, not read; ``basis``:
    :func:`_basis`; ``share``: of the least thrust that could hold a hover, under which a still thrust shows the
    floor carrying the vehicle, :func:`_floor_carries`)."""
    n, u, last = len(rec.t), basis.u, basis.last
    held = np.minimum(basis.pos, len(u) - 1)
    rest_u = basis.still_u & (np.abs(rec.h[u] - h0) <= lim.height_tol_m)
    resting = (last >= 0) & np.isfinite(rec.h) & rest_u[held]
    still = (last >= 0) & basis.still_u[held]
    scale = _thrust_scale(rec, h0, basis.weight, lim) if calibrate else 1.0
    ratio = basis.ratio * scale  # a median commutes with a positive factor
    seen = given or rec.lift is None or _floor_carries(rec.t, rec.h, resting, ratio, share * basis.hover_at, lim)
    return _Reading(h0, seen, resting if seen else np.zeros(n, bool), last >= 0, still, basis.speed_u, basis.pos,
                    ratio, scale, basis.hover_at)


def _floor_carries(t: np.ndarray, h: np.ndarray, resting: np.ndarray, ratio: np.ndarray, hover_at: np.ndarray,
                   lim: ContactLimits) -> bool:
    """Whether the floor is seen to carry the vehicle on the rows ``resting`` (still and level at the lowest
    height ``h`` [m]): a thrust no hover could need there, under ``idle_ratio`` of the weight (however short) or
    under ``hover_at`` (the least share that could hold a hover in the strongest surface lift) for ``min_s``; or a
    thrust that moves through ``ramp_ratio`` of the weight within ``ramp_s`` while the height stays within
    ``ramp_m``, the vehicle still ``window_s`` before and after (rotors spooling up or down on the gear: a hover's
    thrust follows its height whatever the law, and a lift-off leaves)."""
    for a, b in _runs(resting & ((ratio < lim.idle_ratio) | (ratio < hover_at))):
        if t[b - 1] - t[a] >= lim.min_s or np.min(ratio[a:b]) < lim.idle_ratio:
            return True
    for a, b in _runs(resting):
        if t[b - 1] - t[a] < lim.ramp_s + 2 * lim.window_s:
            continue
        tt, hh = t[a:b], _window_median(t[a:b], h[a:b], lim.window_s)
        later = np.searchsorted(tt, tt + lim.ramp_s)
        i = np.flatnonzero((tt >= tt[0] + lim.window_s) & (later < b - a))
        j = later[i]
        i, j = i[tt[j] <= tt[-1] - lim.window_s], j[tt[j] <= tt[-1] - lim.window_s]
        if np.any((np.abs(ratio[a:b][j] - ratio[a:b][i]) >= lim.ramp_ratio) & (np.abs(hh[j] - hh[i]) <= lim.ramp_m)):
            return True
    return False


def _contact_in(rec: _Recording, mass: float, landed: float | None, calibrate: bool, lim: ContactLimits,
                rotor_plane: bool, skim_top: float | None, skim_landed: bool = True
                ) -> tuple[np.ndarray, list[tuple[float, float, str]]]:
    """Contact rows (margins included) and ``(t_start, t_end, why)`` of one recording."""
    n = len(rec.t)
    out = np.zeros(n, bool)
    reading = _read(rec, mass, landed, calibrate, lim, rotor_plane)
    if reading is None:
        return out, []
    h0, ratio, pos, scale = reading.h0, reading.ratio, reading.pos, reading.scale
    resting = reading.resting.copy()
    # still and level with the rotors idling or off for a while: something carries the vehicle at whatever height
    # it reads (a barometer's height drifts: a real PX4 log read its rest 0.45 m over the lowest height of the
    # recording). Shorter stretches are a motor cut in the air: commanded speeds drop at once, the rotors spin
    # down by their lag and the fall starts after it (Crazyflies: 0.25 s still at 5 cm with the commands at 0)
    idle = reading.still & (ratio < lim.idle_ratio) & ~resting
    for a, b in _runs(idle):
        idle[a:b] = rec.t[b - 1] - rec.t[a] >= lim.idle_rest_s
    resting |= idle
    resting &= ratio < 1.0  # once the rotors carry the weight, it lifts off
    hover_at = np.zeros(n)  # the least share of the weight that could hold a hover, on rows where that decides
    if rec.lift is not None:
        above = resting & (rec.h > h0 + lim.skim_m)  # beyond the gear's reach: a still hover in ground effect?
        above &= reading.hover_at > 0  # where no law bounds the lift (inside its pole), height alone decides
        hover_at[above] = reading.hover_at[above]
        resting &= ~above | (ratio < hover_at) | (ratio < lim.idle_ratio)  # idling rotors hold no hover
    found = []
    for a, b in _runs(resting):
        lowest = float(np.min(ratio[a:b]))
        # rotors off or idling (a drop to the floor before a restart) cannot hold a hover however short the rest
        median = float(np.median(ratio[a:b]))
        if (rec.t[b - 1] - rec.t[a] < lim.min_s and lowest >= lim.idle_ratio) or median >= lim.thrust_ratio:
            continue
        out |= (rec.t >= rec.t[a] - lim.margin_s) & (rec.t <= rec.t[b - 1] + lim.margin_s)
        core = slice(a, b)
        decides = hover_at[core] > 0
        found.append(_why(rec, core, h0, landed is not None, rotor_plane, float(np.max(reading.speed[pos[core]])),
                          median, scale, lim, float(np.min(hover_at[core][decides])) if decides.any() else None,
                          bool(np.all(idle[core])), reading.lowest))
    top = h0 + lim.skim_m if skim_top is None else skim_top
    seen = reading.landed if skim_top is None else skim_landed
    low = top - lim.skim_m
    # a rotor plane further under the landed height than the gear's give is no skim: the gear holds it up there,
    # so that recording's heights are measured otherwise (a second recording's motion capture 10 cm high had put
    # the vehicle's landed height at 0.160 m and the first's hover at 0.059 m "within 0.5 cm of" it, on the floor)
    skim = reading.known & np.isfinite(rec.h) & (rec.h <= top) & (rec.h >= low - lim.skim_m) & ~out
    rested = out.copy()
    skims = []  # (t_start, t_end, lowest height [m], lowest thrust share) of each skim
    for a, b in _runs(skim):
        if np.min(ratio[a:b]) >= lim.thrust_ratio or (a > 0 and rested[a - 1]) or (b < n and rested[b]):
            continue  # the rotors carry the weight, or a lift-off or touch-down its rest's margins cover
        if not seen and reading.still[max(a - 1, 0):b + 1].any():
            # no rest seen at the lowest height: a still vehicle there hovers (a recording that never lands, its
            # thrust under the weight by the ground effect itself), and so does one that leaves or settles into
            # such a hover; only a dip moving throughout may be the gear touching (real walks' dips to their
            # lowest set point: never still)
            continue
        out |= (rec.t >= rec.t[a] - lim.skim_margin_s) & (rec.t <= rec.t[b - 1] + lim.skim_margin_s)
        skims.append((float(rec.t[a]), float(rec.t[b - 1]), float(np.min(rec.h[a:b])), float(np.min(ratio[a:b]))))
    landed_text = ((f"the landed height {low:.3f} m" if seen else
                    f"the lowest the recording reached, {low:.3f} m (no rest seen there; the vehicle moving)")
                   if skim_top is None else
                   f"the vehicle's landed height over its recordings, {low:.3f} m" if seen else
                   f"the lowest the vehicle came over its recordings, {low:.3f} m (no rest seen; the vehicle moving)")
    return out, [(float(rec.t[a]), float(rec.t[b - 1]),
                  _joined_why(found, skims, rec.t[a], rec.t[b - 1], "rotor-plane height" if rotor_plane else "height",
                              landed_text, lim.skim_m))
                 for a, b in _runs(out)]


def _joined_why(found: list[tuple[float, float, str]], skims: list[tuple[float, float, float, float]], t0: float,
                t1: float, name: str, landed_text: str, skim_m: float) -> str:
    """The sentences of the contact cores inside ``[t0, t1]``, joined (several merge where margins overlap), and
    one for the skims among them (``(t_start, t_end, lowest height [m], lowest thrust share)``), however many."""
    def inside(a: float, b: float) -> bool:
        return a >= t0 - 1e-9 and b <= t1 + 1e-9

    sentences = list(dict.fromkeys(w for a, b, w in found if inside(a, b)))
    mine = [k for k in skims if inside(k[0], k[1])]
    if mine:
        times = "" if len(mine) == 1 else f" {len(mine)} times"
        sentences.append(f"skimming the floor{times}: {name} down to {min(k[2] for k in mine):.3f} m, within "
                         f"{100 * skim_m:.1f} cm of {landed_text}, thrust down to "
                         f"{100 * min(k[3] for k in mine):.0f} % of the weight: the landing gear may touch "
                         f"(a skid or a bounce)")
    return "; ".join(sentences)


def _resting_updates(rec: _Recording, u: np.ndarray, h0: float, lim: ContactLimits
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """On the update rows ``u``: whether the vehicle rests (height, stillness, attitude), the speed [m/s]
    (median over ``window_s``), and whether it is still and level at any height."""
    tu = rec.t[u]
    step = float(np.median(np.diff(tu))) if len(tu) > 1 else 1.0
    nw = max(3, int(round(lim.window_s / step)) | 1)
    speed = median_filter(np.linalg.norm(rec.v[u], axis=1), nw, mode="nearest")
    tilt = rec.tilt[u]
    swing = maximum_filter1d(tilt, nw, mode="nearest") - minimum_filter1d(tilt, nw, mode="nearest")
    still = (speed < lim.still_mps) & (tilt < lim.level_deg) & (swing < lim.steady_deg)
    return still & (np.abs(rec.h[u] - h0) <= lim.height_tol_m), speed, still


def _thrust_scale(rec: _Recording, h0: float, weight: float, lim: ContactLimits) -> float:
    """Factor that makes the thrust's vertical part carry the weight in the air (median), or 1.

    Rows ``air_m`` above the landed height count as in the air; where there are fewer than 10,
    rows above three height tolerances; where still too few, no scaling.
    """
    vertical = rec.thrust * np.cos(np.radians(rec.tilt))
    for above in (lim.air_m, 3 * lim.height_tol_m):
        air = np.isfinite(rec.h) & (rec.h > h0 + above) & (vertical > 0)
        if air.sum() >= 10:
            return float(weight / np.median(vertical[air]))
    return 1.0


def _window_median(t: np.ndarray, x: np.ndarray, window_s: float) -> np.ndarray:
    """Running median of ``x`` over about ``window_s`` [s] of rows."""
    step = float(np.median(np.diff(t))) if len(t) > 1 else 1.0
    return median_filter(x, max(1, int(round(window_s / step)) | 1), mode="nearest")


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """``(start, stop)`` row indices of the runs of True in ``mask``."""
    d = np.diff(np.r_[0, mask.astype(np.int8), 0])
    return list(zip(np.flatnonzero(d == 1), np.flatnonzero(d == -1)))


def _why(rec: _Recording, core: slice, h0: float, given: bool, rotor_plane: bool, speed: float, ratio: float,
         scale: float, lim: ContactLimits, hover_at: float | None = None, idle_only: bool = False,
         lowest: float | None = None) -> tuple[float, float, str]:
    """``(t_start, t_end, sentence)`` of one contact core (margins not included in the times); ``ratio``
    is the share of the weight the thrust carried there (median); ``hover_at`` the least share that could
    have held a hover on its rows beyond the gear's reach (None: none there); ``lowest`` the lowest height the
    recording reached where the landed height ``h0`` is a still height above it."""
    h = rec.h[core]
    name = "rotor-plane height" if rotor_plane else "height"
    ref = (f"the landed height given, {h0:.3f} m" if given
           else f"within {100 * lim.height_tol_m:.1f} cm of the lowest the recording reached, {h0:.3f} m"
           if lowest is None else
           f"within {100 * lim.height_tol_m:.1f} cm of {h0:.3f} m, the lowest still height where the floor is seen "
           f"to carry the vehicle; it came down to {lowest:.3f} m elsewhere, nearer another surface below")
    scaled = (f" (thrust scaled by {scale:.2f} so that it carries the weight in the air)" if abs(scale - 1) > 0.02
              else "")
    hover = ("" if hover_at is None else
             f"; more than {100 * lim.skim_m:.1f} cm up it stayed under the {100 * hover_at:.0f} % that could hold a "
             f"hover there in the strongest ground effect allowed")
    if idle_only:  # away from the landed height: the idling rotors alone tell it
        below = "the lowest the recording reached" if lowest is None else "its landed height"
        ref = (f"{np.min(h) - h0:.2f} m over {below}: the height drifts, but rotors idling "
               f"under {100 * lim.idle_ratio:.0f} % of the weight hold no still vehicle in the air")
    why = (f"on the landing gear: {name} {np.min(h):.3f}-{np.max(h):.3f} m ({ref}), speed under {speed:.2f} m/s, "
           f"level within {np.max(rec.tilt[core]):.0f} deg and thrust {100 * ratio:.0f} % of the weight"
           f"{scaled}{hover}: the floor carries the rest ({lim.margin_s:.1f} s margins either side)")
    return float(rec.t[core.start]), float(rec.t[core.stop - 1]), why
