"""Geometric tracking controller for multirotors (Lee, Leok & McClamroch 2010, with
the differential-flatness body-rate feed-forward of Mellinger & Kumar 2011).

Cascade, evaluated once per control period:

1. Position PID in W with acceleration feed-forward (and an optional known external
   force ``f_ext`` [N] as feed-forward)::

       F_des = m (a_d + g e_z) - k_p e_p - k_v e_v - k_i ∫e_p dt - f_ext

   with tilt limited to ``max_tilt_deg`` and the integral term bounded.
2. Desired attitude ``R_d = [b1_d, b2_d, b3_d]`` from ``b3_d = F_des / |F_des|`` and the
   desired yaw; collective thrust ``T = F_des · R e_z``; desired body rates from the jerk
   and yaw rate of the reference.
3. Attitude PD on SO(3)::

       e_R = 1/2 vee(R_d^T R - R^T R_d),   e_w = w - R^T R_d w_d
       tau = -k_R e_R - k_w e_w + w × J w - J (hat(w) R^T R_d w_d - R^T R_d dw_d)

4. Allocation: squared rotor speeds ``w^2 = A^+ [T, tau]`` with ``A`` the vehicle's
   allocation matrix (the minimum-norm solution for more than four rotors); when a rotor
   would leave ``[0, w_max^2]`` the yaw torque is cut first, then speeds are clipped:
   ``w = sqrt(clip(w^2, 0, w_max^2))``.

Gains are given as bandwidths [rad/s] and damping ratios and scaled by the vehicle's
mass and inertia, so the same :class:`ControllerGains` fly the 50 g quadrotor and the
1.5 kg hexarotor built-in vehicles.
"""

from __future__ import annotations

from dataclasses import dataclass

import casadi as ca
import numpy as np

from uavturb.physics.dynamics import (
    GRAVITY,
    IDX_P,
    IDX_Q,
    IDX_V,
    IDX_W,
    rotation_matrix_sym,
)
from uavturb.physics.vehicle import Vehicle
from uavturb.sim.core.signals import Setpoint

E_Z = np.array([0.0, 0.0, 1.0])


@dataclass(frozen=True)
class ControllerGains:
    """Controller tuning as bandwidths and damping ratios.

    Attributes
    ----------
    position_bandwidth : rad/s, natural frequency of the horizontal position loop (``k_p = m w^2``)
    position_damping : -, damping ratio of the position loop (``k_v = 2 zeta m w``)
    vertical_bandwidth : rad/s, natural frequency of the height loop (stiffer: ground effect
        is a height-dependent force that the integral alone follows too slowly)
    integral_rate : 1/s, ``k_i = k_p * integral_rate`` (0 switches the integral off)
    integral_limit : -, bound on each component of the integral force, as a fraction of ``m g``
    attitude_bandwidth : rad/s, roll and pitch (``k_R = J w^2``, per axis)
    attitude_damping : -, roll and pitch (``k_w = 2 zeta J w``)
    yaw_bandwidth : rad/s
    yaw_damping : -
    max_tilt_deg : deg, largest angle between the thrust and world ``+z``
    max_thrust_ratio : -, largest commanded thrust as a fraction of the thrust at ``max_rotor_speed``
    """

    position_bandwidth: float = 3.0
    position_damping: float = 0.9
    vertical_bandwidth: float = 5.0
    integral_rate: float = 1.0
    integral_limit: float = 0.7
    attitude_bandwidth: float = 16.0
    attitude_damping: float = 0.8
    yaw_bandwidth: float = 4.0
    yaw_damping: float = 0.9
    max_tilt_deg: float = 40.0
    max_thrust_ratio: float = 0.9


