"""Parameter identification by linear least squares (the paper, "Dynamical drone model").

The paper writes the model linearly in four parameters::

    theta_0 = k_T / m,  theta_1 = l k_T / J_x,  theta_2 = k_M / J_z,  theta_3 = J_z / J_x

and assumes ``J_x = J_y``. We fit the same equations, generalised to ``J_x != J_y``:

* translation, body ``z`` (rows from MoCap and, where there is one, from the IMU)::

      e_z . R^T (v_dot + g e_z) = theta_0 S                       S = sum(w_i^2)
      a_imu,z                   = theta_0 S + b_z                 b_z: accelerometer bias left

* rotation, per body axis (``M`` the paper's geometry matrix, ``u = M w^2``)::

      w_dot_x = (l k_T / J_x) u_1 + ((J_y - J_z) / J_x) w_y w_z + c_x
      w_dot_y = (l k_T / J_y) u_2 + ((J_z - J_x) / J_y) w_x w_z + c_y
      w_dot_z = (k_M / J_z)   u_3 + ((J_x - J_y) / J_z) w_x w_y + c_z

  with constant angular accelerations ``c`` (a centre of mass off the rotor plane's centre).
  With the mass known, ``k_T = m theta_0`` fixes the scale: ``J_x = l k_T / a_x``,
  ``J_y = l k_T / a_y``, ``J_z`` from the gyroscopic coefficients, ``k_M = theta_2 J_z``.
  When ``a_x`` and ``a_y`` do not differ beyond their uncertainty, the paper's ``J_x = J_y``
  model is fitted instead (``model = "jx=jy"``).

Samples near a surface (ground or ceiling effect) or on the ground (contact forces) are
left out. Standard errors: Newey-West covariances of each fit (``least_squares``),
propagated to derived quantities by Monte Carlo.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Sequence

import numpy as np

from uavturb.errors import InputError
from uavturb.io.recording import Recording
from uavturb.physics import quaternion as quat
from uavturb.physics.dynamics import GRAVITY
from uavturb.physics.vehicle import Vehicle
from uavturb.sysid.flight_data import FlightData, flight_data
from uavturb.sysid.least_squares import lstsq


@dataclass
class Identification:
    """Identified constants with standard errors (same units).

    Attributes
    ----------
    mass : float, kg (given)
    thrust_coefficient, moment_coefficient : float, N/(rad/s)^2 and N m/(rad/s)^2
    inertia : (3,) kg m^2, diagonal of J
    theta : (4,) the paper's ``[k_T/m, l k_T/J_x, k_M/J_z, J_z/J_x]``
    accel_bias : (3,) m/s^2 in B, accelerometer bias left after the state file's; ``None`` when
        the flights have no IMU (motion capture only: there is no accelerometer, so no bias to
        estimate, and none is fitted)
    model : ``"general"`` or ``"jx=jy"``
    """

    mass: float
    thrust_coefficient: float
    thrust_coefficient_se: float
    moment_coefficient: float
    moment_coefficient_se: float
    inertia: np.ndarray
    inertia_se: np.ndarray
    theta: np.ndarray
    theta_se: np.ndarray
    accel_bias: np.ndarray | None
    angular_bias: np.ndarray
    model: str
    n_samples: int
    rms: dict[str, float]
    recordings: list[str] = field(default_factory=list)

    def apply(self, vehicle: Vehicle) -> Vehicle:
        """The vehicle with the identified constants."""
        return vehicle.with_params(thrust_coefficient=float(self.thrust_coefficient),
                                   moment_coefficient=float(self.moment_coefficient),
                                   inertia=tuple(float(j) for j in self.inertia))

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dictionary (the ``identify --json`` output)."""
        return {
            "recordings": self.recordings,
            "model": self.model,
            "n_samples": self.n_samples,
            "mass": self.mass,
            "thrust_coefficient": self.thrust_coefficient,
            "thrust_coefficient_stderr": self.thrust_coefficient_se,
            "moment_coefficient": self.moment_coefficient,
            "moment_coefficient_stderr": self.moment_coefficient_se,
            "inertia": [float(j) for j in self.inertia],
            "inertia_stderr": [float(j) for j in self.inertia_se],
            "theta": [float(t) for t in self.theta],
            "theta_stderr": [float(t) for t in self.theta_se],
            "theta_names": ["k_T/m", "l*k_T/J_x", "k_M/J_z", "J_z/J_x"],
            "accel_bias": None if self.accel_bias is None else [float(b) for b in self.accel_bias],
            "sources": "imu+mocap" if self.accel_bias is not None else "mocap",
            "angular_bias": [float(b) for b in self.angular_bias],
            "rms": self.rms,
        }


