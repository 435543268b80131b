"""What the recordings really hold, before any fit (``recordings.md``: streams that update slowly or
late, ground contact).

- **Streams**: each stream's rows and updates (:func:`uavturb.sysid.streams.stream_updates`); the
  physics reads held streams on their updates (:func:`uavturb.sysid.flight_data.held_updates`), and
  the report says where a stream updates too slowly for what was asked (:func:`stream_limits`).
- **Late rotor telemetry**: measured rotor speeds (ESC telemetry, ``rotor_speed_source: measured``)
  arrive 40-80 ms late on real logs. Their delay against the thrust the motion capture or the IMU
  says was needed is estimated (:func:`uavturb.sysid.streams.estimate_lag`) and, where resolved,
  taken out of the rotor timestamps (:func:`delay_corrected`). Commanded speeds are left alone: their
  lag behind the rotors is the ``motor_lag`` effect, which the finder tests. What is left uncertain of
  the delay is an interval (:func:`timing_interval`) over which the finder refits its named effects
  (:func:`rotor_shifted`; the ``rotor_timing`` term of :mod:`uavturb.gap.uncertainty`).
- **Ground contact**: rows where the floor carries the vehicle (:func:`uavturb.sysid.contact.ground_contact`)
  are left out of every fit and listed in the report.
"""

from __future__ import annotations

import dataclasses
from typing import Any, Sequence

import numpy as np
from scipy.ndimage import median_filter

from uavturb.errors import InputError
from uavturb.gap.landed_heights import LandedHeights, landed_alignment, moved_heights
from uavturb.io.body_frame import moved_origin
from uavturb.io.consistency import FLIGHT_SHARE
from uavturb.io.recording import GroundTruth, Recording, Rotors
from uavturb.numerics.stream_updates import update_mask
from uavturb.numerics.threads import in_threads
from uavturb.physics import quaternion as quat
from uavturb.physics.constants import GRAVITY
from uavturb.physics.effects import strongest_surface_lift
from uavturb.physics.vehicle import Vehicle
from uavturb.sysid.accelerometer import mocap_specific_force
from uavturb.sysid.contact import ContactLimits, ground_contact, landed_height
from uavturb.sysid.flight_data import FlightData, flight_data, held_updates, rotor_repeats
from uavturb.sysid.nominal import moved_speeds
from uavturb.sysid.lever_arm import LeverArm, lever_arm
from uavturb.sysid.streams import estimate_lag, needed_rate_hz, slow_for, stream_updates

#: s, motor time constant a motor_lag test must resolve (effects.md: 12.5-25 ms)
MOTOR_LAG_S = 0.02
#: s, time to cross the height range where a ground effect changes (0.1 m at 0.5 m/s)
SURFACE_CROSSING_S = 0.2
#: contact thresholds (:class:`~uavturb.sysid.contact.ContactLimits`'s defaults). A hover close to the
#: floor also reads a thrust 5-25 % under the weight (the ground effect itself): the lowest height a recording
#: reaches is its landed height only where the floor is seen carrying the vehicle there (idling rotors, a thrust
#: no hover could need, or one that moves while the vehicle does not); there a still vehicle within ``skim_m`` of
#: it is left out even then (losing a second of the lowest hover costs less than counting the floor's reaction as
#: aerodynamics); above that, only where its thrust could not hold a hover under the registry's strongest surface
#: lift (:func:`contact_masks`)
CONTACT_LIMITS = ContactLimits()
#: s, smallest delay of the rotor telemetry worth taking out
MIN_DELAY_S = 0.01
#: s, the longest delay of rotor telemetry ``recordings.md`` names ("40-80 ms late"): where a stream's
#: delay cannot be timed, its true delay is taken to lie anywhere between 0 and this
TELEMETRY_DELAY_MAX_S = 0.08
#: the strongest surface lift (registry, top of range) under which rows time the rotor telemetry, and the rows
#: needed there (fewer: every row in the air). Near a surface the thrust per rotor speed squared moves with
#: height, and the thrust the flight needs no longer follows the rotors' own: two PX4-like hexarotor flights
#: whose ESCs reported at 3 Hz, 60 and 80 ms late, flown low over the floor, explained 3-6 % of the needed
#: thrust at any delay ("not resolvable"); above 4 rotor radii (strongest lift 5 %), 90-97 %, read 53 +- 18 and
#: 75 +- 9 ms
LAG_FAR_LIFT, LAG_MIN_FAR_ROWS = 1.05, 200


