"""``uavturb import ulog``: a PX4 log (ULog, ``.ulg``) as a recording folder of ``recordings.md``, read
with pyulog (PX4's maintained reader).

Topics (PX4 uORB messages; timestamps in microseconds since boot):

* ``vehicle_local_position``: ``x, y, z`` [m], ``vx, vy, vz`` [m/s] in NED; rows flagged invalid
  (``xy_valid``, ``z_valid``, ``v_xy_valid``, ``v_z_valid``) are left out and counted. Its times are the
  ground truth's.
* ``vehicle_attitude``: ``q[4]`` (w, x, y, z), FRD body to NED; interpolated (slerp) onto the local
  position's times, inside its own time span.
* With ``height="dist_bottom"``: ``vehicle_local_position``'s ``dist_bottom`` [m] (and ``dist_bottom_valid``),
  PX4's height over the ground from a range sensor or its terrain estimate, replaces ``z`` as the height over a
  floor at 0; rows without it are left out and counted. Without motion capture ``z`` is a barometer's, which
  drifts tens of centimetres in a flight.
* ``sensor_combined`` (``gyro_rad[3]`` [rad/s], ``accelerometer_m_s2[3]`` [m/s^2], FRD), else
  ``vehicle_imu`` (``delta_angle[3]`` / ``delta_angle_dt``, ``delta_velocity[3]`` / ``delta_velocity_dt``):
  ``imu0``.
* ``esc_status`` (``esc[i].esc_rpm``): measured rotor speeds (``rotor_speed_source: measured``; the
  sign, a reversed rotation on some ESCs, is dropped); else ``actuator_outputs`` (``output[i]``) through
  a thrust map (:mod:`uavturb.io.thrust_map`, ``--thrust-map``): commanded ones.
* ``battery_status``: ``voltage_v`` [V], ``current_a`` [A] as ``battery0`` (rows with no voltage left out).

Frames (:mod:`uavturb.io.log_frames`): NED becomes the recording's NWU world (x north, y west, z up)
and FRD its FLU body frame B, both by a half turn about x. Motor order: PX4 numbers the motors of an
airframe its own way; ``motor_order`` (vehicle rotor ``i`` is ESC / output ``motor_order[i]``) maps them
to ``vehicle.yaml``'s order. Multi-instance topics: the lowest instance is read (the others are named
in the summary). Logging dropouts stay gaps in the streams.
"""

from __future__ import annotations

import contextlib
import io
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Sequence

import numpy as np
from pyulog import ULog

from uavturb.errors import InputError
from uavturb.io.log_frames import BODIES, RECORDING_WORLD, WORLDS, attitude_to_recording, body_vectors, \
    world_vectors
from uavturb.io.log_import import ImportSummary, check_conventions, check_import_options, finish_import, floor_note
from uavturb.io.recording import Battery, GroundTruth, Imu, Recording, Rotors
from uavturb.io.thrust_map import ThrustMap, held_voltage, rpm_to_rad_s
from uavturb.io.vehicle_file import named_vehicle
from uavturb.io.yaml_mapping import read_yaml_mapping
from uavturb.physics import quaternion as quat
from uavturb.physics.vehicle import Vehicle

TOPICS = ("vehicle_local_position", "vehicle_attitude", "sensor_combined", "vehicle_imu", "esc_status",
          "actuator_outputs", "battery_status")
ROTOR_SOURCES = ("auto", "esc", "outputs")
#: where the recording's height comes from: the local position's ``z`` (PX4's estimator: motion capture, GNSS or
#: a barometer, which drifts tens of centimetres), or ``dist_bottom``, the height over the ground that PX4 keeps
#: from a range sensor (or its terrain estimate), with the floor at z = 0
HEIGHT_SOURCES = ("local", "dist_bottom")


@dataclass
class _Log:
    """The topics of one ULog: ``{topic: (t_ns (N,), fields {name: (N,) array})}``, lowest instance."""

    path: Path
    topics: dict[str, tuple[np.ndarray, dict[str, np.ndarray]]]
    notes: list[str] = field(default_factory=list)
    left_out: list[str] = field(default_factory=list)

    def get(self, topic: str, *names: str) -> np.ndarray:
        """``(N, len(names))`` float64 columns of ``topic``; a missing field names topic and field."""
        t, data = self.topics[topic]
        missing = [n for n in names if n not in data]
        if missing:
            raise InputError(self.path, f"topic {topic} has no field '{missing[0]}'")
        return np.column_stack([np.asarray(data[n], dtype=np.float64) for n in names])


