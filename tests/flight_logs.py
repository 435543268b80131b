"""Test helpers: a simulated flight written the way flight controllers and loggers write it.

* :func:`write_ulog`: a minimal ULog writer following PX4's documented file format (header, flag
  bits, formats, subscriptions, data and dropout messages), independent of the reader under test.
* :func:`write_px4_log`: a recording as the PX4 topics ``uavturb import ulog`` reads (NED, FRD, µs).
* :func:`write_csv_log`: a recording as a logger's CSV in a chosen convention, with the map that
  describes it.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np
import yaml

from uavturb.io.log_frames import attitude_from_recording, body_vectors, euler_from_quaternion, \
    world_vectors_from_recording
from uavturb.io.recording import Recording
from uavturb.physics import quaternion as quat

_CODES = {"uint64_t": "Q", "int64_t": "q", "uint32_t": "I", "int32_t": "i", "uint16_t": "H", "int16_t": "h",
          "uint8_t": "B", "int8_t": "b", "bool": "?", "float": "f", "double": "d"}


@dataclass
class Topic:
    """One logged topic instance: its format (``[(type, name)]``, arrays as ``float[4]``), and its rows
    (one tuple of flattened scalars per message, the timestamp [µs] first)."""

    name: str
    fields: list[tuple[str, str]]
    rows: list[tuple]
    multi_id: int = 0


def _message(kind: bytes, payload: bytes) -> bytes:
    return struct.pack("<HB", len(payload), kind[0]) + payload


def _scalar_codes(fields: list[tuple[str, str]], formats: dict[str, list[tuple[str, str]]]) -> str:
    """struct codes of a format, nested types and arrays flattened as pyulog flattens them."""
    out = ""
    for typ, _ in fields:
        base, n = (typ.split("[")[0], int(typ.split("[")[1][:-1])) if "[" in typ else (typ, 1)
        out += (_CODES[base] if base in _CODES else _scalar_codes(formats[base], formats)) * n
    return out


def write_ulog(path: Path, topics: Sequence[Topic], *, nested: dict[str, list[tuple[str, str]]] | None = None,
               dropouts: Sequence[tuple[int, int]] = (), start_us: int = 0) -> None:
    """Write a ULog file (version 1): PX4's documented format, little endian, no padding.

    ``nested``: formats of nested types (``esc_report``); ``dropouts``: ``(time [µs], duration [ms])``.
    """
    nested = nested or {}
    out = bytearray(b"ULog\x01\x12\x35" + bytes([1]) + struct.pack("<Q", start_us))
    out += _message(b"B", bytes(16) + struct.pack("<3Q", 0, 0, 0))
    formats = dict(nested)
    for t in topics:
        formats.setdefault(t.name, t.fields)
    for name, fields in formats.items():
        out += _message(b"F", (name + ":" + "".join(f"{typ} {n};" for typ, n in fields)).encode())
    out += _message(b"I", bytes([len("char[3] ver_hw")]) + b"char[3] ver_hw" + b"SIM")
    items = []
    for msg_id, t in enumerate(topics):
        out += _message(b"A", struct.pack("<BH", t.multi_id, msg_id) + t.name.encode())
        codes = "<" + _scalar_codes(t.fields, formats)
        for row in t.rows:
            items.append((int(row[0]), _message(b"D", struct.pack("<H", msg_id) + struct.pack(codes, *row))))
    items += [(int(t_us), _message(b"O", struct.pack("<H", ms))) for t_us, ms in dropouts]
    items.sort(key=lambda x: x[0])
    out += b"".join(m for _, m in items)
    Path(path).write_bytes(bytes(out))


def to_us(t_ns: np.ndarray) -> np.ndarray:
    return np.rint(np.asarray(t_ns) / 1000).astype(np.int64)


ESC_REPORT = [("uint64_t", "timestamp"), ("uint32_t", "esc_errorcount"), ("int32_t", "esc_rpm"),
              ("float", "esc_voltage"), ("float", "esc_current")]


def px4_topics(rec: Recording, *, motor_order: Sequence[int] | None = None, rotors: str = "esc",
               thrust_per_command: float | None = None, imu: str = "sensor_combined",
               invalid_rows: Sequence[int] = (), height_drift_m: float = 0.0,
               dist_bottom_invalid: Sequence[int] | None = None) -> list[Topic]:
    """The PX4 topics of a recording (in B): NED/FRD, µs, float32 as PX4 logs them.

    ``rotors``: ``esc`` (``esc_status`` rpm, log index ``motor_order[i]`` holds vehicle rotor ``i``) or
    ``outputs`` (``actuator_outputs`` = PWM in [1000, 2000], thrust = ``thrust_per_command * u`` [N] with
    ``u`` = (PWM - 1000) / 1000). ``imu``: ``sensor_combined`` or ``vehicle_imu`` (integrated over each
    sample's interval); ``invalid_rows``: local-position rows flagged ``xy_valid = false``. ``height_drift_m``:
    the local position's height sinks by this much over the log (a barometer's drift). ``dist_bottom_invalid``:
    not None adds ``dist_bottom`` (the true height over a floor at z = 0) and ``dist_bottom_valid``, false on
    those rows.
    """
    gt = rec.ground_truth
    n_rot = rec.vehicle.rotor_count
    order = list(motor_order or range(n_rot))
    p = world_vectors_from_recording(gt.p, "ned")
    v = world_vectors_from_recording(gt.v, "ned")
    q = attitude_from_recording(gt.q, "ned", "frd")
    t_gt = to_us(gt.t_ns)
    below = gt.p[:, 2].copy()  # m over the floor at z = 0
    p[:, 2] += height_drift_m * np.linspace(0.0, 1.0, len(p))  # NED: down grows, the height sinks
    ranged = [] if dist_bottom_invalid is None else [("float", "dist_bottom"), ("bool", "dist_bottom_valid")]
    lp = Topic("vehicle_local_position", [("uint64_t", "timestamp"), ("float", "x"), ("float", "y"), ("float", "z"),
                                          ("float", "vx"), ("float", "vy"), ("float", "vz"), ("bool", "xy_valid"),
                                          ("bool", "z_valid"), ("bool", "v_xy_valid"), ("bool", "v_z_valid"), *ranged],
               [(int(t), *map(float, p[k]), *map(float, v[k]), k not in invalid_rows, True, True, True,
                 *((float(below[k]), k not in dist_bottom_invalid) if ranged else ())) for k, t in enumerate(t_gt)])
    att = Topic("vehicle_attitude", [("uint64_t", "timestamp"), ("float[4]", "q")],
                [(int(t), *map(float, q[k])) for k, t in enumerate(t_gt)])
    topics = [lp, att]
    if rec.imu is not None and imu == "vehicle_imu":
        g, a = body_vectors(rec.imu.gyro, "frd"), body_vectors(rec.imu.acc, "frd")
        t_imu = to_us(rec.imu.t_ns)
        dt = np.diff(t_imu, prepend=t_imu[0] - (t_imu[1] - t_imu[0]))  # µs
        topics.append(Topic("vehicle_imu", [("uint64_t", "timestamp"), ("float[3]", "delta_angle"),
                                            ("float[3]", "delta_velocity"), ("uint16_t", "delta_angle_dt"),
                                            ("uint16_t", "delta_velocity_dt")],
                            [(int(t), *map(float, g[k] * dt[k] * 1e-6), *map(float, a[k] * dt[k] * 1e-6), int(dt[k]),
                              int(dt[k])) for k, t in enumerate(t_imu)]))
    elif rec.imu is not None:
        g, a = body_vectors(rec.imu.gyro, "frd"), body_vectors(rec.imu.acc, "frd")  # FLU -> FRD: the same map
        topics.append(Topic("sensor_combined", [("uint64_t", "timestamp"), ("float[3]", "gyro_rad"),
                                                ("float[3]", "accelerometer_m_s2")],
                            [(int(t), *map(float, g[k]), *map(float, a[k]))
                             for k, t in enumerate(to_us(rec.imu.t_ns))]))
    slots = np.zeros((len(rec.rotors), 8))
    for i, j in enumerate(order):
        slots[:, j] = rec.rotors.speeds[:, i]
    t_rot = to_us(rec.rotors.t_ns)
    if rotors == "esc":
        rpm = np.rint(slots * 60.0 / (2.0 * np.pi)).astype(int)
        topics.append(Topic("esc_status", [("uint64_t", "timestamp"), ("uint8_t", "esc_count"),
                                           ("esc_report[8]", "esc")],
                            [(int(t), n_rot, *sum(((int(t), 0, int(r), 12.0, 1.0) for r in rpm[k]), ()))
                             for k, t in enumerate(t_rot)]))
    else:
        k_T = rec.vehicle.thrust_coefficient
        u = k_T * slots**2 / thrust_per_command  # thrust [N] = thrust_per_command * u
        pwm = np.where(np.arange(8) < n_rot, 1000.0 + 1000.0 * u, 900.0)
        topics.append(Topic("actuator_outputs", [("uint64_t", "timestamp"), ("uint32_t", "noutputs"),
                                                 ("float[16]", "output")],
                            [(int(t), n_rot, *map(float, pwm[k]), *([0.0] * 8)) for k, t in enumerate(t_rot)]))
    if rec.battery is not None:
        topics.append(Topic("battery_status", [("uint64_t", "timestamp"), ("float", "voltage_v"),
                                               ("float", "current_a")],
                            [(int(t), float(rec.battery.voltage[k]), float(rec.battery.current[k]))
                             for k, t in enumerate(to_us(rec.battery.t_ns))]))
    return topics


def write_px4_log(rec: Recording, path: Path, **kw) -> Path:
    """:func:`px4_topics` written as a ULog file; ``dropouts`` and other keywords of :func:`write_ulog`
    pass through."""
    write_kw = {k: kw.pop(k) for k in ("dropouts", "start_us") if k in kw}
    write_ulog(path, px4_topics(rec, **kw), nested={"esc_report": ESC_REPORT}, **write_kw)
    return path


# --- CSV -----------------------------------------------------------------------------------

TIME_SCALE = {"s": 1e-9, "ms": 1e-6, "us": 1e-3, "ns": 1.0}


def write_csv_log(rec: Recording, path: Path, *, world: str = "enu", body: str = "flu", attitude: str = "quaternion",
                  order: str = "wxyz", time_unit: str = "s", rotor_unit: str = "rad/s",
                  motor_order: Sequence[int] | None = None, header: bool = True, delimiter: str = ",",
                  use_indices: bool = False, thrust_map: dict | None = None, velocity: bool = True,
                  euler_unit: str = "deg", sequence: str = "zyx", direction: str = "body_to_world") -> dict:
    """Write the recording's ground truth, rotors, IMU and battery (all on the ground truth's rows; other
    streams' rows hold nan where they have no sample) as one CSV; returns the map (a dict) describing it."""
    gt = rec.ground_truth
    t_all = np.unique(np.concatenate([gt.t_ns] + [s.t_ns for s in (rec.rotors, rec.imu, rec.battery)
                                                  if s is not None]))
    cols: dict[str, np.ndarray] = {"time": t_all * TIME_SCALE[time_unit]}

    def put(names: list[str], t: np.ndarray, values: np.ndarray) -> None:
        at = np.searchsorted(t_all, t)
        for j, name in enumerate(names):
            c = np.full(len(t_all), np.nan)
            c[at] = values[:, j]
            cols[name] = c

    put(["px", "py", "pz"], gt.t_ns, world_vectors_from_recording(gt.p, world))
    q = attitude_from_recording(gt.q, "ned" if world == "neu" else world, body)
    q = quat.conjugate(q) if direction == "world_to_body" else q
    if attitude == "quaternion":
        q_cols = ["qw", "qx", "qy", "qz"] if order == "wxyz" else ["qx", "qy", "qz", "qw"]
        put(q_cols, gt.t_ns, q if order == "wxyz" else q[:, [1, 2, 3, 0]])
    else:
        rpy = euler_from_quaternion(q, sequence)
        put(["roll", "pitch", "yaw"], gt.t_ns, np.degrees(rpy) if euler_unit == "deg" else rpy)
    if velocity:
        put(["vx", "vy", "vz"], gt.t_ns, world_vectors_from_recording(gt.v, world))
    n_rot = rec.vehicle.rotor_count
    m_order = list(motor_order or range(n_rot))
    log_cols = [f"m{j + 1}" for j in range(n_rot)]
    w = rec.rotors.speeds
    if rotor_unit == "rpm":
        w = w * 60.0 / (2.0 * np.pi)
    elif rotor_unit == "command":
        w = rec.vehicle.thrust_coefficient * w**2 / thrust_map["terms"][0][2]  # thrust = c u  [N]
    log_values = np.zeros_like(w)
    for i, j in enumerate(m_order):
        log_values[:, j] = w[:, i]
    put(log_cols, rec.rotors.t_ns, log_values)
    if rec.imu is not None:
        put(["gx", "gy", "gz"], rec.imu.t_ns, body_vectors(rec.imu.gyro, body))
        put(["ax", "ay", "az"], rec.imu.t_ns, body_vectors(rec.imu.acc, body))
    if rec.battery is not None:
        put(["vbat", "ibat"], rec.battery.t_ns, np.column_stack([rec.battery.voltage, rec.battery.current]))
    names = list(cols)
    table = np.column_stack([cols[n] for n in names])
    sep = {"space": " ", "tab": "\t"}.get(delimiter, delimiter)
    text = [[repr(float(x)) for x in row] for row in table]
    if time_unit == "ns":  # integer nanoseconds, as loggers write them
        for row, t in zip(text, t_all):
            row[0] = str(int(t))
    lines = ([sep.join(names)] if header else []) + [sep.join(row) for row in text]
    Path(path).write_text("\n".join(lines) + "\n")

    def ref(*ns: str):
        r = [names.index(n) if use_indices else n for n in ns]
        return r if len(r) > 1 else r[0]

    m: dict = {"time": {"column": ref("time"), "unit": time_unit}, "world": world, "body": body,
               "position": {"columns": ref("px", "py", "pz"), "unit": "m"}, "delimiter": delimiter,
               "header": header}
    if attitude == "quaternion":
        m["quaternion"] = {"columns": ref(*q_cols), "order": order, "direction": direction}
    else:
        m["euler"] = {"columns": ref("roll", "pitch", "yaw"), "unit": euler_unit, "sequence": sequence}
    if velocity:
        m["velocity"] = {"columns": ref("vx", "vy", "vz"), "unit": "m/s"}
    m["rotors"] = {"columns": ref(*log_cols), "unit": rotor_unit, "motor_order": m_order}
    if thrust_map is not None:
        m["rotors"]["thrust_map"] = thrust_map
    if rec.imu is not None:
        m["imu"] = {"gyro": ref("gx", "gy", "gz"), "acc": ref("ax", "ay", "az")}
    if rec.battery is not None:
        m["battery"] = {"voltage": ref("vbat"), "current": ref("ibat")}
    return m


def write_map(m: dict, path: Path) -> Path:
    Path(path).write_text(yaml.safe_dump(m, sort_keys=False))
    return path


def same_attitudes(q1: np.ndarray, q2: np.ndarray) -> float:
    """Largest angle [rad] between two attitude series."""
    d = np.abs(np.sum(quat.normalize(q1) * quat.normalize(q2), axis=1))
    return float(np.max(2 * np.arccos(np.clip(d, 0, 1))))
