"""Checks of a recording against what a flying multirotor must show, before any physics.

Mistakes that pass every format check and silently spoil identification, residuals and gap
reports: the commands that do physics stop on them with one line (``recordings.md``).

* **Thrust axis** (:func:`check_thrust_axis`). Rotors push along ``+z_B``; whatever the
  vehicle does, the mean specific force over a flight (what an accelerometer reads: thrust
  plus external forces over the mass) points along it, up to the mean external force. A
  ``T_BS`` that is missing or wrong (EuRoC's IMU frame S has x within ~20 deg of up) puts it
  far off. Threshold :data:`MAX_THRUST_AXIS_ANGLE_DEG` = 30 deg: a correct frame stays within a
  few degrees (a sustained mean horizontal force of 0.58 g would be needed to reach 30 deg,
  more drag than any indoor flight has), while a wrong axis assignment is off by 70-180 deg
  (EuRoC without ``T_BS``: about 70 deg).
* **Rotor columns** (:func:`check_rotor_columns`). A column that is zero, or constant, while
  the vehicle flies and the other rotors vary, is a dead sensor, a wrong column order or a
  stream that is not rotor speeds: the vehicle could not fly so.
* **Units, frames and clocks** (:func:`check_position_velocity`, :func:`check_imu`,
  :func:`check_rotor_clock`): positions that move as the velocities say, an IMU that reads the motion
  capture's specific force and rate of turn on its clock, rotor speeds whose thrust follows the force on
  theirs. Millimetres, g, deg/s, quaternions in x, y, z, w order and a stream 0.3 s off had each given a
  report naming nothing over a residual the size of the weight.

"In flight": rows whose rotor ``sum(w_i^2)`` is at least :data:`FLIGHT_SHARE` of its 95th
percentile (hover dominates a flight; idling or resting on the ground is far below).
"""

from __future__ import annotations

import numpy as np

from uavturb.errors import InputError
from uavturb.io import align
from uavturb.io.differentiate import derivative
from uavturb.io.recording import Recording
from uavturb.numerics.filters import high_passed, moving_mean_bounds
from uavturb.numerics.stream_updates import hold_period_s, read_between_updates, staggered, update_mask
from uavturb.physics import quaternion as quat
from uavturb.physics.dynamics import GRAVITY

MAX_THRUST_AXIS_ANGLE_DEG = 30.0
FLIGHT_SHARE = 0.5
#: below this norm [m/s^2] the mean specific force has no direction worth checking (free fall)
MIN_SPECIFIC_FORCE = 0.3 * GRAVITY
#: s, window of the ground-truth velocity derivative when there is no IMU
MOCAP_DERIVATIVE_WINDOW_S = 0.1
MIN_FLIGHT_ROWS = 20


def _where(rec: Recording, relative: str) -> str:
    return f"{rec.path}/{relative}" if rec.path is not None else f"{rec.name}: {relative}"


def in_flight(rec: Recording, t_ns: np.ndarray) -> np.ndarray:
    """(N,) bool: rows at ``t_ns`` where the rotors carry at least :data:`FLIGHT_SHARE` of their
    95th-percentile ``sum(w^2)``; all rows when there are no rotor speeds or too few such rows.

    A held rotor stream (ESC telemetry updated at 3 Hz, one motor at a time or all together) keeps its last
    value until the next update: each interval in flight ends one update period
    (:func:`uavturb.numerics.stream_updates.hold_period_s`)
    before the held values say. Rotor speeds held at 3 Hz and 60 ms late had kept their hover value 0.3 s
    into each touchdown of a real take-off flight, and the landing impacts let in had hidden a correctly
    stamped IMU's clock (correlation 0.14 instead of 0.93) behind a spurious 0.12 s offset."""
    if rec.rotors is None or len(rec.rotors) < 2:
        return np.ones(len(t_ns), bool)
    S = align.interpolate(rec.rotors.t_ns, np.sum(rec.rotors.speeds**2, axis=1), t_ns)
    top = np.percentile(S, 95)
    flying = S >= FLIGHT_SHARE * top if top > 0 else np.zeros(len(t_ns), bool)
    hold = hold_period_s(rec.rotors.t_ns, rec.rotors.speeds)
    if hold > 0 and flying.any():
        t = (np.asarray(t_ns, np.int64) - int(t_ns[0])) * 1e-9
        ends = np.append(t[np.flatnonzero(flying[:-1] & ~flying[1:]) + 1], np.inf)  # first rows after each interval
        flying &= ends[np.searchsorted(ends, t)] - t > hold
    return flying if flying.sum() >= MIN_FLIGHT_ROWS else np.ones(len(t_ns), bool)


def mean_specific_force(rec: Recording) -> tuple[np.ndarray, str]:
    """Mean specific force in flight [m/s^2] in B (3,), and its source (``imu0`` or ``ground truth``).

    IMU: the accelerometer in B. Without one: ``R_WB^T (dv/dt + g e_z)`` from the ground truth.
    """
    if rec.imu is not None and len(rec.imu) > 0:
        return rec.imu.acc[in_flight(rec, rec.imu.t_ns)].mean(axis=0), "imu0"
    gt = rec.ground_truth
    t = (gt.t_ns - gt.t_ns[0]) * 1e-9
    dv = derivative(t, gt.v, MOCAP_DERIVATIVE_WINDOW_S)  # m/s^2 in W
    f_B = quat.rotate_inverse(gt.q, dv + np.array([0.0, 0.0, GRAVITY]))  # R_WB^T (dv/dt + g e_z)
    return f_B[in_flight(rec, gt.t_ns)].mean(axis=0), "ground truth"


def check_thrust_axis(rec: Recording) -> float:
    """Angle [deg] between the mean specific force in flight and ``+z_B``; raises past 30 deg.

    Raises
    ------
    InputError
        ``<rec>/vehicle.yaml: T_BS: the mean specific force in flight points A deg away from the
        rotor axis +z_B ...``
    """
    if rec.frame != "B":
        raise ValueError("check_thrust_axis needs a recording in the rotor frame B")
    f, source = mean_specific_force(rec)
    norm = float(np.linalg.norm(f))
    if not np.isfinite(norm) or norm < MIN_SPECIFIC_FORCE:
        return float("nan")
    angle = float(np.degrees(np.arccos(np.clip(f[2] / norm, -1.0, 1.0))))
    if angle > MAX_THRUST_AXIS_ANGLE_DEG:
        raise InputError(_where(rec, "vehicle.yaml"),
                         f"T_BS: the mean specific force in flight points {angle:.0f} deg away from the rotor axis "
                         f"+z_B (reads ({f[0]:.1f}, {f[1]:.1f}, {f[2]:.1f}) m/s^2 in B, from {source}); set T_BS "
                         f"to the pose of the sensor frame S in the rotor frame B")
    return angle


#: the median acceleration in flight [g] over which the ground truth's positions and velocities are read as in
#: millimetres (105 real Crazyflie flights: 0.02-0.21 g; millimetres make it a thousand times that)
MAX_MEDIAN_ACCELERATION_G = 3.0


