"""Write a :class:`Recording` as a recording folder (the EuRoC-MAV layout of ``recordings.md``).

The folder is built in a sibling temporary folder and renamed into place, so a reader never
sees a half-written recording. Floats are written as the shortest text that reads back to
the same float64: :func:`read_recording` of a written recording returns the same numbers.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from uavturb.errors import InputError
from uavturb.io import euroc_csv, ply, sensor_yaml
from uavturb.io.body_frame import to_sensor
from uavturb.io.publish import publish_folder
from uavturb.io.reader import (
    BATTERY_CSV,
    CAM_CSV,
    CAM_DATA,
    CAM_YAML,
    GROUNDTRUTH_CSV,
    IMU_CSV,
    IMU_YAML,
    POINTS_PLY,
    ROTORS_CSV,
    VEHICLE_YAML,
    VICON_CSV,
)
from uavturb.io.recording import Recording
from uavturb.io.vehicle_file import save_vehicle


def _write_streams(rec: Recording, root: Path) -> None:
    """Every file of ``rec`` under ``root`` (an empty folder); ground truth and IMU in S, as stored."""
    rec = to_sensor(rec)  # a recording in B goes back into S with vehicle.yaml's T_BS
    save_vehicle(rec.vehicle, root / VEHICLE_YAML)
    gt = rec.ground_truth
    euroc_csv.write_csv(root / GROUNDTRUTH_CSV, euroc_csv.GROUNDTRUTH_HEADER, gt.t_ns,
                        np.hstack([gt.p, gt.q, gt.v, gt.b_w, gt.b_a]))
    if rec.imu is not None:
        imu = rec.imu
        euroc_csv.write_csv(root / IMU_CSV, euroc_csv.IMU_HEADER, imu.t_ns, np.hstack([imu.gyro, imu.acc]))
        T_BS = np.eye(4) if imu.T_BS is None else imu.T_BS
        sensor_yaml.write_imu_yaml(root / IMU_YAML, sensor_yaml.ImuSensor(T_BS=T_BS, rate_hz=imu.rate_hz))
    if rec.rotors is not None:
        speeds = np.asarray(rec.rotors.speeds, dtype=np.float64)
        n = speeds.shape[1] if speeds.ndim == 2 else 0
        if n != rec.vehicle.rotor_count:
            raise InputError(root / ROTORS_CSV, f"rotor speeds have {n} columns but the vehicle "
                                                f"'{rec.vehicle.name}' has rotor_count {rec.vehicle.rotor_count}")
        euroc_csv.write_csv(root / ROTORS_CSV, euroc_csv.rotors_header(n), rec.rotors.t_ns,
                            speeds / rec.vehicle.rotor_speed_scale)
    if rec.points is not None:
        ply.write_ply(root / POINTS_PLY, rec.points)
    if rec.cam0 is not None:
        sensor_yaml.write_camera_yaml(root / CAM_YAML, rec.cam0)
        if len(rec.cam0.files):  # a camera without frames is described by its sensor.yaml alone
            euroc_csv.write_frame_list(root / CAM_CSV, rec.cam0.t_ns, rec.cam0.files)
        (root / CAM_DATA).mkdir(parents=True, exist_ok=True)
    if rec.battery is not None:
        b = rec.battery
        if b.current is None:
            euroc_csv.write_csv(root / BATTERY_CSV, euroc_csv.BATTERY_VOLTAGE_HEADER, b.t_ns, b.voltage[:, None])
        else:
            euroc_csv.write_csv(root / BATTERY_CSV, euroc_csv.BATTERY_HEADER, b.t_ns,
                                np.column_stack([b.voltage, b.current]))
    if rec.vicon is not None:
        euroc_csv.write_csv(root / VICON_CSV, euroc_csv.VICON_HEADER, rec.vicon.t_ns,
                            np.hstack([rec.vicon.p, rec.vicon.q]))


def write_recording(rec: Recording, path: str | Path, *, overwrite: bool = False,
                    extras: dict[str, str] | None = None) -> Path:
    """Write ``rec`` as a recording folder, atomically.

    Parameters
    ----------
    rec : the recording (rotor speeds in rad/s; they are divided by the vehicle's
        ``rotor_speed_scale`` on the way out, so reading back returns them unchanged). Ground
        truth and IMU of a recording in B (``rec.frame``) are written in S with the vehicle's
        ``T_BS`` (:func:`uavturb.io.body_frame.to_sensor`), so reading back returns them in B.
    path : the recording folder to create
    overwrite : replace an existing folder at ``path`` (else it is an error)
    extras : ``{relative path: text}``, further files written with the streams (a simulator's
        ``truth.yaml``), inside the same atomic publication

    Returns
    -------
    Path of the written folder. Camera images are not written (the caller puts them
    under ``mav0/cam0/data/``, which is created).

    Raises
    ------
    InputError
        ``path`` exists and ``overwrite`` is false (or holds files uavturb did not write),
        or a stream cannot be written
        (mismatched shapes, non-finite values, timestamps not strictly increasing).
        Nothing is left at ``path`` (nor any temporary folder) when writing fails.
    """
    with publish_folder(path, overwrite=overwrite, command="uavturb recording",
                        hint=" (pass --overwrite / overwrite=True to replace it)") as tmp:
        _write_streams(rec, tmp)
        for rel, text in (extras or {}).items():
            (tmp / rel).parent.mkdir(parents=True, exist_ok=True)
            (tmp / rel).write_text(text)
    return Path(path)
