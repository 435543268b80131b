"""A recording's ground truth and IMU moved between the sensor frame S and the rotor frame B.

On disk the ground truth (``q_RS``, ``p_RS_R``, ``v_RS_R``, biases in S) and the IMU are in S;
the physics works in B (``recordings.md``). ``vehicle.yaml``'s ``T_BS`` is the pose of S in B
(``x_B = T_BS x_S``); ``imu0/sensor.yaml``'s ``T_BS`` is the IMU's pose in S (identity in EuRoC),
so the IMU sits at ``T_B,imu = T_BS(vehicle) T_S,imu`` in B. The laws are those of
:mod:`uavturb.physics.frames`; this module supplies the angular velocity and acceleration they
need, by differentiating the streams (:mod:`uavturb.io.differentiate`, window
:data:`LEVER_ARM_WINDOW_S`):

* ground truth: ``omega_B = 2 Im(q_WB^-1 dq_WB/dt)`` from the attitude (the same whichever way
  the conversion runs, so :func:`to_sensor` undoes :func:`to_body` to rounding);
* IMU: ``omega_B`` = the gyroscope rotated into B, ``alpha_B`` its derivative. The gyroscope's
  bias is not removed for the lever-arm terms: its effect, ``~2 |omega| |b_w| |r|``, is under
  1e-3 m/s^2 for EuRoC's 2e-3 rad/s bias and 0.15 m lever arm.

Where the transforms are identities nothing is computed and the arrays are returned as they
are (exact round trips of the project's own recordings, S = B).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from uavturb.io.differentiate import derivative
from uavturb.io.recording import GroundTruth, Imu, Recording
from uavturb.physics import frames
from uavturb.physics import quaternion as quat

#: s, window of the derivatives that give the lever-arm terms (quadratic fit, as flight data's)
LEVER_ARM_WINDOW_S = 0.05


def _is_identity(T: np.ndarray) -> bool:
    return bool(np.array_equal(T, np.eye(4)))


def _seconds(t_ns: np.ndarray) -> np.ndarray:
    return (np.asarray(t_ns, np.int64) - int(t_ns[0])) * 1e-9


def _body_rates(t_ns: np.ndarray, q_WB: np.ndarray) -> np.ndarray:
    """``omega_B`` [rad/s] (N, 3) from attitudes ``q_WB``: ``2 Im(conj(q) dq/dt)``, ``dq/dt`` by a
    local quadratic fit over :data:`LEVER_ARM_WINDOW_S`."""
    if len(q_WB) < 3:
        return np.zeros((len(q_WB), 3))
    qdot = derivative(_seconds(t_ns), q_WB, LEVER_ARM_WINDOW_S)
    return 2.0 * quat.multiply(quat.conjugate(q_WB), qdot)[:, 1:]


def imu_pose_in_body(rec: Recording) -> np.ndarray:
    """``T_B,imu = T_BS(vehicle.yaml) T_S,imu(imu0/sensor.yaml)`` (4, 4): the IMU's pose in B."""
    T = rec.vehicle.T_BS_matrix
    if rec.imu is not None and rec.imu.T_BS is not None and not _is_identity(np.asarray(rec.imu.T_BS, float)):
        T_S_imu = np.asarray(rec.imu.T_BS, float).copy()
        U, _, Vt = np.linalg.svd(T_S_imu[:3, :3])
        T_S_imu[:3, :3] = U @ Vt
        T = T @ T_S_imu
    return T


def groundtruth_to_body(gt: GroundTruth, T_BS: np.ndarray) -> GroundTruth:
    """Ground truth of S (``q_WS``, ``p_WS``, ``v_WS``, biases in S) as that of B."""
    if _is_identity(T_BS):
        return gt
    q_WB = frames.attitude_to_body(gt.q, T_BS)
    omega_B = _body_rates(gt.t_ns, q_WB)
    return GroundTruth(t_ns=gt.t_ns, p=frames.position_to_body(gt.p, q_WB, T_BS), q=q_WB,
                       v=frames.velocity_to_body(gt.v, q_WB, omega_B, T_BS),
                       b_w=frames.vector_to_body(gt.b_w, T_BS), b_a=frames.vector_to_body(gt.b_a, T_BS))


