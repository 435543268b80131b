"""Raw EuRoC-MAV ROS1 bags into a :class:`Recording`, with the ``rosbags`` library (no ROS needed).

Topics read (names configurable):

- ``/fcu/motor_speed``: the flight controller's motor speeds, integers 0..200 in an array
  field (``motor_speed``, else the first numeric array field of the message); multiplied
  by ``rotor_speed_scale`` into rad/s (``recordings.md``: the conversion is not published).
- ``/imu0``: ``sensor_msgs/Imu``, in the sensor frame S; moved into the rotor frame B with
  the vehicle's ``T_BS`` (:func:`uavturb.io.body_frame.imu_to_body`: rotated, lever-arm
  accelerations removed).
- ``/vicon/firefly_sbx/firefly_sbx``: ``geometry_msgs/TransformStamped`` (or ``PoseStamped``),
  the ground truth: position and attitude of the Vicon body frame, taken as the rotor frame B
  (EuRoC's Firefly: its Vicon frame is aligned with the rotors, see ``uavturb/vehicles/firefly.yaml``);
  velocity by differentiating the position; biases 0.

The returned recording is in B (``Recording.frame``); writing it stores the ground truth and
the IMU in S, with ``T_BS`` in ``vehicle.yaml``.

Message types, custom ones included, are registered from the definitions the bag carries.
Timestamps are the message header stamps (the bag's record time where a message has none);
each stream is sorted by time and exact duplicates are dropped.
"""

from __future__ import annotations

import struct
from pathlib import Path
from typing import Any

import numpy as np
from rosbags.interfaces import Nodetype
from rosbags.rosbag1 import Reader, ReaderError
from rosbags.serde import SerdeError
from rosbags.typesys import Stores, TypesysError, get_types_from_msg, get_typestore
from rosbags.typesys.store import Typestore

from uavturb.errors import InputError
from uavturb.io import align
from uavturb.io.body_frame import imu_to_body
from uavturb.io.reader import check_rotor_speeds, checked_quaternions
from uavturb.io.recording import GroundTruth, Imu, Poses, Recording, Rotors
from uavturb.numerics.filters import savgol_filter
from uavturb.physics.vehicle import Vehicle

MOTOR_TOPIC = "/fcu/motor_speed"
IMU_TOPIC = "/imu0"
VICON_TOPIC = "/vicon/firefly_sbx/firefly_sbx"

_NUMERIC = ("int8", "uint8", "int16", "uint16", "int32", "uint32", "int64", "uint64", "float32", "float64")


def _typestore(path: Path, connections: list[Any]) -> Typestore:
    """ROS1 Noetic types plus every type defined in the bag's ``connections``.

    A bag whose definition of a standard type differs from Noetic's is deserialised with
    its own definitions only.
    """
    typs: dict[str, Any] = {}
    for c in connections:
        if c.msgdef.data:
            try:
                typs.update(get_types_from_msg(c.msgdef.data, c.msgtype))
            except TypesysError as e:
                raise InputError(path, f"cannot parse the message definition of topic '{c.topic}' ({e})") from None
    store = get_typestore(Stores.ROS1_NOETIC)
    try:
        store.register(typs)
    except TypesysError:
        store = get_typestore(Stores.EMPTY)
        store.register(typs)
    return store


def _array_field(store: Typestore, msgtype: str) -> str | None:
    """The motor-speed field of ``msgtype``: ``motor_speed`` if present, else the first numeric array."""
    fields = store.fielddefs[msgtype][1]
    numeric = [name for name, (kind, sub) in fields
               if kind in (Nodetype.ARRAY, Nodetype.SEQUENCE) and sub[0][0] == Nodetype.BASE
               and sub[0][1][0] in _NUMERIC]
    if "motor_speed" in numeric:
        return "motor_speed"
    return numeric[0] if numeric else None


