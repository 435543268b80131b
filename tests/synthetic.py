"""Synthetic flights by inverse dynamics, for tests: exact known parameters, no controller.

Body rates and thrust are chosen as smooth signals; the rotor speeds that produce them are
solved from the allocation matrix, and the translational state follows from the model.
"""

from __future__ import annotations

import numpy as np
from scipy.integrate import cumulative_trapezoid
from scipy.signal import savgol_filter

from uavturb.physics import quaternion as quat
from uavturb.physics.dynamics import GRAVITY
from uavturb.physics.vehicle import Vehicle
from uavturb.sysid.flight_data import FlightData


def inverse_dynamics_flight(vehicle: Vehicle, *, duration=60.0, rate=200.0, seed=0, rate_amp=(1.6, 1.6, 0.8),
                            gyro_noise=2.4e-3, acc_noise=2.8e-2, rotor_quantum=1.0, f_ext=None, acc_bias=(0, 0, 0),
                            rotor_noise=0.0):
    """Return ``(FlightData, truth dict)`` for ``vehicle`` (its constants are the truth).

    ``rotor_noise``: relative white noise on each recorded rotor speed (commands that are not what the rotors do).
    """
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, duration, 1.0 / rate)
    w = np.zeros((len(t), 3))
    dw = np.zeros_like(w)
    for i in range(3):
        for _ in range(4):
            f = rng.uniform(0.1, 0.8)
            a = rate_amp[i] / 4 * rng.uniform(0.5, 1.0)
            ph = rng.uniform(0, 2 * np.pi)
            w[:, i] += a * np.sin(2 * np.pi * f * t + ph)
            dw[:, i] += a * 2 * np.pi * f * np.cos(2 * np.pi * f * t + ph)
    J = np.asarray(vehicle.inertia)
    tau = J * dw + np.cross(w, J * w)
    T = vehicle.mass * GRAVITY * (1.0 + 0.15 * np.sin(2 * np.pi * 0.3 * t) + 0.1 * np.sin(2 * np.pi * 0.77 * t + 1))
    A = vehicle.allocation()
    w2 = np.linalg.lstsq(A, np.vstack([T, tau.T]), rcond=None)[0].T  # (K, N) minimum-norm rotor speeds^2
    assert np.all(w2 > 0), "torques too large for the rotors"
    omega = np.sqrt(w2)
    # attitude by integrating q_dot = 1/2 q ∘ [0, w] finely
    q = np.zeros((len(t), 4))
    q[0] = [1, 0, 0, 0]
    dt = 1.0 / rate
    for k in range(len(t) - 1):
        wm = 0.5 * (w[k] + w[k + 1])
        ang = np.linalg.norm(wm) * dt
        axis = wm / max(np.linalg.norm(wm), 1e-12)
        dq = np.r_[np.cos(ang / 2), np.sin(ang / 2) * axis]
        q[k + 1] = quat.normalize(quat.multiply(q[k], dq))
    R = quat.to_rotation_matrix(q)
    F_ext = np.zeros((len(t), 3)) if f_ext is None else f_ext(t)
    acc_world = (T[:, None] * R[:, :, 2] + F_ext) / vehicle.mass - np.array([0, 0, GRAVITY])
    v = cumulative_trapezoid(acc_world, t, axis=0, initial=0.0)
    p = cumulative_trapezoid(v, t, axis=0, initial=0.0) + np.array([0, 0, 1.5])
    spec = np.einsum("kji,kj->ki", R, T[:, None] * R[:, :, 2] + F_ext) / vehicle.mass
    gyro = w + rng.normal(0, gyro_noise, w.shape)
    acc = spec + np.asarray(acc_bias) + rng.normal(0, acc_noise, spec.shape)
    omega_meas = omega * (1.0 + rotor_noise * rng.standard_normal(omega.shape)) if rotor_noise else omega
    omega_meas = np.round(omega_meas / rotor_quantum) * rotor_quantum if rotor_quantum else omega_meas
    window = 11
    dv = savgol_filter(v, window, 2, deriv=1, delta=dt, axis=0, mode="interp")
    dwm = savgol_filter(gyro, window, 2, deriv=1, delta=dt, axis=0, mode="interp")
    t_ns = (1_403_636_579_758_555_392 + np.round(t * 1e9)).astype(np.int64)
    fd = FlightData("synthetic", t_ns, t, p, q, v, gyro, acc, omega_meas, dv, dwm, None, None, window)
    return fd, {"omega": omega, "F_ext": F_ext, "spec": spec, "w": w}