def groundtruth_to_sensor(gt: GroundTruth, T_BS: np.ndarray) -> GroundTruth:
    """The inverse of :func:`groundtruth_to_body`."""
    if _is_identity(T_BS):
        return gt
    omega_B = _body_rates(gt.t_ns, gt.q)
    return GroundTruth(t_ns=gt.t_ns, p=frames.position_to_sensor(gt.p, gt.q, T_BS),
                       q=frames.attitude_to_sensor(gt.q, T_BS),
                       v=frames.velocity_to_sensor(gt.v, gt.q, omega_B, T_BS),
                       b_w=frames.vector_to_sensor(gt.b_w, T_BS), b_a=frames.vector_to_sensor(gt.b_a, T_BS))


def imu_to_body(imu: Imu, T_B_imu: np.ndarray) -> Imu:
    """IMU readings in its own frame as those of an IMU at B's origin, in B (lever-arm terms removed)."""
    if _is_identity(T_B_imu):
        return imu
    gyro_B = frames.vector_to_body(imu.gyro, T_B_imu)  # rad/s in B
    alpha_B = derivative(_seconds(imu.t_ns), gyro_B, LEVER_ARM_WINDOW_S) if len(imu) >= 3 else 0 * gyro_B
    acc_B = frames.specific_force_to_body(imu.acc, gyro_B, alpha_B, T_B_imu)  # m/s^2 in B
    return replace(imu, gyro=gyro_B, acc=acc_B)


def imu_to_sensor(imu: Imu, T_B_imu: np.ndarray) -> Imu:
    """The inverse of :func:`imu_to_body`."""
    if _is_identity(T_B_imu):
        return imu
    alpha_B = derivative(_seconds(imu.t_ns), imu.gyro, LEVER_ARM_WINDOW_S) if len(imu) >= 3 else 0 * imu.gyro
    acc_S = frames.specific_force_to_sensor(imu.acc, imu.gyro, alpha_B, T_B_imu)
    return replace(imu, gyro=frames.vector_to_sensor(imu.gyro, T_B_imu), acc=acc_S)


def to_body(rec: Recording) -> Recording:
    """``rec`` (frame S, as stored) with ground truth and IMU in B; other streams unchanged."""
    if rec.frame == "B":
        return rec
    imu = None if rec.imu is None else imu_to_body(rec.imu, imu_pose_in_body(rec))
    return replace(rec, ground_truth=groundtruth_to_body(rec.ground_truth, rec.vehicle.T_BS_matrix), imu=imu,
                   frame="B")


def to_sensor(rec: Recording) -> Recording:
    """``rec`` (frame B) with ground truth and IMU back in S, as they are stored."""
    if rec.frame == "S":
        return rec
    imu = None if rec.imu is None else imu_to_sensor(rec.imu, imu_pose_in_body(rec))
    return replace(rec, ground_truth=groundtruth_to_sensor(rec.ground_truth, rec.vehicle.T_BS_matrix), imu=imu,
                   frame="S")


def moved_origin(rec: Recording, r: np.ndarray, keep_rotor_plane: bool) -> Recording:
    """``rec`` (frame B) at a new origin, its streams having been measured at ``r`` [m] (3,) from it (in B, as
    :mod:`uavturb.sysid.lever_arm` reads it): the ground truth and IMU moved to the new origin (the rotation's
    accelerations at ``r`` taken out) and the vehicle's ``T_BS`` composed with the move. ``keep_rotor_plane``:
    ``rotor_plane_z`` is raised by ``r_z``, so that the rotor plane stays where it was; otherwise it stays the same
    number, now counted from the new origin."""
    T = np.eye(4)
    T[:3, 3] = np.asarray(r, float)
    rotor_plane_z = rec.vehicle.rotor_plane_z + (float(r[2]) if keep_rotor_plane else 0.0)
    vehicle = replace(rec.vehicle, T_BS=tuple(tuple(float(x) for x in row) for row in T @ rec.vehicle.T_BS_matrix),
                      rotor_plane_z=float(rotor_plane_z))
    imu = None if rec.imu is None else imu_to_body(rec.imu, T)
    return replace(rec, vehicle=vehicle, ground_truth=groundtruth_to_body(rec.ground_truth, T), imu=imu)