#: µs, the first ULog time that nanoseconds (int64) cannot hold
_MAX_TIME_US = (2**63 - 1) // 1000


def _load(path: Path) -> _Log:
    """Read the topics of :data:`TOPICS` with pyulog; their times sorted, repeated times dropped."""
    if not path.is_file():
        raise InputError(path, "file not found")
    said = io.StringIO()  # pyulog prints its warnings (a corrupt file): they become one note
    try:
        with contextlib.redirect_stdout(said):
            ulog = ULog(str(path), message_name_filter_list=list(TOPICS), disable_str_exceptions=True)
    except Exception as e:  # pyulog raises many kinds on a file that is not a ULog
        raise InputError(path, f"not a readable ULog file ({type(e).__name__}: {str(e)[:80]})") from None
    log = _Log(path=path, topics={})
    if said.getvalue().strip():
        log.notes.append("pyulog: " + said.getvalue().strip().splitlines()[0][:120])
    for topic in TOPICS:
        instances = sorted((d for d in ulog.data_list if d.name == topic), key=lambda d: d.multi_id)
        if not instances:
            continue
        d = instances[0]
        if len(instances) > 1:
            log.notes.append(f"{topic} instance {d.multi_id} of {len(instances)}")
        t_us = np.asarray(d.data["timestamp"], dtype=np.int64)
        order = np.argsort(t_us, kind="stable")
        t_us = t_us[order]
        # a time past int64 nanoseconds (a flipped bit in a corrupt file) would wrap round once in ns: left out
        keep = np.concatenate([[True], np.diff(t_us) > 0]) & (t_us > 0) & (t_us < _MAX_TIME_US)
        if (t_us >= _MAX_TIME_US).any():
            log.notes.append(f"{int((t_us >= _MAX_TIME_US).sum())} {topic} rows with a time past the year 2262 "
                             "left out")
        log.topics[topic] = (t_us[keep] * 1000, {k: np.asarray(v)[order][keep] for k, v in d.data.items()})
    if ulog.dropouts:
        total = sum(int(x.duration) for x in ulog.dropouts)
        log.notes.append(f"{len(ulog.dropouts)} logging dropouts ({total} ms) kept as gaps")
    if ulog.file_corruption:
        log.notes.append("the file is partly corrupt (pyulog skipped what it could not read)")
    return log


def _ground_truth(log: _Log, world: str, body: str, height: str = "local") -> GroundTruth:
    for topic in ("vehicle_local_position", "vehicle_attitude"):
        if topic not in log.topics:
            raise InputError(log.path, f"no {topic} messages: the ground truth needs position and attitude")
    t_p = log.topics["vehicle_local_position"][0]
    xyz = log.get("vehicle_local_position", "x", "y", "z", "vx", "vy", "vz")
    flags = [f for f in ("xy_valid", "z_valid", "v_xy_valid", "v_z_valid")
             if f in log.topics["vehicle_local_position"][1]]
    valid = np.all(np.isfinite(xyz), axis=1)
    if flags:
        valid &= np.all(log.get("vehicle_local_position", *flags) != 0, axis=1)
    if height == "dist_bottom":
        xyz[:, 2], ranged = _dist_bottom(log)
        if (valid & ~ranged).sum():
            log.left_out.append(f"{int((valid & ~ranged).sum())} vehicle_local_position rows without a valid "
                                "dist_bottom")
        valid &= ranged
    t_q = log.topics["vehicle_attitude"][0]
    q = log.get("vehicle_attitude", "q[0]", "q[1]", "q[2]", "q[3]")  # w, x, y, z, FRD to NED
    q_ok = np.all(np.isfinite(q), axis=1) & (np.linalg.norm(q, axis=1) > 0.5)
    t_q, q = t_q[q_ok], q[q_ok]
    if len(t_q) < 2:
        raise InputError(log.path, "topic vehicle_attitude holds fewer than 2 valid attitudes")
    valid &= (t_p >= t_q[0]) & (t_p <= t_q[-1])
    if (~valid).sum():
        log.left_out.append(f"{int((~valid).sum())} vehicle_local_position rows invalid or outside the attitudes")
    if valid.sum() < 2:
        raise InputError(log.path, "topic vehicle_local_position holds fewer than 2 valid rows with an attitude")
    t = t_p[valid]
    q_log = quat.slerp((t_q - t_q[0]) * 1e-9, q, (t - t_q[0]) * 1e-9)
    zeros = np.zeros((len(t), 3))
    return GroundTruth(t_ns=t, p=world_vectors(xyz[valid, :3], world), q=attitude_to_recording(q_log, world, body),
                       v=world_vectors(xyz[valid, 3:], world), b_w=zeros, b_a=zeros.copy())  # m, m/s in W