def _stamp(msg: Any, t_record: int) -> int:
    """Header stamp [ns] of ``msg``, or its record time when it has no (non-zero) header stamp."""
    header = getattr(msg, "header", None)
    if header is not None:
        t = int(header.stamp.sec) * 1_000_000_000 + int(header.stamp.nanosec)
        if t > 0:
            return t
    return int(t_record)


def _sorted_unique(t_ns: list[int], *values: list[Any]) -> tuple[np.ndarray, ...]:
    """Arrays sorted by time with repeated timestamps dropped (the first kept)."""
    t = np.asarray(t_ns, dtype=np.int64)
    order = np.argsort(t, kind="stable")
    t = t[order]
    keep = np.concatenate([[True], np.diff(t) > 0])
    return (t[keep],) + tuple(np.asarray(v, dtype=np.float64)[order][keep] for v in values)


def velocity_from_positions(t_ns: np.ndarray, p: np.ndarray, window_s: float | None = 0.05) -> np.ndarray:
    """Velocity [m/s] of a position series by differentiation.

    Parameters
    ----------
    t_ns : (N,) int64 increasing timestamps [ns]
    p : (N, 3) positions [m]
    window_s : Savitzky-Golay window [s] (quadratic fit) when the sampling is uniform to 10%;
        ``None``, a window under 5 samples or irregular sampling use central differences

    Returns
    -------
    (N, 3) velocities [m/s]; exact for positions quadratic in time
    """
    p = np.asarray(p, dtype=np.float64)
    if len(p) < 2:
        return np.zeros_like(p)
    t = (np.asarray(t_ns, dtype=np.int64) - int(t_ns[0])) * 1e-9
    dt = np.diff(t)
    med = float(np.median(dt))
    if window_s is not None and np.all(np.abs(dt - med) <= 0.1 * med):
        n = int(round(window_s / med)) | 1
        if 5 <= n <= len(p):
            return savgol_filter(p, n, 2, deriv=1, delta=med, axis=0)
    return np.gradient(p, t, axis=0)


