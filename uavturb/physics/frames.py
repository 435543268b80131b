"""Rigid-body kinematics between the sensor frame S and the rotor frame B (``recordings.md``).

Both frames are fixed on one rigid body. ``T_BS`` is the pose of S in B::

    x_B = T_BS x_S = R_BS x_S + t_BS          # t_BS [m]: the origin of S, in B coordinates

so the lever arm from B's origin to S's origin is ``r = t_BS`` (in B). With ``R_WS`` the
attitude of S (EuRoC's ``q_RS``) and ``omega_B`` the body angular velocity in B:

* attitude:  ``R_WB = R_WS R_SB = R_WS R_BS^T``            (quaternions: ``q_WB = q_WS * q_BS^-1``)
* position:  the B origin has S coordinates ``x_S = R_BS^T (0 - t_BS)``, so
  ``p_WB = p_WS + R_WS (-R_BS^T t_BS) = p_WS - R_WB t_BS``
* velocity:  ``d/dt`` of the above, ``d/dt R_WB = R_WB [omega_B]x``:
  ``v_WB = v_WS - R_WB (omega_B x t_BS)``
* angular velocity (any point, same body): ``omega_B = R_BS omega_S``; a gyroscope bias too.
* specific force (an accelerometer at S, reading ``f_S`` in S): the acceleration of the point
  S is that of B's origin plus the rigid-body terms ``alpha_B x r + omega_B x (omega_B x r)``
  (tangential and centripetal); gravity is the same at both points, so the specific force at
  B's origin, in B, is ``f_B = R_BS f_S - alpha_B x r - omega_B x (omega_B x r)``; an
  accelerometer bias rotates as a vector: ``b_B = R_BS b_S``.

Every function here has an exact inverse (to rounding) given the same ``omega_B``,
``alpha_B``; recordings are read into B with them and written back into S.
"""

from __future__ import annotations

import numpy as np

from uavturb.physics import quaternion as quat


def rotation_quaternion(T_BS: np.ndarray) -> np.ndarray:
    """``q_BS`` (4,), quaternion w, x, y, z of ``R_BS`` (S vectors into B)."""
    return quat.from_rotation_matrix(np.asarray(T_BS, float)[:3, :3])


def attitude_to_body(q_WS: np.ndarray, T_BS: np.ndarray) -> np.ndarray:
    """``q_WB = q_WS * q_BS^-1`` (N, 4), i.e. ``R_WB = R_WS R_BS^T``."""
    q_BS = rotation_quaternion(T_BS)
    return quat.make_continuous(quat.normalize(quat.multiply(q_WS, quat.conjugate(q_BS)[None, :])))


def attitude_to_sensor(q_WB: np.ndarray, T_BS: np.ndarray) -> np.ndarray:
    """``q_WS = q_WB * q_BS`` (N, 4): the inverse of :func:`attitude_to_body`."""
    q_BS = rotation_quaternion(T_BS)
    return quat.make_continuous(quat.normalize(quat.multiply(q_WB, q_BS[None, :])))


def position_to_body(p_WS: np.ndarray, q_WB: np.ndarray, T_BS: np.ndarray) -> np.ndarray:
    """``p_WB = p_WS - R_WB t_BS`` [m], (N, 3); ``q_WB`` the attitude of B."""
    return p_WS - quat.rotate(q_WB, np.broadcast_to(np.asarray(T_BS, float)[:3, 3], p_WS.shape))


def position_to_sensor(p_WB: np.ndarray, q_WB: np.ndarray, T_BS: np.ndarray) -> np.ndarray:
    """``p_WS = p_WB + R_WB t_BS`` [m], (N, 3)."""
    return p_WB + quat.rotate(q_WB, np.broadcast_to(np.asarray(T_BS, float)[:3, 3], p_WB.shape))


def velocity_to_body(v_WS: np.ndarray, q_WB: np.ndarray, omega_B: np.ndarray, T_BS: np.ndarray) -> np.ndarray:
    """``v_WB = v_WS - R_WB (omega_B x t_BS)`` [m/s] in W, (N, 3); ``omega_B`` [rad/s] in B."""
    t = np.asarray(T_BS, float)[:3, 3]
    return v_WS - quat.rotate(q_WB, np.cross(omega_B, t))


def velocity_to_sensor(v_WB: np.ndarray, q_WB: np.ndarray, omega_B: np.ndarray, T_BS: np.ndarray) -> np.ndarray:
    """``v_WS = v_WB + R_WB (omega_B x t_BS)`` [m/s] in W, (N, 3)."""
    t = np.asarray(T_BS, float)[:3, 3]
    return v_WB + quat.rotate(q_WB, np.cross(omega_B, t))


def vector_to_body(x_S: np.ndarray, T_BS: np.ndarray) -> np.ndarray:
    """A free vector (angular velocity, a bias) from S to B: ``x_B = R_BS x_S``, (N, 3)."""
    return x_S @ np.asarray(T_BS, float)[:3, :3].T


def vector_to_sensor(x_B: np.ndarray, T_BS: np.ndarray) -> np.ndarray:
    """``x_S = R_BS^T x_B``, (N, 3)."""
    return x_B @ np.asarray(T_BS, float)[:3, :3]


def lever_arm_acceleration(omega_B: np.ndarray, alpha_B: np.ndarray, T_BS: np.ndarray) -> np.ndarray:
    """``alpha_B x r + omega_B x (omega_B x r)`` [m/s^2] in B, (N, 3), ``r = t_BS``: how much more
    the point S accelerates than B's origin (tangential + centripetal).

    ``omega_B`` [rad/s] and ``alpha_B = d omega_B / dt`` [rad/s^2], both (N, 3) in B.
    """
    r = np.broadcast_to(np.asarray(T_BS, float)[:3, 3], np.shape(omega_B))
    return np.cross(alpha_B, r) + np.cross(omega_B, np.cross(omega_B, r))


def specific_force_to_body(f_S: np.ndarray, omega_B: np.ndarray, alpha_B: np.ndarray,
                           T_BS: np.ndarray) -> np.ndarray:
    """Accelerometer at S (``f_S`` [m/s^2] in S) as one at B's origin, in B:
    ``f_B = R_BS f_S - alpha_B x r - omega_B x (omega_B x r)``, (N, 3)."""
    return vector_to_body(f_S, T_BS) - lever_arm_acceleration(omega_B, alpha_B, T_BS)


def specific_force_to_sensor(f_B: np.ndarray, omega_B: np.ndarray, alpha_B: np.ndarray,
                             T_BS: np.ndarray) -> np.ndarray:
    """``f_S = R_BS^T (f_B + alpha_B x r + omega_B x (omega_B x r))``, (N, 3): the inverse."""
    return vector_to_sensor(f_B + lever_arm_acceleration(omega_B, alpha_B, T_BS), T_BS)