def needed_thrust(fd: FlightData, mass: float) -> np.ndarray:
    """(K,) N, the force along the body z axis the rotors must make: ``m a_z`` (IMU) or
    ``m (R^T (v_dot + g e_z))_z`` (motion capture)."""
    if fd.acc is not None:
        return mass * fd.acc[:, 2]
    return mass * mocap_specific_force(quat.to_rotation_matrix(fd.q), fd.dv)[:, 2]


def delay_corrected(rec: Recording, fd: FlightData) -> tuple[Recording, dict[str, Any] | None]:
    """``rec`` with its measured rotor speeds' delay taken out of their timestamps, and what was found
    (None for commanded speeds)."""
    if rec.vehicle.rotor_speed_source != "measured" or rec.rotors is None:
        return rec, None
    _, rotors = held_updates(rec)  # a held stream on its updates, a staggered one column by column
    t_sig = rec.seconds(rotors.t_ns)
    signal = np.sum(rotors.speeds**2, axis=1)
    S = np.sum(fd.rotor_speeds**2, axis=1)
    ok = S >= FLIGHT_SHARE * np.percentile(S, 95)  # in the air: on the gear the floor takes what the rotors do not
    if fd.covered is not None:
        ok &= fd.covered  # not across a stream's dropout
    far = ok & _beyond_surfaces(fd, rec.vehicle)
    if far.sum() >= LAG_MIN_FAR_ROWS:
        ok = far
    lag = estimate_lag(fd.t[ok], needed_thrust(fd, rec.vehicle.mass)[ok], t_sig, signal)
    found = {"stream": "rotors0", "lag_s": lag.lag_s, "stderr_s": lag.stderr_s, "r2": lag.r2,
             "resolvable": lag.resolvable, "describe": lag.describe("rotors0 (measured rotor speeds)")}
    found["applied"] = bool(lag.resolvable and lag.lag_s >= max(MIN_DELAY_S, 2.0 * lag.stderr_s))
    found["uncertain_s"] = list(timing_interval(found))
    if not found["applied"]:
        return rec, found
    return rotor_shifted(rec, lag.lag_s), found


def _beyond_surfaces(fd: FlightData, vehicle: Vehicle) -> np.ndarray:
    """(K,) bool, rows where no surface law of the registry at the top of its range could lift the thrust by more
    than :data:`LAG_FAR_LIFT` (every row where no heights are known)."""
    geometry = {"arm_length": vehicle.arm_length, "rotor_count": vehicle.rotor_count}
    out = np.ones(len(fd.t), bool)
    for surface, d in (("d_down", fd.d_down), ("d_up", fd.d_up)):
        if d is not None:
            h = np.where(np.isfinite(d), d, np.inf)
            with np.errstate(invalid="ignore", divide="ignore"):
                out &= strongest_surface_lift(h, surface, vehicle.rotor_radius, **geometry) <= LAG_FAR_LIFT
    return out


def timing_interval(found: dict[str, Any]) -> tuple[float, float]:
    """s, ``(earliest, latest)`` the rotor stream's true delay may still be, relative to what was taken out
    of its timestamps (``found``: :func:`delay_corrected`'s account of one stream).

    - delay taken out: one standard error either side of it;
    - a delay timed but too small to take out: between none and one standard error beyond it;
    - a delay that could not be timed: between none and :data:`TELEMETRY_DELAY_MAX_S` (``recordings.md``).
    Telemetry is never early, so an interval never reaches below a delay of zero.
    """
    lag, se = float(found["lag_s"]), float(found["stderr_s"])
    if found["applied"]:
        return max(-se, -lag), se
    if found["resolvable"] and np.isfinite(lag) and np.isfinite(se):
        return 0.0, min(max(lag + se, MIN_DELAY_S), TELEMETRY_DELAY_MAX_S)
    return 0.0, TELEMETRY_DELAY_MAX_S


def rotor_shifted(rec: Recording, delay_s: float) -> Recording:
    """``rec`` with its rotor stream's timestamps moved ``delay_s`` [s] earlier (a delay taken out)."""
    shift = int(round(delay_s * 1e9))
    return dataclasses.replace(rec, rotors=Rotors(t_ns=rec.rotors.t_ns - shift, speeds=rec.rotors.speeds))


