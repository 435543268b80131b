"""Which constants a flight determines, and why not the others.

A least-squares fit always returns numbers; whether they mean anything depends on the flight.
Every constant of :func:`uavturb.sysid.identification.identify` gets a :class:`ParameterStatus`,
``identified`` or one of these reasons (in this order of precedence: the first that applies is
the reason, the others are added to the explanation):

``absent``
    the stream it needs is not in the recording (no ``imu0``: no accelerometer bias).
``not excited``
    the motion that makes it visible never happened. Measured per body axis on the samples
    used, after a :data:`LOWPASS_S` moving average (manoeuvres are slower than 5 Hz; the
    average removes sensor noise and the noise of rates differentiated from motion capture):
    the body-rate standard deviation must reach :data:`RATE_MIN` and the angular-acceleration
    standard deviation :data:`ACC_MIN`. Which axes a constant needs: ``J_x``/``theta_1`` roll,
    ``J_y`` pitch (roll or pitch with ``J_x = J_y``), ``J_z``/``theta_3`` the yaw rate (its
    gyroscopic terms ``w_y w_z``, ``w_x w_z``), ``theta_2 = k_M/J_z`` the yaw acceleration,
    ``k_M`` both (a held heading gives neither ``theta_2`` nor ``k_M``: the yaw torque is then the
    controller's answer to noise).
``ill-conditioned``
    the data hold it but cannot pin it: relative standard error above :data:`REL_SE_MAX`, or
    condition number of the (column-normalised) regression it comes from above
    :data:`COND_MAX` (nearly collinear columns), or, for the accelerometer bias, a standard error
    above :data:`BIAS_SE_MAX`; or, for a slope on the rotor-torque column (``theta_1``, ``J_x``,
    ``J_y``, ``theta_2``), a column that carries less than :data:`SHARE_MIN` of the angular
    acceleration's variance (``share``). Least squares shrinks a slope towards zero by the share of
    its column's variance that is noise (errors in variables: recorded rotor speeds are commands, or
    quantised, or late); with a share ``s`` the data only bound the slope between the estimate and
    ``1/s`` times it (the forward and reverse regressions of one column), so the bound is held to the
    same :data:`REL_SE_MAX` as a standard error. Real Crazyflie walks at a held heading gave
    ``theta_2`` 8 to 700 times under its nominal value at shares of 0.01-0.24.
``rotor columns out of order``
    the flight's roll and pitch accelerations follow the rotor torques of the columns in another order than
    ``vehicle.yaml``'s angles (:mod:`uavturb.sysid.rotor_order`): every constant read from the torques (``k_M``, the
    inertias, ``theta_1`` to ``theta_3``) is then wrong, whatever its fit says; the thrust, a sum, is not.
``physically impossible``
    a value no rigid multirotor has: ``k_T``, ``k_M`` or an inertia not positive; an inertia
    above ``m (l + r)^2`` (the whole mass at the propeller tips), or a ``theta_1`` that puts ``J_x``
    there (rotor columns in another order than ``vehicle.yaml``'s angles); ``k_M > k_T r`` (a rotor
    whose drag torque exceeds thrust times radius: blades with more drag than lift); the
    triangle inequality of principal moments ``J_k <= J_i + J_j`` broken by more than
    :data:`TRIANGLE_SLACK` beyond two standard errors (the least certain of the three is
    withdrawn).
A constant computed from another that is not identified inherits that one's reason
(``k_M = theta_2 J_z``; ``J_x = l k_T / (l k_T/J_x)``; ``theta_0 = k_T/m``).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Sequence

import numpy as np
from scipy.ndimage import uniform_filter1d

from uavturb.sysid.rotor_order import GIVEN as GIVEN_ORDER
from uavturb.sysid.rotor_order import OTHER as OTHER_ORDER
from uavturb.sysid.rotor_order import REORDER, RotorOrder

#: s, moving-average window before measuring excitation (removes noise, keeps manoeuvres < 5 Hz)
LOWPASS_S = 0.2
#: rad/s, smallest body-rate standard deviation that counts as a manoeuvre about an axis (3 deg/s;
#: a held heading under a position controller stays near 0.001-0.01 rad/s)
RATE_MIN = 0.05
#: rad/s^2, smallest angular-acceleration standard deviation that counts as a manoeuvre
ACC_MIN = 0.05
#: largest relative standard error |se / value| of an identified constant
REL_SE_MAX = 0.3
#: largest condition number of a column-normalised regression (variance inflation ~ COND^2)
COND_MAX = 1.0e3
#: smallest share of the angular acceleration's variance that the rotor-torque column must carry for its
#: slope to be identified: the slope then lies between the estimate and 1/SHARE_MIN = 1 + REL_SE_MAX times it
SHARE_MIN = 1.0 / (1.0 + REL_SE_MAX)
#: a rotor-torque column's share of the variance under which it tells nothing of the rotors' order (an inertia
#: read above its physical bound is then said to come from noise or from columns in another order alike)
SHARE_TELLS = 0.05
#: standard errors by which a yaw slope (``theta_2``, ``k_M``) must fall under zero to be read as rotor directions
#: given the other way round (noise alone puts it there in one flight of 740 at most)
REVERSED_Z = 3.0
#: m/s^2, largest standard error of an identified accelerometer bias component
BIAS_SE_MAX = 0.05
#: how far J_k may exceed J_i + J_j: RotorS's Firefly inertia, used by the built-in hexarotor
#: and the shipped firefly.yaml, exceeds it by 21 % (J_z = 0.0977 > 0.0806): a model estimate
TRIANGLE_SLACK = 0.3

IDENTIFIED = "identified"
ABSENT = "absent"
NOT_EXCITED = "not excited"
ILL_CONDITIONED = "ill-conditioned"
IMPOSSIBLE = "physically impossible"
OUT_OF_ORDER = "rotor columns out of order"
PRECEDENCE = (ABSENT, OUT_OF_ORDER, NOT_EXCITED, ILL_CONDITIONED, IMPOSSIBLE)
#: the constants read from the rotor torques, which columns in another order than vehicle.yaml's angles make wrong
#: (the thrust, a sum over the rotors, stays right)
FROM_TORQUES = ("k_M", "J_x", "J_y", "J_z", "theta_1", "theta_2", "theta_3")

AXES = ("roll", "pitch", "yaw")

#: per constant: its unit, the vehicle.yaml key that can stand in for it, the manoeuvre that
#: determines it
PARAMETERS: dict[str, dict[str, str]] = {
    "k_T": {"unit": "N/(rad/s)^2", "key": "thrust_coefficient", "manoeuvre": "fly thrust changes (climbs, descents)"},
    "k_M": {"unit": "N m/(rad/s)^2", "key": "moment_coefficient", "manoeuvre": "fly yaw steps"},
    "J_x": {"unit": "kg m^2", "key": "inertia", "manoeuvre": "fly roll doublets"},
    "J_y": {"unit": "kg m^2", "key": "inertia", "manoeuvre": "fly pitch doublets"},
    "J_z": {"unit": "kg m^2", "key": "inertia", "manoeuvre": "fly yaw steps while rolling and pitching"},
    "theta_0": {"unit": "N/(kg (rad/s)^2)", "key": "thrust_coefficient", "manoeuvre": "fly thrust changes"},
    "theta_1": {"unit": "rad/(s^2 (rad/s)^2)", "key": "inertia", "manoeuvre": "fly roll doublets"},
    "theta_2": {"unit": "rad/(s^2 (rad/s)^2)", "key": "moment_coefficient", "manoeuvre": "fly yaw steps"},
    "theta_3": {"unit": "-", "key": "inertia", "manoeuvre": "fly yaw steps while rolling and pitching"},
    "accel_bias": {"unit": "m/s^2", "key": "", "manoeuvre": "record the IMU (imu0)"},
}


@dataclass(frozen=True)
class AxisExcitation:
    """How much a flight moved about one body axis (samples used by the fits).

    Attributes
    ----------
    rate_std : rad/s, standard deviation of the body rate after a :data:`LOWPASS_S` average
    acc_std : rad/s^2, standard deviation of the angular acceleration after the same average
    share : -, share of the angular acceleration's variance explained by the rotor-torque column
    """

    rate_std: float
    acc_std: float
    share: float = float("nan")

    def to_dict(self) -> dict[str, float]:
        return {"rate_std": self.rate_std, "acc_std": self.acc_std, "share": self.share}


@dataclass(frozen=True)
class ParameterStatus:
    """One constant: its estimate, and whether the flight determines it.

    Attributes
    ----------
    name : ``k_T``, ``k_M``, ``J_x`` ... (keys of :data:`PARAMETERS`)
    value, stderr : float, or (3,) for ``accel_bias``; the raw least-squares estimate
    identifiable : whether it can be used as a result
    reason : ``identified`` or one of :data:`PRECEDENCE`
    why : the findings in words ("" when identified)
    """

    name: str
    value: Any
    stderr: Any
    identifiable: bool
    reason: str
    why: str = ""

    @property
    def unit(self) -> str:
        return PARAMETERS[self.name]["unit"]

    def advice(self) -> str:
        """What would determine it: the manoeuvre, or the vehicle.yaml key that can stand in (the rotor angles in the
        columns' order, for columns out of order)."""
        if self.reason == OUT_OF_ORDER:
            return REORDER
        p = PARAMETERS[self.name]
        return f"{p['manoeuvre']} or give {p['key']} in vehicle.yaml" if p["key"] else p["manoeuvre"]

    def to_dict(self) -> dict[str, Any]:
        def plain(x):
            if x is None:
                return None
            if np.ndim(x):
                return [plain(v) for v in np.asarray(x, float)]
            return float(x) if np.isfinite(x) else None

        return {"value": plain(self.value), "stderr": plain(self.stderr), "identifiable": self.identifiable,
                "reason": self.reason, "why": self.why}


def axis_excitation(rates: Sequence[np.ndarray], accelerations: Sequence[np.ndarray], masks: Sequence[np.ndarray],
                    dts: Sequence[float]) -> dict[str, AxisExcitation]:
    """Excitation per body axis over several flights.

    Parameters
    ----------
    rates : per flight (K, 3) rad/s, body rates
    accelerations : per flight (K, 3) rad/s^2, body angular accelerations
    masks : per flight (K,) bool, the samples the fits use
    dts : per flight, s, sampling step
    """
    w_lp, a_lp = [], []
    for w, a, m, dt in zip(rates, accelerations, masks, dts):
        n = max(1, int(round(LOWPASS_S / dt)))
        w_lp.append(uniform_filter1d(np.asarray(w, float), n, axis=0, mode="nearest")[m])
        a_lp.append(uniform_filter1d(np.asarray(a, float), n, axis=0, mode="nearest")[m])
    W, A = np.concatenate(w_lp), np.concatenate(a_lp)
    return {ax: AxisExcitation(float(np.std(W[:, i])), float(np.std(A[:, i]))) for i, ax in enumerate(AXES)}


def column_share(coef: float, column: np.ndarray, target: np.ndarray) -> float:
    """Share of ``target``'s variance that ``coef * column`` carries (may exceed 1 with cancelling terms)."""
    var = float(np.var(target))
    return float(np.var(coef * np.asarray(column, float)) / var) if var > 0 else float("nan")


@dataclass
class _Findings:
    """Findings on one constant, gathered before the status is decided."""

    items: list[tuple[str, str]] = field(default_factory=list)

    def add(self, reason: str, why: str) -> None:
        self.items.append((reason, why))

    def status(self, name: str, value: Any, stderr: Any) -> ParameterStatus:
        """Identified when nothing was found; else the reason of highest precedence, and the first
        finding of each reason in words."""
        if not self.items:
            return ParameterStatus(name, value, stderr, True, IDENTIFIED)
        ordered = sorted(self.items, key=lambda rw: PRECEDENCE.index(rw[0]))
        first: dict[str, str] = {}
        for reason, why in ordered:
            first.setdefault(reason, why)
        return ParameterStatus(name, value, stderr, False, ordered[0][0], "; ".join(first.values()))


def _not_excited(f: _Findings, ex: dict[str, AxisExcitation], axes: Sequence[tuple[str, str]]) -> None:
    """One finding per axis that lacks the motion: ``axes`` lists ``(axis, "rate" | "acc")``."""
    missing: dict[str, list[str]] = {}
    for axis, kind in axes:
        e = ex[axis]
        if kind == "rate" and e.rate_std < RATE_MIN:
            missing.setdefault(axis, []).append(f"{axis} rate std {e.rate_std:.2g} rad/s, under {RATE_MIN:g}")
        if kind == "acc" and e.acc_std < ACC_MIN:
            missing.setdefault(axis, []).append(f"{axis} acceleration std {e.acc_std:.2g} rad/s^2, under {ACC_MIN:g}")
    for axis, what in missing.items():
        f.add(NOT_EXCITED, f"the flight has no {axis} manoeuvre ({'; '.join(what)})")


def _conditioning(f: _Findings, value: float, stderr: float, conds: dict[str, float], fits: Sequence[str]) -> None:
    if not np.isfinite(value) or not np.isfinite(stderr):
        if not f.items:  # a constant left out of the fit for want of excitation says so already
            f.add(ILL_CONDITIONED, "the regression gives no finite estimate")
        return
    if value != 0 and stderr / abs(value) > REL_SE_MAX:
        f.add(ILL_CONDITIONED, f"relative standard error {stderr / abs(value):.2g} (above {REL_SE_MAX:g})")
    for fit in fits:
        c = conds.get(fit, 0.0)
        if c > COND_MAX:
            f.add(ILL_CONDITIONED, f"condition number {c:.2g} of the {fit} regression (above {COND_MAX:g}): its "
                                   f"columns are nearly collinear")


def _share(f: _Findings, ex: dict[str, AxisExcitation], axis: str) -> None:
    """A slope on the rotor-torque column about ``axis`` whose column carries too little of the variance."""
    s = ex[axis].share
    if np.isfinite(s) and s < SHARE_MIN:
        f.add(ILL_CONDITIONED, f"the rotor-torque column carries {100 * s:.2g} % of the {axis} acceleration's variance "
                               f"(under {100 * SHARE_MIN:.0f} %): with noise in the recorded rotor speeds the slope "
                               f"could be up to {1 / max(s, 1e-3):.2g} times the estimate")


def _why_too_large(times: float, ex: AxisExcitation, order: RotorOrder | None = None) -> str:
    """Why an inertia ``times`` its physical bound may have been read.

    Where the flight tells the rotor columns' order (``order``, :func:`~uavturb.sysid.rotor_order.rotor_order`), what
    it says: columns in another order, named; or vehicle.yaml's order, beside what noise in the rotor-torque column
    allows (:func:`_share`: the slope under the estimate by up to ``1 / share``, the inertia over it as much). A
    Neural-Swarm take-off read 2.9 times the bound, its share allowing 2.8 times, and had been asked whether its
    columns were in another order: its order leads the best of the 23 others by 0.7 in correlation.

    Where it does not tell: the column's noise where its share of the variance allows that much, else rotor columns
    in another order than the angles; both where the column carries almost nothing (under :data:`SHARE_TELLS`),
    which columns in another order do too. A Neural-Swarm walk's commanded speeds (share 15 %: up to 6.6 times) read
    4.5 times the bound and had been asked about their order; the same walk with its columns shifted by one reads 47
    times it, its share under 1 %."""
    s = ex.share
    noise_allows = bool(np.isfinite(s) and s < SHARE_MIN and times <= 1.0 / max(s, 1e-3))
    if order is not None and order.verdict == OTHER_ORDER:  # the finding OUT_OF_ORDER says what the flight tells
        which = "which order the flight does not tell" if order.alike else f"read as {order.columns()}"
        return f"{times:.2g} times it: rotor columns out of order, {which}"
    if order is not None and order.verdict == GIVEN_ORDER:
        noise = (f"within what noise in the recorded rotor speeds does to the slope (up to {1 / s:.2g} times)"
                 if noise_allows else
                 "more than noise in the recorded rotor speeds does to the slope by their share of the variance alone"
                 + (f" (up to {1 / s:.2g} times)" if np.isfinite(s) and s > 0 else ""))
        return f"{times:.2g} times it: {noise}; {order.sentence()}"
    if not noise_allows:
        return "rotor columns in another order than vehicle.yaml's angles?"
    if s < SHARE_TELLS:
        return (f"{times:.2g} times it: noise in the recorded rotor speeds, whose torque column carries "
                f"{100 * s:.2g} % of the acceleration's variance, or rotor columns in another order than "
                "vehicle.yaml's angles?")
    return (f"{times:.2g} times it: within what noise in the recorded rotor speeds does to the slope "
            f"(up to {1 / s:.2g} times)")


def _inherit(f: _Findings, name: str, status: dict[str, ParameterStatus], deps: Sequence[str]) -> None:
    """A constant that looks sound itself but is computed from one that is not identified takes that
    one's reason (its first finding)."""
    if f.items:
        return
    for d in deps:
        s = status[d]
        if not s.identifiable:
            f.add(s.reason, f"{name} is computed from {d}, and {s.why.split('; ')[0]}")
            return


def assess(est: dict[str, Any], se: dict[str, Any], excitation: dict[str, AxisExcitation], conds: dict[str, float],
           *, has_imu: bool, mass: float, arm_length: float, rotor_radius: float,
           jx_equals_jy: bool, rotor_order: RotorOrder | None = None) -> dict[str, ParameterStatus]:
    """The status of every constant of :data:`PARAMETERS`.

    Parameters
    ----------
    est, se : estimates and standard errors by name (``accel_bias``: (3,) arrays)
    excitation : :func:`axis_excitation` per axis (``share`` filled in)
    conds : condition numbers by fit: ``thrust``, ``roll``, ``pitch``, ``yaw``
    has_imu : whether an accelerometer was recorded
    mass : kg; arm_length, rotor_radius : m (the physical bounds)
    jx_equals_jy : the paper's ``J_x = J_y`` model was fitted (roll or pitch excites both)
    rotor_order : what the flight says of the rotor columns' order (:func:`~uavturb.sysid.rotor_order.rotor_order`),
        where read: an inertia above its physical bound says why from it
    """
    ex = dict(excitation)
    if jx_equals_jy:  # one joint fit: the better-excited of roll and pitch serves both
        best = max((ex["roll"], ex["pitch"]), key=lambda e: min(e.rate_std / RATE_MIN, e.acc_std / ACC_MIN))
        ex["roll"] = ex["pitch"] = best
    j_max = mass * (arm_length + rotor_radius) ** 2  # kg m^2, all the mass at the propeller tips
    a = _Assessment(est, se, ex, conds, j_max, jx_equals_jy, rotor_order)
    a.thrust()
    a.roll_and_pitch()
    a.yaw(rotor_radius)
    a.accel_bias(has_imu)
    return {name: a.out[name] for name in PARAMETERS}


@dataclass
class _Assessment:
    """The statuses of :func:`assess`, decided in order: a constant computed from others inherits
    their reason, so those come first."""

    est: dict[str, Any]
    se: dict[str, Any]
    ex: dict[str, AxisExcitation]
    conds: dict[str, float]
    j_max: float  # kg m^2, the physical bound on an inertia
    jx_equals_jy: bool
    rotor_order: RotorOrder | None = None
    out: dict[str, ParameterStatus] = field(default_factory=dict)

    def _decide(self, name: str, f: _Findings) -> None:
        order = self.rotor_order
        if name in FROM_TORQUES and order is not None and order.verdict == OTHER_ORDER:
            f.add(OUT_OF_ORDER, order.sentence())
        self.out[name] = f.status(name, self.est[name], self.se[name])

    def _positive(self, f: _Findings, name: str, what: str) -> None:
        if np.isfinite(self.est[name]) and not self.est[name] > 0:
            f.add(IMPOSSIBLE, f"{what} {self.est[name]:.3g} is not positive{self._directions_reversed(name)}")

    def _directions_reversed(self, name: str) -> str:
        """Where a yaw slope (``theta_2``, ``k_M``) is negative by :data:`REVERSED_Z` standard errors or more, why
        (the yaw acceleration follows the rotors' drag torques turned the other way, as with ``rotor_directions`` in
        the other sign convention, ``+1`` counter-clockwise seen from above), as a clause; else ''. Said only where
        the yaw excites it (a held heading's slope is noise)."""
        value, stderr = self.est[name], self.se[name]
        excited = self.ex["yaw"].rate_std >= RATE_MIN and self.ex["yaw"].acc_std >= ACC_MIN
        if name not in ("theta_2", "k_M") or not excited or not (np.isfinite(value) and np.isfinite(stderr)
                                                                  and 0 < stderr < -value / REVERSED_Z):
            return ""
        return (f" ({-value / stderr:.0f} standard errors under zero: the yaw acceleration follows the rotors' drag "
                "torques turned the other way, as with vehicle.yaml's rotor_directions reversed; +1 is "
                "counter-clockwise seen from above)")

    def _inertia_bound(self, f: _Findings, name: str) -> None:
        if np.isfinite(self.est[name]) and self.est[name] > self.j_max:
            f.add(IMPOSSIBLE, f"{self.est[name]:.3g} kg m^2 exceeds m (l + r)^2 = {self.j_max:.3g} kg m^2, the "
                              "inertia of the whole mass at the propeller tips")

    def thrust(self) -> None:
        """``k_T`` and ``theta_0 = k_T / m``."""
        f = _Findings()
        _conditioning(f, self.est["k_T"], self.se["k_T"], self.conds, ["thrust"])
        self._positive(f, "k_T", "the thrust coefficient")
        self._decide("k_T", f)
        f = _Findings()
        _inherit(f, "theta_0", self.out, ["k_T"])
        self._decide("theta_0", f)

    def roll_and_pitch(self) -> None:
        """``theta_1 = l k_T / J_x``, ``J_x`` and ``J_y``."""
        est, se, ex = self.est, self.se, self.ex
        for name, theta, axis in (("J_x", "theta_1", "roll"), ("J_y", None, "pitch")):
            fits = ["roll", "pitch"] if self.jx_equals_jy else [axis]
            if theta is not None:
                f = _Findings()
                _not_excited(f, ex, [(axis, "rate"), (axis, "acc")])
                _conditioning(f, est[theta], se[theta], self.conds, fits)
                _share(f, ex, axis)
                self._positive(f, theta, theta)
                if np.isfinite(est[name]) and est[name] > self.j_max:  # what it says of the vehicle is impossible
                    why = _why_too_large(est[name] / self.j_max, ex[axis], self.rotor_order)
                    f.add(IMPOSSIBLE, f"it puts {name} = l k_T / {theta} at {est[name]:.3g} kg m^2, above m (l + r)^2 "
                                      f"= {self.j_max:.3g} kg m^2 ({why})")
                self._decide(theta, f)
            f = _Findings()
            _not_excited(f, ex, [(axis, "rate"), (axis, "acc")])
            _conditioning(f, est[name], se[name], self.conds, fits)
            _share(f, ex, axis)
            self._positive(f, name, "the inertia")
            self._inertia_bound(f, name)
            _inherit(f, name, self.out, ["k_T"])
            self._decide(name, f)

    def yaw(self, rotor_radius: float) -> None:
        """``J_z`` (then the triangle inequality of the three inertias), ``theta_2 = k_M / J_z``,
        ``theta_3 = J_z / J_x`` and ``k_M`` (at most ``k_T r``, ``rotor_radius`` r [m])."""
        est, se, ex = self.est, self.se, self.ex
        f = _Findings()
        _not_excited(f, ex, [("yaw", "rate")])
        _conditioning(f, est["J_z"], se["J_z"], self.conds, ["roll", "pitch"])
        self._positive(f, "J_z", "the inertia")
        self._inertia_bound(f, "J_z")
        _inherit(f, "J_z", self.out, ["J_x", "J_y"])
        self._decide("J_z", f)
        _triangle(self.out, se)

        f = _Findings()
        _not_excited(f, ex, [("yaw", "rate"), ("yaw", "acc")])
        _conditioning(f, est["theta_2"], se["theta_2"], self.conds, ["yaw"])
        _share(f, ex, "yaw")
        self._positive(f, "theta_2", "theta_2")
        self._decide("theta_2", f)
        f = _Findings()
        _not_excited(f, ex, [("yaw", "rate")])
        _conditioning(f, est["theta_3"], se["theta_3"], {}, [])
        _inherit(f, "theta_3", self.out, ["J_z", "J_x"])
        self._decide("theta_3", f)

        f = _Findings()
        _not_excited(f, ex, [("yaw", "rate"), ("yaw", "acc")])
        _conditioning(f, est["k_M"], se["k_M"], self.conds, ["yaw"])
        self._positive(f, "k_M", "the moment coefficient")
        if est["k_M"] > 0 and est["k_T"] > 0 and est["k_M"] > est["k_T"] * rotor_radius:
            f.add(IMPOSSIBLE, f"k_M {est['k_M']:.3g} exceeds k_T r = {est['k_T'] * rotor_radius:.3g}: a rotor whose "
                              "drag torque exceeds thrust times radius")
        _inherit(f, "k_M", self.out, ["theta_2", "J_z"])
        self._decide("k_M", f)

    def accel_bias(self, has_imu: bool) -> None:
        """The accelerometer bias: absent without an IMU."""
        se = self.se
        f = _Findings()
        if not has_imu:
            f.add(ABSENT, "the recording has no IMU (imu0), so no accelerometer and no bias to estimate")
        elif np.any(~np.isfinite(se["accel_bias"])) or np.max(se["accel_bias"]) > BIAS_SE_MAX:
            f.add(ILL_CONDITIONED, f"standard error {np.max(se['accel_bias']):.2g} m/s^2 (above {BIAS_SE_MAX:g}; with "
                                   "several recordings it covers the spread of their own biases, listed apart)")
        self.out["accel_bias"] = (f.status("accel_bias", self.est["accel_bias"], se["accel_bias"]) if has_imu
                                  else f.status("accel_bias", None, None))


def _triangle(out: dict[str, ParameterStatus], se: dict[str, Any]) -> None:
    """Withdraw the least certain inertia when the three break ``J_k <= J_i + J_j`` (in place)."""
    names = ("J_x", "J_y", "J_z")
    if not all(out[n].identifiable for n in names):
        return
    J = np.array([out[n].value for n in names], float)
    s = np.array([se[n] for n in names], float)
    for k in range(3):
        i, j = [n for n in range(3) if n != k]
        excess = J[k] - (1.0 + TRIANGLE_SLACK) * (J[i] + J[j])
        if excess > 2.0 * float(np.sqrt(s[k] ** 2 + s[i] ** 2 + s[j] ** 2)):
            rel = s / np.abs(J)
            worst = k if rel[k] >= rel.max() * (1 - 1e-9) else int(np.argmax(rel))
            why = (f"{names[k]} = {J[k]:.3g} > {1 + TRIANGLE_SLACK:g} ({names[i]} + {names[j]}) = "
                   f"{(1 + TRIANGLE_SLACK) * (J[i] + J[j]):.3g} kg m^2 breaks the triangle inequality of principal "
                   f"moments; {names[worst]} is the least certain of the three")
            old = out[names[worst]]
            out[names[worst]] = ParameterStatus(old.name, old.value, old.stderr, False, IMPOSSIBLE, why)
            return