def _vee(M: np.ndarray) -> np.ndarray:
    return np.array([M[2, 1], M[0, 2], M[1, 0]])


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``a × b`` of two 3-vectors (``np.cross`` costs ten times more on single vectors)."""
    return np.array([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]])


class RotationOf:
    """``R(q)`` (3x3, body to world) of one unit quaternion ``w, x, y, z``: the dynamics'
    symbolic :func:`~uavturb.physics.dynamics.rotation_matrix_sym`, evaluated through a
    preallocated CasADi buffer (about 1 us a call, for per-step use in simulation loops)."""

    def __init__(self) -> None:
        q = ca.SX.sym("q", 4)
        self._f = ca.Function("R", [q], [ca.reshape(rotation_matrix_sym(q), 9, 1)])
        self._buf, self._run = self._f.buffer()
        self._q, self._out = np.zeros(4), np.zeros(9)
        self._buf.set_arg(0, memoryview(self._q))
        self._buf.set_res(0, memoryview(self._out))

    def __call__(self, q: np.ndarray) -> np.ndarray:
        self._q[:] = q
        self._run()
        return self._out.reshape(3, 3, order="F").copy()


@dataclass
class ControlOutput:
    """What one controller update produced (for logs and tests).

    Attributes
    ----------
    rotor_speeds : (N,) rad/s, commanded rotor speeds
    thrust : float, N, commanded collective thrust (before allocation limits)
    torque : (3,) N m, commanded body torques in B (before allocation limits)
    R_d : (3, 3) desired attitude, body to world
    saturated : bool, whether allocation limits changed the command
    """

    rotor_speeds: np.ndarray
    thrust: float
    torque: np.ndarray
    R_d: np.ndarray
    saturated: bool


class GeometricController:
    """Position and attitude tracking on SE(3) with rotor allocation.

    Parameters
    ----------
    vehicle : Vehicle with known ``thrust_coefficient``, ``moment_coefficient`` and ``inertia``
    gains : ControllerGains
    max_rotor_speed : rad/s, actuator bound (default: the vehicle's, else 2.5 x hover speed)

    Notes
    -----
    Stateful (the position integral): call :meth:`reset` before a new flight.
    """

    def __init__(self, vehicle: Vehicle, gains: ControllerGains = ControllerGains(),
                 max_rotor_speed: float | None = None):
        self.vehicle = vehicle
        self.gains = gains
        m = vehicle.mass  # kg
        J = np.asarray(vehicle.inertia, float)  # kg m^2, diagonal
        self.m, self.J = m, J
        g = gains
        w_pos = np.array([g.position_bandwidth, g.position_bandwidth, g.vertical_bandwidth])
        self.k_p = m * w_pos**2  # N/m, per world axis
        self.k_v = 2 * g.position_damping * m * w_pos  # N s/m
        self.k_i = self.k_p * g.integral_rate  # N/(m s)
        w_att = np.array([g.attitude_bandwidth, g.attitude_bandwidth, g.yaw_bandwidth])
        z_att = np.array([g.attitude_damping, g.attitude_damping, g.yaw_damping])
        self.k_R = J * w_att**2  # N m/rad
        self.k_w = 2 * z_att * J * w_att  # N m s/rad
        self.A = vehicle.allocation()  # (4, N): [T, tau] = A w^2
        self.A_pinv = np.linalg.pinv(self.A)  # (N, 4)
        w_max = max_rotor_speed or vehicle.max_rotor_speed or 2.5 * vehicle.hover_speed()
        self.w2_max = float(w_max) ** 2  # rad^2/s^2
        self.T_max = g.max_thrust_ratio * float(np.sum(self.A[0])) * self.w2_max  # N
        self.tan_tilt = np.tan(np.deg2rad(g.max_tilt_deg))
        self.integral = np.zeros(3)  # m s, ∫ e_p dt
        self._rotation = RotationOf()
        self.last: ControlOutput | None = None

    def reset(self, f_ext: np.ndarray | None = None) -> None:
        """Clear the position integral, or preload it so that it cancels a known steady world
        force ``f_ext`` [N] from the start (a vehicle that was resting in it)."""
        self.integral = np.zeros(3)
        if f_ext is not None and self.gains.integral_rate > 0:
            self.integral = np.asarray(f_ext, float) / self.k_i

    def update(self, x: np.ndarray, sp: Setpoint, dt: float, f_ext: np.ndarray | None = None) -> np.ndarray:
        """One control step.

        Parameters
        ----------
        x : (13,) state ``p (m), q (w, x, y, z, body to world), v (m/s, W), w (rad/s, B)``
        sp : one-sample :class:`Setpoint` (``p, v, a, j`` (3,) in W; yaw, yaw_rate, yaw_acc)
        dt : s, control period (integral update)
        f_ext : (3,) N, known external force in W to cancel by feed-forward (optional)

        Returns
        -------
        (N,) rad/s, rotor speed commands.
        """
        g = self.gains
        m = self.m
        p, q, v, w = x[IDX_P], x[IDX_Q], x[IDX_V], x[IDX_W]
        R = self._rotation(q)
        e_p = p - sp.p
        e_v = v - sp.v
        # position integral, bounded (anti-windup)
        if self.gains.integral_rate > 0:
            lim = g.integral_limit * m * GRAVITY / self.k_i  # per axis
            self.integral = np.clip(self.integral + e_p * dt, -lim, lim)
        F = m * (sp.a + GRAVITY * E_Z) - self.k_p * e_p - self.k_v * e_v - self.k_i * self.integral
        if f_ext is not None:
            F = F - np.asarray(f_ext, float)
        # tilt limit: keep the vertical component, shrink the horizontal one
        F[2] = max(F[2], 0.1 * m * GRAVITY)
        h = np.hypot(F[0], F[1])
        if h > self.tan_tilt * F[2]:
            F[:2] *= self.tan_tilt * F[2] / h
        F_norm = float(np.sqrt(F @ F))
        b3 = F / F_norm
        b1c = np.array([np.cos(sp.yaw), np.sin(sp.yaw), 0.0])
        b2 = _cross(b3, b1c)
        b2 /= np.sqrt(b2 @ b2)
        b1 = _cross(b2, b3)
        R_d = np.column_stack([b1, b2, b3])
        T = float(np.clip(F @ R[:, 2], 0.0, self.T_max))
        # desired body rates from the jerk (differential flatness) and the yaw rate
        c = F_norm / m  # m/s^2, thrust acceleration
        h_w = (sp.j - (b3 @ sp.j) * b3) / c
        w_d = np.array([-(h_w @ b2), h_w @ b1, sp.yaw_rate * b3[2]])
        dw_d = np.array([0.0, 0.0, sp.yaw_acc * b3[2]])
        # attitude PD on SO(3)
        RtRd = R.T @ R_d
        e_R = 0.5 * _vee(RtRd.T - RtRd)
        w_d_B = RtRd @ w_d
        e_w = w - w_d_B
        Jw = self.J * w
        tau = -self.k_R * e_R - self.k_w * e_w + _cross(w, Jw) - self.J * (_cross(w, w_d_B) - RtRd @ dw_d)
        omega, saturated = self.allocate(T, tau)
        self.last = ControlOutput(omega, T, tau, R_d, saturated)
        return omega

    def allocate(self, thrust: float, torque: np.ndarray) -> tuple[np.ndarray, bool]:
        """Rotor speeds [rad/s] (N,) for a thrust [N] and body torques [N m] (3,), and whether
        limits were hit. The yaw torque is reduced first (it is the least useful and, on
        multirotors, the weakest axis); what still exceeds ``[0, w_max^2]`` is clipped."""
        base = self.A_pinv[:, :3] @ np.array([thrust, torque[0], torque[1]])
        yaw = self.A_pinv[:, 3] * torque[2]
        w2 = base + yaw
        saturated = False
        if np.any(w2 < 0.0) or np.any(w2 > self.w2_max):
            saturated = True
            s = 1.0
            if np.all(base >= 0.0) and np.all(base <= self.w2_max):
                # largest s in [0, 1] keeping base + s * yaw inside the bounds
                with np.errstate(divide="ignore", invalid="ignore"):
                    hi = np.where(yaw > 0, (self.w2_max - base) / yaw, np.where(yaw < 0, -base / yaw, np.inf))
                s = float(np.clip(np.min(hi), 0.0, 1.0))
            w2 = base + s * yaw
        return np.sqrt(np.clip(w2, 0.0, self.w2_max)), saturated
