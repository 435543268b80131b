"""``uavturb import-euroc``: a raw EuRoC sequence (its ROS bag, optionally its ASL folder) as a
recording folder of ``recordings.md``."""

from __future__ import annotations

from pathlib import Path

from uavturb.errors import InputError
from uavturb.io.recording import Recording
from uavturb.io.vehicle_file import preset


def import_euroc(bag: str | Path, out: str | Path, *, vehicle: str = "firefly", asl: str | Path | None = None,
                 rotor_speed_scale: float | None = None, overwrite: bool = False) -> Recording:
    """``uavturb import-euroc``: a raw EuRoC sequence as a recording folder of ``recordings.md``.

    The bag gives the rotor speeds (``/fcu/motor_speed``), and, without ``asl``, the IMU and the
    Vicon ground truth. With ``asl`` (the sequence's ASL folder, ``mav0/`` inside), its
    ground-truth state, IMU, point cloud and camera description are used and only the rotor
    speeds come from the bag. Camera frames are not copied (depth comes from the point cloud).
    """
    from dataclasses import replace

    from uavturb.io.align import overlap
    from uavturb.io.reader import read_recording
    from uavturb.io.rosbag import read_rosbag
    from uavturb.io.writer import write_recording

    v = preset(vehicle) if isinstance(vehicle, str) else vehicle
    from_bag = read_rosbag(bag, v, rotor_speed_scale=rotor_speed_scale)
    if from_bag.rotors is None:
        raise InputError(bag, "no rotor speeds (/fcu/motor_speed) in the bag")
    if asl is None:
        rec = from_bag
    else:
        rec = read_recording(asl, vehicle=from_bag.vehicle)
        rec.rotors = from_bag.rotors
        rec.vehicle = from_bag.vehicle
        if rec.cam0 is not None:
            rec.cam0 = replace(rec.cam0, t_ns=rec.cam0.t_ns[:0], files=[])
    start, end = overlap(rec.ground_truth.t_ns, rec.rotors.t_ns)
    if end <= start:
        raise InputError(bag, f"its rotor speeds do not overlap the ground truth of {asl} in time")
    write_recording(rec, out, overwrite=overwrite)
    rec.path = Path(out)
    return rec

