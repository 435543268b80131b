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

Samples near a surface (ground or ceiling effect: within six rotor radii) or on the ground (contact
forces) are left out; flights that spend their time near a surface are read down to two rotor radii from it,
its Cheeseman-Bennett law fitted beside ``k_T`` (:func:`surface_columns`), and where flights visit a surface's
reach ``k_T``'s error carries half the change between the two readings. Standard errors: Newey-West
covariances of each fit (``least_squares``), propagated to derived quantities by Monte Carlo.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any, Sequence

import numpy as np

from uavturb.errors import InputError
from uavturb.io.recording import Recording
from uavturb.numerics.blocks import block_labels, block_mean_and_se, contiguous_blocks, jackknife_se
from uavturb.numerics.stream_updates import rotor_quantum, rounding_share
from uavturb.physics import quaternion as quat
from uavturb.physics.dynamics import GRAVITY
from uavturb.physics.vehicle import Vehicle
from uavturb.physics.effects import lag_rotor_speeds
from uavturb.sysid.accelerometer import BLOCK_S, AnchoredBias, mocap_specific_force
from uavturb.sysid.command_lag import CommandLag, command_lag, lagged
from uavturb.sysid.flight_data import FlightData, flight_data
from uavturb.sysid.identifiability import (
    ACC_MIN,
    BIAS_SE_MAX,
    COND_MAX,
    LOWPASS_S,
    RATE_MIN,
    REL_SE_MAX,
    SHARE_MIN,
    TRIANGLE_SLACK,
    AxisExcitation,
    ParameterStatus,
    assess,
    axis_excitation,
    column_share,
)
from uavturb.sysid.least_squares import lstsq
from uavturb.sysid.nominal import (SpeedOffset, moved_speeds, offset_cells, speed_offset,
                                     stated_offset)
from uavturb.sysid.rotor_order import RotorOrder, rotor_order