def _dist_bottom(log: _Log) -> tuple[np.ndarray, np.ndarray]:
    """(N,) m, ``vehicle_local_position``'s ``dist_bottom`` as a NED ``z`` over a floor at 0 (``-dist_bottom``), and
    (N,) bool, the rows where it holds (finite, not negative, ``dist_bottom_valid`` where logged)."""
    fields = log.topics["vehicle_local_position"][1]
    if "dist_bottom" not in fields:
        raise InputError("--height", f"dist_bottom: {log.path} logs no dist_bottom in vehicle_local_position (no range "
                                     "sensor or terrain estimate)")
    below = log.get("vehicle_local_position", "dist_bottom")[:, 0]
    ok = np.isfinite(below) & (below >= 0.0)
    if "dist_bottom_valid" in fields:
        ok &= log.get("vehicle_local_position", "dist_bottom_valid")[:, 0] != 0
    return -below, ok


def _imu(log: _Log, body: str) -> Imu | None:
    if "sensor_combined" in log.topics:
        t = log.topics["sensor_combined"][0]
        x = log.get("sensor_combined", "gyro_rad[0]", "gyro_rad[1]", "gyro_rad[2]", "accelerometer_m_s2[0]",
                    "accelerometer_m_s2[1]", "accelerometer_m_s2[2]")
    elif "vehicle_imu" in log.topics:
        t = log.topics["vehicle_imu"][0]
        da = log.get("vehicle_imu", "delta_angle[0]", "delta_angle[1]", "delta_angle[2]", "delta_angle_dt")
        dv = log.get("vehicle_imu", "delta_velocity[0]", "delta_velocity[1]", "delta_velocity[2]",
                     "delta_velocity_dt")
        with np.errstate(divide="ignore", invalid="ignore"):
            x = np.hstack([da[:, :3] / (da[:, 3:] * 1e-6), dv[:, :3] / (dv[:, 3:] * 1e-6)])  # rad/s, m/s^2
    else:
        return None
    ok = np.all(np.isfinite(x), axis=1)
    if (~ok).sum():
        log.left_out.append(f"{int((~ok).sum())} imu rows with nan")
    if ok.sum() < 2:
        return None
    return Imu(t_ns=t[ok], gyro=body_vectors(x[ok, :3], body), acc=body_vectors(x[ok, 3:], body), T_BS=np.eye(4))


def _battery(log: _Log) -> Battery | None:
    if "battery_status" not in log.topics:
        return None
    t, data = log.topics["battery_status"]
    volt = log.get("battery_status", "voltage_v")[:, 0]  # V
    cur = log.get("battery_status", "current_a")[:, 0] if "current_a" in data else None  # A
    ok = np.isfinite(volt) & (volt > 0) & (np.isfinite(cur) if cur is not None else True)
    if (~ok).sum():
        log.left_out.append(f"{int((~ok).sum())} battery_status rows without a voltage")
    if ok.sum() < 2:
        return None
    return Battery(t_ns=t[ok], voltage=volt[ok], current=None if cur is None else cur[ok])