def check_state_units(rec: Recording) -> float:
    """The median acceleration in flight [m/s^2] of the ground truth's velocities; raises where it is over
    :data:`MAX_MEDIAN_ACCELERATION_G`: positions and velocities in millimetres alike pass
    :func:`check_position_velocity`, and had been blamed on the quaternions or on ``T_BS``. ``nan`` with too few
    rows in flight.

    Raises
    ------
    InputError
        ``<rec>/mav0/state_groundtruth_estimate0/data.csv: the velocities change by A g (median in flight) ...``
    """
    gt = rec.ground_truth
    t = (gt.t_ns - gt.t_ns[0]) * 1e-9
    a = np.linalg.norm(derivative(t, gt.v, MOCAP_DERIVATIVE_WINDOW_S), axis=1)
    rows = in_flight(rec, gt.t_ns) & np.isfinite(a)
    if rows.sum() < MIN_FLIGHT_ROWS:
        return float("nan")
    median = float(np.median(a[rows]))
    if median > MAX_MEDIAN_ACCELERATION_G * GRAVITY:
        raise InputError(_where(rec, "mav0/state_groundtruth_estimate0/data.csv"),
                         f"the velocities change by {median / GRAVITY:.3g} g (median in flight), where flights stay "
                         "well under one (real Crazyflies' 0.02-0.21 g): positions and velocities in millimetres? "
                         "(recordings.md: metres, m/s)")
    return median


#: without an IMU, quaternions are read as stored x, y, z, w where the rotor axis lies this many degrees or more from
#: the motion capture's specific force in flight (median over rows) as read, and under :data:`QUATERNION_ALIGNED_DEG`
#: (and a third of that) with the columns read as x, y, z, w. A flight's thrust follows its attitude within a few
#: degrees (drag and noise); the probe's quadrotor, its columns stored x, y, z, w, read a 180 degree turn about an
#: axis near z: the mean force passed :func:`check_thrust_axis`, and the report said the nominal model missed by 99 %
QUATERNION_MISREAD_DEG, QUATERNION_ALIGNED_DEG = 20.0, 10.0


def check_quaternion_order(rec: Recording) -> tuple[float, float]:
    """Without an IMU (whose gyroscope tells the quaternions' order, :func:`check_imu`), the median angle [deg] in
    flight between the rotor axis and the motion capture's specific force ``dv/dt + g e_z``, as the quaternions are
    read (w, x, y, z) and with the columns read as x, y, z, w; raises where the second reading fits and the first
    does not (:data:`QUATERNION_MISREAD_DEG`). ``(nan, nan)`` with an IMU, a ``T_BS`` (its rotation was applied to
    the quaternions as read), or too few rows in flight.

    Raises
    ------
    InputError
        ``<rec>/mav0/state_groundtruth_estimate0/data.csv: the rotor axis lies A deg from the specific force ...``
    """
    nan = (float("nan"), float("nan"))
    if (rec.imu is not None and len(rec.imu) > 0) or not np.allclose(rec.vehicle.T_BS_matrix, np.eye(4)):
        return nan
    gt = rec.ground_truth
    t = (gt.t_ns - gt.t_ns[0]) * 1e-9
    f_W = derivative(t, gt.v, MOCAP_DERIVATIVE_WINDOW_S) + np.array([0.0, 0.0, GRAVITY])  # m/s^2, W
    norm = np.linalg.norm(f_W, axis=1)
    rows = in_flight(rec, gt.t_ns) & np.isfinite(norm) & (norm > MIN_SPECIFIC_FORCE)
    if rows.sum() < MIN_FLIGHT_ROWS:
        return nan
    unit = f_W[rows] / norm[rows, None]

    def median_angle(q: np.ndarray) -> float:
        axis = quat.to_rotation_matrix(quat.normalize(q))[:, :, 2]  # rotor axis z_B in W
        return float(np.degrees(np.median(np.arccos(np.clip(np.sum(axis * unit, axis=1), -1.0, 1.0)))))

    as_read, as_xyzw = median_angle(gt.q[rows]), median_angle(gt.q[rows][:, [3, 0, 1, 2]])
    if as_read >= QUATERNION_MISREAD_DEG and as_xyzw < min(QUATERNION_ALIGNED_DEG, as_read / 3.0):
        raise InputError(_where(rec, "mav0/state_groundtruth_estimate0/data.csv"),
                         f"the rotor axis lies {as_read:.0f} deg from the motion capture's specific force in flight "
                         f"(median over rows), {as_xyzw:.1f} deg with the quaternion columns read as x, y, z, w: "
                         "quaternions must be stored w, x, y, z (recordings.md)")
    return as_read, as_xyzw


#: below this correlation between vertical acceleration and vertical thrust the world's z looks inverted: on an
#: imported log, and (stricter: a recording is not converted by uavturb, and flights that barely climb read
#: correlations near zero either way, -0.22 on a test bag) on a recording. Real flights read 0.25-0.89 (Neural-Swarm's
#: 35 Crazyflie logs; a take-off that holds one height longest the lowest), the same flights with z negated the
#: opposite; a simulated PX4-like log (positions updated at 9 Hz, measured rotor speeds at 3 Hz and 60 ms late) 0.12
MIN_VERTICAL_CORRELATION, MIN_VERTICAL_CORRELATION_RECORDING = -0.2, -0.5


def check_vertical_response(rec: Recording, least: float = MIN_VERTICAL_CORRELATION) -> float:
    """Correlation of the vertical acceleration with the vertical thrust in flight; raises when it is
    clearly negative (at most ``least``: :data:`MIN_VERTICAL_CORRELATION` on an imported log,
    :data:`MIN_VERTICAL_CORRELATION_RECORDING` on a recording).

    A vehicle speeds its rotors up to climb: ``d v_z/dt`` (ground truth, W) rises with
    ``(R_WB e_z)_z sum(w_i^2)``. A world whose z axis points down (NED positions read as z-up) while
    the attitude is turned with it passes :func:`check_thrust_axis` at hover, but accelerates down
    when the thrust rises. ``nan`` when there are no rotor speeds or too few rows to tell.

    Raises
    ------
    InputError
        ``<rec>/mav0/state_groundtruth_estimate0/data.csv: the vehicle accelerates down when its
        rotors speed up ...``
    """
    gt = rec.ground_truth
    if rec.rotors is None or len(rec.rotors) < MIN_FLIGHT_ROWS or len(gt) < MIN_FLIGHT_ROWS:
        return float("nan")
    t = (gt.t_ns - gt.t_ns[0]) * 1e-9
    a_z = derivative(t, gt.v[:, 2], MOCAP_DERIVATIVE_WINDOW_S)  # m/s^2, W
    S = align.interpolate(rec.rotors.t_ns, np.sum(rec.rotors.speeds**2, axis=1), gt.t_ns)
    thrust_z = quat.to_rotation_matrix(gt.q)[:, 2, 2] * S  # vertical thrust / k_T
    rows = in_flight(rec, gt.t_ns) & np.isfinite(a_z) & np.isfinite(thrust_z)
    if rows.sum() < MIN_FLIGHT_ROWS or np.std(a_z[rows]) == 0 or np.std(thrust_z[rows]) == 0:
        return float("nan")
    r = float(np.corrcoef(a_z[rows], thrust_z[rows])[0, 1])
    if r <= least:
        raise InputError(_where(rec, "mav0/state_groundtruth_estimate0/data.csv"),
                         f"the vehicle accelerates down when its rotors speed up (correlation {r:.2f} between "
                         f"vertical acceleration and vertical thrust): the world's z axis looks inverted against the "
                         f"attitudes (positions and velocities with z down, NED, beside quaternions with z up?; "
                         f"recordings.md: world z up)")
    return r


