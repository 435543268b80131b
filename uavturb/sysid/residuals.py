"""Ground-truth turbulence: the residual force of the identified model (paper, "Estimating GT turbulences").

The paper defines it as the external force that makes one explicit step of the model land
on the next measured state::

    f*_a,t = argmin_f || x_{t+1} - (x_t + dt f(x_t, Omega_t, f)) ||^2

For the velocity rows that is ``F = m (v_{t+1} - v_t)/dt - R T e_z + m g e_z``
(``derivative="forward"``). Smoother alternatives are offered:

* ``source="imu"`` (the default where an IMU stream exists): an accelerometer at the centre
  of mass reads ``a = R^T (F_thrust + F_ext)/m`` (``recordings.md``), so
  ``F_ext = R (m a - T e_z)``: no differentiation, far less noise;
* ``source="mocap"``: ``F_ext = m (v_dot + g e_z) - R T e_z`` with ``v_dot`` by
  Savitzky-Golay (``derivative="savgol"``) or by the paper's forward difference.

Torques: ``tau_ext = J w_dot + w x J w - tau(Omega)`` in B.

Motion-capture-only flights (no ``imu0``, 50 Hz and up, jittered timestamps) use the MoCap
source; ``v_dot`` is then a local quadratic fit at the samples' true times over a window in
seconds (:mod:`uavturb.sysid.flight_data`). The residual's noise floor is measured on the data
(:func:`noise_floor`), never assumed: the differentiated velocity's noise is not white (it is
the derivative filter's response to white noise), so first differences would understate it.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from uavturb.errors import InputError
from uavturb.io.differentiate import local_quadratic, window_samples
from uavturb.io.publish import publish_file
from uavturb.io.recording import Recording
from uavturb.numerics.filters import savgol_coeffs
from uavturb.physics import quaternion as quat
from uavturb.physics.dynamics import GRAVITY, dynamics_for, physical_params
from uavturb.physics.vehicle import Vehicle
from uavturb.sysid.flight_data import FlightData, flight_data

E_Z = np.array([0.0, 0.0, 1.0])
#: s, the residual's slow part (unmodelled physics) is a quadratic fit over this window
NOISE_WINDOW_S = 0.5


@dataclass
class Residuals:
    """Residual (unmodelled) force and torque over ``K`` samples.

    Attributes
    ----------
    t : (K,) s since the first ground-truth row
    force : (K, 3) N, in W
    force_body : (K, 3) N, in B
    torque : (K, 3) N m, in B
    thrust : (K,) N, ``k_T sum(w^2)`` with the model's ``k_T``
    sum_omega2 : (K,) rad^2/s^2
    source : ``imu`` or ``mocap``
    data : the aligned flight the residual was computed on
    ground_contact : (K,) bool, rows where the floor carries the vehicle (its reaction is in ``force``: no
        aerodynamic law explains it), or None where not looked for
    """

    t: np.ndarray
    force: np.ndarray
    force_body: np.ndarray
    torque: np.ndarray
    thrust: np.ndarray
    sum_omega2: np.ndarray
    source: str
    data: FlightData
    ground_contact: np.ndarray | None = None

    @property
    def rmse(self) -> float:
        """Root mean square of the force norm [N]."""
        return float(np.sqrt(np.mean(np.sum(self.force**2, axis=1))))

    @property
    def on_ground(self) -> int:
        """Rows where the floor carries the vehicle (0 where not looked for)."""
        return 0 if self.ground_contact is None else int(np.sum(self.ground_contact))

    @property
    def rmse_in_flight(self) -> float:
        """Root mean square of the force norm [N] off the ground (:attr:`ground_contact` left out; nan where
        the vehicle never left it)."""
        air = np.ones(len(self.t), bool) if self.ground_contact is None else ~self.ground_contact
        return float(np.sqrt(np.mean(np.sum(self.force[air] ** 2, axis=1)))) if air.any() else float("nan")

    def noise_floor(self, window_s: float = NOISE_WINDOW_S) -> np.ndarray:
        """Per-axis noise level of ``force`` [N] (3,), W: see :func:`noise_floor`."""
        return noise_floor(self.t, self.force, window_s)


def noise_floor(t: np.ndarray, r: np.ndarray, window_s: float = NOISE_WINDOW_S) -> np.ndarray:
    """Noise level [units of ``r``] per column of a residual ``r`` (K, D) at times ``t`` [s], from its
    high-frequency content.

    The slow part (unmodelled physics varies over seconds) is a local quadratic fit over
    ``window_s``; what is left holds the sensor noise and the derivative filter's response to it.
    Its robust spread, ``1.4826 MAD``, is divided by ``sqrt(1 - h)`` (``h`` the fit's own weight at
    the centre sample, so that white noise is not understated).
    """
    r = np.asarray(r, float).reshape(len(r), -1)
    n = window_samples(np.asarray(t, float), window_s)
    if n < 5:
        return np.full(r.shape[1], np.nan)
    hf = r - local_quadratic(t, r, n, deriv=0)
    inner = hf[n // 2: len(hf) - n // 2] if len(hf) > n else hf  # away from the fit's edges
    mad = np.median(np.abs(inner - np.median(inner, axis=0)), axis=0)
    h = float(savgol_coeffs(n, 2)[n // 2])
    return 1.4826 * mad / np.sqrt(1.0 - h)


def residual_forces(rec: Recording | FlightData, vehicle: Vehicle, *, source: str = "auto",
                    derivative: str = "savgol", window_s: float = 0.05,
                    accel_bias: np.ndarray | None = None) -> Residuals:
    """Residual force and torque of ``vehicle``'s model on a flight.

    Parameters
    ----------
    rec : recording, or its aligned :class:`FlightData`
    vehicle : vehicle with known (identified) ``k_T``, ``k_M`` and inertia; with ``k_T`` alone the
        forces are computed and the torques are ``nan``
    source : ``auto`` (IMU where present), ``imu`` or ``mocap``
    derivative : ``savgol`` or ``forward`` (the paper's one-step arg-min), for MoCap
    window_s : derivative filter window [s]
    accel_bias : (3,) m/s^2 in B, the accelerometer's bias, taken off its specific force (``source`` imu); a
        sensor's error, not a force: left in, a 67 g vehicle's bias of 0.2-0.4 m/s^2 reads as a steady push of
        0.014-0.027 N along body x
    """
    fd = rec if isinstance(rec, FlightData) else flight_data(rec, window_s=window_s)
    if source == "auto":
        source = "imu" if fd.acc is not None else "mocap"
    if source not in ("imu", "mocap"):
        raise InputError("residuals.source", f"unknown source '{source}' (allowed: auto, imu, mocap)")
    if derivative not in ("savgol", "forward"):
        raise InputError("residuals.derivative", f"unknown derivative '{derivative}' (allowed: savgol, forward)")
    if source == "imu" and fd.acc is None:
        raise InputError(f"{fd.name}/mav0/imu0/data.csv", "an IMU stream is needed for source=imu")
    m = vehicle.mass
    rotational = vehicle.inertia is not None and vehicle.moment_coefficient is not None
    if rotational:
        T, tau = dynamics_for(vehicle).thrust_torque(fd.rotor_speeds, physical_params(vehicle))
    elif vehicle.thrust_coefficient is not None:  # forces only: torques unknown (nan)
        T = vehicle.thrust_coefficient * np.sum(fd.rotor_speeds**2, axis=1)
    else:
        raise InputError(vehicle.name, "thrust_coefficient is unknown (identify it or give it in vehicle.yaml)")
    R = quat.to_rotation_matrix(fd.q)
    thrust_world = T[:, None] * R[:, :, 2]
    if source == "imu":
        acc = fd.acc if accel_bias is None else fd.acc - np.asarray(accel_bias, float)
        f_body = m * acc - T[:, None] * E_Z
        force = np.einsum("kij,kj->ki", R, f_body)
    else:
        if derivative == "forward":
            dv = np.empty_like(fd.v)
            dv[:-1] = np.diff(fd.v, axis=0) / np.diff(fd.t)[:, None]
            dv[-1] = dv[-2]
        else:
            dv = fd.dv
        force = m * (dv + GRAVITY * E_Z) - thrust_world
        f_body = np.einsum("kji,kj->ki", R, force)
    if rotational:
        J, w = np.asarray(vehicle.inertia, float), fd.w
        torque = J * fd.dw + np.cross(w, J * w) - tau
    else:
        torque = np.full((len(fd.t), 3), np.nan)
    return Residuals(t=fd.t, force=force, force_body=f_body, torque=torque, thrust=T,
                     sum_omega2=np.sum(fd.rotor_speeds**2, axis=1), source=source, data=fd)


RESIDUAL_COLUMNS = [
    "t [s]", "timestamp [ns]",
    "F_x [N]", "F_y [N]", "F_z [N]",
    "F_Bx [N]", "F_By [N]", "F_Bz [N]",
    "tau_Bx [N m]", "tau_By [N m]", "tau_Bz [N m]",
    "thrust [N]", "sum_omega2 [rad^2 s^-2]", "d_down [m]", "d_up [m]", "ground_contact",
]


def residual_table(res: Residuals):
    """The residual time series as a pandas DataFrame (columns :data:`RESIDUAL_COLUMNS`; ``ground_contact`` 1 on
    the rows where the floor carries the vehicle, 0 elsewhere, empty where it was not looked for)."""
    fd = res.data
    nan = np.full(len(res.t), np.nan)
    contact = nan if res.ground_contact is None else res.ground_contact.astype(int)  # 1: on the ground
    cols = [res.t, fd.t_ns, *res.force.T, *res.force_body.T, *res.torque.T, res.thrust, res.sum_omega2,
            fd.d_down if fd.d_down is not None else nan, fd.d_up if fd.d_up is not None else nan, contact]
    return pd.DataFrame(dict(zip(RESIDUAL_COLUMNS, cols)))


def write_residuals(res: Residuals, path: str | Path, *, overwrite: bool = False) -> Path:
    """Write the residual series: Parquet if ``path`` ends in ``.parquet``, else CSV.

    Written to a temporary file and renamed, so ``path`` is complete or absent; an existing
    ``path`` is replaced only with ``overwrite``.
    """
    path = Path(path)
    df = residual_table(res)
    with publish_file(path, overwrite=overwrite) as tmp:
        if path.suffix == ".parquet":
            df.to_parquet(tmp, index=False)
        else:
            df.to_csv(tmp, index=False, float_format="%.9g")
    return path
