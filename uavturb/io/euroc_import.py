"""``uavturb import euroc``: a raw EuRoC sequence (its ROS bag, optionally its ASL folder) as a
recording folder of ``recordings.md``.

Frames. EuRoC's ground truth (``state_groundtruth_estimate0``) and IMU are in its body frame,
the VI-sensor's IMU: the recordings' sensor frame S, whose x axis is within ~20 deg of up. The
rotor frame B of the Firefly is its Vicon body frame (``/vicon/firefly_sbx``, set up aligned
with the rotors). ``mav0/vicon0/sensor.yaml`` gives that Vicon frame's pose in S
(``x_S = T_vicon x_B``, EuRoC's convention: every ``sensor.yaml``'s ``T_BS`` is the sensor in
EuRoC's body frame), so the recording's ``T_BS`` (pose of S in B) is its inverse,
``T_BS = T_vicon^-1 = [R^T, -R^T t]``. Check: the mean specific force at hover, about
(9.2, 0.0, -3.3) m/s^2 in S, reads (0.0, -0.1, 9.8) m/s^2 in B with the V1 sequences' values.
(That rotation is close to a half-turn, so ``R`` and ``R^T`` both send the specific force up; the
lever arm tells them apart: ``t_BS = -R^T t``, not ``t``.) Without an ASL folder, the vehicle's
own ``T_BS`` (``uavturb/vehicles/firefly.yaml``: the V1 sequences' value) is used. Either way
the import stops when the thrust axis disagrees with the data
(:func:`uavturb.io.consistency.check_thrust_axis`).
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np

from uavturb.errors import InputError
from uavturb.io.align import overlap
from uavturb.io.body_frame import to_body
from uavturb.io.consistency import check_recording
from uavturb.io.reader import read_recording
from uavturb.io.recording import Recording
from uavturb.io.rosbag import read_rosbag
from uavturb.io.sensor_yaml import read_sensor_pose
from uavturb.io.vehicle_file import named_vehicle
from uavturb.io.writer import write_recording
from uavturb.physics.vehicle import Vehicle

VICON_YAML = "mav0/vicon0/sensor.yaml"


def rotor_frame_from_vicon(T_S_vicon: np.ndarray) -> tuple[tuple[float, ...], ...]:
    """``T_BS`` (pose of S in B) when B is the Vicon body frame whose pose in S is ``T_S_vicon``:
    the rigid inverse ``[R^T, -R^T t; 0 0 0 1]``, as ``vehicle.yaml`` holds it."""
    R, t = T_S_vicon[:3, :3], T_S_vicon[:3, 3]
    T = np.eye(4)
    T[:3, :3] = R.T
    T[:3, 3] = -R.T @ t
    return tuple(tuple(float(x) for x in row) for row in T)


def import_euroc(bag: str | Path, out: str | Path, *, vehicle: str | Vehicle = "firefly",
                 asl: str | Path | None = None, rotor_speed_scale: float | None = None,
                 overwrite: bool = False) -> Recording:
    """``uavturb import euroc``: a raw EuRoC sequence as a recording folder of ``recordings.md``.

    The bag gives the rotor speeds (``/fcu/motor_speed``), and, without ``asl``, the IMU and the
    Vicon ground truth. With ``asl`` (the sequence's ASL folder, ``mav0/`` inside), its
    ground-truth state, IMU, point cloud and camera description are copied as they are (in S)
    and only the rotor speeds come from the bag; ``T_BS`` comes from its ``vicon0/sensor.yaml``
    where it has one. Camera frames are not copied (depth comes from the point cloud).
    """
    v = named_vehicle(vehicle) if isinstance(vehicle, str) else vehicle
    frame_source = f"vehicle '{vehicle}'" if isinstance(vehicle, str) else f"vehicle '{v.name}'"
    if asl is not None and (Path(asl) / VICON_YAML).is_file():
        v = v.with_params(T_BS=rotor_frame_from_vicon(read_sensor_pose(Path(asl) / VICON_YAML)))
        frame_source = str(Path(asl) / VICON_YAML)
    from_bag = read_rosbag(bag, v, rotor_speed_scale=rotor_speed_scale)
    if from_bag.rotors is None:
        raise InputError(bag, "no rotor speeds (/fcu/motor_speed) in the bag")
    if asl is None:
        rec = from_bag
    else:
        rec = read_recording(asl, vehicle=from_bag.vehicle, frame="S")  # copied as stored, in S
        rec.rotors = from_bag.rotors
        rec.vehicle = from_bag.vehicle
        if rec.cam0 is not None:
            rec.cam0 = replace(rec.cam0, t_ns=rec.cam0.t_ns[:0], files=[])
    start, end = overlap(rec.ground_truth.t_ns, rec.rotors.t_ns)
    if end <= start:
        raise InputError(bag, f"its rotor speeds do not overlap the ground truth of {asl} in time")
    checked = replace(to_body(rec), path=None)
    try:  # the rotor streams and the thrust axis against the data, before anything is written
        check_recording(checked)
    except InputError as e:
        where = frame_source if "T_BS" in e.problem else f"{bag}:/fcu/motor_speed"
        raise InputError(where, e.problem) from None
    write_recording(rec, out, overwrite=overwrite)
    rec.path = Path(out)
    return rec