def read_rosbag(path: str | Path, vehicle: Vehicle, *, rotor_speed_scale: float | None = None,
                motor_topic: str = MOTOR_TOPIC, imu_topic: str = IMU_TOPIC, vicon_topic: str = VICON_TOPIC,
                velocity_window_s: float | None = 0.05) -> Recording:
    """Read a raw EuRoC ROS1 bag.

    Parameters
    ----------
    path : ``.bag`` file
    vehicle : the vehicle flown (a bag does not describe it)
    rotor_speed_scale : rad/s per unit of the motor topic's values (default
        ``vehicle.rotor_speed_scale``); the returned recording's vehicle carries it, so
        writing the recording and reading it back gives the same rad/s
    motor_topic, imu_topic, vicon_topic : topic names
    velocity_window_s : see :func:`velocity_from_positions`

    Returns
    -------
    Recording
        ``ground_truth`` from the vicon topic (also kept as ``vicon``); ``imu`` and
        ``rotors`` when their topics are in the bag; ``path`` is the bag.

    Raises
    ------
    InputError
        Naming the bag: missing or unreadable file, no vicon messages, a motor array of
        another length than ``vehicle.rotor_count``, negative speeds, a bad quaternion, or an
        IMU/motor stream that does not overlap the vicon stream in time.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError(path, "file not found")
    scale = vehicle.rotor_speed_scale if rotor_speed_scale is None else float(rotor_speed_scale)
    if not np.isfinite(scale) or scale <= 0:
        raise InputError("rotor_speed_scale", f"must be a positive number, got {rotor_speed_scale!r}")
    if scale != vehicle.rotor_speed_scale:
        vehicle = vehicle.with_params(rotor_speed_scale=scale)

    data = _read_topics(path, motor_topic, imu_topic, vicon_topic)
    t_v, p_v, q_v = data[vicon_topic]
    if len(t_v) < 2:
        raise InputError(path, f"topic '{vicon_topic}' has {len(t_v)} messages (ground truth needs at least 2)")
    t_gt, p, q = _sorted_unique(t_v, p_v, q_v)
    q = checked_quaternions(f"{path}:{vicon_topic}", q, unit="message")
    zeros = np.zeros((len(t_gt), 3))
    gt = GroundTruth(t_ns=t_gt, p=p, q=q, v=velocity_from_positions(t_gt, p, velocity_window_s), b_w=zeros,
                     b_a=zeros.copy())

    imu = None
    if data[imu_topic][0]:
        t, gyro, acc = _sorted_unique(*data[imu_topic])
        align.require_overlap(t_gt, t, f"{path}:{imu_topic}", "the vicon stream")
        imu = imu_to_body(Imu(t_ns=t, gyro=gyro, acc=acc, T_BS=np.eye(4)), vehicle.T_BS_matrix)

    rotors = None
    if data[motor_topic][0]:
        lengths = {len(x) for x in data[motor_topic][1]}
        if len(lengths) != 1:
            raise InputError(f"{path}:{motor_topic}", f"motor arrays of different lengths {sorted(lengths)}")
        t, raw_speeds = _sorted_unique(*data[motor_topic][:2])
        check_rotor_speeds(f"{path}:{motor_topic}", raw_speeds, vehicle, unit="message")
        align.require_overlap(t_gt, t, f"{path}:{motor_topic}", "the vicon stream")
        rotors = Rotors(t_ns=t, speeds=raw_speeds * scale)

    return Recording(vehicle=vehicle, ground_truth=gt, imu=imu, rotors=rotors,
                     vicon=Poses(t_ns=t_gt.copy(), p=p.copy(), q=q.copy()), path=path, frame="B")


def _read_topics(path: Path, motor_topic: str, imu_topic: str, vicon_topic: str
                 ) -> dict[str, tuple[list, list, list]]:
    """The three topics' messages as lists, per topic ``(stamps [ns], a, b)``: motor arrays (``b`` empty);
    gyroscope [rad/s] and accelerometer [m/s^2]; vicon positions [m] and quaternions w,x,y,z."""
    wanted = (motor_topic, imu_topic, vicon_topic)
    data: dict[str, tuple[list, list, list]] = {topic: ([], [], []) for topic in wanted}
    try:
        with Reader(path) as bag:
            connections = [c for c in bag.connections if c.topic in wanted]
            store = _typestore(path, connections)
            motor_field = {c.msgtype: _array_field(store, c.msgtype) for c in connections if c.topic == motor_topic}
            for c, t_record, raw in bag.messages(connections=connections) if connections else ():
                msg = store.deserialize_ros1(raw, c.msgtype)
                t, a, b = data[c.topic]
                t.append(_stamp(msg, t_record))
                if c.topic == motor_topic:
                    name = motor_field[c.msgtype]
                    if name is None:
                        raise InputError(path, f"topic '{motor_topic}' ({c.msgtype}) has no numeric array field")
                    a.append(np.asarray(getattr(msg, name), dtype=np.float64))
                elif c.topic == imu_topic:
                    a.append((msg.angular_velocity.x, msg.angular_velocity.y, msg.angular_velocity.z))
                    b.append((msg.linear_acceleration.x, msg.linear_acceleration.y, msg.linear_acceleration.z))
                else:
                    pos, rot = (msg.transform.translation, msg.transform.rotation) if hasattr(msg, "transform") \
                        else (msg.pose.position, msg.pose.orientation)
                    a.append((pos.x, pos.y, pos.z))
                    b.append((rot.w, rot.x, rot.y, rot.z))
    except (ReaderError, SerdeError, TypesysError, KeyError, ValueError, IndexError, UnicodeDecodeError,
            OSError, struct.error) as e:  # a random or truncated file meets any of them in the parsers
        raise InputError(path, f"not a readable ROS1 bag ({type(e).__name__}: {e})") from None
    except AttributeError as e:
        raise InputError(path, f"unexpected message layout ({e})") from None
    return data

