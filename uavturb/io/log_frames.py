"""Flight-controller log conventions turned into the recording's frames (``recordings.md``).

Logs name their frames differently; every importer (``uavturb import ulog|csv``) goes through
these functions, so each convention has one definition, tested once.

World frames of a log (``world``):

* ``enu``: x east, y north, z up. The recording's world W is this frame itself.
* ``ned``: x north, y east, z down (PX4, ArduPilot). W is then **NWU**: x north, y west, z up,
  the NED frame turned half a turn about north: ``v_W = R_x(pi) v_NED = (n, -e, -d)``.
* ``neu``: x north, y east, z up, as some loggers write NED positions with the altitude made
  positive. It is a mirror image, no rotation of any world, so its positions and velocities are
  taken as ``(n, e, u)`` -> W = NWU ``(n, -e, u)``, and its attitudes as NED attitudes (the
  loggers that write it keep the flight controller's NED attitude).

Body frames of a log (``body``): ``flu`` (x forward, y left, z up: the recording's B) or ``frd``
(x forward, y right, z down: PX4), with ``v_B = R_x(pi) v_FRD = (f, -r, -d)``.

Attitudes: a log's quaternion rotates its body frame into its world frame; the recording's is
``R_WB = R_W,log R_log,body R_body,B``: with ``R_x(pi)`` on the left for a NED (or NEU) world
and on the right for an FRD body. A level vehicle heading north has the identity attitude in
NWU; heading east, a yaw of -90 deg about W's z (east is W's -y).
"""

from __future__ import annotations

import numpy as np

from uavturb.physics import quaternion as quat

WORLDS = ("enu", "ned", "neu")
BODIES = ("flu", "frd")
EULER_SEQUENCES = ("zyx", "xyz")

#: quaternion w, x, y, z of R_x(pi), the half turn about x that takes NED to NWU and FRD to FLU
_HALF_TURN_X = np.array([0.0, 1.0, 0.0, 0.0])
#: the recording's world for each log world
RECORDING_WORLD = {"enu": "ENU (x east, y north, z up)", "ned": "NWU (x north, y west, z up)",
                   "neu": "NWU (x north, y west, z up)"}


def world_vectors(v: np.ndarray, world: str) -> np.ndarray:
    """Positions [m] or velocities [m/s] ``(N, 3)`` of the log's ``world`` in W."""
    v = np.asarray(v, dtype=np.float64)
    if world == "enu":
        return v.copy()
    if world == "ned":
        return v * np.array([1.0, -1.0, -1.0])  # (n, e, d) -> (n, -e, -d): R_x(pi)
    if world == "neu":
        return v * np.array([1.0, -1.0, 1.0])  # (n, e, u) -> (n, -e, u)
    raise ValueError(f"unknown world frame {world!r}")


def body_vectors(v: np.ndarray, body: str) -> np.ndarray:
    """Vectors ``(N, 3)`` in the log's ``body`` frame (gyroscope [rad/s], specific force [m/s^2]) in B (FLU)."""
    v = np.asarray(v, dtype=np.float64)
    if body == "flu":
        return v.copy()
    if body == "frd":
        return v * np.array([1.0, -1.0, -1.0])  # (f, r, d) -> (f, -r, -d): R_x(pi)
    raise ValueError(f"unknown body frame {body!r}")


def attitude_to_recording(q: np.ndarray, world: str, body: str) -> np.ndarray:
    """Attitudes ``(N, 4)`` (quaternion w, x, y, z, log body to log world) as the recording's
    (w, x, y, z, B to W), sign-continuous. ``neu`` attitudes are NED attitudes (module docstring)."""
    q = quat.normalize(np.asarray(q, dtype=np.float64))
    if world in ("ned", "neu"):
        q = quat.multiply(_HALF_TURN_X, q)  # R_W,NED = R_x(pi)
    elif world != "enu":
        raise ValueError(f"unknown world frame {world!r}")
    if body == "frd":
        q = quat.multiply(q, _HALF_TURN_X)  # R_FRD,FLU = R_x(pi)
    elif body != "flu":
        raise ValueError(f"unknown body frame {body!r}")
    return quat.make_continuous(quat.normalize(q))


def attitude_from_recording(q_WB: np.ndarray, world: str, body: str) -> np.ndarray:
    """The inverse of :func:`attitude_to_recording` (writes simulated flights as logs in tests and docs)."""
    q = np.asarray(q_WB, dtype=np.float64)
    if world in ("ned", "neu"):
        q = quat.multiply(_HALF_TURN_X, q)  # R_x(pi) is its own inverse
    if body == "frd":
        q = quat.multiply(q, _HALF_TURN_X)
    return quat.make_continuous(quat.normalize(q))


def world_vectors_from_recording(v_W: np.ndarray, world: str) -> np.ndarray:
    """The inverse of :func:`world_vectors` (each of its maps is its own inverse)."""
    return world_vectors(v_W, world)


def euler_to_quaternion(roll: np.ndarray, pitch: np.ndarray, yaw: np.ndarray, sequence: str) -> np.ndarray:
    """Quaternions w, x, y, z ``(N, 4)`` of Euler angles [rad].

    ``zyx``: ``R = Rz(yaw) Ry(pitch) Rx(roll)`` (aerospace and ROS: yaw, then pitch, then roll about
    the moving axes); ``xyz``: ``R = Rx(roll) Ry(pitch) Rz(yaw)``.
    """
    if sequence == "zyx":
        return quat.from_euler(roll, pitch, yaw)
    if sequence != "xyz":
        raise ValueError(f"unknown Euler sequence {sequence!r}")
    zeros = np.zeros_like(np.asarray(roll, dtype=np.float64))
    qx, qy, qz = quat.from_euler(roll, zeros, zeros), quat.from_euler(zeros, pitch, zeros), \
        quat.from_euler(zeros, zeros, yaw)
    return quat.multiply(quat.multiply(qx, qy), qz)


def euler_from_quaternion(q: np.ndarray, sequence: str) -> np.ndarray:
    """``(N, 3)`` roll, pitch, yaw [rad] of quaternions w, x, y, z: the inverse of
    :func:`euler_to_quaternion` (pitch within +-90 deg)."""
    R = quat.to_rotation_matrix(q)
    if sequence == "zyx":
        return np.stack([np.arctan2(R[:, 2, 1], R[:, 2, 2]), np.arcsin(np.clip(-R[:, 2, 0], -1, 1)),
                         np.arctan2(R[:, 1, 0], R[:, 0, 0])], axis=1)
    if sequence == "xyz":
        return np.stack([np.arctan2(-R[:, 1, 2], R[:, 2, 2]), np.arcsin(np.clip(R[:, 0, 2], -1, 1)),
                         np.arctan2(-R[:, 0, 1], R[:, 0, 0])], axis=1)
    raise ValueError(f"unknown Euler sequence {sequence!r}")