def rotor_speeds_moved(rec: Recording, delta: float, w_hover: float) -> Recording:
    """``rec`` with every turning rotor's recorded speed ``w`` read as the affine ``(w + delta) w_hover /
    (w_hover + delta)`` [rad/s]: an idle speed in the command map (:mod:`uavturb.sysid.nominal`, **Thrust map**)
    whose scale is kept exact at the hover speed ``w_hover`` (what the records say there stays, so laws linear
    in the speeds, such as rotor drag, keep their scale). Stopped rotors (0) stay stopped, and none is moved
    below 0."""
    return dataclasses.replace(rec, rotors=Rotors(t_ns=rec.rotors.t_ns,
                                                  speeds=moved_speeds(rec.rotors.speeds, delta, w_hover)))


def stream_limits(rec: Recording) -> tuple[list[str], dict[str, str], float]:
    """(one line per stream: rows and updates; a sentence where a stream updates too slowly for what it must
    resolve, keyed ``"surface"`` (the ground truth, for a surface effect) or ``"motor_lag"`` (the rotor speeds);
    the slowest update rate [Hz] of the streams the residual force and the model read)."""
    streams = {"state_groundtruth_estimate0": (rec.ground_truth.t_ns, rec.ground_truth.p)}
    if rec.rotors is not None:
        streams["rotors0"] = (rec.rotors.t_ns, rec.rotors.speeds)
    if rec.imu is not None:
        streams["imu0"] = (rec.imu.t_ns, rec.imu.acc)
    lines, limits, slowest = [], {}, np.inf
    for name, (t, x) in streams.items():
        u = stream_updates(f"{rec.name}/{name}", t, x, rounded=name == "rotors0" and rotor_repeats(x) == "rounded")
        lines.append(u.describe())
        slowest = min(slowest, u.update_rate_hz)
        if name == "state_groundtruth_estimate0":
            kind, why = "surface", slow_for(u, needed_rate_hz(SURFACE_CROSSING_S),
                                            "a surface effect (heights crossed in 0.2 s)")
        elif name == "rotors0":
            kind, why = "motor_lag", slow_for(u, needed_rate_hz(MOTOR_LAG_S),
                                              f"a motor lag of {1e3 * MOTOR_LAG_S:.0f} ms")
        else:
            kind, why = None, None
        if why:
            limits[kind] = why
    if rec.battery is not None and len(rec.battery.t_ns):
        line = stream_updates(f"{rec.name}/battery0", rec.battery.t_ns, rec.battery.voltage[:, None]).describe()
        apart = (rec.battery.t_ns[-1] < rec.ground_truth.t_ns[0]) or (rec.battery.t_ns[0] > rec.ground_truth.t_ns[-1])
        use = ("read by battery_voltage where the rotor speeds are commanded and it covers the flight"
               if rec.vehicle.rotor_speed_source != "measured" else
               "not read (measured rotor speeds already show the voltage)")
        lines.append(f"{line}; {'outside the ground truth in time, ' if apart else ''}{use}")
    return lines, limits, slowest


def state_thinned(rec: Recording) -> Recording:
    """``rec`` with its ground truth at half its update rate: every other update dropped and the one before it
    held through its rows (the **stream rate** term of :mod:`uavturb.gap.uncertainty`)."""
    gt = rec.ground_truth
    changed = update_mask(np.hstack([gt.p, gt.q, gt.v]))
    first = np.flatnonzero(changed)
    k = np.cumsum(changed) - 1  # the update in force at each row
    src = first[k - k % 2]
    return dataclasses.replace(rec, ground_truth=GroundTruth(t_ns=gt.t_ns, p=gt.p[src], q=gt.q[src], v=gt.v[src],
                                                             b_w=gt.b_w[src], b_a=gt.b_a[src]))


def _vehicle_landed_height(lows: Sequence[float | None], d_downs: Sequence[np.ndarray | None]
                           ) -> tuple[float | None, bool]:
    """m, the vehicle's landed rotor-plane height, and whether the floor was seen to carry it there.

    It is the lowest of its recordings' own (``lows``: each recording's :func:`~uavturb.sysid.contact.landed_height`
    of ``d_down``, None where it never lands); where none lands, the lowest rotor-plane height over all flights
    (5-row median, as ``ground_contact`` reads it) and False. None where a flight has no ``d_down`` (``d_downs``).
    """
    if not d_downs or any(d is None for d in d_downs):
        return None, False
    seen = [low for low in lows if low is not None]
    if seen:
        return min(seen), True
    return min(float(np.min(median_filter(d[np.isfinite(d)], 5, mode="nearest"))) for d in d_downs), False