def _rotors(log: _Log, vehicle: Vehicle, order: Sequence[int], source: str, thrust_map: ThrustMap | None,
            battery: Battery | None) -> tuple[Rotors | None, str]:
    """Rotor speeds [rad/s] in ``vehicle.yaml`` order and their source (``measured`` / ``commanded``)."""
    has_esc = "esc_status" in log.topics
    if has_esc and source in ("auto", "esc"):
        t = log.topics["esc_status"][0]
        rpm = log.get("esc_status", *(f"esc[{i}].esc_rpm" for i in order))
        if source == "esc" or np.any(rpm != 0):
            _check_no_other_rotor_turns(log, order)
            return Rotors(t_ns=t, speeds=rpm_to_rad_s(rpm)), "measured"
    if source == "esc":
        raise InputError(log.path, "no esc_status messages (rotor speeds measured by the ESCs)")
    if "actuator_outputs" not in log.topics:
        raise InputError(log.path, "no rotor speeds: neither esc_status rpm nor actuator_outputs in the log")
    if thrust_map is None:
        raise InputError("--thrust-map", f"{log.path} has no esc_status rpm: its actuator_outputs become rotor "
                                         "speeds through a thrust map (give --thrust-map FILE.yaml)")
    if vehicle.thrust_coefficient is None:
        raise InputError("vehicle.yaml", "thrust_coefficient: required to turn actuator_outputs into rotor speeds")
    t = log.topics["actuator_outputs"][0]
    u = log.get("actuator_outputs", *(f"output[{i}]" for i in order))
    _check_no_other_output_drives_a_rotor(log, order, u)
    volt = None
    if thrust_map.needs_voltage:
        if battery is None:
            raise InputError(log.path, "the thrust map uses the battery voltage but the log has no battery_status")
        volt = np.interp(t.astype(np.float64), battery.t_ns.astype(np.float64), battery.voltage)[:, None]  # V
        volt = held_voltage(u, volt)  # held outputs keep their voltage: their speeds repeat bit for bit
    w, negative = thrust_map.rotor_speeds(u, volt, vehicle.thrust_coefficient)
    if negative:
        log.notes.append(f"{negative} rotor commands off or below the thrust map read as rotors at rest")
    return Rotors(t_ns=t, speeds=w), "commanded"


def _check_no_other_rotor_turns(log: _Log, order: Sequence[int]) -> None:
    """Refuse a log whose ESCs outside ``order`` report turning rotors: a hexarotor's log read with a quadrotor's
    vehicle.yaml would leave two rotors' thrust out of every force."""
    fields = log.topics["esc_status"][1]
    others = [i for i in range(16) if i not in order and f"esc[{i}].esc_rpm" in fields]
    if not others:
        return
    rpm = log.get("esc_status", *(f"esc[{i}].esc_rpm" for i in others))
    turning = [i for i, col in zip(others, rpm.T) if np.any(np.abs(col) > 0)]
    if turning:
        raise InputError(log.path, f"esc_status reports turning rotors on ESC {', '.join(map(str, turning))}, which "
                                   f"the vehicle's {len(order)} rotors (ESC {', '.join(map(str, order))}) leave out: "
                                   "give the vehicle.yaml of this airframe, or --motor-order")


#: an ``actuator_outputs`` channel outside the vehicle's rotors drives a rotor too where, in the rows the rotors
#: are well above their lowest output, it follows the rotors' mean (correlation) and sits at their level (its
#: median distance from their mean, as a share of the span of that mean): a servo holds still or moves on its own
OUTPUT_ROTOR_CORRELATION = 0.8
OUTPUT_ROTOR_LEVEL = 0.5
#: share of the span of the rotors' mean output over its lowest value that counts a row as the rotors driven
OUTPUT_ACTIVE_SHARE = 0.2