@dataclass
class Identification:
    """Identified constants with standard errors (same units), and what the flight determines.

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
    status : name -> :class:`~uavturb.sysid.identifiability.ParameterStatus` (``k_T``, ``k_M``,
        ``J_x``, ``J_y``, ``J_z``, ``theta_0`` .. ``theta_3``, ``accel_bias``): whether the flight
        determines each constant, and why not. The fields above are the raw estimates: use
        :meth:`apply` (or check ``status``) rather than reading them as results.
    excitation : axis (``roll``, ``pitch``, ``yaw``) -> AxisExcitation
    conditions : fit (``thrust``, ``roll``, ``pitch``, ``yaw``) -> condition number
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
    status: dict[str, ParameterStatus] = field(default_factory=dict)
    excitation: dict[str, AxisExcitation] = field(default_factory=dict)
    conditions: dict[str, float] = field(default_factory=dict)
    accel_bias_se: np.ndarray = field(default_factory=lambda: np.full(3, np.nan))
    #: ``{recording: (k_T, its standard error)}`` fitted on each alone (two or more recordings; ``k_T``'s stated
    #: error is at least their spread)
    thrust_coefficient_per_recording: dict[str, tuple[float, float]] = field(default_factory=dict)
    #: ``{recording: (b, its standard error)}``, (3,) m/s^2 in B each: the accelerometer bias each recording's IMU
    #: reads beyond its motion capture (two or more recordings with an IMU; ``accel_bias`` pools them)
    accel_bias_per_recording: dict[str, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)
    #: m, how near a surface the rows come where the flights spend their time near one (their surfaces' law then
    #: fitted beside ``k_T``, :func:`surface_columns`); None where the rows keep six rotor radii from every surface
    near_surface_m: float | None = None
    #: N/(rad/s)^2, half the change of ``k_T`` between the rows beyond six rotor radii of every surface and the rows
    #: down to :data:`NEAR_SURFACE_RADII` with the surfaces' law beside it, in its error (quadrature) where the
    #: flights visit a surface's reach and both are read (a Crazyflie's walks 5-45 cm over the floor, whose curve
    #: no law fits: 0.34 %); None otherwise
    surface_term: float | None = None
    #: the commanded rotor speeds' offset read on the rows (an idle speed in the command map,
    #: :func:`idle_offset`): the reading, the offset the constants were identified at (``applied_rad_s``, the hover
    #: speed kept) and each constant's term for the offsets it leaves open (``terms``, in the error); None for
    #: measured speeds or too few rows
    rotor_speed_offset: dict[str, Any] | None = None
    #: the rotors' lag behind commanded speeds read on the torques (:mod:`uavturb.sysid.command_lag`): the reading,
    #: the lag the constants were identified at (``applied_s``) and each constant's term for the lags it leaves open
    #: (``terms``, in the error); None for measured speeds or too few rows
    command_lag: dict[str, Any] | None = None
    #: which order of the rotor columns the roll and pitch accelerations follow (:mod:`uavturb.sysid.rotor_order`);
    #: None with too few rows
    rotor_order: RotorOrder | None = None

    def rotor_speeds_read(self, rotor_speeds: np.ndarray, t: np.ndarray | None = None) -> np.ndarray:
        """Recorded rotor speeds ``rotor_speeds`` (K, N) [rad/s] at times ``t`` (K,) [s] as these constants were
        identified on them: moved by the offset applied (:attr:`rotor_speed_offset`, the hover speed kept; an idle
        speed in the command map) and lagged by the lag applied (:attr:`command_lag`; only with ``t``), as they are
        where neither was. Torques from these constants need them: the inertia is the rotors' own, the recorded
        speeds' differences are larger by the map's scale, and commands lead the rotors by their lag."""
        out = np.asarray(rotor_speeds, float)
        found = self.rotor_speed_offset
        if found and found["applied_rad_s"] != 0.0:
            out = moved_speeds(out, found["applied_rad_s"], found["hover_speed_rad_s"])
        lag = self.command_lag
        if t is not None and lag and lag["applied_s"] > 0.0:
            out = lag_rotor_speeds(t, out, lag["applied_s"])
        return out

    def speeds_read_note(self) -> str | None:
        """How :meth:`rotor_speeds_read` reads the recorded speeds (moved by the offset applied, lagged by the lag
        applied), as a phrase; None where it leaves them as recorded."""
        offset, lag = self.rotor_speed_offset, self.command_lag
        how = ([f"moved by {offset['applied_rad_s']:.4g} rad/s (an idle speed in the command map, the hover speed "
                "kept)"] if offset and offset["applied_rad_s"] != 0.0 else [])
        how += ([f"lagged by {1e3 * lag['applied_s']:.0f} ms (the motors' lag behind their commands)"]
                if lag and lag["applied_s"] > 0.0 else [])
        return " and ".join(how) or None

    def flight_data_read(self, fd: FlightData) -> FlightData:
        """``fd`` with its rotor speeds read as these constants were identified on them (:meth:`rotor_speeds_read`):
        what a force or torque from these constants needs. A thrust coefficient identified on commands moved by
        an idle speed, applied to the commands as recorded, misreads the thrust wherever the speeds leave the
        hover speed (a hexarotor's noise-free flight, its commands 30 % of the hover speed under the rotors': the
        ground-truth f_a 0.47 N off the true lift of 1.28 N rms, 0.015 N read so)."""
        if self.speeds_read_note() is None:
            return fd
        return replace(fd, rotor_speeds=self.rotor_speeds_read(fd.rotor_speeds, fd.t))

    def identified(self, name: str) -> bool:
        """Whether the flight determines constant ``name`` (``k_T``, ``J_z``, ...)."""
        s = self.status.get(name)
        return True if s is None else s.identifiable

    @property
    def not_identified(self) -> list[str]:
        """Names of the constants the flight does not determine."""
        return [n for n, s in self.status.items() if not s.identifiable]

    def apply(self, vehicle: Vehicle) -> Vehicle:
        """The vehicle with the identified constants; a constant the flight does not determine keeps
        ``vehicle``'s nominal value (from vehicle.yaml). Without one, raises :class:`InputError`
        naming the constant, why the flight cannot determine it and what would."""
        nominal_J = vehicle.inertia
        J = []
        for i, name in enumerate(("J_x", "J_y", "J_z")):
            J.append(self._pick(name, float(self.inertia[i]), None if nominal_J is None else nominal_J[i]))
        return vehicle.with_params(
            thrust_coefficient=self._pick("k_T", float(self.thrust_coefficient), vehicle.thrust_coefficient),
            moment_coefficient=self._pick("k_M", float(self.moment_coefficient), vehicle.moment_coefficient),
            inertia=tuple(J))

    def _pick(self, name: str, value: float, nominal: float | None) -> float:
        if self.identified(name):
            return value
        if nominal is not None:
            return float(nominal)
        s = self.status[name]
        raise InputError(name, f"{s.why}; {s.advice()}")

    def fallbacks(self, vehicle: Vehicle) -> list[str]:
        """The constants :meth:`apply` takes from ``vehicle`` rather than from the flight, with why."""
        nominal = {"k_T": vehicle.thrust_coefficient, "k_M": vehicle.moment_coefficient,
                   **{n: (None if vehicle.inertia is None else vehicle.inertia[i])
                      for i, n in enumerate(("J_x", "J_y", "J_z"))}}
        return [f"{n} = {nominal[n]:.6g} from vehicle.yaml ({self.status[n].reason} on this flight)"
                for n in nominal if not self.identified(n) and nominal[n] is not None]

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dictionary (the ``identify --json`` output).

        The flat keys (``thrust_coefficient``, ``inertia``, ``theta`` ...) hold the raw estimates, as
        before; ``parameters`` says per constant whether the flight determines it:
        ``{"value", "stderr", "identifiable", "reason", "why"}``.
        """
        return {
            "recordings": self.recordings,
            "model": self.model,
            "n_samples": self.n_samples,
            "mass": self.mass,
            "thrust_coefficient": self.thrust_coefficient,
            "thrust_coefficient_stderr": self.thrust_coefficient_se,
            "thrust_coefficient_per_recording": {n: {"value": k, "stderr": se}
                                                 for n, (k, se) in self.thrust_coefficient_per_recording.items()},
            "moment_coefficient": self.moment_coefficient,
            "moment_coefficient_stderr": self.moment_coefficient_se,
            "inertia": [float(j) for j in self.inertia],
            "inertia_stderr": [float(j) for j in self.inertia_se],
            "theta": [float(t) for t in self.theta],
            "theta_stderr": [float(t) for t in self.theta_se],
            "theta_names": ["k_T/m", "l*k_T/J_x", "k_M/J_z", "J_z/J_x"],
            "accel_bias": None if self.accel_bias is None else [float(b) for b in self.accel_bias],
            "accel_bias_stderr": None if self.accel_bias is None else [float(b) for b in self.accel_bias_se],
            "near_surface_m": self.near_surface_m,
            "thrust_coefficient_surface_term": self.surface_term,
            "rotor_speed_offset": self.rotor_speed_offset,
            "command_lag": self.command_lag,
            "rotor_order": None if self.rotor_order is None else self.rotor_order.to_dict(),
            "accel_bias_per_recording": {n: {"value": [float(x) for x in b], "stderr": [float(x) for x in se]}
                                         for n, (b, se) in self.accel_bias_per_recording.items()},
            "sources": "imu+mocap" if self.accel_bias is not None else "mocap",
            "angular_bias": [float(b) for b in self.angular_bias],
            "rms": self.rms,
            "parameters": {n: s.to_dict() for n, s in self.status.items()},
            "not_identified": self.not_identified,
            "excitation": {a: e.to_dict() for a, e in self.excitation.items()},
            "condition_numbers": self.conditions,
            "thresholds": {"rate_min_rad_s": RATE_MIN, "acc_min_rad_s2": ACC_MIN, "rel_se_max": REL_SE_MAX,
                           "cond_max": COND_MAX, "bias_se_max_m_s2": BIAS_SE_MAX, "lowpass_s": LOWPASS_S,
                           "triangle_slack": TRIANGLE_SLACK, "share_min": SHARE_MIN},
        }