def _contact_rows(fd: FlightData, vehicle: Vehicle
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None, np.ndarray | None]:
    """What ground contact is read from in one flight: tilt [deg], thrust [N] (vehicle.yaml's k_T, or the weight
    at the median speeds), ``d_down`` [m] (None: no surface under any row) and the strongest surface lift the
    registry allows at each row's height [-] (None without heights; 1 where no surface is below)."""
    geometry = {"arm_length": vehicle.arm_length, "rotor_count": vehicle.rotor_count}
    R = quat.to_rotation_matrix(fd.q)
    tilt = np.degrees(np.arccos(np.clip(R[:, 2, 2], -1.0, 1.0)))
    S = np.sum(fd.rotor_speeds**2, axis=1)
    k_T = vehicle.thrust_coefficient
    thrust = k_T * S if k_T else S / np.median(S) * vehicle.mass * GRAVITY
    d_down = fd.d_down if fd.d_down is not None and np.any(np.isfinite(fd.d_down)) else None
    lift = None if fd.d_down is None else np.where(
        np.isfinite(fd.d_down), strongest_surface_lift(fd.d_down, "d_down", vehicle.rotor_radius, **geometry), 1.0)
    return tilt, thrust, d_down, lift


def _landed_low(fd: FlightData, rows: tuple, mass: float) -> float | None:
    """m, one flight's landed rotor-plane height (:func:`uavturb.sysid.contact.landed_height`; ``rows``: its
    :func:`_contact_rows`), None where it never lands or has no heights."""
    tilt, thrust, d_down, lift = rows
    if d_down is None:
        return None
    return landed_height(fd.t, fd.p[:, 2], fd.v, tilt, thrust, mass, d_down=d_down, limits=CONTACT_LIMITS, lift=lift)


def landings_aligned(fds: Sequence[FlightData], vehicle: Vehicle) -> tuple[list[FlightData], LandedHeights]:
    """The flights with their heights moved so that the recordings that land land at one rotor-plane height
    (:mod:`uavturb.gap.landed_heights`), and what was read and moved."""
    landed = landed_alignment(list(in_threads(lambda fd: _landed_low(fd, _contact_rows(fd, vehicle), vehicle.mass),
                                              fds)))
    return [moved_heights(fd, s) for fd, s in zip(fds, landed.shifts)], landed