def _check_no_other_output_drives_a_rotor(log: _Log, order: Sequence[int], u: np.ndarray) -> None:
    """Refuse a log whose ``actuator_outputs`` channels outside ``order`` drive rotors as the vehicle's do.

    A hexarotor's log read with a quadrotor's ``vehicle.yaml`` would leave two rotors' thrust out of every
    force. Unused channels hold a fixed value (PX4's disarmed or failsafe output, or NaN) and servo channels
    (a gimbal, a payload) move on their own; a channel that follows the rotors' mean output at their level
    while they are driven (:data:`OUTPUT_ROTOR_CORRELATION`, :data:`OUTPUT_ROTOR_LEVEL`) is a rotor.

    Parameters
    ----------
    u : (N, R) the outputs of the vehicle's rotors, in ``order``
    """
    fields = log.topics["actuator_outputs"][1]
    others = [i for i in range(16) if i not in order and f"output[{i}]" in fields]
    mean = np.mean(u, axis=1)
    ok = np.isfinite(mean)
    if not others or ok.sum() < 10:
        return
    lo, hi = np.min(mean[ok]), np.max(mean[ok])
    active = ok & (mean > lo + OUTPUT_ACTIVE_SHARE * (hi - lo))
    if active.sum() < 10 or hi <= lo:
        return
    driven = []
    for i in others:
        col = log.get("actuator_outputs", f"output[{i}]")[:, 0]
        rows = active & np.isfinite(col)
        if rows.sum() < 10 or np.std(col[rows]) == 0.0 or np.std(mean[rows]) == 0.0:
            continue
        corr = float(np.corrcoef(col[rows], mean[rows])[0, 1])
        level = float(np.median(np.abs(col[rows] - mean[rows]))) / (hi - lo)
        if corr > OUTPUT_ROTOR_CORRELATION and level < OUTPUT_ROTOR_LEVEL:
            driven.append(i)
    if driven:
        raise InputError(log.path, f"actuator_outputs channel{'s' if len(driven) > 1 else ''} "
                                   f"{', '.join(map(str, driven))} follow{'' if len(driven) > 1 else 's'} the rotors' "
                                   f"outputs at their level, outside the vehicle's {len(order)} rotors (outputs "
                                   f"{', '.join(map(str, order))}): give the vehicle.yaml of this airframe, or "
                                   "--motor-order")


def _parse_motor_order(motor_order: Sequence[int] | None, n: int) -> list[int]:
    order = list(range(n)) if motor_order is None else [int(i) for i in motor_order]
    if len(order) != n or len(set(order)) != n or min(order) < 0 or max(order) >= 16:
        raise InputError("--motor-order", f"expected {n} different indices 0..15 (vehicle rotor i is ESC / output "
                                          f"motor_order[i]), got {list(motor_order or [])}")
    return order


def _build(log: _Log, vehicle: Vehicle, order: list[int], source: str, thrust_map: ThrustMap | None,
           world: str = "ned", body: str = "frd", height: str = "local") -> Recording:
    battery = _battery(log)
    rotors, speed_source = _rotors(log, vehicle, order, source, thrust_map, battery)
    return Recording(vehicle=vehicle.with_params(rotor_speed_source=speed_source),
                     ground_truth=_ground_truth(log, world, body, height), imu=_imu(log, body), rotors=rotors,
                     battery=battery, frame="B")


