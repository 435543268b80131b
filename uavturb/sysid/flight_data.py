"""A recording's streams on one time base, with the derivatives dynamics work needs.

The time base is the IMU's timestamps where there is an IMU (the accelerometer is then
used as recorded, never interpolated), else the ground truth's (motion-capture-only flights,
50 Hz and up); it is cut to the span that every stream covers. Ground truth and IMU are in the
rotor frame B (the readers put them there with ``vehicle.yaml``'s ``T_BS``).

Derivatives are local quadratic fits over a window given in seconds
(:mod:`uavturb.io.differentiate`: Savitzky-Golay on uniform sampling, correct on jittered
timestamps too); the window holds at least 5 samples, so at 50 Hz a 0.05 s window becomes
0.1 s. The same filter smooths regressors, so that fits compare like with like. Streams at
other rates (rotor speeds at 50 Hz, jittered) are interpolated linearly at their true times.
Streams a logger writes faster than they update (sample-and-hold repeats) are read on their
updates (:func:`held_updates`), rotor speeds that repeat because they are rounded where they crossed a rounding
boundary (:func:`rotor_repeats`). A stream that stops for a while (a logger's or a radio's dropout, motion
capture losing the markers) is not interpolated across: the rows in its dropouts, and those within a
derivative window of them, are marked (:attr:`FlightData.covered`) for fits to leave out
(:func:`uavturb.sysid.streams.dropouts`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from uavturb.errors import InputError
from uavturb.io import align
from uavturb.io.body_frame import to_body
from uavturb.io.differentiate import derivative_matched, local_quadratic
from uavturb.io.recording import GroundTruth, Recording, Rotors
from uavturb.physics import quaternion as quat
from uavturb.scene.heights import SurfaceIndex
from uavturb.numerics.stream_updates import (column_update_masks, hold_period_s, read_at_crossings, rounding_steps,
                                             staggered, update_mask)
from uavturb.sysid.streams import MAD_TO_SIGMA, dropouts


@dataclass
class FlightData:
    """Aligned samples of one flight, ``K`` rows.

    Attributes
    ----------
    name : str, the recording's name
    t_ns : (K,) int64 ns, the time base
    t : (K,) s since the first ground-truth row
    p : (K, 3) m, position in W
    q : (K, 4) quaternion w, x, y, z, B to world
    v : (K, 3) m/s, velocity of B's origin in W
    w : (K, 3) rad/s, body rates (gyro minus bias, or from the quaternions)
    acc : (K, 3) m/s^2 or None, specific force in B, biases of the state file removed
    rotor_speeds : (K, N) rad/s
    dv : (K, 3) m/s^2, smoothed derivative of ``v``
    dw : (K, 3) rad/s^2, smoothed derivative of ``w``
    d_down, d_up : (K,) m or None, heights of the rotor plane (``vehicle.rotor_plane_z`` above the body
        origin) over the surface below and to the surface above (``inf``: none)
    window : int, Savitzky-Golay window [samples]
    rotor_fresh : (K,) bool or None, where the rotor stream is held (:func:`held_updates`): the rows
        nearest each of its updates, the only rows whose rotor speeds were measured rather than
        interpolated between updates (None: the stream updates on every row, or its repeats are those of
        its resolution, :func:`rotor_repeats`)
    covered : (K,) bool or None, rows where every stream the physics reads has samples around them (None:
        no stream has a dropout); see :func:`uavturb.sysid.streams.dropouts`
    gaps : the dropouts, ``(stream file, t_start, t_end)`` [s since the first ground-truth row]
    voltage : (K,) V or None, the battery's voltage (``battery0``, interpolated between its updates; nan outside
        its span); None where the recording has no battery stream
    voltage_noise_v2 : V^2 or None, the variance of ``voltage``'s noise at a row, mean over the rows
        (:func:`battery_voltage_noise`); None without a battery stream
    scan_noise_m : m or None, the point cloud's noise that the heights were read through
        (:attr:`uavturb.scene.heights.SurfaceIndex.scan_noise_m`; 0: answered point by point); None without heights
    floor_filled : share of the rows whose ``d_down`` is over the cloud's floor plane, no point of the cloud lying
        under their rotor plane (:meth:`uavturb.scene.heights.SurfaceIndex.d_down_filled`); None without heights
    floor_tilt : where the cloud's floor slopes (a scan tilted against the world), its slope [degrees] and the
        largest height levelled [m] (:meth:`uavturb.scene.heights.SurfaceIndex.tilt`); None where it is level
    """

    name: str
    t_ns: np.ndarray
    t: np.ndarray
    p: np.ndarray
    q: np.ndarray
    v: np.ndarray
    w: np.ndarray
    acc: np.ndarray | None
    rotor_speeds: np.ndarray
    dv: np.ndarray
    dw: np.ndarray
    d_down: np.ndarray | None
    d_up: np.ndarray | None
    window: int
    rotor_fresh: np.ndarray | None = None
    covered: np.ndarray | None = None
    gaps: list[tuple[str, float, float]] = field(default_factory=list)
    voltage: np.ndarray | None = None
    scan_noise_m: float | None = None
    floor_filled: float | None = None
    floor_tilt: tuple[float, float] | None = None
    voltage_noise_v2: float | None = None

    def __len__(self) -> int:
        return len(self.t)

    @property
    def dt(self) -> float:
        """Median sampling step [s]."""
        return float(np.median(np.diff(self.t)))

    def smooth(self, x: np.ndarray) -> np.ndarray:
        """The filter of the derivatives, without differentiating (axis 0)."""
        return local_quadratic(self.t, np.asarray(x, float), self.window, deriv=0)

    def matched(self, x: np.ndarray) -> np.ndarray:
        """The filter the derivatives ``dv``, ``dw`` put on a rate, on ``x`` (axis 0): a cause regressed against a
        derivative, filtered alike (:func:`~uavturb.io.differentiate.derivative_matched`)."""
        return derivative_matched(self.t, np.asarray(x, float), self.window)

    def subset(self, mask: np.ndarray) -> "FlightData":
        """Rows where ``mask`` holds (derivatives already computed stay as they are)."""
        def pick(a):
            return None if a is None else a[mask]
        return FlightData(self.name, self.t_ns[mask], self.t[mask], self.p[mask], self.q[mask], self.v[mask],
                          self.w[mask], pick(self.acc), self.rotor_speeds[mask], self.dv[mask], self.dw[mask],
                          pick(self.d_down), pick(self.d_up), self.window, pick(self.rotor_fresh),
                          pick(self.covered), list(self.gaps), pick(self.voltage), self.scan_noise_m, self.floor_filled,
                          self.floor_tilt, self.voltage_noise_v2)


#: share of repeated rows above which a stream may be held (read on its updates only: sample-and-hold loggers)
HELD_SHARE = 0.2
#: share of a held stream's updates that its logger repeats at least once
HELD_UPDATES = 0.8


def held_updates(rec: Recording) -> tuple[GroundTruth, Rotors]:
    """The ground truth and rotor speeds on their updates (``recordings.md``: "what a stream really holds
    is its updates"): where a logger repeats the last value in more than :data:`HELD_SHARE` of a
    stream's rows, the repeats are dropped, so that derivatives and interpolation work between real
    updates instead of on steps. Rotor speeds whose columns update on their own (:func:`uavturb.sysid.streams.
    staggered`: one ESC reported at a time) keep every row where some column updated, each column
    interpolated between its own updates. A value holds across a gap far longer than the stream's others
    (:func:`held_across_long_gaps`). Rotor speeds that repeat because they are rounded (:func:`rotor_repeats`) are
    read where they crossed a rounding boundary (:func:`~uavturb.numerics.stream_updates.read_at_crossings`).
    Streams that update on every row are returned as they are."""
    gt, rotors = rec.ground_truth, rec.rotors
    m = _updates(np.hstack([gt.p, gt.q, gt.v]))
    if m is not None:
        gt = GroundTruth(t_ns=gt.t_ns[m], p=gt.p[m], q=gt.q[m], v=gt.v[m], b_w=gt.b_w[m], b_a=gt.b_a[m])
    repeats = rotor_repeats(rotors.speeds)
    if repeats == "rounded":
        rotors = Rotors(*read_at_crossings(rotors.t_ns, rotors.speeds))
    elif repeats == "held":
        m = _updates(rotors.speeds)
        rotors = (_columns_on_their_updates(rotors, m) if staggered(rotors.speeds) else
                  held_across_long_gaps(Rotors(t_ns=rotors.t_ns[m], speeds=rotors.speeds[m]), rotors.t_ns))
    return gt, rotors


#: a gap between a rotor stream's changes this many times its median gap is a value that held (a steady hover)
HOLD_GAPS = 3.0


def held_across_long_gaps(updates: Rotors, row_ns: np.ndarray) -> Rotors:
    """A rotor stream read on its changes (``updates``), with each value held until just before the next change
    where the two are more than :data:`HOLD_GAPS` times the median gap apart (a point one row period of the
    recorded rows ``row_ns`` [ns] before the change, carrying the value): the value held there, update after update
    (a steady hover whose speed rounds alike, or ESC telemetry repeating it), and a line drawn between the changes
    would be off by up to a step. A 17 s hover at a true 147.7 rad/s rounded to 148, between a change from 147 and
    one to 149, read up to 1 rad/s high drawn as a line: 1.4 % of thrust near the floor, a small quadrotor's
    simulated ground effect (mu = 2) read 1.5."""
    t = np.asarray(updates.t_ns, np.int64)
    if len(t) < 3 or len(row_ns) < 2:
        return updates
    gaps = np.diff(t)
    long = np.flatnonzero(gaps > HOLD_GAPS * np.median(gaps))
    row = int(np.median(np.diff(np.asarray(row_ns, np.int64))))
    long = long[gaps[long] > row]
    if not len(long):
        return updates
    t_all = np.concatenate([t, t[long + 1] - row])
    w_all = np.concatenate([updates.speeds, updates.speeds[long]])
    order = np.argsort(t_all, kind="stable")
    return Rotors(t_ns=t_all[order], speeds=w_all[order])


def _columns_on_their_updates(rotors: Rotors, rows: np.ndarray) -> Rotors:
    """A staggered held stream (each rotor's speed updating on its own) on the rows ``rows`` where any
    column updated, each column interpolated between its own updates (and the stream's last row): a column
    held since its last update is a third of a second stale at 3 Hz. A column's value holds across a gap far longer
    than its others (:func:`held_across_long_gaps`)."""
    own = column_update_masks(rotors.speeds)
    own[:, -1] = True
    t = rotors.t_ns[rows]
    columns = [held_across_long_gaps(Rotors(rotors.t_ns[m], rotors.speeds[m, c:c + 1]), rotors.t_ns)
               for c, m in enumerate(own)]
    speeds = np.column_stack([align.interpolate(col.t_ns, col.speeds[:, 0], t) for col in columns])
    return Rotors(t_ns=t, speeds=speeds)


def _updates(values: np.ndarray) -> np.ndarray | None:
    """The update rows of a held stream and its last row (a held value still holds until the stream
    ends), or None for a stream that is not held.

    A logger that writes faster than a stream updates repeats nearly every update for one row or
    more; values that merely repeat when they change by less than their resolution (rotor speeds
    rounded to 1 rad/s in a still hover, positions to 1 mm) repeat in bursts, most updates not at all.
    A stream is held where more than :data:`HELD_SHARE` of its rows repeat *and* more than
    :data:`HELD_UPDATES` of its updates are repeated at least once."""
    m = update_mask(values)
    if len(m) < 3 or 1.0 - m.mean() <= HELD_SHARE:
        return None
    repeated = ~m[1:][m[:-1]]  # for each update row (but the last row), whether the next row repeats it
    if not len(repeated) or repeated.mean() <= HELD_UPDATES:
        return None
    m[-1] = True
    return m


def flight_data(rec: Recording, *, window_s: float = 0.05, heights: bool = True,
                time_base: str = "auto") -> FlightData:
    """Put a recording's streams on one time base.

    Parameters
    ----------
    rec : Recording with ground truth and rotor speeds
    window_s : Savitzky-Golay window [s] for derivatives and smoothing
    heights : compute ``d_down``/``d_up`` from the point cloud when there is one
    time_base : ``auto`` (IMU if present), ``imu`` or ``groundtruth``
    """
    rec = to_body(rec)  # no-op for the readers' recordings, already in B
    where = rec.path or rec.name
    if rec.rotors is None:
        raise InputError(f"{where}/mav0/rotors0/data.csv", "rotor speeds are needed but the recording has none")
    gt, rotors = held_updates(rec)
    rotors_held = rotor_repeats(rec.rotors.speeds) == "held"
    use_imu = rec.imu is not None and time_base in ("auto", "imu")
    if time_base == "imu" and rec.imu is None:
        raise InputError(f"{where}/mav0/imu0/data.csv", "file not found (time_base=imu)")
    streams = [("mav0/state_groundtruth_estimate0/data.csv", gt.t_ns), ("mav0/rotors0/data.csv", rotors.t_ns)]
    if use_imu:
        streams.append(("mav0/imu0/data.csv", rec.imu.t_ns))
    start = max(int(s[1][0]) for s in streams)
    end = min(int(s[1][-1]) for s in streams)
    if end <= start:
        raise InputError(f"{where}/{streams[-1][0]}", "does not overlap the other streams in time")
    base = rec.imu.t_ns if use_imu else gt.t_ns
    t_ns = base[(base >= start) & (base <= end)]
    t_rel = (t_ns - t_ns[0]) * 1e-9 if len(t_ns) else np.zeros(0)
    dt = float(np.median(np.diff(t_rel))) if len(t_ns) > 1 else 0.0
    window = max(5, int(round(window_s / dt)) | 1) if dt > 0 else 5
    if len(t_ns) < window + 2:
        span = float(t_rel[-1]) if len(t_rel) else 0.0
        raise InputError(str(where), f"only {len(t_ns)} samples ({span:.3g} s) where all streams overlap: too few for "
                                     f"the {window_s:g} s windows of a derivative (at least {min(window, 5) + 2} "
                                     "samples spanning one window)")

    p = align.interpolate(gt.t_ns, gt.p, t_ns)
    v = align.interpolate(gt.t_ns, gt.v, t_ns)
    q = align.interpolate_quaternions(gt.t_ns, gt.q, t_ns)
    b_w = align.interpolate(gt.t_ns, gt.b_w, t_ns)
    b_a = align.interpolate(gt.t_ns, gt.b_a, t_ns)
    rotor = align.interpolate(rotors.t_ns, rotors.speeds, t_ns)
    t = (t_ns - rec.t0_ns) * 1e-9

    if use_imu:
        imu = rec.imu
        sel = np.searchsorted(imu.t_ns, t_ns)
        gyro, acc = imu.gyro[sel], imu.acc[sel]  # in B, lever-arm terms removed by the reader
        w = gyro - b_w
        acc = acc - b_a
    else:
        w = quat.angular_velocity_body(t, q)
        acc = None

    dv = local_quadratic(t_rel, v, window, deriv=1)  # m/s^2, at the samples' true times
    dw = local_quadratic(t_rel, w, window, deriv=1)  # rad/s^2

    d_down = d_up = scan_noise = floor_filled = floor_tilt = None
    if heights and rec.points is not None:
        index = SurfaceIndex(rec.points)
        scan_noise = index.scan_noise_m
        # surface effects depend on the rotor plane's height, not the body origin's (recordings.md)
        rotor_plane = rec.vehicle.rotor_plane_positions(p, quat.to_rotation_matrix(q))
        tilt = index.tilt(rotor_plane)
        body = p
        if tilt is not None:  # a scan tilted against the world, levelled about the flight's centre: the levelled
            # cloud's heights at a position are the tilted one's where its floor lies that much higher
            up = np.c_[np.zeros((len(tilt[0]), 2)), tilt[0]]
            rotor_plane, body = rotor_plane + up, p + up
            floor_tilt = (tilt[1], float(np.max(np.abs(tilt[0]))))
        (d_down, filled), d_up = index.d_down_filled(rotor_plane), index.d_up(rotor_plane)
        floor_filled = float(np.mean(filled)) if len(filled) else 0.0
        _check_rotor_plane_above_surfaces(rec, index, body, t, d_up, np.any(rotor > 0.0, axis=1))
    fresh = _nearest_rows(t_ns, rotors.t_ns) if rotors_held else None
    # a dropout is a stretch with no row: a held stream's rows go on while its value holds, and a quantised
    # one's updates can be seconds apart in a steady hover
    rows = [("mav0/state_groundtruth_estimate0/data.csv", rec.ground_truth.t_ns), ("mav0/rotors0/data.csv",
                                                                                 rec.rotors.t_ns)]
    covered, gaps = _covered(t_ns, rec.t0_ns, window, rows + streams[2:])
    battery = _battery_samples(rec)  # read once: the voltage and its noise
    return FlightData(rec.name, t_ns, t, p, q, v, w, acc, rotor, dv, dw, d_down, d_up, window, fresh, covered, gaps,
                      _voltage_at(battery, t_ns), scan_noise, floor_filled, floor_tilt, _voltage_noise(battery, t_ns))


def _battery_samples(rec: Recording) -> tuple[np.ndarray, np.ndarray] | None:
    """``(t_ns, V)`` of the battery stream's samples: its updates where a logger repeats them (:func:`_updates`),
    its rows otherwise, finite voltages only; None without two of them."""
    bat = rec.battery
    if bat is None or len(bat.t_ns) < 2:
        return None
    volts = np.asarray(bat.voltage, float)
    m = _updates(volts[:, None])
    keep = np.isfinite(volts) if m is None else (m & np.isfinite(volts))
    if keep.sum() < 2:
        return None
    return bat.t_ns[keep], volts[keep]


def battery_voltage(rec: Recording, t_ns: np.ndarray) -> np.ndarray | None:
    """(K,) V, the battery's voltage at ``t_ns`` [ns]: interpolated linearly between the stream's updates where a
    logger repeats them (:func:`_updates`), between its rows otherwise; nan outside its span and where it holds
    no finite voltage. None without a ``battery0`` stream of two rows or more."""
    return _voltage_at(_battery_samples(rec), t_ns)


def _voltage_at(samples: tuple[np.ndarray, np.ndarray] | None, t_ns: np.ndarray) -> np.ndarray | None:
    """:func:`battery_voltage` from the stream's samples (:func:`_battery_samples`)."""
    if samples is None:
        return None
    tb, vb = samples
    out = np.interp(t_ns.astype(float), tb.astype(float), vb)
    out[(t_ns < tb[0]) | (t_ns > tb[-1])] = np.nan
    return out


def battery_voltage_noise(rec: Recording, t_ns: np.ndarray) -> float | None:
    """V^2, the variance of the noise of :func:`battery_voltage` at ``t_ns`` [ns], mean over the rows within the
    stream's span; None without a battery stream (or under four samples).

    The samples' own noise ``s^2`` is read from their second differences, ``v[k+1] - 2 v[k] + v[k-1]``, whose
    variance is ``6 s^2`` for white noise on a voltage that changes smoothly from sample to sample: ``s`` is their
    median absolute deviation times 1.4826 over sqrt(6), which the few steps of a load changing within a sample interval
    (a take-off) do not move. A row between samples ``k`` and ``k + 1``, a fraction ``f`` of the way, holds
    ``(1 - f)^2 + f^2`` of ``s^2`` (linear interpolation: half at the middle). A voltage that changes by less than
    its resolution between samples has second differences of 0 mostly, and reads no noise: its rounding is then
    no error that varies from row to row."""
    return _voltage_noise(_battery_samples(rec), t_ns)


def _voltage_noise(samples: tuple[np.ndarray, np.ndarray] | None, t_ns: np.ndarray) -> float | None:
    """:func:`battery_voltage_noise` from the stream's samples (:func:`_battery_samples`)."""
    if samples is None or len(samples[0]) < 4:
        return None
    tb, vb = (np.asarray(x, float) for x in samples)
    d2 = vb[2:] - 2.0 * vb[1:-1] + vb[:-2]
    s2 = (MAD_TO_SIGMA * float(np.median(np.abs(d2 - np.median(d2))))) ** 2 / 6.0
    t = np.asarray(t_ns, float)
    t = t[(t >= tb[0]) & (t <= tb[-1])]
    if not len(t):
        return None
    k = np.clip(np.searchsorted(tb, t, side="right") - 1, 0, len(tb) - 2)
    f = (t - tb[k]) / (tb[k + 1] - tb[k])
    return s2 * float(np.mean((1.0 - f) ** 2 + f**2))


#: m, how far under the surface below the body origin the rotor plane may seem to dip (a scan's noise, a
#: height reference off by a centimetre) before ``rotor_plane_z`` is refused
UNDER_SURFACE_M = 0.02
#: rows the rotor plane must spend that far under the surface to be refused (a single bad row of a
#: position stream is no evidence of a wrong vehicle file)
UNDER_SURFACE_ROWS = 5


def _check_rotor_plane_above_surfaces(rec: Recording, index: SurfaceIndex, p: np.ndarray, t: np.ndarray,
                                      d_up: np.ndarray, turning: np.ndarray) -> None:
    """Refuse a ``rotor_plane_z`` (``vehicle.yaml``) that puts the rotor plane under the surface the body origin
    stands over while the rotors turn: rotors cannot turn inside the floor, so its sign (or the point cloud's
    floor) is wrong.

    A rotor plane below the body origin (``rotor_plane_z < 0``) that dips into the floor sees the floor *above*
    it (``d_up``, (K,) m, of the rotor plane) while the body origin ``p`` (K, 3) [m, W] sees it below: the
    rows where the rotors turn (``turning``, (K,) bool) and the rotor plane's ``d_up`` is within
    ``|rotor_plane_z|`` are checked against the body origin's own height. Refused where
    :data:`UNDER_SURFACE_ROWS` rows or more lie over :data:`UNDER_SURFACE_M` under it. Rows with the rotors
    stopped say nothing of them: a landed vehicle's state estimate may drift down through the floor (a 67 g
    Crazyflie's, after its motors stopped, sank 0.4 m in 2 s and had been refused as a wrong sign). (A rotor plane
    above the body origin given the wrong sign stays above the floor: nothing shows it here.)
    """
    z_r = float(rec.vehicle.rotor_plane_z)
    if z_r >= 0.0:
        return
    rows = np.flatnonzero(np.isfinite(d_up) & (d_up <= -z_r) & turning)
    if not len(rows):
        return
    body = index.d_down(p[rows])  # the body origin's height over the surface below it
    depth = np.where(np.isfinite(body) & (body < -z_r), d_up[rows], 0.0)  # the rotor plane under that surface
    under = rows[depth > UNDER_SURFACE_M]
    if len(under) < UNDER_SURFACE_ROWS:
        return
    where = f"{rec.path}/vehicle.yaml" if rec.path is not None else f"{rec.name}: vehicle.yaml"
    raise InputError(where, f"rotor_plane_z {z_r:.3g} m puts the rotor plane up to {float(depth.max()):.2f} m under "
                            f"the floor (or the surface below the body origin) in {len(under)} rows ({t[under[0]]:.1f}-"
                            f"{t[under[-1]]:.1f} s): it is the height of the rotor discs above the body origin along "
                            "z_B, negative below it; its sign may be wrong, or the point cloud's floor too high")


def _covered(t_ns: np.ndarray, t0_ns: int, window: int, streams: list[tuple[str, np.ndarray]]
             ) -> tuple[np.ndarray | None, list[tuple[str, float, float]]]:
    """(rows of the time base ``t_ns`` away from every stream's dropouts by more than ``window`` rows, or
    None where there is none; the dropouts as ``(stream file, t_start, t_end)`` [s from ``t0_ns``])."""
    gaps = [(name, a, b) for name, ts in streams for a, b in dropouts(ts)]
    if not gaps:
        return None, []
    mark = np.zeros(len(t_ns) + 1, int)
    for _, a, b in gaps:
        lo = max(int(np.searchsorted(t_ns, a, side="right")) - window, 0)
        hi = min(int(np.searchsorted(t_ns, b, side="left")) + window, len(t_ns))
        mark[lo] += 1
        mark[hi] -= 1
    covered = np.cumsum(mark[:-1]) == 0
    return covered, [(name, (a - t0_ns) * 1e-9, (b - t0_ns) * 1e-9) for name, a, b in gaps]


def rotor_repeats(speeds: np.ndarray) -> str | None:
    """Why a rotor stream ``speeds`` (K, N) repeats rows: ``"held"`` (a logger writing faster than the stream
    updates, :func:`_updates`), ``"rounded"`` (values that change by one step of their resolution, repeated until
    the speed moves by a step: :func:`~uavturb.numerics.stream_updates.rounding_steps`), or None (it updates on
    nearly every row, or repeats only in bursts)."""
    if _updates(speeds) is None:
        return None
    return "rounded" if rounding_steps(speeds) else "held"


def rotor_hold_s(rotors: Rotors) -> float:
    """s, how long the rotor stream ``rotors`` holds a value as read (:func:`held_updates`): its updates' period
    (:func:`~uavturb.numerics.stream_updates.hold_period_s`), one row's where its repeats are rounding (read at its
    crossings, which are known to a row)."""
    if rotor_repeats(rotors.speeds) == "rounded":
        return float(np.median(np.diff(np.asarray(rotors.t_ns, np.int64)))) * 1e-9
    return hold_period_s(rotors.t_ns, rotors.speeds)


def _nearest_rows(t_ns: np.ndarray, update_ns: np.ndarray) -> np.ndarray:
    """(K,) bool, the rows of the time base ``t_ns`` nearest each update time in ``update_ns`` that falls
    within it (a held stream's last row, which only marks where the stream ends, excepted)."""
    fresh = np.zeros(len(t_ns), bool)
    u = update_ns[:-1]
    u = u[(u >= t_ns[0]) & (u <= t_ns[-1])]
    if len(u) and len(t_ns) > 1:
        i = np.clip(np.searchsorted(t_ns, u), 1, len(t_ns) - 1)
        fresh[np.where(u - t_ns[i - 1] <= t_ns[i] - u, i - 1, i)] = True
    return fresh