def contact_masks(fds: Sequence[FlightData], vehicle: Vehicle, paths: Sequence[str]
                  ) -> tuple[list[np.ndarray], list[dict[str, Any]]]:
    """Per flight, the rows where the floor carries the vehicle, and the report's ``ground_contact``.

    A recording's landed height is the lowest it reaches only where the floor is seen to carry the vehicle there
    (:func:`uavturb.sysid.contact.landed_height`: still and level with a thrust no hover could need, idling,
    under the least share that could hold a hover in the strongest ground-effect law of the registry at the top
    of its range for this vehicle's rotors (:func:`uavturb.physics.effects.strongest_surface_lift`), or moving
    while the vehicle does not); a hover that never lands keeps its lowest rows. The recordings are of one vehicle
    and ``d_down`` is measured to the surface below, so the vehicle's landed rotor-plane height is the lowest over
    the recordings that land: a recording that never came down within ``skim_m`` of it skims nothing (its lowest
    hover is a hover). Where none lands, the lowest rotor-plane height over all of them serves for skims alone,
    and only for dips moving throughout (real walks' dips to their lowest set point; a still vehicle there
    hovers). A still stretch that stays higher than ``skim_m`` over its recording's landed height is a rest only
    where its thrust could not hold a hover there under that law."""
    mass = vehicle.mass
    rows = list(in_threads(lambda fd: _contact_rows(fd, vehicle), fds))
    lows = list(in_threads(lambda fd_row: _landed_low(*fd_row, mass), zip(fds, rows)))
    skim_top, skim_landed = _vehicle_landed_height(lows, [r[2] for r in rows])
    if skim_top is not None:
        skim_top += CONTACT_LIMITS.skim_m

    def contact(fd_rows: tuple[FlightData, tuple]) -> tuple[np.ndarray, list, np.ndarray | None]:
        """One flight's contact rows, its intervals and (with a point cloud) its rests found from the body's
        height."""
        fd, (tilt, thrust, d_down, lift) = fd_rows
        # no point cloud: where the floor lies is unknown, and a still hover at the lowest height may hold any lift
        # (a 2.5 kg hexarotor hovering at 6.7 cm on 58 % of its weight had been read as on its gear): only idling
        # rotors or a thrust ramp on the spot show the floor carrying it
        unbounded = np.full(len(fd.t), np.inf) if fd.d_down is None else None
        mask, intervals = ground_contact(fd.t, fd.p[:, 2], fd.v, tilt, thrust, mass, d_down=d_down,
                                         limits=CONTACT_LIMITS, skim_top=skim_top if d_down is not None else None,
                                         skim_landed=skim_landed, lift=lift if d_down is not None else unbounded)
        by_height = None
        if fd.d_down is not None:
            # rests found from the body's height, the floor seen to carry the vehicle by the same rule (the lift
            # read off the cloud's heights: 1 where it puts no surface below)
            by_height = mask if d_down is None else ground_contact(fd.t, fd.p[:, 2], fd.v, tilt, thrust, mass,
                                                                   limits=CONTACT_LIMITS, lift=lift)[0]
        return mask, intervals, by_height

    masks, report = [], []
    for fd, path, d_down, (mask, intervals, by_height) in zip(fds, paths, (r[2] for r in rows),
                                                              in_threads(contact, zip(fds, rows))):
        if by_height is not None:  # a point cloud: it must be under the vehicle where it rests
            _check_cloud_under_rests(path, fd.t, fd.d_down, by_height, mask if d_down is not None else
                                     np.zeros_like(mask))
        masks.append(mask)
        report += [iv.to_report(path) for iv in intervals]
    return masks, report


#: s, rests on the landing gear (found from the body's height) a point cloud must agree with before it is refused
CLOUD_REST_S = 1.0
#: share of such rests the cloud's heights may miss as contact
CLOUD_REST_MISSED = 0.8


def _check_cloud_under_rests(path: str, t: np.ndarray, d_down: np.ndarray, rests: np.ndarray, contact: np.ndarray
                             ) -> None:
    """Refuse a point cloud that is not under the vehicle where it rests: ``rests`` (K,) bool, the rows where
    the body's own height finds it on its landing gear (the lowest it came, still, level, the rotors under the
    weight, the floor seen to carry it there by the rule :func:`contact_masks` applies to the cloud's heights: a
    hover that never lands rests nowhere); ``contact`` (K,) bool, those the cloud's rotor-plane heights ``d_down``
    (K,) [m] find. Where
    :data:`CLOUD_REST_S` or more of rests are mostly (:data:`CLOUD_REST_MISSED`) missed because the cloud puts
    no surface under the rotor plane, or one more than a landing gear's height (``ContactLimits.gear_max_m``)
    below it, the cloud's floor is not where the vehicle lands: the floor carrying the vehicle would be read
    as flight (a 2.7 N residual that no effect explained, on a floor 0.5 m off)."""
    dt = np.diff(t, append=t[-1])
    if float(np.sum(dt[rests])) < CLOUD_REST_S or np.mean(contact[rests]) > 1.0 - CLOUD_REST_MISSED:
        return
    h = d_down[rests]
    finite = np.isfinite(h)
    if np.mean(finite) >= 0.5 and float(np.median(h[finite])) <= CONTACT_LIMITS.gear_max_m:
        return
    where = ("puts no surface under its rotor plane there" if np.mean(finite) < 0.5 else
             f"puts its rotor plane {float(np.median(h[finite])):.2f} m over the surface below it there (a landing "
             f"gear is at most {CONTACT_LIMITS.gear_max_m:g} m)")
    first = t[np.flatnonzero(rests)[0]]
    raise InputError(f"{path}/mav0/pointcloud0/data.ply",
                     f"the vehicle rests on its landing gear ({float(np.sum(dt[rests])):.1f} s from {first:.1f} s: the "
                     f"lowest it came, still, level, the rotors under its weight) and the point cloud {where}: the "
                     "cloud's floor is not where the ground truth lands (its height, units or frame off)")