def import_ulog(log_file: str | Path, out: str | Path, *, vehicle: str | Vehicle,
                motor_order: Sequence[int] | None = None, rotors: str = "auto",
                thrust_map: str | Path | ThrustMap | None = None, floor_z: float | None = None,
                rotor_plane_z: float | None = None, overwrite: bool = False, height: str = "local"
                ) -> tuple[Recording, ImportSummary]:
    """``uavturb import ulog LOG.ulg --vehicle VEHICLE --out REC``.

    Parameters
    ----------
    log_file : the ``.ulg`` file
    out : recording folder to create
    vehicle : ``vehicle.yaml`` path, built-in vehicle or Vehicle (rotor geometry in its own order)
    motor_order : vehicle rotor ``i`` is ESC / actuator output ``motor_order[i]`` (default ``0..N-1``)
    rotors : ``auto`` (ESC rpm where the log has any, else actuator outputs), ``esc`` or ``outputs``
    thrust_map : YAML file (or ThrustMap) turning actuator outputs into thrust (:mod:`uavturb.io.thrust_map`)
    floor_z : m, height of a flat floor in W (z up; PX4's local origin is where the EKF started,
        usually on the ground: 0) written as ``pointcloud0``; ``None``: no point cloud
    rotor_plane_z : m, overrides the vehicle's ``rotor_plane_z``
    overwrite : replace an existing ``out`` (one uavturb wrote)
    height : ``local`` (the local position's ``z``) or ``dist_bottom`` (the height over the ground PX4 keeps from a
        range sensor; rows without it left out; the floor at z = 0 unless ``floor_z`` says otherwise)

    Returns
    -------
    The recording (in B, ``path`` = ``out``) and the summary of the import.
    """
    check_import_options(out, [log_file], floor_z=floor_z, rotor_plane_z=rotor_plane_z)
    if rotors not in ROTOR_SOURCES:
        raise InputError("--rotors", f"unknown value {rotors!r} (known: {', '.join(ROTOR_SOURCES)})")
    if height not in HEIGHT_SOURCES:
        raise InputError("--height", f"unknown value {height!r} (known: {', '.join(HEIGHT_SOURCES)})")
    if height == "dist_bottom" and floor_z is None:
        floor_z = 0.0  # dist_bottom is the height over the floor
    v = named_vehicle(vehicle) if isinstance(vehicle, str) else vehicle
    if rotor_plane_z is not None:
        v = v.with_params(rotor_plane_z=float(rotor_plane_z))
    order = _parse_motor_order(motor_order, v.rotor_count)
    if thrust_map is not None and not isinstance(thrust_map, ThrustMap):
        thrust_map = ThrustMap.from_dict(read_yaml_mapping(thrust_map), thrust_map, prefix="thrust map")
    log = _load(Path(log_file))
    rec = _build(log, v, order, rotors, thrust_map, height=height)
    try:
        check_conventions(rec, {"world": "ned", "body": "frd"}, {"world": WORLDS, "body": BODIES},
                          f"{log.path}:vehicle_attitude",
                          rebuild=lambda c: _build(replace(log, notes=[], left_out=[]), v, order, rotors, thrust_map,
                                                   c["world"], c["body"], height),
                          rotor_column=lambda i: f"esc/output {order[i]}")
    except InputError as e:
        if height != "dist_bottom":
            raise
        t = (rec.ground_truth.t_ns - rec.ground_truth.t_ns[0]) * 1e-9
        raise InputError("--height", f"dist_bottom: only the rows where {log.path} holds a valid dist_bottom are kept "
                                     f"({len(t)} rows; up to {rec.ground_truth.p[:, 2].max():.2f} m "
                                     f"over the floor, longest gap {np.max(np.diff(t), initial=0.0):.1f} s), and on "
                                     f"them the checks fail: {e.problem}") from None
    rec = finish_import(rec, out, floor_z=floor_z, overwrite=overwrite)
    return rec, _summary(rec, log, Path(out), floor_z, height)


def _summary(rec: Recording, log: _Log, out: Path, floor_z: float | None, height: str = "local") -> ImportSummary:
    s = ImportSummary(out=out, left_out=list(log.left_out), notes=list(log.notes))
    s.notes += [n for n in [floor_note(rec, floor_z)] if n]
    s.streams["ground truth"] = f"{len(rec.ground_truth)} rows (world {RECORDING_WORLD['ned']}" + (
        ", height from dist_bottom)" if height == "dist_bottom" else ")")
    s.streams["rotors"] = f"{len(rec.rotors)} rows ({rec.vehicle.rotor_speed_source}, from " \
                          f"{'esc_status' if rec.vehicle.rotor_speed_source == 'measured' else 'actuator_outputs'})"
    for name, stream in (("imu", rec.imu), ("battery", rec.battery)):
        s.streams[name] = "none" if stream is None else f"{len(stream)} rows"
    s.streams["floor"] = "none" if rec.points is None else f"z = {rec.points[0, 2]:g} m"
    lacking: list[Any] = [t for t in TOPICS if t not in log.topics]
    if "sensor_combined" in log.topics or "vehicle_imu" not in log.topics:
        lacking = [t for t in lacking if t != "vehicle_imu"]
    if "vehicle_imu" in log.topics:
        lacking = [t for t in lacking if t != "sensor_combined"]
    if rec.vehicle.rotor_speed_source == "measured":
        lacking = [t for t in lacking if t != "actuator_outputs"]
    s.lacks = lacking
    return s