def check_rotor_columns(rec: Recording) -> None:
    """No rotor column is zero, or constant, in flight while the other rotors vary.

    Raises
    ------
    InputError
        ``<rec>/mav0/rotors0/data.csv: column w_3 is 0 throughout the flight ...``
    """
    if rec.rotors is None or len(rec.rotors) < MIN_FLIGHT_ROWS:
        return
    w = rec.rotors.speeds[in_flight(rec, rec.rotors.t_ns)]
    where = _where(rec, "mav0/rotors0/data.csv")
    spins = np.any(w > 0, axis=0)
    varies = np.ptp(w, axis=0) > 0
    if np.any(spins) and not np.any(varies) and np.ptp(rec.ground_truth.p[:, 2]) > MIN_AXIS_MOTION_M:
        raise InputError(where, "every rotor column holds one value throughout while the vehicle moves up and down: "
                                "not the rotor speeds of a flying vehicle")
    for c in range(w.shape[1]):
        others = np.delete(np.arange(w.shape[1]), c)
        if not spins[c] and np.any(spins[others]):
            raise InputError(where, f"column w_{c} is 0 throughout the flight while the other rotors spin: "
                                    f"a dead motor or a missing stream cannot fly")
        if spins[c] and not varies[c] and np.any(varies[others]):
            value = w[0, c] / rec.vehicle.rotor_speed_scale  # as written in the file
            raise InputError(where, f"column w_{c} holds the constant value {value:.6g} throughout the flight "
                                    f"while the other rotors vary: not a rotor speed of a flying vehicle")


#: s, windows over which positions are compared with the integrated velocity, and the accelerometer with the
#: motion capture's specific force (block means: vibration and held values average out)
POSITION_WINDOW_S, FORCE_WINDOW_S = 1.0, 0.25
#: a position axis must move this much [m rms over windows] for its scale against the velocity to be read
MIN_AXIS_MOTION_M = 0.02
#: allowed ratio of displacement to integrated velocity (units or frames off give 0.001, 1000, -1, 0)
VELOCITY_SCALE_RANGE = (0.8, 1.25)
#: allowed ratio of the accelerometer to the motion capture's specific force (g for m/s^2 gives 0.1), and
#: the largest rms disagreement [share of g] of their block means (an attitude turned wrong gives ~1 g)
ACCEL_SCALE_RANGE, MAX_FORCE_DISAGREEMENT_G = (0.8, 1.25), 0.35
#: an accelerometer whose mean along the thrust axis in flight is under this share of the motion capture's (about g)
#: has had gravity taken out: in g it reads 1/9.81 = 0.10 of it, as a linear acceleration about 0
GRAVITY_REMOVED_SHARE = 0.05
#: m/s^2, how much the motion capture's specific force along an axis must move (rms of its block means in flight
#: about their mean) for that accelerometer axis to be checked alone; below :data:`DEAD_AXIS_SHARE` of it the axis is
#: dead or stuck. Real
#: Crazyflie walks, take-offs and swarm flights (81 recordings with an IMU): z moves by 0.23-1.4 m/s^2 and the
#: accelerometer by 0.76-1.1 times that (correlations 0.49-1.0); x and y, where they move that much (one vehicle's
#: swarm flights), by 1.9-5.6 times it (vibration), correlations -0.14 to 0.19
MIN_AXIS_FORCE, DEAD_AXIS_SHARE = 0.1, 0.25


def _window_edges(t: np.ndarray, window_s: float) -> tuple[np.ndarray, np.ndarray]:
    """(starts, ends) [s] of consecutive windows of ``window_s`` over ``t`` [s] that hold no gap in ``t``
    longer than a tenth of a window.

    Windows are laid over each stretch of ``t`` between such gaps, so that there are at most a tenth as many
    as samples whatever the span (a stream stepping by minutes once made 40 million windows)."""
    big = np.flatnonzero(np.diff(t) > 0.1 * window_s)
    first = np.concatenate([[0], big + 1])
    last = np.concatenate([big, [len(t) - 1]])
    starts, ends = [], []
    for a, b in zip(first, last):
        edges = np.arange(t[a], t[b], window_s)
        starts.append(edges[:-1])
        ends.append(edges[1:])
    return np.concatenate(starts), np.concatenate(ends)


def check_position_velocity(rec: Recording) -> None:
    """Positions move as far as the velocities say, axis by axis (both in W, m and m/s: ``recordings.md``).

    Over windows of :data:`POSITION_WINDOW_S` in flight (:func:`in_flight`), the displacement is compared with
    the integral of the velocity; the least-squares ratio of each axis that moves (:data:`MIN_AXIS_MOTION_M`) must
    lie in :data:`VELOCITY_SCALE_RANGE`. Positions in millimetres, velocities in the body frame or in other units,
    one axis flipped in one and not the other: each passes every format check and spoils the physics (velocities
    all left at zero never reach here: the reader takes them from the positions). Windows
    with the rotors stopped are left out: an onboard estimate may drift away once the motors stop (67 g
    Crazyflies of a swarm, their motors cut at the end, read 0.15 and -0.93 there, in flight 1.0).

    Raises
    ------
    InputError
        ``<rec>/mav0/state_groundtruth_estimate0/data.csv: on axis z the positions move -1 times as far ...``
    """
    gt = rec.ground_truth
    if len(gt) < MIN_FLIGHT_ROWS:
        return
    t = (gt.t_ns - gt.t_ns[0]) * 1e-9
    integral = np.vstack([np.zeros(3), np.cumsum(0.5 * (gt.v[1:] + gt.v[:-1]) * np.diff(t)[:, None], axis=0)])
    a, b = _window_edges(t, POSITION_WINDOW_S)
    grounded = np.concatenate([[0], np.cumsum(~in_flight(rec, gt.t_ns))])  # rows not in flight before each row
    ia, ib = np.searchsorted(t, a), np.searchsorted(t, b, side="right")
    flown = grounded[ib] == grounded[ia]
    a, b = a[flown], b[flown]
    if len(a) < 5:
        return
    dp = np.stack([np.interp(b, t, gt.p[:, k]) - np.interp(a, t, gt.p[:, k]) for k in range(3)], 1)
    dv = np.stack([np.interp(b, t, integral[:, k]) - np.interp(a, t, integral[:, k]) for k in range(3)], 1)
    for k, axis in enumerate("xyz"):
        moved, said = np.sqrt(np.mean(dp[:, k] ** 2)), np.sqrt(np.mean(dv[:, k] ** 2))
        if max(moved, said) < MIN_AXIS_MOTION_M:
            continue
        ratio = float(np.sum(dp[:, k] * dv[:, k]) / np.sum(dv[:, k] ** 2)) if said > 0 else np.inf
        if not VELOCITY_SCALE_RANGE[0] <= ratio <= VELOCITY_SCALE_RANGE[1]:
            shown = "infinitely many" if not np.isfinite(ratio) else f"{ratio:.3g}"
            raise InputError(_where(rec, "mav0/state_groundtruth_estimate0/data.csv"),
                             f"on axis {axis} the positions move {shown} times as far as the velocities say (over "
                             f"{POSITION_WINDOW_S:g} s windows in flight): positions in m and velocities in m/s, "
                             "both in the world frame, z up")


def _paired_means(a: np.ndarray, b: np.ndarray, *series: tuple[np.ndarray, np.ndarray]
                  ) -> tuple[list[np.ndarray], np.ndarray]:
    """Means of each ``(times [s], values (N, 3))`` series over the windows ``[a, b)``, and (W,) bool: the windows
    every series has a row in."""
    means, ok = [], np.ones(len(a), bool)
    for tt, f in series:
        c = np.vstack([np.zeros(3), np.cumsum(f, axis=0)])
        lo, hi = np.searchsorted(tt, a), np.searchsorted(tt, b)
        means.append((c[hi] - c[lo]) / np.maximum(hi - lo, 1)[:, None])
        ok &= hi > lo
    return means, ok


