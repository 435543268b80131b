"""``uavturb import csv``: any logger's CSV file, described by a map (:mod:`uavturb.io.csv_map`), as a
recording folder of ``recordings.md``.

Each stream takes the rows where all of its mapped columns are numbers: rows with ``nan`` or empty
fields (before arming, or a stream logged at a lower rate than the rows) are left out of that stream
and counted. Rows whose time is missing, repeated or going back are left out of every stream and
counted. Nothing is resampled: sample-and-hold repeats stay as they are.

Frames and units are converted by :mod:`uavturb.io.log_frames` (world, body, Euler angles) and
:mod:`uavturb.io.thrust_map` (rpm, commands); the recording is checked against the data before it is
written (:func:`uavturb.io.log_import.check_conventions`), so a map with a wrong frame or sign fails
with one line naming the key that looks wrong.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from uavturb.errors import InputError
from uavturb.io import align
from uavturb.io.csv_map import CsvMap, load_csv_map
from uavturb.io.csv_table import Table, read_table
from uavturb.io.differentiate import derivative
from uavturb.io.log_frames import BODIES, RECORDING_WORLD, WORLDS, attitude_to_recording, body_vectors, \
    euler_to_quaternion, world_vectors
from uavturb.io.log_import import ImportSummary, check_conventions, check_import_options, finish_import, floor_note
from uavturb.io.reader import checked_quaternions
from uavturb.io.recording import Battery, GroundTruth, Imu, Recording, Rotors
from uavturb.io.thrust_map import held_voltage, rpm_to_rad_s
from uavturb.io.vehicle_file import named_vehicle
from uavturb.physics import quaternion as quat
from uavturb.physics.vehicle import Vehicle

#: s, window of the velocity derived from positions when the map gives no velocity columns
VELOCITY_WINDOW_S = 0.05


@dataclass
class _Rows:
    """The table's rows with a usable time, and what was left out."""

    t_ns: np.ndarray  # (N,) int64, strictly increasing
    keep: np.ndarray  # (N,) indices into the table's rows
    left_out: list[str] = field(default_factory=list)


#: ns, the longest step between two rows of one log taken as real (a logger paused for hours resumes in a new file)
MAX_TIME_LEAP_NS = 86_400 * 10**9


def _time_rows(table: Table, m: CsvMap, where: str | Path) -> _Rows:
    t = table.values["time.column"] * m.time_ns_per_unit
    finite = np.isfinite(t)
    idx = np.flatnonzero(finite)
    too_late = np.flatnonzero(np.abs(t[idx]) >= 2.0**63)  # past int64 nanoseconds (year 2262): a wrong time.unit
    if len(too_late):
        k = int(idx[too_late[0]])
        raise InputError(where, f"line {int(table.lines[k])}: time {table.values['time.column'][k]:.6g} read in the "
                                f"map's time.unit is past what nanoseconds can count (the year 2262): "
                                f"the wrong time.unit?")
    if "time.column" in table.integers:  # integer times (ns, µs) exactly, beyond float64's digits
        t_ns = table.integers["time.column"][idx] * int(m.time_ns_per_unit)
    else:
        t_ns = np.rint(t[idx]).astype(np.int64)
    steps = np.diff(t_ns)
    leap = np.flatnonzero(steps > MAX_TIME_LEAP_NS)
    if len(leap):  # before anything is left out as going back: every row after a leap would be
        k = int(leap[0]) + 1
        raise InputError(where, f"line {int(table.lines[idx[k]])}: the time leaps {steps[k - 1] * 1e-9:.3g} s past the "
                                f"row before (over a day between two rows of one log): a corrupt timestamp, or the "
                                f"wrong time.unit")
    running = np.maximum.accumulate(t_ns) if len(t_ns) else t_ns
    increasing = np.concatenate([[True], t_ns[1:] > running[:-1]]) if len(t_ns) else np.zeros(0, bool)
    rows = _Rows(t_ns=t_ns[increasing], keep=idx[increasing])
    if (~finite).sum():
        rows.left_out.append(f"{int((~finite).sum())} rows without a time")
    if (~increasing).sum():
        rows.left_out.append(f"{int((~increasing).sum())} rows whose time repeats or goes back")
    if table.truncated:
        rows.left_out.append(f"{table.truncated} truncated last row")
    return rows


def _stack(table: Table, rows: _Rows, keys: list[str]) -> np.ndarray:
    return np.column_stack([table.values[k][rows.keep] for k in keys]) if keys else np.zeros((len(rows.keep), 0))


def _group(m: CsvMap, prefix: str) -> list[str]:
    return [k for k in m.columns() if k.startswith(prefix + "[")]


def _finite_rows(x: np.ndarray, what: str, left_out: list[str]) -> np.ndarray:
    ok = np.all(np.isfinite(x), axis=1)
    if (~ok).sum():
        left_out.append(f"{int((~ok).sum())} {what} rows with nan")
    return ok