#: rows a fit needs; rotor radii from a surface that rows near it come down to; the share of those rows (``near``)
#: that must lie beyond six rotor radii (``usable_mask``'s cut) for the fit to keep to them (a 3 kg hexarotor's six
#: radii are 1.1 m: its indoor flights had been refused), and the share of rows more between the two for a surface
#: to count as visited; rotor radii within which a surface's Cheeseman-Bennett column is fitted beside ``k_T``
MIN_ROWS, NEAR_SURFACE_RADII, FAR_SHARE_MIN, NEAR_SHARE_MIN, SURFACE_TERM_RADII = 50, 2.0, 0.25, 0.01, 6.0


def surface_columns(fd: FlightData, vehicle: Vehicle, mask: np.ndarray) -> np.ndarray:
    """(K, s) the Cheeseman-Bennett shape ``(r / (4 d))^2`` of the rotor plane's height ``d`` over the floor and
    under the ceiling [-], one column for each surface that a row of ``mask`` comes within
    :data:`SURFACE_TERM_RADII` rotor radii of (0 where a row has no height). ``k_T S (1 + mu (r / 4d)^2)`` is the
    thrust with the law linearised (``effects.md``'s ``ground_effect``, ``rho / (1 - rho)`` to first order): its
    column fitted beside ``S`` keeps the lift out of ``k_T`` (left in, 0.35 % at six radii with mu = 2, it had put
    ``k_T`` 9-22 stated errors high on flights near the floor, away from ``gap``'s)."""
    r = vehicle.rotor_radius
    cols = []
    for d in (fd.d_down, fd.d_up):
        if d is None or not np.any(mask & (d < SURFACE_TERM_RADII * r)):
            continue
        with np.errstate(divide="ignore", invalid="ignore"):
            c = (r / (4.0 * d)) ** 2
        cols.append(np.where(np.isfinite(c) & (d > 0), c, 0.0))
    return np.stack(cols, axis=1) if cols else np.zeros((len(fd), 0))