#: rad/s: the attitude must turn this fast (rms of 0.25 s means) for the gyroscope's scale to be read; and the
#: ratio of gyroscope to attitude rate allowed (deg/s for rad/s gives 57)
MIN_TURN_RATE, GYRO_SCALE_RANGE = 0.01, (0.7, 1.4)  # rms 0.017 rad/s read 0.95 on a 12 s simulated flight


def _check_gyroscope(rec: Recording, a: np.ndarray, b: np.ndarray, t: np.ndarray, t_imu: np.ndarray,
                     inside: np.ndarray) -> None:
    """The gyroscope reads the rate the motion capture's attitude turns at, in B (windows ``[a, b)`` in flight):
    a gyroscope in deg/s spoils the inertia ``identify`` gives. Where it does not, and the quaternions read in
    another order or direction would agree (:data:`QUATERNION_MISREADINGS`; only where S is B), the ground truth's
    file is named with that cause (the IMU's had been, for quaternions stored x, y, z, w)."""
    gyro = rec.imu.gyro[inside] - align.interpolate(rec.ground_truth.t_ns, rec.ground_truth.b_w, rec.imu.t_ns[inside])
    ratio = _gyro_ratio(a, b, t, rec.ground_truth.q, t_imu, gyro)
    if ratio is None or GYRO_SCALE_RANGE[0] <= ratio <= GYRO_SCALE_RANGE[1]:
        return
    if rec.vehicle.T_BS is None:
        for misread, how in QUATERNION_MISREADINGS:
            again = _gyro_ratio(a, b, t, misread(rec.ground_truth.q), t_imu, gyro)
            if again is not None and GYRO_SCALE_RANGE[0] <= again <= GYRO_SCALE_RANGE[1]:
                raise InputError(_where(rec, "mav0/state_groundtruth_estimate0/data.csv"),
                                 f"the gyroscope reads {ratio:.3g} times the rate these quaternions turn at, and "
                                 f"{again:.3g} times it with the quaternions read as {how}: they must be w, x, y, z "
                                 "and rotate S into the world (q_RS)")
    degrees = 0.7 * np.degrees(1.0) <= ratio <= 1.4 * np.degrees(1.0)
    cause = ("it must be in rad/s, not deg/s" if degrees else
             "quaternions must be w, x, y, z and rotate S into the world (q_RS), and the gyroscope in rad/s in S")
    raise InputError(_where(rec, "mav0/imu0/data.csv"),
                     f"the gyroscope reads {ratio:.3g} times the rate the motion capture's attitude turns at "
                     f"({FORCE_WINDOW_S:g} s means in flight, body frame): {cause}")


#: ways a logger writes quaternions that the ground truth's layout does not mean, and how to read them back:
#: x, y, z, w order (ROS, scipy), or the rotation from the world into S (q_SR, the conjugate)
QUATERNION_MISREADINGS = ((lambda q: q[:, [3, 0, 1, 2]], "x, y, z, w (the last column the scalar)"),
                          (lambda q: q * np.array([1.0, -1.0, -1.0, -1.0]), "rotating the world into S (q_SR)"))


def _gyro_ratio(a: np.ndarray, b: np.ndarray, t: np.ndarray, q: np.ndarray, t_imu: np.ndarray, gyro: np.ndarray
                ) -> float | None:
    """Least-squares ratio of the gyroscope's window means to the rate the attitudes ``q`` turn at (body frame,
    windows ``[a, b)``), or None where the attitude barely turns or too few windows hold both."""
    w_mocap = quat.angular_velocity_body(t, quat.make_continuous(q))
    (m_mocap, m_gyro), ok = _paired_means(a, b, (t, w_mocap), (t_imu, gyro))
    m_mocap, m_gyro = m_mocap[ok], m_gyro[ok]
    if len(m_mocap) < 5 or np.sqrt(np.mean(np.sum(m_mocap**2, axis=1))) < MIN_TURN_RATE:
        return None
    return float(np.sum(m_gyro * m_mocap) / np.sum(m_mocap**2))


def check_imu(rec: Recording) -> None:
    """The IMU reads what the motion capture shows, in B, on the ground truth's clock.

    - its clock: :func:`_check_imu_clock`;
    - its gyroscope: the attitude's rate of turn (:func:`_check_gyroscope`);
    - its accelerometer: the specific force (``recordings.md``: ``a_imu = R_BS^T R_WB^T (F_thrust + F_ext) / m``),
      block means over :data:`FORCE_WINDOW_S` in flight, their least-squares ratio in :data:`ACCEL_SCALE_RANGE`
      and their rms disagreement under :data:`MAX_FORCE_DISAGREEMENT_G` of g. An accelerometer in g, or
      quaternions in another order or direction than ``q_RS`` (w, x, y, z, S to world), fail it.

    Needs the recording in B and an IMU; else nothing.

    Raises
    ------
    InputError
        ``<rec>/mav0/imu0/data.csv: the accelerometer reads 0.102 times ...``
    """
    if rec.imu is None or len(rec.imu) < MIN_FLIGHT_ROWS or len(rec.ground_truth) < MIN_FLIGHT_ROWS or rec.frame != "B":
        return
    gt = rec.ground_truth
    t = (gt.t_ns - gt.t_ns[0]) * 1e-9
    f_mocap = quat.rotate_inverse(gt.q, derivative(t, gt.v, MOCAP_DERIVATIVE_WINDOW_S) + np.array([0, 0, GRAVITY]))
    inside = (rec.imu.t_ns >= gt.t_ns[0]) & (rec.imu.t_ns <= gt.t_ns[-1])
    if inside.sum() < MIN_FLIGHT_ROWS:
        return
    t_imu = (rec.imu.t_ns[inside] - gt.t_ns[0]) * 1e-9
    f_imu = rec.imu.acc[inside] - align.interpolate(gt.t_ns, gt.b_a, rec.imu.t_ns[inside])
    a, b = _window_edges(t, FORCE_WINDOW_S)
    flying = in_flight(rec, gt.t_ns)
    means, ok = _paired_means(a, b, (t, f_mocap), (t_imu, f_imu))
    ok &= np.interp(0.5 * (a + b), t, flying.astype(float)) > 0.5
    if ok.sum() < 5:
        return
    _check_imu_clock(rec, t, f_mocap[:, 2], t_imu, f_imu[:, 2], flying)
    _check_gyroscope(rec, a[ok], b[ok], t, t_imu, inside)
    m_mocap, m_imu = means[0][ok], means[1][ok]
    ratio = float(np.sum(m_imu * m_mocap) / np.sum(m_mocap**2))
    miss = float(np.sqrt(np.mean(np.sum((m_imu - m_mocap) ** 2, axis=1)))) / GRAVITY
    scaled_miss = float(np.sqrt(np.mean(np.sum((m_imu - ratio * m_mocap) ** 2, axis=1)))) / GRAVITY
    where = _where(rec, "mav0/imu0/data.csv")
    in_range = ACCEL_SCALE_RANGE[0] <= ratio <= ACCEL_SCALE_RANGE[1]
    up_mocap, up_imu = float(np.mean(m_mocap[:, 2])), float(np.mean(m_imu[:, 2]))
    if up_mocap > 0.5 * GRAVITY and abs(up_imu) < GRAVITY_REMOVED_SHARE * up_mocap:
        raise InputError(where, f"the accelerometer reads {up_imu:.2g} m/s^2 along the thrust axis on average in "
                                f"flight, where the motion capture shows {up_mocap:.3g} m/s^2 (the specific force "
                                "that holds the vehicle up): gravity was taken out (a linear acceleration); imu0 must "
                                "hold what an accelerometer reads, gravity included")
    if not in_range and ratio > 0 and scaled_miss * ratio <= MAX_FORCE_DISAGREEMENT_G * min(ratio, 1.0):
        raise InputError(where, f"the accelerometer reads {ratio:.3g} times the specific force the motion capture "
                                "shows in flight, in the same directions: it must be in m/s^2 (not g)")
    if not in_range or miss > MAX_FORCE_DISAGREEMENT_G:
        _name_misread_ground_truth(rec, a[ok], b[ok], t, t_imu, f_imu, miss)
        raise InputError(where, f"the accelerometer and the motion capture's specific force (R^T (dv/dt + g), "
                                f"{FORCE_WINDOW_S:g} s means in flight, body frame) differ by {miss:.2g} g rms "
                                f"(least-squares ratio {ratio:.2g}): quaternions must be w, x, y, z and rotate S "
                                "into the world (q_RS), the world's z must point up, and the IMU must be stamped "
                                "on the ground truth's clock")
    _check_accelerometer_axes(where, m_mocap, m_imu)


