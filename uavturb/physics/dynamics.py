"""Rigid-body multirotor dynamics, the paper's eq. 1, written once in CasADi.

State ``x`` (13,)::

    p  (3)  m,      position of B in W
    q  (4)  -,      quaternion w, x, y, z, body to world (Hamilton)
    v  (3)  m/s,    velocity in W
    w  (3)  rad/s,  angular velocity of B in B

Inputs: rotor speeds ``Omega`` (N,) [rad/s]; external force ``f_ext`` (3,) [N] in W;
external torque ``tau_ext`` (3,) [N m] in B. Parameters ``theta_phys`` (6,) =
``[m (kg), k_T (N/(rad/s)^2), k_M (N m/(rad/s)^2), J_x, J_y, J_z (kg m^2)]``.

Equations (``recordings.md``; paper eq. 1, after Furrer et al. 2016)::

    p_dot = v
    q_dot = 1/2 q ∘ [0, w]
    v_dot = (R(q) [0, 0, T] + f_ext) / m - g e_z
    w_dot = J^-1 (-w × J w + tau + tau_ext)

The symbolic expressions serve the MPC directly; every numeric evaluation in the project
goes through the CasADi ``Function`` objects built here (``.map`` over arrays), so there
is one copy of the model and nothing can drift.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import casadi as ca
import numpy as np

from uavturb.errors import InputError
from uavturb.physics.constants import GRAVITY
from uavturb.physics.vehicle import Vehicle

N_STATE = 13
IDX_P = slice(0, 3)
IDX_Q = slice(3, 7)
IDX_V = slice(7, 10)
IDX_W = slice(10, 13)


def rotation_matrix_sym(q: ca.SX) -> ca.SX:
    """``R(q)`` (3x3, body to world) of a symbolic quaternion ``w, x, y, z``."""
    w, x, y, z = q[0], q[1], q[2], q[3]
    return ca.vertcat(
        ca.horzcat(1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)),
        ca.horzcat(2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)),
        ca.horzcat(2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)),
    )


def quat_mul_sym(a: ca.SX, b: ca.SX) -> ca.SX:
    """Hamilton product ``a ∘ b`` of symbolic quaternions ``w, x, y, z``."""
    return ca.vertcat(
        a[0] * b[0] - a[1] * b[1] - a[2] * b[2] - a[3] * b[3],
        a[0] * b[1] + a[1] * b[0] + a[2] * b[3] - a[3] * b[2],
        a[0] * b[2] - a[1] * b[3] + a[2] * b[0] + a[3] * b[1],
        a[0] * b[3] + a[1] * b[2] - a[2] * b[1] + a[3] * b[0],
    )


def physical_params(vehicle: Vehicle) -> np.ndarray:
    """``[m, k_T, k_M, J_x, J_y, J_z]`` of a vehicle whose constants are known."""
    if not vehicle.is_complete():
        raise InputError(vehicle.name, "thrust_coefficient, moment_coefficient and inertia must be known")
    return np.array([vehicle.mass, vehicle.thrust_coefficient, vehicle.moment_coefficient, *vehicle.inertia])


@dataclass(frozen=True)
class _Geometry:
    arm_length: float
    angles_deg: tuple[float, ...]
    directions: tuple[int, ...]


class Dynamics:
    """CasADi model of one rotor layout; parameters are inputs, so one object serves
    identification (varying parameters), simulation and the MPC.

    Attributes
    ----------
    wrench : casadi.Function
        ``(Omega (N,), theta (6,)) -> (T (1,) N, tau (3,) N m)``, rotor thrust and torques in B.
    f : casadi.Function
        ``(x (13,), Omega (N,), theta (6,), f_ext (3,), tau_ext (3,)) -> x_dot (13,)``.
    rk4 : casadi.Function
        ``(x, Omega, theta, f_ext, tau_ext, dt) -> x_next``: one RK4 step with inputs held,
        quaternion renormalised.
    """

    def __init__(self, vehicle: Vehicle):
        self.geometry = _Geometry(vehicle.arm_length, tuple(vehicle.rotor_angles_deg), tuple(vehicle.rotor_directions))
        self.n_rotors = vehicle.rotor_count
        M = vehicle.mixer()  # (4, N) geometry only: rows T, tau_x/(l k_T), tau_y/(l k_T), tau_z/k_M
        l = vehicle.arm_length

        Omega = ca.SX.sym("Omega", self.n_rotors)
        theta = ca.SX.sym("theta", 6)
        m, k_T, k_M = theta[0], theta[1], theta[2]
        J = theta[3:6]
        u = ca.mtimes(ca.DM(M), Omega**2)  # (4,) [rad^2/s^2]
        T = k_T * u[0]  # N, along +z_B
        tau = ca.vertcat(l * k_T * u[1], l * k_T * u[2], k_M * u[3])  # N m, in B
        self.wrench = ca.Function("wrench", [Omega, theta], [T, tau], ["Omega", "theta"], ["T", "tau"])

        x = ca.SX.sym("x", N_STATE)
        f_ext = ca.SX.sym("f_ext", 3)
        tau_ext = ca.SX.sym("tau_ext", 3)
        q, v, w = x[IDX_Q], x[IDX_V], x[IDX_W]
        R = rotation_matrix_sym(q)
        p_dot = v
        q_dot = 0.5 * quat_mul_sym(q, ca.vertcat(0, w))
        v_dot = (ca.mtimes(R, ca.vertcat(0, 0, T)) + f_ext) / m - ca.vertcat(0, 0, GRAVITY)
        Jw = J * w
        w_dot = (-ca.cross(w, Jw) + tau + tau_ext) / J
        xdot = ca.vertcat(p_dot, q_dot, v_dot, w_dot)
        self.f = ca.Function("f", [x, Omega, theta, f_ext, tau_ext], [xdot],
                             ["x", "Omega", "theta", "f_ext", "tau_ext"], ["x_dot"])

        dt = ca.SX.sym("dt")
        k1 = self.f(x, Omega, theta, f_ext, tau_ext)
        k2 = self.f(x + dt / 2 * k1, Omega, theta, f_ext, tau_ext)
        k3 = self.f(x + dt / 2 * k2, Omega, theta, f_ext, tau_ext)
        k4 = self.f(x + dt * k3, Omega, theta, f_ext, tau_ext)
        xn = x + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        xn = ca.vertcat(xn[IDX_P], xn[IDX_Q] / ca.norm_2(xn[IDX_Q]), xn[IDX_V], xn[IDX_W])
        self.rk4 = ca.Function("rk4", [x, Omega, theta, f_ext, tau_ext, dt], [xn],
                               ["x", "Omega", "theta", "f_ext", "tau_ext", "dt"], ["x_next"])
        self._maps: dict[tuple[str, int], ca.Function] = {}

    # --- numeric evaluation over arrays -------------------------------------------
    def _mapped(self, name: str, n: int) -> ca.Function:
        key = (name, n)
        if key not in self._maps:
            self._maps[key] = getattr(self, name).map(n)
        return self._maps[key]

    def thrust_torque(self, Omega: np.ndarray, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Rotor thrust and torques for many samples.

        Parameters
        ----------
        Omega : (K, N) rotor speeds [rad/s]
        theta : (6,) ``[m, k_T, k_M, J_x, J_y, J_z]``

        Returns
        -------
        T : (K,) thrust [N] along +z_B
        tau : (K, 3) torques [N m] in B
        """
        Omega = np.atleast_2d(np.asarray(Omega, dtype=float))
        K = Omega.shape[0]
        T, tau = self._mapped("wrench", K)(Omega.T, np.asarray(theta, float))
        return np.asarray(T).ravel(), np.asarray(tau).T

    def xdot(self, x: np.ndarray, Omega: np.ndarray, theta: np.ndarray,
             f_ext: np.ndarray | None = None, tau_ext: np.ndarray | None = None) -> np.ndarray:
        """State derivative for many samples: ``x (K, 13)``, ``Omega (K, N)`` → ``(K, 13)``."""
        x = np.atleast_2d(np.asarray(x, float))
        K = x.shape[0]
        f_ext = np.zeros((K, 3)) if f_ext is None else np.broadcast_to(f_ext, (K, 3))
        tau_ext = np.zeros((K, 3)) if tau_ext is None else np.broadcast_to(tau_ext, (K, 3))
        out = self._mapped("f", K)(x.T, np.atleast_2d(Omega).T, np.asarray(theta, float), f_ext.T, tau_ext.T)
        return np.asarray(out).T

    def step(self, x: np.ndarray, Omega: np.ndarray, theta: np.ndarray, dt: float,
             f_ext: np.ndarray | None = None, tau_ext: np.ndarray | None = None) -> np.ndarray:
        """One RK4 step of one state ``(13,)`` with inputs held over ``dt`` [s]."""
        f_ext = np.zeros(3) if f_ext is None else f_ext
        tau_ext = np.zeros(3) if tau_ext is None else tau_ext
        return np.asarray(self.rk4(x, Omega, theta, f_ext, tau_ext, dt)).ravel()

    def step_many(self, x: np.ndarray, Omega: np.ndarray, theta: np.ndarray, dt: float,
                  f_ext: np.ndarray | None = None, tau_ext: np.ndarray | None = None) -> np.ndarray:
        """One RK4 step from each of ``K`` states at once: ``x (K, 13)`` → ``(K, 13)``
        (open-loop multi-step prediction from many starting points)."""
        x = np.atleast_2d(np.asarray(x, float))
        K = x.shape[0]
        f_ext = np.zeros((K, 3)) if f_ext is None else np.broadcast_to(f_ext, (K, 3))
        tau_ext = np.zeros((K, 3)) if tau_ext is None else np.broadcast_to(tau_ext, (K, 3))
        out = self._mapped("rk4", K)(x.T, np.atleast_2d(Omega).T, np.asarray(theta, float), f_ext.T, tau_ext.T, dt)
        return np.asarray(out).T


@lru_cache(maxsize=16)
def _dynamics_for(geometry: _Geometry, n: int) -> Dynamics:
    v = Vehicle(name="geometry", mass=1.0, arm_length=geometry.arm_length, rotor_angles_deg=geometry.angles_deg,
                rotor_directions=geometry.directions, rotor_radius=0.1)
    return Dynamics(v)


def dynamics_for(vehicle: Vehicle) -> Dynamics:
    """A (cached) :class:`Dynamics` for the vehicle's rotor layout."""
    g = _Geometry(vehicle.arm_length, tuple(vehicle.rotor_angles_deg), tuple(vehicle.rotor_directions))
    return _dynamics_for(g, vehicle.rotor_count)