def _ground_truth(table: Table, m: CsvMap, rows: _Rows, world: str, body: str, left_out: list[str]) -> GroundTruth:
    att_keys = _group(m, f"{m.attitude_kind}.columns")
    vel_keys = _group(m, "velocity.columns")
    x = _stack(table, rows, _group(m, "position.columns") + att_keys + vel_keys)
    ok = _finite_rows(x, "ground-truth", left_out)
    if ok.sum() < 2:
        raise InputError(m.path, f"fewer than 2 rows hold a position and an attitude ({int(ok.sum())} of {len(ok)})")
    x, t_ns, lines = x[ok], rows.t_ns[ok], table.lines[rows.keep][ok]
    p = world_vectors(x[:, :3] * m.position_scale, world)  # m, W
    if m.attitude_kind == "quaternion":
        q = x[:, 3:7] if m.quaternion_order == "wxyz" else x[:, [6, 3, 4, 5]]  # w, x, y, z
        q = checked_quaternions(f"{m.path} (map key quaternion.columns)", q, lines)
        q = quat.conjugate(q) if m.quaternion_direction == "world_to_body" else q
    else:
        rpy = x[:, 3:6] * m.euler_scale  # rad
        q = euler_to_quaternion(rpy[:, 0], rpy[:, 1], rpy[:, 2], m.euler_sequence)
    q = attitude_to_recording(q, world, body)  # w, x, y, z, B to W
    n_att = len(att_keys)
    if vel_keys:
        v = world_vectors(x[:, 3 + n_att:6 + n_att] * m.velocity_scale, world)  # m/s, W
    else:
        v = derivative((t_ns - t_ns[0]) * 1e-9, p, VELOCITY_WINDOW_S)  # m/s, W
    zeros = np.zeros((len(t_ns), 3))
    return GroundTruth(t_ns=t_ns, p=p, q=q, v=v, b_w=zeros, b_a=zeros.copy())


def _rotors(table: Table, m: CsvMap, rows: _Rows, vehicle: Vehicle, battery: Battery | None, left_out: list[str],
            notes: list[str]) -> Rotors | None:
    if m.rotors is None:
        return None
    keys = _group(m, "rotors.columns")
    if len(keys) != vehicle.rotor_count:
        raise InputError(m.path, f"map key rotors.columns: {len(keys)} columns but the vehicle '{vehicle.name}' "
                                 f"has rotor_count {vehicle.rotor_count}")
    order = list(m.motor_order or range(len(keys)))
    x = _stack(table, rows, [keys[i] for i in order])  # vehicle.yaml order
    ok = _finite_rows(x, "rotor", left_out)
    x, t_ns = x[ok], rows.t_ns[ok]
    if m.rotor_unit == "rpm":
        w = rpm_to_rad_s(x)
    elif m.rotor_unit == "rad/s":
        w = np.abs(x)
    else:
        if vehicle.thrust_coefficient is None:
            raise InputError("vehicle.yaml", "thrust_coefficient: required to turn rotor commands into rotor "
                                             "speeds through the map's thrust_map (w = sqrt(f / k_T))")
        volt = None
        if m.thrust_map.needs_voltage:  # the battery's voltage [V] at the rotor rows, interpolated
            if battery is None:
                raise InputError(m.path, "rotors.thrust_map uses the battery voltage but no row holds one")
            volt = np.interp(t_ns.astype(np.float64), battery.t_ns.astype(np.float64), battery.voltage)[:, None]
            volt = held_voltage(x, volt)  # held commands keep their voltage: their speeds repeat bit for bit
        w, negative = m.thrust_map.rotor_speeds(x, volt, vehicle.thrust_coefficient)
        if negative:
            notes.append(f"{negative} rotor commands off or below the thrust map read as rotors at rest")
    return Rotors(t_ns=t_ns, speeds=w) if len(t_ns) >= 2 else None


def _battery(table: Table, m: CsvMap, rows: _Rows, left_out: list[str]) -> Battery | None:
    if m.voltage is None:
        return None
    volt = table.values["battery.voltage"][rows.keep] * m.voltage_scale  # V
    cur = table.values["battery.current"][rows.keep] * m.current_scale if m.current is not None else None  # A
    ok = np.isfinite(volt) & (volt > 0) & (np.isfinite(cur) if cur is not None else True)
    if (~ok).sum():
        left_out.append(f"{int((~ok).sum())} battery rows with nan or no voltage")
    if ok.sum() < 2:
        return None
    return Battery(t_ns=rows.t_ns[ok], voltage=volt[ok], current=None if cur is None else cur[ok])