#: m/s^2, gravity's direction in the world as loggers' other conventions have it: y up (OptiTrack's default), z down
#: (NED), x up
OTHER_UPS = (("its y axis points up (OptiTrack's default)", np.array([0.0, GRAVITY, 0.0])),
             ("its z axis points down (NED)", np.array([0.0, 0.0, -GRAVITY])),
             ("its x axis points up", np.array([GRAVITY, 0.0, 0.0])))


def _name_misread_ground_truth(rec: Recording, a: np.ndarray, b: np.ndarray, t: np.ndarray, t_imu: np.ndarray,
                               f_imu: np.ndarray, miss: float) -> None:
    """Where the accelerometer disagrees with the motion capture (``miss`` [g] rms) but would agree with the ground
    truth read another way (its quaternions in another order or direction, :data:`QUATERNION_MISREADINGS`; its world
    with another axis up, :data:`OTHER_UPS`), refuse naming the ground truth's file and that cause (the IMU's had
    been named). Only where S is B."""
    if rec.vehicle.T_BS is not None:
        return
    gt = rec.ground_truth
    dv = derivative(t, gt.v, MOCAP_DERIVATIVE_WINDOW_S)
    up = np.array([0.0, 0.0, GRAVITY])
    readings = [(misread(gt.q), up, f"quaternions read as {how}") for misread, how in QUATERNION_MISREADINGS]
    readings += [(gt.q, g, f"a world whose {how[4:]}") for how, g in OTHER_UPS]
    best: tuple[float, str] | None = None
    for q, g, how in readings:
        f_mocap = quat.rotate_inverse(quat.make_continuous(q), dv + g)
        (m_mocap, m_imu), ok = _paired_means(a, b, (t, f_mocap), (t_imu, f_imu))
        if ok.sum() < 5:
            continue
        again = float(np.sqrt(np.mean(np.sum((m_imu[ok] - m_mocap[ok]) ** 2, axis=1)))) / GRAVITY
        if again <= MAX_FORCE_DISAGREEMENT_G and (best is None or again < best[0]):
            best = (again, how)
    if best is not None:  # the reading that agrees best (a level flight's y-up world and x, y, z, w order both may)
        raise InputError(_where(rec, "mav0/state_groundtruth_estimate0/data.csv"),
                         f"the accelerometer and the motion capture's specific force differ by {miss:.2g} g rms, "
                         f"and by {best[0]:.2g} g with {best[1]}: the world's z must point up and the quaternions be "
                         "w, x, y, z rotating S into the world (q_RS)")


def _check_accelerometer_axes(where: str, m_mocap: np.ndarray, m_imu: np.ndarray) -> None:
    """Each accelerometer axis moves as the motion capture's specific force along it does (block means in flight,
    (W, 3) m/s^2 each, body frame): a dead or stuck axis (it reads a constant) passes the checks on all three
    together, and spoils every force along it (a z axis stuck at 9.81 m/s^2 hid a 32 g vehicle's ground effect).
    Only axes the motion capture sees move by :data:`MIN_AXIS_FORCE` or more are checked (on a multirotor, z: the
    body's x and y feel drag alone, a few hundredths of g).

    Raises
    ------
    InputError
        ``<rec>/mav0/imu0/data.csv: the accelerometer's z axis barely moves ...``
    """
    dm, di = m_mocap - m_mocap.mean(axis=0), m_imu - m_imu.mean(axis=0)
    for k, axis in enumerate("xyz"):
        moves, reads = float(np.std(dm[:, k])), float(np.std(di[:, k]))
        if moves < MIN_AXIS_FORCE:
            continue
        if reads < DEAD_AXIS_SHARE * moves:
            raise InputError(where, f"the accelerometer's {axis} axis barely moves, {reads:.3f} m/s^2 rms "
                                    f"({FORCE_WINDOW_S:g} s means in flight, body frame), where the motion capture's "
                                    f"specific force along it moves by {moves:.3f} m/s^2: a dead or stuck axis; leave "
                                    "mav0/imu0 out to analyse the motion capture alone")


#: s, offsets between a stream's clock and the ground truth's searched; by how much the best offset's correlation
#: must beat the recording's own stamps' (and be at least twice it), and the least correlation it must reach, on
#: signals high-passed (:func:`uavturb.numerics.filters.high_passed`). Measured at the true offset: an IMU against the
#: motion capture 0.73-0.98, the rotors' thrust 0.56-0.86 (real Crazyflie and simulated flights); a spurious peak of a
#: flight whose rotors barely vary reached 0.36
CLOCK_SEARCH_S, CLOCK_GAIN = 0.6, 0.1
#: s, offsets searched beyond ``CLOCK_SEARCH_S`` (a stream stamped on another clock by seconds: rotors 1 s late
#: had left a 0.5 N residual and a report naming the right effect beside it), and the step of that coarse search
CLOCK_WIDE_S, CLOCK_WIDE_STEP_S = 5.0, 0.05
#: rows at most in the wide search (a correlation over 4000 rows has a noise of about 0.02, far under CLOCK_GAIN)
CLOCK_WIDE_ROWS = 4_000
#: the least correlation of an offset beyond ``CLOCK_SEARCH_S``, and s, how far from it another peak must stay
#: ``CLOCK_GAIN`` lower: a flight that repeats itself correlates with itself a period away (a noise-free simulated
#: flight whose thrust hardly varied read 0.59 at 3.4 s, -0.04 as stamped); true offsets read 0.82-0.97
CLOCK_WIDE_MIN_CORRELATION, CLOCK_WIDE_PEAK_S = 0.7, 0.25
IMU_CLOCK_MIN_CORRELATION, ROTOR_CLOCK_MIN_CORRELATION = 0.5, 0.5
#: rows at most in a clock's correlation (a flight-hour at 200 Hz is thinned to one row in 72), and s, the steps of
#: the coarse and the fine search of its offset
CLOCK_ROWS, CLOCK_STEPS_S = 10_000, (0.02, 0.005)
#: s, the smallest offset refused: an IMU samples the force at once; commanded rotor speeds lead the force by a
#: motor lag (60-90 ms on the Crazyflie logs), ESC telemetry trails it by 40-80 ms (``recordings.md``) and, read
#: one ESC at a time at 3 Hz, by half a column's period more (0.18 s in all measured), all of which gap models
IMU_CLOCK_MAX_S, ROTOR_CLOCK_MAX_S = 0.05, 0.25
#: how much better than as stamped an IMU's offset must correlate (real Crazyflies' IMUs: best within 5 ms of their
#: stamps, 0.90-0.99; one vehicle's 15-30 ms, 0.71-0.81 against 0.49-0.61, under IMU_CLOCK_MAX_S)
IMU_CLOCK_GAIN = 0.02
#: s, how late commanded rotor speeds may match the force they make (commands lead it by a motor lag: 15-135 ms
#: early on 80 real Crazyflie flights, never over 10 ms late; ESC telemetry written without its
#: ``rotor_speed_source``, 40-80 ms late in ``recordings.md``, passes), and s, the latest match read so (beyond it
#: the search for another clock decides, ``ROTOR_CLOCK_MAX_S``)
COMMAND_LATE_S, COMMAND_LATE_MAX_S = 0.1, 0.3
#: the least correlation of a late match, the least as stamped (a stream late by tenths of a second still resembles
#: the force: 0.31-0.53 on the probe's, against a spurious 0.35 at 0.46 s on a valid 30 s flight with -0.03 as
#: stamped), and the gain over the stamps (0.25 s late had passed at 0.45 against 0.31, under the 0.5 asked of any
#: other offset)
COMMAND_LATE_CORRELATION, COMMAND_LATE_STAMPED, COMMAND_LATE_GAIN = 0.4, 0.2, 0.03
#: the least correlation, and gain over the stamps, of a late match read so whatever the stamps' own correlation
#: (commands 0.19 s late had passed: 0.94 against 0.16 as stamped, under COMMAND_LATE_STAMPED)
COMMAND_LATE_CLEAR, COMMAND_LATE_CLEAR_GAIN = 0.7, 0.3