def usable_mask(fd: FlightData, vehicle: Vehicle, *, min_height_radii: float = 6.0,
                min_thrust_ratio: float = 0.3, k_T_guess: float | None = None) -> np.ndarray:
    """Rows free of surface effects and ground contact, away from the filter's edges.

    A row is kept when the vehicle is more than ``min_height_radii`` rotor radii from the
    surfaces below and above (Cheeseman-Bennett: ``rho < mu/576``, under 0.5 % for
    ``mu <= 3``), and its rotors carry at least ``min_thrust_ratio`` of the weight.
    """
    keep = np.ones(len(fd), dtype=bool)
    h = min_height_radii * vehicle.rotor_radius
    if fd.d_down is not None:
        keep &= ~(fd.d_down < h)
    if fd.d_up is not None:
        keep &= ~(fd.d_up < h)
    S = np.sum(fd.rotor_speeds**2, axis=1)
    k_T = k_T_guess or vehicle.thrust_coefficient
    if k_T is not None:
        keep &= k_T * S > min_thrust_ratio * vehicle.mass * GRAVITY
    else:
        keep &= S > min_thrust_ratio * np.median(S)
    edge = fd.window
    keep[:edge] = False
    keep[-edge:] = False
    return keep


def _rows(fds: Sequence[FlightData], vehicle: Vehicle, masks: Sequence[np.ndarray]) -> dict[str, np.ndarray]:
    """Stack the regression rows of several flights."""
    M = vehicle.mixer()
    parts: dict[str, list[np.ndarray]] = {}

    def add(key, value):
        parts.setdefault(key, []).append(value)

    for g, (fd, m) in enumerate(zip(fds, masks)):
        S = np.sum(fd.rotor_speeds**2, axis=1)
        u = (fd.rotor_speeds**2) @ M.T  # (K, 4)
        R = quat.to_rotation_matrix(fd.q)
        spec_mocap = np.einsum("kji,kj->ki", R, fd.dv + np.array([0.0, 0.0, GRAVITY]))
        w = fd.w
        add("S_smooth", fd.smooth(S)[m])
        add("S", S[m])
        add("y_mocap", spec_mocap[m, 2])
        add("acc", fd.acc[m] if fd.acc is not None else np.full((m.sum(), 3), np.nan))
        add("u", fd.smooth(u)[m])
        add("ww", fd.smooth(np.stack([w[:, 1] * w[:, 2], w[:, 0] * w[:, 2], w[:, 0] * w[:, 1]], 1))[m])
        add("dw", fd.dw[m])
        add("group", np.full(m.sum(), g))
    return {k: np.concatenate(v) for k, v in parts.items()}