def _imu(table: Table, m: CsvMap, rows: _Rows, gt: GroundTruth, world: str, body: str,
         left_out: list[str]) -> Imu | None:
    """The IMU in B. An accelerometer logged in the world frame (``imu.acc_frame: world``, e.g. a
    Crazyflie's ``stateEstimate.a*``: specific force rotated into the world) is rotated back into B
    with the ground truth's attitude at its rows (slerp; rows outside the ground truth's span left out)."""
    if m.gyro is None:
        return None
    x = _stack(table, rows, _group(m, "imu.gyro") + _group(m, "imu.acc"))
    ok = _finite_rows(x, "imu", left_out)
    t_ns = rows.t_ns
    if m.acc_frame == "world":
        inside = (t_ns >= gt.t_ns[0]) & (t_ns <= gt.t_ns[-1])
        if (ok & ~inside).sum():
            left_out.append(f"{int((ok & ~inside).sum())} imu rows outside the ground truth's time span")
        ok &= inside
    if ok.sum() < 2:
        return None
    gyro = body_vectors(x[ok, :3] * m.gyro_scale, body)  # rad/s, B
    if m.acc_frame == "world":
        q_WB = align.interpolate_quaternions(gt.t_ns, gt.q, t_ns[ok])
        acc = quat.rotate_inverse(q_WB, world_vectors(x[ok, 3:] * m.acc_scale, world))  # m/s^2, R_WB^T a_W
    else:
        acc = body_vectors(x[ok, 3:] * m.acc_scale, body)  # m/s^2, specific force in B
    return Imu(t_ns=t_ns[ok], gyro=gyro, acc=acc, T_BS=np.eye(4))


def _build(table: Table, m: CsvMap, rows: _Rows, vehicle: Vehicle, world: str, body: str
           ) -> tuple[Recording, list[str], list[str]]:
    """The recording with the given conventions, what was left out, and notes."""
    left_out: list[str] = list(rows.left_out)
    notes: list[str] = []
    gt = _ground_truth(table, m, rows, world, body, left_out)
    battery = _battery(table, m, rows, left_out)
    rotors = _rotors(table, m, rows, vehicle, battery, left_out, notes)
    if rotors is not None:
        vehicle = vehicle.with_params(rotor_speed_source=m.rotor_source)
    rec = Recording(vehicle=vehicle, ground_truth=gt, imu=_imu(table, m, rows, gt, world, body, left_out),
                    rotors=rotors, battery=battery, frame="B")
    return rec, left_out, notes


def import_csv(log: str | Path, map_file: str | Path, out: str | Path, *, vehicle: str | Vehicle,
               floor_z: float | None = None, rotor_plane_z: float | None = None,
               overwrite: bool = False) -> tuple[Recording, ImportSummary]:
    """``uavturb import csv LOG --map MAP --vehicle VEHICLE --out REC``.

    Parameters
    ----------
    log : the CSV file
    map_file : its map (:mod:`uavturb.io.csv_map`)
    out : recording folder to create
    vehicle : ``vehicle.yaml`` path, built-in vehicle or Vehicle: the rotor order of ``rotors0`` is its order
    floor_z : m, height of a flat floor in W (z up) written as ``pointcloud0``; ``None``: no point cloud
    rotor_plane_z : m, overrides the vehicle's ``rotor_plane_z``
    overwrite : replace an existing ``out`` (one uavturb wrote)

    Returns
    -------
    The recording (in B, ``path`` = ``out``) and the summary of the import.
    """
    check_import_options(out, [log, map_file], floor_z=floor_z, rotor_plane_z=rotor_plane_z)
    m = load_csv_map(map_file)
    v = named_vehicle(vehicle) if isinstance(vehicle, str) else vehicle
    if rotor_plane_z is not None:
        v = v.with_params(rotor_plane_z=float(rotor_plane_z))
    table = read_table(log, m.columns(), delimiter=m.delimiter, header=m.header, exact=("time.column",))
    rows = _time_rows(table, m, log)
    rec, left_out, notes = _build(table, m, rows, v, m.world, m.body)
    order = list(m.motor_order or range(len(m.rotors or ())))
    check_conventions(rec, {"world": m.world, "body": m.body}, {"world": WORLDS, "body": BODIES}, str(m.path),
                      rebuild=lambda c: _build(table, m, rows, v, c["world"], c["body"])[0],
                      rotor_column=lambda i: repr(m.rotors[order[i]]))
    rec = finish_import(rec, out, floor_z=floor_z, overwrite=overwrite)
    return rec, _summary(rec, m, Path(out), left_out, notes, floor_z)


def _summary(rec: Recording, m: CsvMap, out: Path, left_out: list[str], notes: list[str],
             floor_z: float | None) -> ImportSummary:
    s = ImportSummary(out=out, left_out=left_out)
    s.streams["ground truth"] = f"{len(rec.ground_truth)} rows (world {RECORDING_WORLD[m.world]})"
    lacks = []
    for name, stream in (("rotors", rec.rotors), ("imu", rec.imu), ("battery", rec.battery)):
        if stream is not None:
            extra = f" ({rec.vehicle.rotor_speed_source}, from {m.rotor_unit})" if name == "rotors" else ""
            s.streams[name] = f"{len(stream)} rows{extra}"
        else:
            lacks.append(name)
    s.streams["floor"] = "none" if rec.points is None else f"z = {rec.points[0, 2]:g} m"
    s.lacks, s.notes = lacks, notes + [n for n in [floor_note(rec, floor_z)] if n]
    return s