#: lags whose shifted signals a clock search holds at once (a few of the rows' copies in memory: tens of MB at most)
CLOCK_LAGS_AT_ONCE = 32


def clock_offset(t: np.ndarray, reference: np.ndarray, t_sig: np.ndarray, signal: np.ndarray
                 ) -> tuple[float, float, float]:
    """(s, the offset ``d`` within ``+-`` :data:`CLOCK_SEARCH_S` at which ``signal(t + d)`` correlates best with
    ``reference(t)``, or within ``+-`` :data:`CLOCK_WIDE_S` where a farther offset correlates clearly better
    (:func:`_wide_offset`); that correlation; the correlation at ``d = 0``), or nans where the rows cannot tell."""
    rows = np.isfinite(reference) & (t > t_sig[0] + CLOCK_SEARCH_S) & (t < t_sig[-1] - CLOCK_SEARCH_S)
    if rows.sum() < MIN_FLIGHT_ROWS or np.std(reference[rows]) == 0 or np.std(signal) == 0:
        return float("nan"), float("nan"), float("nan")
    idx = np.flatnonzero(rows)
    idx = idx[:: max(1, len(idx) // CLOCK_ROWS)]  # a long flight's rows thinned evenly: the time stays bounded
    tr = t[idx]
    bounds = moving_mean_bounds(tr, CLOCK_HIGH_PASS_S)  # the rows each moving mean takes: the same at every lag
    y = high_passed(tr, reference[idx], CLOCK_HIGH_PASS_S, bounds)

    def correlations(lags: np.ndarray) -> np.ndarray:
        # CLOCK_LAGS_AT_ONCE lags' shifted signals at once, a column each: one interpolation and one moving mean
        out = []
        for chunk in np.array_split(lags, -(-len(lags) // CLOCK_LAGS_AT_ONCE)):
            shifted = np.interp(chunk[:, None] + tr[None, :], t_sig, signal).T  # time-ordered rows: interp's guess
            out.append(_column_correlations(y, high_passed(tr, shifted, CLOCK_HIGH_PASS_S, bounds)))
        return np.concatenate(out)

    # a coarse grid, then the best of it refined on a fine one
    coarse = np.arange(-CLOCK_SEARCH_S, CLOCK_SEARCH_S + CLOCK_STEPS_S[0] / 2, CLOCK_STEPS_S[0])
    corr = correlations(coarse)
    if not np.any(np.isfinite(corr)):
        return float("nan"), float("nan"), float("nan")
    centre = coarse[int(np.nanargmax(corr))]
    fine = centre + np.arange(-CLOCK_STEPS_S[0], CLOCK_STEPS_S[0] + CLOCK_STEPS_S[1] / 2, CLOCK_STEPS_S[1])
    fine_corr = correlations(fine)
    k = int(np.nanargmax(fine_corr))
    at_zero = float(correlations(np.zeros(1))[0])
    flying = np.isfinite(reference)  # every row: a far offset leaves the near search's edges out of its overlap
    wide = _wide_offset(t[flying], reference[flying], t_sig, signal, float(fine_corr[k]))
    if wide is not None:
        return wide[0], wide[1], at_zero
    return float(fine[k]), float(fine_corr[k]), at_zero


def _wide_offset(t: np.ndarray, reference: np.ndarray, t_sig: np.ndarray, signal: np.ndarray, near_best: float
                 ) -> tuple[float, float] | None:
    """(s, correlation) of an offset beyond ``CLOCK_SEARCH_S`` and within ``CLOCK_WIDE_S`` that correlates better
    than ``near_best`` (the best within ``CLOCK_SEARCH_S``) by :data:`CLOCK_GAIN`, reaches
    :data:`CLOCK_WIDE_MIN_CORRELATION` and stands :data:`CLOCK_GAIN` above every other offset farther than
    :data:`CLOCK_WIDE_PEAK_S` from it, or None. Both signals are
    high-passed once on their own rows (a moving mean commutes with a shift) and compared on the reference's
    rows whose shifted times the signal covers; the coarse search's best is refined in steps of
    ``CLOCK_STEPS_S[1]``."""
    idx = np.arange(0, len(t), max(1, len(t) // CLOCK_WIDE_ROWS))
    tr, y = t[idx], high_passed(t[idx], reference[idx], CLOCK_HIGH_PASS_S)
    sig = high_passed(t_sig, signal, CLOCK_HIGH_PASS_S)

    def correlations(lags: np.ndarray) -> np.ndarray:
        # CLOCK_LAGS_AT_ONCE lags at once, a row each: Pearson's r on the rows whose shifted times the signal covers
        out = []
        for chunk in np.array_split(lags, -(-len(lags) // CLOCK_LAGS_AT_ONCE)):
            shifted = tr[None, :] + chunk[:, None]
            ok = (shifted >= t_sig[0]) & (shifted <= t_sig[-1])
            out.append(_masked_correlation(np.broadcast_to(y, ok.shape), np.interp(shifted, t_sig, sig), ok))
        return np.concatenate(out)

    lags = np.arange(-CLOCK_WIDE_S, CLOCK_WIDE_S + CLOCK_WIDE_STEP_S / 2, CLOCK_WIDE_STEP_S)
    lags = lags[np.abs(lags) > CLOCK_SEARCH_S]
    corr = correlations(lags)
    if not np.any(np.isfinite(corr)) or np.nanmax(corr) < max(near_best + CLOCK_GAIN, CLOCK_WIDE_MIN_CORRELATION):
        return None
    centre = lags[int(np.nanargmax(corr))]
    others = corr[np.abs(lags - centre) > CLOCK_WIDE_PEAK_S]
    if np.any(np.isfinite(others)) and np.nanmax(corr) < np.nanmax(others) + CLOCK_GAIN:
        return None  # no single peak: a flight that repeats itself
    fine = centre + np.arange(-CLOCK_WIDE_STEP_S, CLOCK_WIDE_STEP_S + CLOCK_STEPS_S[1] / 2, CLOCK_STEPS_S[1])
    fine_corr = correlations(fine)
    k = int(np.nanargmax(fine_corr))
    return float(fine[k]), float(fine_corr[k])


def _column_correlations(y: np.ndarray, X: np.ndarray) -> np.ndarray:
    """(L,) Pearson's correlation of ``y`` (N,) with each column of ``X`` (N, L), clipped to [-1, 1] as
    ``np.corrcoef`` clips it; nan where either is constant. All columns at once (one ``corrcoef`` a column had
    taken half a clock check's time)."""
    yc = y - y.mean()
    Xc = X - X.mean(axis=0)
    with np.errstate(invalid="ignore", divide="ignore"):
        r = (yc @ Xc) / np.sqrt(float(yc @ yc) * np.einsum("nl,nl->l", Xc, Xc))
    return np.clip(r, -1.0, 1.0)


def _masked_correlation(x: np.ndarray, y: np.ndarray, ok: np.ndarray) -> np.ndarray:
    """(L,) Pearson's correlation of each row of ``x`` and ``y`` (L, N) on its rows' ``ok`` (L, N) samples; nan
    where under :data:`MIN_FLIGHT_ROWS` samples are ok or either row is constant there."""
    n = ok.sum(axis=1)
    m = np.maximum(n, 1)
    xm = np.where(ok, x, 0.0).sum(axis=1) / m
    ym = np.where(ok, y, 0.0).sum(axis=1) / m
    dx = np.where(ok, x - xm[:, None], 0.0)
    dy = np.where(ok, y - ym[:, None], 0.0)
    sxx, syy, sxy = (dx * dx).sum(axis=1), (dy * dy).sum(axis=1), (dx * dy).sum(axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        r = np.clip(sxy / np.sqrt(sxx * syy), -1.0, 1.0)
    return np.where((n >= MIN_FLIGHT_ROWS) & (sxx > 0) & (syy > 0), r, np.nan)


#: s, the slow part taken off both signals before they are timed (a surface lifting the vehicle changes the thrust
#: over seconds; the clock shows in the faster swings)
CLOCK_HIGH_PASS_S = 2.0


def _off_clock(offset: tuple[float, float, float], smallest_s: float, least_correlation: float,
               gain: float = CLOCK_GAIN, times: float = 2.0) -> bool:
    """Whether a :func:`clock_offset` reads a stream on another clock: at least ``smallest_s`` [s] off and clearly
    better than its own stamps (correlation at least ``least_correlation``, ``gain`` more and ``times`` as much)."""
    lag, best, at_zero = offset
    return bool(np.isfinite(lag) and abs(lag) >= smallest_s and best >= least_correlation
                and best - at_zero >= gain and best >= times * at_zero)


def _clock_text(offset: tuple[float, float, float], what: str) -> str:
    """``what`` matches the motion capture's best so far off (correlation ... against ... as stamped)."""
    lag, best, at_zero = offset
    return (f"{what} matches the motion capture's best {abs(lag):.2f} s {'late' if lag > 0 else 'early'} "
            f"(correlation {best:.2f}, against {at_zero:.2f} as stamped)")


def _refuse_clock(rec: Recording, stream: str, offset: tuple[float, float, float], smallest_s: float,
                  least_correlation: float, what: str, gain: float = CLOCK_GAIN, times: float = 2.0) -> None:
    """InputError naming ``stream`` where its :func:`clock_offset` reads it on another clock (:func:`_off_clock`)."""
    if _off_clock(offset, smallest_s, least_correlation, gain, times):
        raise InputError(_where(rec, f"mav0/{stream}/data.csv"),
                         f"{_clock_text(offset, what)}: it must be stamped on the ground truth's clock")


def _check_imu_clock(rec: Recording, t: np.ndarray, f_mocap_z: np.ndarray, t_imu: np.ndarray, f_imu_z: np.ndarray,
                     flying: np.ndarray) -> None:
    """The IMU's vertical specific force matches the motion capture's best at its own timestamps: an IMU
    stamped on another clock (0.3 s late) leaves a residual of half the weight's swings that no effect
    explains. Refused where an offset of :data:`IMU_CLOCK_MAX_S` or more (and half the ground truth's hold period)
    matches better by :data:`IMU_CLOCK_GAIN` (the two read one force: their correlation is high, and an offset
    shows however small; 0.1 s late had passed at 0.95 against 0.87 as stamped, the held-out error five times
    larger)."""
    ref = np.where(flying, f_mocap_z, np.nan)
    gt = rec.ground_truth
    # a held ground truth (9 Hz in rows at 50 Hz) trails what it measures by half its hold: the IMU reads early by it
    held = 0.5 * hold_period_s(gt.t_ns, gt.p)
    _refuse_clock(rec, "imu0", clock_offset(t, ref, t_imu, f_imu_z), IMU_CLOCK_MAX_S + held,
                  IMU_CLOCK_MIN_CORRELATION, "its specific force", gain=IMU_CLOCK_GAIN, times=1.0)


#: the least correlation at which the rotors' roll and pitch torques time their stream (against the body's angular
#: acceleration; 0.36-0.66 on Neural-Swarm's Crazyflie flights, on their stamps and shifted alike), and s, how far
#: the torques' timing may lie from the thrust's for the two to read one clock
TORQUE_CLOCK_MIN_CORRELATION, TORQUE_CLOCK_AGREE_S = 0.3, 0.1


def _rotor_updates(rec: Recording) -> tuple[np.ndarray, np.ndarray]:
    """(U, n) rotor speeds [rad/s] at the rotor stream's update rows and (U,) s, their times since the ground truth's
    first row: a held stream read on its updates (its steps lag by half a step: 0.17 s at 3 Hz), the last row kept;
    one whose rotors report in turn (:func:`~uavturb.numerics.stream_updates.staggered`) each between its own
    updates, where the rows any rotor changes on are nearly all rows (a probe's 40 ms late telemetry, one ESC at a
    time at 10 Hz, had read 90 ms late and been refused)."""
    w = rec.rotors.speeds
    t = (rec.rotors.t_ns - rec.ground_truth.t_ns[0]) * 1e-9
    fresh = update_mask(w)
    fresh[-1] = True
    if staggered(w):
        w = read_between_updates(t, w)
    return w[fresh], t[fresh]


def rotor_torque_offset(rec: Recording) -> tuple[float, float, float]:
    """:func:`clock_offset` of the rotors' roll or pitch torque shape (``sum(sin a_i w_i^2)``, ``-sum(cos a_i
    w_i^2)``, a rotor at angle ``a_i``) against the body's angular acceleration about that axis (the IMU's gyroscope
    differentiated, else the motion capture's attitude), whichever axis correlates better at its best offset; nans
    where neither can tell. A stream on another clock is off in its torques as in its thrust; a controller that
    raises the thrust ahead of a disturbance it expects (Neural-Swarm's swaps, a learned downwash compensation: the
    thrust led the force by 0.18-0.32 s) moves the thrust only."""
    gt = rec.ground_truth
    t = (gt.t_ns - gt.t_ns[0]) * 1e-9
    w, t_rot = _rotor_updates(rec)
    w2 = w ** 2
    angles = np.radians(np.asarray(rec.vehicle.rotor_angles_deg, float))
    if rec.imu is not None and len(rec.imu) >= MIN_FLIGHT_ROWS and rec.frame == "B":
        rate = np.stack([align.interpolate(rec.imu.t_ns, rec.imu.gyro[:, k], gt.t_ns) for k in range(2)], axis=1)
    else:
        rate = quat.angular_velocity_body(t, gt.q)[:, :2]
    flying = in_flight(rec, gt.t_ns)
    best = (float("nan"), float("nan"), float("nan"))
    for k, shape in enumerate((w2 @ np.sin(angles), -(w2 @ np.cos(angles)))):
        ref = np.where(flying, derivative(t, rate[:, k], MOCAP_DERIVATIVE_WINDOW_S), np.nan)
        found = clock_offset(t, ref, t_rot, shape)
        if np.isfinite(found[1]) and not found[1] <= best[1]:
            best = found
    return best


def _commands_late(offset: tuple[float, float, float]) -> bool:
    """Whether a :func:`clock_offset` of commanded speeds' thrust reads them late, as commands cannot be: between
    :data:`COMMAND_LATE_S` and :data:`COMMAND_LATE_MAX_S`, with the correlations of ``COMMAND_LATE_*`` (or clearly,
    :data:`COMMAND_LATE_CLEAR`, whatever the stamps read)."""
    lag, best, at_zero = offset
    if not (np.isfinite(lag) and COMMAND_LATE_S <= lag <= COMMAND_LATE_MAX_S):
        return False
    clear = best >= COMMAND_LATE_CLEAR and best - at_zero >= COMMAND_LATE_CLEAR_GAIN
    return bool(clear or (best >= COMMAND_LATE_CORRELATION and at_zero >= COMMAND_LATE_STAMPED
                          and best - at_zero >= COMMAND_LATE_GAIN))


def check_rotor_clock(rec: Recording) -> str | None:
    """The rotors' vertical thrust ``(R e_z)_z sum(w^2)`` follows the vertical force the vehicle shows (IMU, else
    motion capture) at the rotor stream's own timestamps, within a motor lag or a telemetry delay: refused in
    one line where an offset of :data:`ROTOR_CLOCK_MAX_S` or more matches clearly better (a stream on
    another clock; commanded speeds matching it over :data:`COMMAND_LATE_S` late are refused too, as commands lead
    the force), unless the rotors' torques (:func:`rotor_torque_offset`) clearly keep time on the stamps
    (within :data:`ROTOR_CLOCK_MAX_S`) and apart from the thrust's offset: then the thrust's lead is the
    vehicle's (a controller anticipating a disturbance), and a note says so (returned; None otherwise)."""
    gt = rec.ground_truth
    if rec.rotors is None or len(rec.rotors) < MIN_FLIGHT_ROWS or len(gt) < MIN_FLIGHT_ROWS:
        return None
    t = (gt.t_ns - gt.t_ns[0]) * 1e-9
    up = quat.to_rotation_matrix(gt.q)[:, 2, 2]  # (R e_z)_z: the share of z_B that points up
    if rec.imu is not None and len(rec.imu) >= MIN_FLIGHT_ROWS and rec.frame == "B":
        a_z = align.interpolate(rec.imu.t_ns, rec.imu.acc[:, 2], gt.t_ns)  # specific force along z_B
        need = a_z * up
    else:
        need = derivative(t, gt.v[:, 2], MOCAP_DERIVATIVE_WINDOW_S) + GRAVITY
    w, t_rot = _rotor_updates(rec)
    S = np.sum(w ** 2, axis=1)
    R33 = np.interp(t_rot, t, up)
    ref = np.where(in_flight(rec, gt.t_ns), need, np.nan)
    thrust = clock_offset(t, ref, t_rot, R33 * S)
    if rec.vehicle.rotor_speed_source != "measured" and _commands_late(thrust):
        raise InputError(_where(rec, "mav0/rotors0/data.csv"),
                         f"{_clock_text(thrust, 'its vertical thrust')} (commanded speeds lead the force they make by "
                         "a motor lag; they cannot trail it): it must be stamped on the ground truth's clock (or, if "
                         "these are the ESCs' measured speeds, vehicle.yaml must say rotor_speed_source: measured)")
    if not _off_clock(thrust, ROTOR_CLOCK_MAX_S, ROTOR_CLOCK_MIN_CORRELATION):
        return None
    torque = rotor_torque_offset(rec)
    if (np.isfinite(torque[0]) and torque[1] >= TORQUE_CLOCK_MIN_CORRELATION and abs(torque[0]) < ROTOR_CLOCK_MAX_S
            and abs(torque[0] - thrust[0]) >= TORQUE_CLOCK_AGREE_S):
        return (f"{_where(rec, 'mav0/rotors0/data.csv')}: {_clock_text(thrust, 'the vertical thrust')}, but the "
                f"roll and pitch torques keep time on the stamps ({1e3 * torque[0]:+.0f} ms, correlation "
                f"{torque[1]:.2f}): read as stamped; the thrust leads what the vehicle feels, as a controller that "
                f"anticipates a disturbance makes it")
    _refuse_clock(rec, "rotors0", thrust, ROTOR_CLOCK_MAX_S, ROTOR_CLOCK_MIN_CORRELATION, "its vertical thrust")
    return None


#: s and share of the ground truth's span: a stream that leaves more of it uncovered (at either end together) is said
STREAM_SPAN_SLACK_S, STREAM_SPAN_SLACK_SHARE = 1.0, 0.05


def stream_span_notes(rec: Recording) -> list[str]:
    """Notes for ``imu0`` and ``rotors0`` where they cover less of the ground truth's time span than it holds (by
    over :data:`STREAM_SPAN_SLACK_S` and :data:`STREAM_SPAN_SLACK_SHARE` of it): the analyses read only where every
    stream they use has rows, and an IMU logged over half the flight had cut ``identify``'s and ``residuals``' rows
    by half without a word."""
    gt = rec.ground_truth.t_ns
    span = (gt[-1] - gt[0]) * 1e-9
    notes = []
    for name, stream in (("imu0", rec.imu), ("rotors0", rec.rotors)):
        if stream is None or len(stream.t_ns) == 0 or span <= 0:
            continue
        a, b = (max(stream.t_ns[0], gt[0]) - gt[0]) * 1e-9, (min(stream.t_ns[-1], gt[-1]) - gt[0]) * 1e-9
        covered = max(b - a, 0.0)
        if span - covered > max(STREAM_SPAN_SLACK_S, STREAM_SPAN_SLACK_SHARE * span):
            notes.append(f"{name} covers only t = {a:.1f}-{b:.1f} s of the ground truth's 0-{span:.1f} s: an "
                         f"analysis that reads it covers that span alone ({100 * covered / span:.0f} % of the "
                         "recording)")
    return notes


def check_recording(rec: Recording) -> list[str]:
    """The checks physics commands run: :func:`check_rotor_columns`, :func:`check_state_units`,
    :func:`check_thrust_axis`, :func:`check_quaternion_order`, :func:`check_position_velocity`, :func:`check_imu`,
    :func:`check_rotor_clock` and, last (quaternions in another order, or a rotor stream on another clock, read
    negative too, and the checks before name them), :func:`check_vertical_response` (at
    :data:`MIN_VERTICAL_CORRELATION_RECORDING`); returns the notes of checks that passed with something to say (and
    :func:`stream_span_notes`) (for the recording's ``read_notes``).

    The vertical response catches positions and velocities with z down beside attitudes with z up where nothing
    else does: with a flat point cloud (a floor, which may as well be a ceiling scanned alone) the flight under it
    had run, and a Neural-Swarm walk so negated reported "no surface below the vehicle" and a rejected ceiling
    effect (correlation -0.74)."""
    check_rotor_columns(rec)
    check_state_units(rec)
    check_thrust_axis(rec)
    check_quaternion_order(rec)
    check_position_velocity(rec)
    check_imu(rec)
    note = check_rotor_clock(rec)
    check_vertical_response(rec, MIN_VERTICAL_CORRELATION_RECORDING)  # last (docstring)
    return stream_span_notes(rec) + ([note] if note else [])