def _with_lever_arm(rec: Recording) -> tuple[FlightData, LeverArm | None]:
    """A recording's flight data and the lever arm read off them (what :func:`prepared` starts from: each
    recording alone, so several at once)."""
    fd = flight_data(rec)
    return fd, lever_arm(fd)


def prepared(recordings: Sequence[Recording], paths: Sequence[str]
             ) -> tuple[list[Recording], list[FlightData], dict[str, Any]]:
    """The recordings with late telemetry corrected, their flight data, and what was found
    (``streams``, ``stream_limits``, ``delays``, ``dropouts``: stretches where a stream has no sample, whose rows
    every fit leaves out; ``state_too_slow``: the recordings whose ground truth updates too slowly for a surface
    effect; ``lever_arms``: the recorded origins' heights read off the centre of mass and moved;
    ``levelled_m``: the largest height levelled in each tilted scan)."""
    recs, fds, delays, lines, limits, gaps, slow_state, levers = [], [], [], [], [], [], [], []
    slowest = np.inf
    for rec, path, (fd, lever) in zip(recordings, paths, in_threads(_with_lever_arm, recordings)):
        if lever is not None and lever.decisive:
            levers.append({"recording": path} | lever.as_dict())
            lines.append(_lever_line(rec, lever))
            rec = moved_origin(rec, lever.move_m, keep_rotor_plane=rec.vehicle.rotor_plane_z != 0.0)
            fd = flight_data(rec)
        gaps += [{"recording": path, "stream": stream, "t_start": a, "t_end": b} for stream, a, b in fd.gaps]
        rec2, found = delay_corrected(rec, fd)
        if found is not None:
            delays.append({"recording": path} | found)
            if found["applied"]:
                fd = flight_data(rec2)
        recs.append(rec2)
        fds.append(fd)
        ln, lim, rate = stream_limits(rec)
        lines += list(rec.read_notes) + ln
        if rec.points is None:
            lines.append(f"{rec.name}/pointcloud0: none (no mav0/pointcloud0/data.ply): heights over surfaces "
                         "unknown, so no surface effect can be tested, and ground contact is read from the rotors "
                         "alone (idling, or a thrust ramp on the spot)")
        if fd.floor_filled:
            lines.append(f"{rec.name}/pointcloud0: {100 * fd.floor_filled:.2g} % of the rows have no point of the "
                         "cloud under their rotor plane within its footprint (a floor given as a sparse grid, or a "
                         "scan's hole): their heights are over the plane through the cloud's floor")
        if rec.points is not None:
            _check_flight_over_cloud(path, rec, fd)
            lines += _cloud_scale_note(rec, fd)
        if fd.floor_tilt is not None:
            lines.append(f"{rec.name}/pointcloud0: the cloud's floor slopes by {fd.floor_tilt[0]:.2g} degrees, where "
                         "a floor is level and the motion capture's z is gravity's: read as a scan tilted against "
                         f"the world, its heights are levelled about the flight's centre (by up to "
                         f"{100 * fd.floor_tilt[1]:.2g} cm), and every stated error covers heights that far off")
        if fd.scan_noise_m:
            lines.append(f"{rec.name}/pointcloud0: a scan with {1000 * fd.scan_noise_m:.1f} mm of noise (standard "
                         "deviation of a flat surface's points): heights are read to each surface's median, not to "
                         "its highest point, which lies about three standard deviations above it")
        limits += list(lim.values())
        slow_state += [path] if "surface" in lim else []
        slowest = min(slowest, rate)
    return recs, fds, {"streams": lines, "stream_limits": limits, "delays": delays, "dropouts": gaps,
                       "slowest_update_hz": slowest, "state_too_slow": slow_state, "lever_arms": levers,
                       "levelled_m": [fd.floor_tilt[1] for fd in fds if fd.floor_tilt is not None]}


#: m, a cloud whose points span more than this in height is a room (floor, walls, furniture), not one flat layer;
#: m, how far under its lowest points a rotor plane counts as under its floor; and the share of the rows there
#: from which the recording is refused
ROOM_HEIGHT_M, UNDER_FLOOR_M, UNDER_FLOOR_SHARE = 1.0, 0.05, 0.5
#: m, a cloud rising more than this is in other units than metres: the rests' check names the cloud
#: (:func:`_check_cloud_under_rests`), and :func:`_cloud_scale_note` says it
ROOM_HEIGHT_MAX_M = 50.0