def identify(recordings: Sequence[Recording] | Sequence[FlightData], vehicle: Vehicle | None = None, *,
             model: str = "auto", window_s: float = 0.05, lag_s: float = 0.25, n_draws: int = 4000,
             seed: int = 0) -> Identification:
    """Identify ``k_T``, ``k_M`` and ``J`` from one or more flights of one vehicle.

    Parameters
    ----------
    recordings : recordings (or their :class:`FlightData`) of the same vehicle
    vehicle : geometry and mass; default the first recording's
    model : ``auto``, ``general`` (``J_x != J_y``) or ``jx=jy`` (the paper's)
    window_s : derivative filter window [s]
    lag_s : correlation length for the Newey-West standard errors [s]
    n_draws : Monte Carlo draws propagating the standard errors
    """
    if not recordings:
        raise InputError("identify", "no recording given")
    if vehicle is None:
        if not isinstance(recordings[0], Recording):
            raise InputError("identify", "a vehicle is needed with FlightData input")
        vehicle = recordings[0].vehicle
    fds = [r if isinstance(r, FlightData) else flight_data(r, window_s=window_s) for r in recordings]
    names = [str(r.path) if isinstance(r, Recording) and r.path else fd.name for r, fd in zip(recordings, fds)]
    masks = [usable_mask(fd, vehicle) for fd in fds]
    n = int(sum(m.sum() for m in masks))
    if n < 50:
        raise InputError(names[0], f"only {n} samples in free flight away from surfaces; cannot identify")
    rows = _rows(fds, vehicle, masks)
    lag = max(1, int(round(lag_s / fds[0].dt)))
    groups = rows["group"]

    # --- translation: theta_0 and the accelerometer's z bias, jointly ---------------
    has_imu = bool(np.all(np.isfinite(rows["acc"])))
    if has_imu:
        K = len(rows["S"])
        A = np.block([[rows["S_smooth"][:, None], np.zeros((K, 1))], [rows["S"][:, None], np.ones((K, 1))]])
        y = np.concatenate([rows["y_mocap"], rows["acc"][:, 2]])
        first = lstsq(A, y, lag=lag)
        var_m = np.var(first.residual[:K])
        var_i = np.var(first.residual[K:])
        wts = np.concatenate([np.full(K, 1 / var_m), np.full(K, 1 / var_i)])
        fit_t = lstsq(A, y, lag=lag, weights=wts, groups=np.concatenate([groups, groups + 1000]))
        theta0, bz = fit_t.coef
        theta0_se = fit_t.stderr[0]
        accel_bias = np.array([np.mean(rows["acc"][:, 0]), np.mean(rows["acc"][:, 1]), bz])
        rms_t = float(np.sqrt(np.mean(fit_t.residual[K:] ** 2)))
    else:
        fit_t = lstsq(rows["S_smooth"][:, None], rows["y_mocap"], lag=lag, groups=groups)
        theta0, theta0_se = fit_t.coef[0], fit_t.stderr[0]
        accel_bias = None  # no accelerometer: nothing to estimate, and nothing is fitted
        rms_t = fit_t.rms
    if theta0 <= 0:
        raise InputError(names[0], "identified thrust coefficient is not positive: rotor speeds or mass are wrong")

    # --- rotation ---------------------------------------------------------------------
    u, ww, dw = rows["u"], rows["ww"], rows["dw"]
    one = np.ones(len(dw))
    fit_x = lstsq(np.stack([u[:, 1], ww[:, 0], one], 1), dw[:, 0], lag=lag, groups=groups)
    fit_y = lstsq(np.stack([u[:, 2], ww[:, 1], one], 1), dw[:, 1], lag=lag, groups=groups)
    fit_z = lstsq(np.stack([u[:, 3], ww[:, 2], one], 1), dw[:, 2], lag=lag, groups=groups)
    a_x, a_y = fit_x.coef[0], fit_y.coef[0]
    differ = abs(a_x - a_y) > 3.0 * np.hypot(fit_x.stderr[0], fit_y.stderr[0])
    chosen = model if model != "auto" else ("general" if differ else "jx=jy")
    if chosen not in ("general", "jx=jy"):
        raise InputError("identify.model", f"unknown model '{model}' (allowed: auto, general, jx=jy)")

    rng = np.random.default_rng(seed)
    m, l = vehicle.mass, vehicle.arm_length
    th0 = rng.normal(theta0, theta0_se, n_draws)
    kT = m * th0
    cz = rng.multivariate_normal(fit_z.coef, fit_z.cov, n_draws)
    if chosen == "general":
        cx = rng.multivariate_normal(fit_x.coef, fit_x.cov, n_draws)
        cy = rng.multivariate_normal(fit_y.coef, fit_y.cov, n_draws)
        Jx, Jy = l * kT / cx[:, 0], l * kT / cy[:, 0]
        Jz1, Jz2 = Jy - cx[:, 1] * Jx, Jx + cy[:, 1] * Jy  # from (J_y - J_z)/J_x and (J_z - J_x)/J_y
        v1, v2 = np.var(Jz1), np.var(Jz2)
        Jz = (Jz1 / v1 + Jz2 / v2) / (1 / v1 + 1 / v2)
        ang_bias = np.array([fit_x.coef[2], fit_y.coef[2], fit_z.coef[2]])
        rms_r = {"roll": fit_x.rms, "pitch": fit_y.rms}
    else:
        # the paper's model: w_dot_x = th1 u_1 + (1 - th3) w_y w_z, w_dot_y = th1 u_2 - (1 - th3) w_x w_z
        K = len(dw)
        zeros = np.zeros(K)
        A = np.block([[np.stack([u[:, 1], ww[:, 0], one, zeros], 1)], [np.stack([u[:, 2], -ww[:, 1], zeros, one], 1)]])
        fit_xy = lstsq(A, np.concatenate([dw[:, 0], dw[:, 1]]), lag=lag, groups=np.concatenate([groups, groups + 1000]))
        cxy = rng.multivariate_normal(fit_xy.coef, fit_xy.cov, n_draws)
        Jx = Jy = l * kT / cxy[:, 0]
        Jz = Jx * (1.0 - cxy[:, 1])
        ang_bias = np.array([fit_xy.coef[2], fit_xy.coef[3], fit_z.coef[2]])
        rms_r = {"roll_pitch": fit_xy.rms}
    kM = cz[:, 0] * Jz

    def est(draws: np.ndarray) -> tuple[float, float]:
        lo, med, hi = np.percentile(draws, [15.87, 50.0, 84.13])
        return float(med), float((hi - lo) / 2.0)

    theta_draws = [th0, l * kT / Jx, cz[:, 0], Jz / Jx]
    theta, theta_se = zip(*(est(d) for d in theta_draws))
    inertia, inertia_se = zip(*(est(d) for d in (Jx, Jy, Jz)))
    kM_est, kM_se = est(kM)
    return Identification(
        mass=m,
        thrust_coefficient=float(m * theta0),
        thrust_coefficient_se=float(m * theta0_se),
        moment_coefficient=kM_est,
        moment_coefficient_se=kM_se,
        inertia=np.array(inertia),
        inertia_se=np.array(inertia_se),
        theta=np.array([theta0, *theta[1:]]),
        theta_se=np.array([theta0_se, *theta_se[1:]]),
        accel_bias=accel_bias,
        angular_bias=ang_bias,
        model=chosen,
        n_samples=n,
        rms={"thrust": rms_t, **rms_r, "yaw": fit_z.rms},
        recordings=names,
    )