def usable_mask(fd: FlightData, vehicle: Vehicle, *, min_height_radii: float = 6.0,
                min_thrust_ratio: float = 0.3, k_T_guess: float | None = None) -> np.ndarray:
    """Rows free of surface effects and ground contact, away from the filter's edges.

    A row is kept when the vehicle is more than ``min_height_radii`` rotor radii from the
    surfaces below and above (Cheeseman-Bennett: ``rho < mu/576``, under 0.5 % for
    ``mu <= 3``), its rotors carry at least ``min_thrust_ratio`` of the weight, and no stream has a
    dropout there (:attr:`FlightData.covered`).
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
    if fd.covered is not None:  # a stream's dropouts are not interpolated across
        keep &= fd.covered
    return keep


def _rows(fds: Sequence[FlightData], vehicle: Vehicle, masks: Sequence[np.ndarray], near_surface: bool = False
          ) -> dict[str, np.ndarray]:
    """Stack the regression rows of several flights (with ``near_surface``, the surfaces' columns too)."""
    M = vehicle.mixer()
    parts: dict[str, list[np.ndarray]] = {}
    surfaces = [surface_columns(fd, vehicle, m) if near_surface else np.zeros((len(fd), 0))
                for fd, m in zip(fds, masks)]
    n_surf = max(c.shape[1] for c in surfaces)

    def add(key, value):
        parts.setdefault(key, []).append(value)

    for g, (fd, m) in enumerate(zip(fds, masks)):
        S = np.sum(fd.rotor_speeds**2, axis=1)
        u = (fd.rotor_speeds**2) @ M.T  # (K, 4)
        R = quat.to_rotation_matrix(fd.q)
        spec_mocap = np.einsum("kji,kj->ki", R, fd.dv + np.array([0.0, 0.0, GRAVITY]))
        w = fd.w
        add("S_smooth", fd.smooth(S)[m])  # beside the IMU's smoothed specific force
        add("S_matched", fd.matched(S)[m])  # beside the motion capture's differentiated velocity
        c = S[:, None] * np.hstack([surfaces[g], np.zeros((len(fd), n_surf - surfaces[g].shape[1]))])
        add("S_surface_smooth", fd.smooth(c)[m] if n_surf else np.zeros((m.sum(), 0)))
        add("S_surface_matched", fd.matched(c)[m] if n_surf else np.zeros((m.sum(), 0)))
        add("S", S[m])
        add("t", fd.t[m])
        add("y_mocap", spec_mocap[m, 2])
        add("spec_mocap", spec_mocap[m])
        add("acc", fd.acc[m] if fd.acc is not None else np.full((m.sum(), 3), np.nan))
        add("acc_smooth", fd.smooth(fd.acc)[m] if fd.acc is not None else np.full((m.sum(), 3), np.nan))
        # the causes of the angular acceleration filtered as its derivative filters them (against the value
        # smoother, a probe's inertia came out 0.7 % high at 17-20 stated errors, without noise)
        add("u", fd.matched(u)[m])
        add("ww", fd.matched(np.stack([w[:, 1] * w[:, 2], w[:, 0] * w[:, 2], w[:, 0] * w[:, 1]], 1))[m])
        add("dw", fd.dw[m])
        add("group", np.full(m.sum(), g))
    return {k: np.concatenate(v) for k, v in parts.items()}


def _anchored_biases(rows: dict[str, np.ndarray]) -> tuple[AnchoredBias, dict[int, AnchoredBias]]:
    """The accelerometer bias over all rows and per recording (``group``), each measured against the motion
    capture (:func:`uavturb.sysid.accelerometer.anchored_bias`): what the IMU reads beyond the specific force
    the motion capture shows, so that it cannot trade with the thrust coefficient."""
    diff = rows["acc"] - rows["spec_mocap"]
    groups = rows["group"]
    labels = np.empty(len(groups), np.int64)  # blocks of one recording each: its own block numbers, its group's
    per = {}
    for g in np.unique(groups):
        mine = groups == g
        labels[mine] = block_labels(rows["t"][mine], BLOCK_S) + (int(g) << 32)
        b, se = block_mean_and_se(diff[mine], labels[mine])
        per[int(g)] = AnchoredBias(b, se, int(mine.sum()))
    b, se = block_mean_and_se(diff, labels)
    return AnchoredBias(b, se, len(diff)), per


def _fit_translation(rows: dict[str, np.ndarray], lag: int) -> dict[str, Any]:
    """``theta_0`` from the body-z specific force, and with an IMU the accelerometer bias.

    The bias is not a fit parameter: it is measured against the motion capture, per recording
    (:func:`_anchored_biases`), and taken off the IMU's rows, which then count as a second, less noisy
    measure of the same specific force (``gap`` anchors it the same way, so the two agree). A bias fitted
    beside ``theta_0`` traded with it: on aggressive real flights ``k_T`` came out 0.2-0.7 % low and ``b_z``
    0.07-0.13 m/s^2 high. Both row sets use the speeds and forces through the derivative filter, so that
    the noise of raw rotor commands does not shrink the slope (errors in variables).
    """
    groups = rows["group"]
    # the rows with an accelerometer reading (recordings without imu0 have none: their motion capture still counts)
    imu = np.all(np.isfinite(rows["acc"]), axis=1) & np.all(np.isfinite(rows["acc_smooth"]), axis=1)
    if imu.any():
        K = len(rows["S"])
        with_imu = {k: v[imu] for k, v in rows.items()}
        pooled, per = _anchored_biases(with_imu)
        bias_se = pooled.stderr
        if len(per) >= 2:  # IMUs of other sessions read other biases: the pooled one's error covers their spread
            bias_se = np.maximum(bias_se, np.std([a.b for a in per.values()], axis=0, ddof=1))
        b_z = np.array([per[int(g)].b[2] for g in with_imu["group"]])
        A = np.concatenate([_thrust_columns(rows, "matched"), _thrust_columns(with_imu, "smooth")])
        y = np.concatenate([rows["y_mocap"], with_imu["acc_smooth"][:, 2] - b_z])
        first = lstsq(A, y, lag=lag)
        var_m = np.var(first.residual[:K])
        var_i = np.var(first.residual[K:])
        wts = np.concatenate([np.full(K, 1 / var_m), np.full(len(b_z), 1 / var_i)])
        fit = lstsq(A, y, lag=lag, weights=wts, groups=np.concatenate([groups, with_imu["group"] + 1000]))
        return {"theta0": fit.coef[0], "theta0_se": fit.stderr[0], "has_imu": True, "bias": pooled.b,
                "bias_se": bias_se, "bias_per_recording": per,
                "rms": float(np.sqrt(np.mean(fit.residual[K:] ** 2))), "cond": fit.cond}
    fit = lstsq(_thrust_columns(rows, "matched"), rows["y_mocap"], lag=lag, groups=groups)
    return {"theta0": fit.coef[0], "theta0_se": fit.stderr[0], "has_imu": False, "bias": np.full(3, np.nan),
            "bias_se": np.full(3, np.nan), "rms": fit.rms, "cond": fit.cond}


def _thrust_columns(rows: dict[str, np.ndarray], filtered: str) -> np.ndarray:
    """(K, 1 + s) the translation fit's regressors: ``S`` and, beside it, each surface's ``S (r / 4d)^2``
    (:func:`surface_columns`) where a surface is within reach (a column all zeros, no row near it, left out),
    ``filtered`` as the specific force they explain: ``"smooth"`` (the IMU's) or ``"matched"`` (the motion
    capture's, differentiated)."""
    surf = rows[f"S_surface_{filtered}"]
    keep = np.any(rows["S_surface_smooth"] != 0.0, axis=0) if surf.size else np.zeros(surf.shape[1], bool)
    return np.column_stack([rows[f"S_{filtered}"], surf[:, keep]])


@dataclass
class _Rows:
    """The usable rows of each flight: ``masks`` (the fit's), whether they come down to
    :data:`NEAR_SURFACE_RADII` (``near``: the surfaces' law then fitted beside ``k_T``), and the other reading's
    masks where the flights visit a surface's reach and both can be read (``other``: the far rows where the fit
    reads the near ones, or the reverse), None otherwise."""

    masks: list[np.ndarray]
    near: bool
    other: list[np.ndarray] | None


def _usable_flights(recordings: Sequence[Recording] | Sequence[FlightData], vehicle: Vehicle | None, model: str,
                    window_s: float) -> tuple[Vehicle, list[FlightData], list[str], _Rows]:
    """(vehicle, flight data, names, usable rows) of the flights, or :class:`InputError` when they cannot identify
    anything (none given, no vehicle, an unknown model, under :data:`MIN_ROWS` usable samples). The rows lie beyond
    six rotor radii of every surface (:func:`usable_mask`) unless under :data:`FAR_SHARE_MIN` of the rows down to
    :data:`NEAR_SURFACE_RADII` (or :data:`MIN_ROWS`) do: then they come down to it, and the surfaces' law is fitted
    beside ``k_T`` (:func:`surface_columns`)."""
    if not recordings:
        raise InputError("identify", "no recording given")
    if vehicle is None:
        if not isinstance(recordings[0], Recording):
            raise InputError("identify", "a vehicle is needed with FlightData input")
        vehicle = recordings[0].vehicle
    if model not in ("auto", "general", "jx=jy"):
        raise InputError("identify.model", f"unknown model '{model}' (allowed: auto, general, jx=jy)")
    fds = [r if isinstance(r, FlightData) else flight_data(r, window_s=window_s) for r in recordings]
    names = [str(r.path) if isinstance(r, Recording) and r.path else fd.name for r, fd in zip(recordings, fds)]
    far = [usable_mask(fd, vehicle) for fd in fds]
    near = [usable_mask(fd, vehicle, min_height_radii=NEAR_SURFACE_RADII) for fd in fds]
    n_far, n_near = int(sum(m.sum() for m in far)), int(sum(m.sum() for m in near))
    visited = n_near > (1.0 + NEAR_SHARE_MIN) * n_far and n_far >= MIN_ROWS and n_near >= MIN_ROWS
    if n_far < MIN_ROWS or n_far < FAR_SHARE_MIN * n_near:  # flights that stay near a surface: read down to it
        rows, n = _Rows(near, True, far if visited else None), n_near
    else:
        rows, n = _Rows(far, False, near if visited else None), n_far
    if n < MIN_ROWS:
        h = NEAR_SURFACE_RADII * vehicle.rotor_radius
        raise InputError(names[0], f"only {n} samples in flight with the rotors over a third of the weight and "
                                   f"more than {h:.2g} m ({NEAR_SURFACE_RADII:g} rotor radii) from any surface; "
                                   "cannot identify (residuals --params nominal uses vehicle.yaml's constants)")
    return vehicle, fds, names, rows


def _columns(*cols: np.ndarray | None) -> np.ndarray:
    """The regressor matrix of the columns given (``None``: a column left out)."""
    return np.stack([c for c in cols if c is not None], 1)


def _fit_rotation_axes(rows: dict[str, np.ndarray], gyro: bool, lag: int) -> tuple[Any, Any, Any]:
    """Least-squares fits of ``w_dot_x``, ``w_dot_y``, ``w_dot_z`` per axis (the general model); without
    yaw motion (``gyro`` false) the roll and pitch fits leave the gyroscopic column out."""
    u, ww, dw, groups = rows["u"], rows["ww"], rows["dw"], rows["group"]
    one = np.ones(len(dw))
    fit_x = lstsq(_columns(u[:, 1], ww[:, 0] if gyro else None, one), dw[:, 0], lag=lag, groups=groups)
    fit_y = lstsq(_columns(u[:, 2], ww[:, 1] if gyro else None, one), dw[:, 1], lag=lag, groups=groups)
    fit_z = lstsq(np.stack([u[:, 3], ww[:, 2], one], 1), dw[:, 2], lag=lag, groups=groups)
    return fit_x, fit_y, fit_z


@dataclass
class _Inertia:
    """One inertia model's Monte Carlo draws of ``J_x``, ``J_y``, ``J_z`` [kg m^2] (NaN: not estimated),
    and what its roll and pitch fits say."""

    Jx: np.ndarray
    Jy: np.ndarray
    Jz: np.ndarray
    bias_xy: tuple[float, float]  # rad/s^2, constant angular accelerations c_x, c_y
    rms: dict[str, float]
    conds: dict[str, float]
    shares: tuple[float, float]  # roll, pitch: the share of w_dot the rotor column carries


def _inertia_general(rows: dict[str, np.ndarray], fit_x: Any, fit_y: Any, gyro: bool, kT: np.ndarray, arm_length: float,
                     rng: np.random.Generator, n_draws: int) -> _Inertia:
    """``J_x != J_y``: ``J_x = l k_T / a_x``, ``J_y = l k_T / a_y``; ``J_z`` from the two gyroscopic
    coefficients ``(J_y - J_z)/J_x`` and ``(J_z - J_x)/J_y``, inverse-variance weighted.
    ``kT``: (n_draws,) draws of k_T [N/(rad/s)^2]; ``arm_length``: l [m]."""
    u, dw = rows["u"], rows["dw"]
    cx = rng.multivariate_normal(fit_x.coef, fit_x.cov, n_draws)
    cy = rng.multivariate_normal(fit_y.coef, fit_y.cov, n_draws)
    with np.errstate(divide="ignore", invalid="ignore"):
        Jx, Jy = arm_length * kT / cx[:, 0], arm_length * kT / cy[:, 0]
        Jz = np.full(n_draws, np.nan)
        if gyro:
            Jz1, Jz2 = Jy - cx[:, 1] * Jx, Jx + cy[:, 1] * Jy  # from (J_y - J_z)/J_x and (J_z - J_x)/J_y
            v1, v2 = np.var(Jz1), np.var(Jz2)
            Jz = (Jz1 / v1 + Jz2 / v2) / (1 / v1 + 1 / v2)
    return _Inertia(Jx, Jy, Jz, (fit_x.coef[-1], fit_y.coef[-1]), {"roll": fit_x.rms, "pitch": fit_y.rms},
                    {"roll": fit_x.cond, "pitch": fit_y.cond},
                    (column_share(fit_x.coef[0], u[:, 1], dw[:, 0]), column_share(fit_y.coef[0], u[:, 2], dw[:, 1])))


def _inertia_jx_equals_jy(rows: dict[str, np.ndarray], gyro: bool, kT: np.ndarray, arm_length: float, lag: int,
                          rng: np.random.Generator, n_draws: int) -> _Inertia:
    """The paper's ``J_x = J_y``: ``w_dot_x = th1 u_1 + (1 - th3) w_y w_z``, ``w_dot_y = th1 u_2 - (1 - th3) w_x w_z``
    fitted jointly; ``J_z = J_x (1 - th3)``."""
    u, ww, dw, groups = rows["u"], rows["ww"], rows["dw"], rows["group"]
    K = len(dw)
    one, zeros = np.ones(K), np.zeros(K)
    A = np.block([[_columns(u[:, 1], ww[:, 0] if gyro else None, one, zeros)],
                  [_columns(u[:, 2], -ww[:, 1] if gyro else None, zeros, one)]])
    fit_xy = lstsq(A, np.concatenate([dw[:, 0], dw[:, 1]]), lag=lag, groups=np.concatenate([groups, groups + 1000]))
    cxy = rng.multivariate_normal(fit_xy.coef, fit_xy.cov, n_draws)
    with np.errstate(divide="ignore", invalid="ignore"):
        Jx = Jy = arm_length * kT / cxy[:, 0]
        Jz = Jx * (1.0 - cxy[:, 1]) if gyro else np.full(n_draws, np.nan)
    return _Inertia(Jx, Jy, Jz, (fit_xy.coef[-2], fit_xy.coef[-1]), {"roll_pitch": fit_xy.rms},
                    {"roll": fit_xy.cond, "pitch": fit_xy.cond},
                    (column_share(fit_xy.coef[0], u[:, 1], dw[:, 0]), column_share(fit_xy.coef[0], u[:, 2], dw[:, 1])))


def _median_and_se(draws: np.ndarray) -> tuple[float, float]:
    """(median, half the 68 % interval) of the finite Monte Carlo draws; NaN with fewer than 10."""
    draws = draws[np.isfinite(draws)]
    if len(draws) < 10:
        return float("nan"), float("nan")
    lo, med, hi = np.percentile(draws, [15.87, 50.0, 84.13])
    return float(med), float((hi - lo) / 2.0)


def identify(recordings: Sequence[Recording] | Sequence[FlightData], vehicle: Vehicle | None = None, *,
             model: str = "auto", window_s: float = 0.05, lag_s: float = 0.25, n_draws: int = 4000,
             seed: int = 0) -> Identification:
    """Identify ``k_T``, ``k_M`` and ``J`` from one or more flights of one vehicle, and say which of
    them the flights determine (:mod:`uavturb.sysid.identifiability`).

    Parameters
    ----------
    recordings : recordings (or their :class:`FlightData`) of the same vehicle
    vehicle : geometry and mass; default the first recording's
    model : ``auto``, ``general`` (``J_x != J_y``) or ``jx=jy`` (the paper's)
    window_s : derivative filter window [s]
    lag_s : correlation length for the Newey-West standard errors [s]
    n_draws : Monte Carlo draws propagating the standard errors
    """
    vehicle, fds, names, usable = _usable_flights(recordings, vehicle, model, window_s)
    raw = [r.rotors.speeds if isinstance(r, Recording) and r.rotors is not None else fd.rotor_speeds
           for r, fd in zip(recordings, fds)]
    commanded = vehicle.rotor_speed_source != "measured"
    reading = idle_offset(fds, usable.masks, vehicle) if commanded else None
    at, ends = offset_plan(reading)
    lag = None
    if commanded:
        # the rotors' lag behind the commands, read on the speeds moved as they are identified at; the offset is
        # then read again on the lagged speeds (commands ahead of the thrust they make blur its level: a
        # hexarotor's 60 ms lag had moved the offset read, and the inertia 4 % low at 7 errors), and the lag on
        # the speeds moved by it (a lag and the offset's move commute: the move is affine)
        lag = command_lag(_moved(fds, at, reading), usable.masks, vehicle)
        if lag is not None and lag.decisive:
            reading = idle_offset(lagged(fds, lag.tau_s), usable.masks, vehicle)
            at, ends = offset_plan(reading)
            lag = command_lag(_moved(fds, at, reading), usable.masks, vehicle)
    tau, tau_ends = lag_plan(lag)

    def read_at(offset: float, tau_s: float) -> list[FlightData]:  # the flights' speeds moved, then lagged
        return lagged(_moved(fds, offset, reading), tau_s)

    def half_change(pair) -> dict[str, float]:  # each constant's half change between two identifications
        lo, hi = (_identified(vehicle, read_at(*p), names, usable, raw, model, lag_s, OFFSET_END_DRAWS, seed)
                  for p in pair)
        return {k: abs(float(hi.values[k]) - float(lo.values[k])) / 2.0 for k in OFFSET_TERM_KEYS}

    # the offsets and the lags the readings leave open: each constant's error carries half its change across each
    terms = half_change([(e, tau) for e in ends]) if ends is not None else {}
    lag_terms = half_change([(at, e) for e in tau_ends]) if tau_ends is not None else {}
    both = {k: float(np.hypot(terms.get(k, 0.0), lag_terms.get(k, 0.0))) for k in set(terms) | set(lag_terms)}
    final = read_at(at, tau)
    # which order of the rotor columns the torques follow: read once, on the speeds the constants are identified on
    order = rotor_order([fd.matched(fd.rotor_speeds**2) for fd in final], [fd.dw for fd in final], vehicle.mixer(),
                        dt=[fd.dt for fd in final], usable=usable.masks)
    out = _identified(vehicle, final, names, usable, raw, model, lag_s, n_draws, seed, both, order)
    out.identification.rotor_speed_offset = _offset_report(reading, at, ends, terms)
    out.identification.command_lag = None if lag is None else lag.to_dict() | {
        "applied_s": tau, "ends_s": None if tau_ends is None else list(tau_ends), "terms": lag_terms}
    return out.identification


def lag_plan(lag: CommandLag | None) -> tuple[float, tuple[float, float] | None]:
    """(s, the lag the constants are identified at; s, the two lags whose change their errors carry, or None) for
    a :func:`~uavturb.sysid.command_lag.command_lag` reading: its value and one standard error either side (the
    lower clipped at 0) where it is decisive; none otherwise (a lag the torques' timing cannot tell from none)."""
    if lag is None or not lag.decisive:
        return 0.0, None
    return lag.tau_s, lag.ends


#: draws of the Monte Carlo at the ends of the offsets a reading leaves open (their medians only are read)
OFFSET_END_DRAWS = 500
#: the constants whose error carries the offsets left open (``k_T`` keeps the hover speed: it barely moves)
OFFSET_TERM_KEYS = ("k_T", "k_M", "J_x", "J_y", "J_z", "theta_0", "theta_1", "theta_2", "theta_3")


def idle_offset(fds: Sequence[FlightData], masks: Sequence[np.ndarray], vehicle: Vehicle) -> SpeedOffset | None:
    """The recorded (commanded) rotor speeds' offset (:func:`uavturb.sysid.nominal.speed_offset`, **Thrust map**)
    read on the rows ``masks`` of the flights ``fds``, one cell per recording beyond :data:`SURFACE_TERM_RADII`
    rotor radii of every surface (rows nearer are left out): the thrust the rotors make, ``m`` times the specific
    force along the body z axis that the motion capture shows (an IMU's bias, measured apart, cannot lean on it), per
    ``sum((w + delta)^2)``. None with too few rows."""
    reach = SURFACE_TERM_RADII * vehicle.rotor_radius
    y, w, t, cells = [], [], [], []
    for g, (fd, m) in enumerate(zip(fds, masks)):
        acc = mocap_specific_force(quat.to_rotation_matrix(fd.q), fd.dv)
        far = np.full(len(fd), np.inf)
        cell = offset_cells(np.full(len(fd), g), far if fd.d_down is None else fd.d_down,
                            far if fd.d_up is None else fd.d_up, vehicle.rotor_radius, reach)
        y.append(vehicle.mass * acc[m, 2])
        w.append(fd.rotor_speeds[m])
        t.append(fd.t[m])
        cells.append(np.where(cell[m] >= 0, g, -1))
    return speed_offset(np.concatenate(y), np.concatenate(w), np.concatenate(cells), np.concatenate(t))


def offset_plan(reading: SpeedOffset | None) -> tuple[float, tuple[float, float] | None]:
    """(the offset [rad/s] the constants are identified at, the two offsets [rad/s] whose change their errors
    carry, or None) for a ``reading`` of the commanded speeds' offset, as ``gap`` states its values: a decisive
    reading is applied, its error either side the ends; a reading that leaves offsets open is stated at their
    centre (:func:`uavturb.sysid.nominal.stated_offset`), the ends theirs; without a reading (none, or at the bound of
    the range searched) the recorded speeds stand and ``identify`` says what they rest on."""
    if reading is None or reading.at_bound or not np.isfinite(reading.delta):
        return 0.0, None
    if reading.decisive:
        return reading.delta, (reading.delta - reading.stderr, reading.delta + reading.stderr)
    ends = reading.open_interval()
    at = stated_offset(reading, ends)
    return (at, ends) if at != 0.0 else (0.0, None)


def _moved(fds: Sequence[FlightData], delta: float, reading: SpeedOffset | None) -> list[FlightData]:
    """The flights with their rotor speeds moved by ``delta`` [rad/s], the hover speed kept
    (:func:`uavturb.sysid.nominal.moved_speeds`); as they are at 0."""
    if delta == 0.0 or reading is None:
        return list(fds)
    return [replace(fd, rotor_speeds=moved_speeds(fd.rotor_speeds, delta, reading.w_hover)) for fd in fds]


def _offset_report(reading: SpeedOffset | None, at: float, ends: tuple[float, float] | None,
                   terms: dict[str, float]) -> dict[str, Any] | None:
    """``Identification.rotor_speed_offset``: the reading, the offset applied and each constant's term."""
    if reading is None:
        return None
    return {"delta_rad_s": float(reading.delta), "stderr_rad_s": float(reading.stderr), "z": float(reading.z),
            "hover_speed_rad_s": float(reading.w_hover), "counts": reading.counts, "decisive": reading.decisive,
            "at_bound": reading.at_bound, "applied_rad_s": float(at),
            "ends_rad_s": None if ends is None else [float(e) for e in ends], "terms": terms}


@dataclass
class _Identified:
    """One identification: the result, and its raw estimates by name (the offset's ends read them)."""

    identification: "Identification"
    values: dict[str, float]


def _identified(vehicle: Vehicle, fds: Sequence[FlightData], names: list[str], usable: "_Rows",
                raw: Sequence[np.ndarray], model: str, lag_s: float, n_draws: int, seed: int,
                offset_terms: dict[str, float] | None = None, order: RotorOrder | None = None) -> _Identified:
    """:func:`identify` on flights ``fds`` as read (their rotor speeds moved or not), with ``offset_terms`` (name ->
    the offset's term, in each constant's unit) added to the errors in quadrature; ``order``: what the flights say
    of the rotor columns' order (:func:`~uavturb.sysid.rotor_order.rotor_order`; None: not read)."""
    masks = usable.masks
    rows = _rows(fds, vehicle, masks, usable.near)
    lag = max(1, int(round(lag_s / fds[0].dt)))

    # translation: theta_0 (the accelerometer's bias measured apart); with two or more recordings, each alone too
    tr = _fit_translation(rows, lag)
    per_recording = _theta0_per_recording(rows, lag, names)
    # sessions, batteries, propellers: the error covers what varies between them; with one recording, what varies
    # between its parts in time
    spread = _spread_between(per_recording) if per_recording else _theta0_between_blocks(rows, lag)
    if spread > tr["theta0_se"]:
        tr = tr | {"theta0_se": spread}
    # a surface's lift on the rows: where the flights visit its reach, read both beyond it and down to it (its law
    # beside theta_0), and the error carries half the difference
    surface_term = 0.0
    if usable.other is not None:
        other = _fit_translation(_rows(fds, vehicle, usable.other, not usable.near), lag)
        surface_term = abs(float(other["theta0"]) - float(tr["theta0"])) / 2.0
        tr = tr | {"theta0_se": float(np.hypot(tr["theta0_se"], surface_term))}
    # rotor speeds rounded to a quantum: in a steady hover the rounding stays, and k_T carries it whole
    share = max(rounding_share(w, rotor_quantum(w)) for w in raw)
    if share > 0:
        tr = tr | {"theta0_se": float(np.hypot(tr["theta0_se"], share * tr["theta0"]))}
    # rotation: without yaw motion the gyroscopic columns (w_y w_z, w_x w_z) hold only noise: they are
    # left out, and J_z (which only they carry) is not estimated
    ex = axis_excitation([fd.w for fd in fds], [fd.dw for fd in fds], masks, [fd.dt for fd in fds])
    gyro = ex["yaw"].rate_std >= RATE_MIN
    fit_x, fit_y, fit_z = _fit_rotation_axes(rows, gyro, lag)
    differ = abs(fit_x.coef[0] - fit_y.coef[0]) > 3.0 * np.hypot(fit_x.stderr[0], fit_y.stderr[0])
    chosen = model if model != "auto" else ("general" if differ else "jx=jy")

    # Monte Carlo: the draws of theta_0 and the yaw fit, then of the chosen model's roll and pitch fits
    rng = np.random.default_rng(seed)
    m, l = vehicle.mass, vehicle.arm_length
    th0 = rng.normal(tr["theta0"], tr["theta0_se"], n_draws)
    kT = m * th0
    cz = rng.multivariate_normal(fit_z.coef, fit_z.cov, n_draws)
    J = (_inertia_general(rows, fit_x, fit_y, gyro, kT, l, rng, n_draws) if chosen == "general"
         else _inertia_jx_equals_jy(rows, gyro, kT, l, lag, rng, n_draws))
    with np.errstate(divide="ignore", invalid="ignore"):
        kM = cz[:, 0] * J.Jz
        theta_draws = [th0, l * kT / J.Jx, cz[:, 0], J.Jz / J.Jx]
    theta, theta_se = zip(*(_median_and_se(d) for d in theta_draws))
    theta = np.array([tr["theta0"], *theta[1:]])
    theta_se = np.array([tr["theta0_se"], *theta_se[1:]])
    inertia, inertia_se = zip(*(_median_and_se(d) for d in (J.Jx, J.Jy, J.Jz)))
    kM_est, kM_se = _median_and_se(kM)

    share = {"roll": J.shares[0], "pitch": J.shares[1],
             "yaw": column_share(fit_z.coef[0], rows["u"][:, 3], rows["dw"][:, 2])}
    ex = {a: AxisExcitation(e.rate_std, e.acc_std, share[a]) for a, e in ex.items()}
    conds = {"thrust": tr["cond"], **J.conds, "yaw": fit_z.cond}
    values = {"k_T": float(m * tr["theta0"]), "k_M": kM_est, "J_x": inertia[0], "J_y": inertia[1],
              "J_z": inertia[2], **{f"theta_{i}": float(theta[i]) for i in range(4)}, "accel_bias": tr["bias"]}
    errors = {"k_T": float(m * tr["theta0_se"]), "k_M": kM_se, "J_x": inertia_se[0], "J_y": inertia_se[1],
              "J_z": inertia_se[2], **{f"theta_{i}": float(theta_se[i]) for i in range(4)},
              "accel_bias": tr["bias_se"]}
    for k, term in (offset_terms or {}).items():  # the offsets the commanded speeds' reading leaves open
        errors[k] = float(np.hypot(errors[k], term)) if np.isfinite(term) else errors[k]
    theta_se = np.array([errors[f"theta_{i}"] for i in range(4)])
    status = assess(values, errors, ex, conds, has_imu=tr["has_imu"], mass=m, arm_length=l,
                    rotor_radius=vehicle.rotor_radius, jx_equals_jy=chosen == "jx=jy", rotor_order=order)
    return _Identified(Identification(
        mass=m, thrust_coefficient=values["k_T"], thrust_coefficient_se=errors["k_T"], moment_coefficient=kM_est,
        moment_coefficient_se=errors["k_M"], inertia=np.array(inertia),
        inertia_se=np.array([errors[n] for n in ("J_x", "J_y", "J_z")]), theta=theta,
        theta_se=theta_se, accel_bias=tr["bias"] if tr["has_imu"] else None,
        angular_bias=np.array([*J.bias_xy, fit_z.coef[2]]), model=chosen, n_samples=int(sum(mk.sum() for mk in masks)),
        rms={"thrust": tr["rms"], **J.rms, "yaw": fit_z.rms}, recordings=names, status=status, excitation=ex,
        conditions={k: float(v) for k, v in conds.items()}, accel_bias_se=tr["bias_se"],
        thrust_coefficient_per_recording={n: (float(m * t), float(m * se)) for n, (t, se) in per_recording.items()},
        accel_bias_per_recording=({names[g]: (a.b, a.stderr) for g, a in tr["bias_per_recording"].items()}
                                  if tr["has_imu"] and len(fds) > 1 else {}),
        near_surface_m=NEAR_SURFACE_RADII * vehicle.rotor_radius if usable.near else None,
        surface_term=float(m * surface_term) if usable.other is not None else None, rotor_order=order), values)


#: rows a recording needs for its own ``theta_0`` (the spread between recordings)
MIN_RECORDING_ROWS = 100


def _theta0_per_recording(rows: dict[str, np.ndarray], lag: int, names: Sequence[str]
                          ) -> dict[str, tuple[float, float]]:
    """``{recording: (theta_0, its standard error)}`` fitted on each recording's rows alone, where there are two or
    more recordings with at least :data:`MIN_RECORDING_ROWS` rows each; ``{}`` otherwise."""
    groups = np.unique(rows["group"])
    counts = {int(g): int(np.sum(rows["group"] == g)) for g in groups}
    usable = [g for g in counts if counts[g] >= MIN_RECORDING_ROWS]
    if len(usable) < 2:
        return {}
    out = {}
    for g in usable:
        mine = rows["group"] == g
        fit = _fit_translation({k: v[mine] for k, v in rows.items()}, lag)
        out[names[g]] = (float(fit["theta0"]), float(fit["theta0_se"]))
    return out


#: contiguous blocks of a recording left out in turn for the jackknife of ``theta_0`` (``gap`` uses as many)
TIME_BLOCKS = 5


def _theta0_between_blocks(rows: dict[str, np.ndarray], lag: int) -> float:
    """The jackknife standard error of ``theta_0`` over :data:`TIME_BLOCKS` contiguous blocks of each recording
    (block ``b`` of every recording left out together): the least-squares error counts samples as independent
    beyond the Newey-West lag, and the motion-capture and IMU rows measure one force twice. On a real walk the
    two halves' k_T differed by 4.6 of their combined stated errors; 0 with fewer than :data:`MIN_RECORDING_ROWS`
    rows."""
    if len(rows["t"]) < MIN_RECORDING_ROWS:
        return 0.0
    block = np.empty(len(rows["t"]), int)
    for g in np.unique(rows["group"]):
        mine = rows["group"] == g
        block[mine] = contiguous_blocks(rows["t"][mine], TIME_BLOCKS)
    values = np.array([_fit_translation({k: v[block != b] for k, v in rows.items()}, lag)["theta0"]
                       for b in range(TIME_BLOCKS)])
    return float(jackknife_se(values))


def _spread_between(per_recording: dict[str, tuple[float, float]]) -> float:
    """The standard deviation of the recordings' own ``theta_0`` (0 with fewer than two): a recording's own fit
    then lands within about two stated errors of the joint one, as ``gap``'s errors do (``gap-report.md``, honest
    errors). Real sessions of one vehicle differ by 2-5 % in thrust per rotor speed squared, where the pooled fit's
    own error was 0.04-0.1 %."""
    values = np.array([v for v, _ in per_recording.values()])
    return float(np.std(values, ddof=1)) if len(values) >= 2 else 0.0