def _check_flight_over_cloud(path: str, rec: Recording, fd: FlightData) -> None:
    """Refuse a flight whose rotor plane lies under a room-sized point cloud's lowest points (its 1st percentile
    height) for most of its rows: positions with z down (NED) beside attitudes with z up, or a cloud in another
    frame. The finder had named a ceiling effect, the floor above read as a ceiling, on a blind probe's flight whose
    positions' and velocities' z were negated (no IMU to tell it). A cloud of one flat layer (a ceiling scanned
    alone) may lie over the whole flight."""
    z = rec.points[:, 2]
    low, high = (float(np.percentile(z, q)) for q in (1.0, 99.0))
    if not ROOM_HEIGHT_M < high - low <= ROOM_HEIGHT_MAX_M or len(fd.t) == 0:
        return
    plane = fd.p[:, 2] + rec.vehicle.rotor_plane_z * quat.to_rotation_matrix(fd.q)[:, 2, 2]  # m, W
    under = plane < low - UNDER_FLOOR_M
    if float(np.mean(under)) < UNDER_FLOOR_SHARE:
        return
    raise InputError(f"{path}/mav0/state_groundtruth_estimate0/data.csv",
                     f"the rotor plane flies under the point cloud's floor in {100 * float(np.mean(under)):.0f} % of "
                     f"the rows (down to {low - float(np.min(plane)):.2f} m under the cloud's lowest points, at z = "
                     f"{low:.2f} m, where the cloud rises {high - low:.1f} m above them): positions with z down (NED) "
                     "beside attitudes with z up, or a cloud in another frame (recordings.md: world z up, the cloud "
                     "in the world frame)")


#: a point cloud spanning more than this many times the flight's horizontal span, and over
#: :data:`CLOUD_SPAN_FAR_M`, is said to be in other units than metres
CLOUD_SPAN_RATIO = 100.0
CLOUD_SPAN_FAR_M = 500.0


def _cloud_scale_note(rec: Recording, fd: FlightData) -> list[str]:
    """A line where the point cloud spans far more than a room around the flight (a scan in millimetres: its
    floor at z = 0 still gives the right heights, and nothing else of it does)."""
    cloud = float(np.max(np.ptp(rec.points[:, :2], axis=0)))
    flight = max(float(np.max(np.ptp(fd.p[:, :2], axis=0))), 1.0)
    if cloud <= max(CLOUD_SPAN_RATIO * flight, CLOUD_SPAN_FAR_M):
        return []
    return [f"{rec.name}/pointcloud0: the cloud spans {cloud:.3g} m where the flight spans {flight:.2g} m: it may be "
            "in millimetres (recordings.md: metres); heights are read from it as given (a floor at z = 0 reads "
            "right in any unit, walls, ceilings and furniture do not)"]


def _lever_line(rec: Recording, lever: LeverArm) -> str:
    """What a lever arm read from the motion does to the recording, in one sentence."""
    t = rec.vehicle.T_BS_matrix[:3, 3]
    given = "puts the ground truth and IMU at the centre of mass" if not np.any(t) else \
        f"puts the ground truth at ({', '.join(f'{100 * x:.3g}' for x in t)}) cm from the centre of mass"
    rpz, dz = rec.vehicle.rotor_plane_z, float(lever.r_m[2])
    plane = (f"rotor_plane_z is read as counted from the recorded origin ({rpz:.3g} m above it: "
             f"{rpz + dz:.3g} m above the centre of mass)") if rpz != 0.0 else \
        "the rotor plane, which vehicle.yaml does not place, is taken at the centre of mass"
    return (f"{rec.name}: vehicle.yaml's T_BS {given}, but the rotation's accelerations (roll and pitch "
            f"accelerations, {lever.accel_rms:.2g} m/s^2 rms over {lever.rows} rows in flight) read them "
            f"{lever.text()}: the streams were moved {100 * abs(dz):.2g} cm {'down' if dz > 0 else 'up'} to the "
            f"centre of mass, {plane}, and every stated error covers heights {100 * abs(dz):.2g} cm apart; set "
            "T_BS's translation (and rotor_plane_z from the centre of mass) to say where they are")
