"""The named physical effects of ``effects.md``: laws, parameters, and a parser.

Every effect is a force [N] in the world frame W added to the nominal model of
``recordings.md``; ``motor_lag`` instead changes the rotor speeds the model sees, and
``battery_sag`` the thrust (written here as the equivalent world force, as ``effects.md``
does). Names and parameter names are an interface: configs, reports and tests use them
verbatim.

Symbols (``effects.md``): ``T = k_T sum(w_i^2)`` thrust with the actual rotor speeds,
``Wsum = sum(w_i)``, ``R = R(q)``, ``v`` world velocity, ``v_B = R^T v``, ``r`` rotor
radius, ``d_down`` / ``d_up`` heights to the surfaces below / above, ``t`` seconds since
the recording's start.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from uavturb.errors import InputError
from uavturb.numerics.filters import first_order_lag
from uavturb.physics import ground_effect as ge
from uavturb.physics import quaternion as quat
from uavturb.physics.constants import GRAVITY
from uavturb.physics.vehicle import QUADROTOR


@dataclass
class EffectInputs:
    """What the laws need, over ``K`` samples.

    Attributes
    ----------
    q : (K, 4) quaternion w, x, y, z, body to world (or None with ``R`` given)
    v : (K, 3) m/s, world velocity
    rotor_speeds : (K, N) rad/s, actual rotor speeds
    k_T : float, N/(rad/s)^2
    rotor_radius : float, m
    d_down, d_up : (K,) m, ``inf`` where there is no surface
    t : (K,) s since the recording's start
    R : (K, 3, 3) body-to-world rotations; computed from ``q`` when not given
    arm_length : m, centre to each rotor hub (laws that use the rotor spacing; None where unknown)
    voltage_dev : (K,) V, the battery's voltage (``battery0``) minus its mean over the recording's flight
    """

    q: np.ndarray | None
    v: np.ndarray
    rotor_speeds: np.ndarray
    k_T: float
    rotor_radius: float
    d_down: np.ndarray | None = None
    d_up: np.ndarray | None = None
    t: np.ndarray | None = None
    R: np.ndarray | None = field(default=None, repr=False)
    arm_length: float | None = None
    voltage_dev: np.ndarray | None = None

    def __post_init__(self) -> None:
        if self.R is None:
            if self.q is None:
                raise InputError("effects", "EffectInputs needs q or R")
            self.R = quat.to_rotation_matrix(self.q)

    @property
    def K(self) -> int:
        return len(self.v)

    @property
    def thrust(self) -> np.ndarray:
        """(K,) N, ``T = k_T sum(w_i^2)``."""
        return self.k_T * np.sum(np.asarray(self.rotor_speeds, float) ** 2, axis=1)

    @property
    def z_body(self) -> np.ndarray:
        """(K, 3) body ``+z`` axis in W, ``R e_z``."""
        return self.R[:, :, 2]

    def need(self, name: str, what: str) -> np.ndarray:
        value = getattr(self, what)
        if value is None:
            raise InputError(name, f"this effect needs '{what}', which the recording does not provide")
        return np.asarray(value, float)


def _surface_force(d: np.ndarray, thrust: np.ndarray, coeff: float, r: float) -> np.ndarray:
    """``e_z T rho/(1-rho)``, ``rho = coeff (r/(4 d))^2``, with the paper's clip (ground_effect.phi)."""
    f = ge.phi(d, thrust, coeff, r)
    out = np.zeros((len(f), 3))
    out[:, 2] = f
    return out


def ground_effect_force(x: EffectInputs, mu: float) -> np.ndarray:
    """Cheeseman-Bennett ground effect: ``F = e_z T rho/(1-rho)``, ``rho = mu (r/(4 d_down))^2``."""
    return _surface_force(x.need("ground_effect", "d_down"), x.thrust, mu, x.rotor_radius)


def ground_effect_multirotor_force(x: EffectInputs, K_b: float) -> np.ndarray:
    """Sanchez-Cuevas et al.'s multirotor ground effect: ``F = e_z T (T_IGE/T_OGE - 1)`` with the ratio of
    :func:`uavturb.physics.ground_effect.multirotor_thrust_ratio` at ``d_down`` (rotor spacing from
    ``arm_length`` and the rotor count); :data:`~uavturb.physics.ground_effect.CLIP_FORCE_N` at and
    under the law's pole, as the Cheeseman-Bennett law is clipped."""
    d = x.need("ground_effect_multirotor", "d_down")
    arm = float(x.need("ground_effect_multirotor", "arm_length"))
    spacing, opposite = ge.rotor_spacing(arm, np.shape(x.rotor_speeds)[1])
    ratio = ge.multirotor_thrust_ratio(d, K_b, x.rotor_radius, spacing, opposite)
    out = np.zeros((len(d), 3))
    out[:, 2] = np.where(np.isnan(ratio), ge.CLIP_FORCE_N, x.thrust * (np.nan_to_num(ratio, nan=1.0) - 1.0))
    return out


def ground_effect_exponential_force(x: EffectInputs, A: float, lam: float) -> np.ndarray:
    """Ground effect decaying exponentially with height: ``F = e_z T A exp(-d_down / (lam r))``
    (:func:`uavturb.physics.ground_effect.exponential_thrust_ratio`); at and under the surface
    (``d_down <= 0``, ground contact) the law's value at the surface, ``A T``."""
    d = np.maximum(x.need("ground_effect_exponential", "d_down"), 0.0)
    out = np.zeros((len(d), 3))
    out[:, 2] = x.thrust * (np.nan_to_num(ge.exponential_thrust_ratio(np.maximum(d, 1e-12), A, lam, x.rotor_radius),
                                          nan=1.0) - 1.0)
    return out


def ceiling_effect_force(x: EffectInputs, kappa: float) -> np.ndarray:
    """Ceiling effect: ``F = e_z T rho/(1-rho)``, ``rho = kappa (r/(4 d_up))^2``. Clipped like the
    ground effect (``effects.md`` gives no clip for it; the pole is the same)."""
    return _surface_force(x.need("ceiling_effect", "d_up"), x.thrust, kappa, x.rotor_radius)


def rotor_drag_force(x: EffectInputs, k_d: float) -> np.ndarray:
    """Rotor drag (blade flapping, induced drag): ``F = -k_d Wsum R [v_B,x, v_B,y, 0]`` (RotorS)."""
    vB = np.einsum("kji,kj->ki", x.R, np.asarray(x.v, float))
    vB[:, 2] = 0.0
    wsum = np.sum(np.asarray(x.rotor_speeds, float), axis=1)
    return -k_d * wsum[:, None] * np.einsum("kij,kj->ki", x.R, vB)


def body_drag_force(x: EffectInputs, c_d: float) -> np.ndarray:
    """Quadratic parasitic drag: ``F = -c_d |v| v``."""
    v = np.asarray(x.v, float)
    return -c_d * np.linalg.norm(v, axis=1, keepdims=True) * v


def wind_force(x: EffectInputs, f_x: float, f_y: float) -> np.ndarray:
    """A steady horizontal push ``F = (f_x, f_y, 0)``."""
    out = np.zeros((x.K, 3))
    out[:, 0], out[:, 1] = f_x, f_y
    return out


def battery_sag_force(x: EffectInputs, s: float) -> np.ndarray:
    """Thrust coefficient decaying as ``k_T (1 - s t)``: ``F = -s t T R e_z``."""
    t = x.need("battery_sag", "t")
    return -(s * t * x.thrust)[:, None] * x.z_body


def battery_voltage_force(x: EffectInputs, k_V: float) -> np.ndarray:
    """Thrust coefficient following the battery's voltage as ``k_T (1 + k_V (V - V_mean))``:
    ``F = k_V (V - V_mean) T R e_z``, with ``V_mean`` the recording's mean voltage in flight (its level is the
    recording's thrust level). A motor driven at a duty cycle turns at a speed proportional to duty times
    voltage (DC motor, back-EMF), so thrust per commanded speed squared goes as ``V^2``: ``k_V V = 2``."""
    dv = x.need("battery_voltage", "voltage_dev")
    return (k_V * dv * x.thrust)[:, None] * x.z_body


def lag_rotor_speeds(t: np.ndarray, w_cmd: np.ndarray, tau: float,
                     stretches: list[tuple[int, int, float | None]] | None = None) -> np.ndarray:
    """Actual rotor speeds under first-order lag ``tau dw/dt = w_cmd - w``.

    Exact discretisation for commands held between samples (zero-order hold), started at
    ``w(t_0) = w_cmd(t_0)``: ``w_k = a_k w_{k-1} + (1 - a_k) w_cmd_{k-1}``, ``a_k = exp(-dt_k / tau)``.

    Parameters
    ----------
    t : (K,) s, increasing
    w_cmd : (K, N) rad/s, the recorded (commanded) speeds
    tau : s, time constant (0 returns the commands)
    stretches : :func:`lag_stretches` of ``t``, where the caller filters the same times at many ``tau``
        (computed here otherwise; the result is the same)

    Notes
    -----
    The recurrence runs vectorised (:func:`uavturb.numerics.filters.first_order_lag`) on each
    stretch between dropouts (steps over :data:`LAG_GAP` times the median step; the lag restarts
    from the command after one, as it has long settled). On a stretch whose steps are jittered by
    less than :data:`LAG_JITTER` of their mean the filter uses the mean step: the error is of the order of the
    jitter times the lag's own small effect. Stretches jittered more run the exact loop over time.
    """
    w_cmd = np.asarray(w_cmd, float)
    if tau <= 0 or len(w_cmd) < 2:
        return w_cmd.copy()
    t = np.asarray(t, float)
    out = np.empty_like(w_cmd)
    for a, b, mean in lag_stretches(t) if stretches is None else stretches:
        _lag_stretch(t[a:b], w_cmd[a:b], tau, mean, out[a:b])
    return out


#: a step over this many median steps is a dropout (the lag restarts from the command after it)
LAG_GAP = 3.0
#: relative spread of the steps under which a stretch is filtered with its mean step
LAG_JITTER = 0.25


def lag_stretches(t: np.ndarray) -> list[tuple[int, int, float | None]]:
    """The stretches ``[a, b)`` of the times ``t`` (K,) [s] between dropouts (:func:`lag_rotor_speeds`),
    each with its mean step [s] where its steps are jittered by less than :data:`LAG_JITTER` (None where
    the exact loop over time must run). They depend on the times only: a filter at many ``tau`` finds
    them once."""
    t = np.asarray(t, float)
    if len(t) < 2:
        return [(0, len(t), None)]
    dt = np.diff(t)
    breaks = np.flatnonzero(dt > LAG_GAP * float(np.median(dt))) + 1
    out = []
    for a, b in zip(np.r_[0, breaks], np.r_[breaks, len(t)]):
        d = dt[a:b - 1]  # the steps inside the stretch (np.diff(t[a:b]))
        mean = float(d.mean()) if len(d) else float("nan")
        out.append((int(a), int(b), mean if len(d) and float(np.std(d)) <= LAG_JITTER * mean else None))
    return out


def _lag_stretch(t: np.ndarray, w_cmd: np.ndarray, tau: float, mean: float | None, out: np.ndarray) -> None:
    """:func:`lag_rotor_speeds` on one stretch without dropouts (``mean``: its even step [s], or None), written
    into ``out`` (the stretch's rows of the output)."""
    out[0] = w_cmd[0]
    if len(t) < 2:
        return
    if mean is not None:
        ak = float(np.exp(-mean / tau))
        # w_k = a w_{k-1} + (1 - a) w_cmd_{k-1}: the input delayed by one sample
        first_order_lag(w_cmd[:-1], ak, w_cmd[0], out=out[1:])
        return
    a = np.exp(-np.diff(t) / tau)
    for k in range(1, len(w_cmd)):
        out[k] = a[k - 1] * out[k - 1] + (1 - a[k - 1]) * w_cmd[k - 1]


def motor_lag_force(x: EffectInputs, tau: float) -> np.ndarray:
    """The thrust change from lagging rotors, as a world force: ``R e_z k_T sum(w_lag^2 - w_cmd^2)``,
    with ``x.rotor_speeds`` the recorded commands."""
    t = x.need("motor_lag", "t")
    w_cmd = np.asarray(x.rotor_speeds, float)
    w_act = lag_rotor_speeds(t, w_cmd, tau)
    dT = x.k_T * np.sum(w_act**2 - w_cmd**2, axis=1)
    return dT[:, None] * x.z_body


@dataclass(frozen=True)
class FlightFacts:
    """What explanations and physical ranges may refer to: facts measured on the recordings at
    hand (never assumed), so every sentence written about an effect holds for these flights.

    Attributes
    ----------
    mass : kg; rotor_count : -; rotor_radius : m
    k_T : N/(rad/s)^2, thrust coefficient identified on the flights
    wsum_hover : rad/s, sum of the rotor speeds at hover, ``n sqrt(m g / (n k_T))``
    speed_p90 : m/s, 90th percentile of the horizontal speed
    heading_span_deg : deg, range of headings flown (0 when the heading never changed)
    has_imu : an accelerometer was recorded (so an accelerometer bias exists)
    d_down_min, d_up_min : m, closest approach to the surface below / above (inf: none known)
    duration_s : s, flight time analysed
    bias_anchored : the accelerometer bias was measured against motion capture (not fitted)
    arm_length : m, centre to rotor hub (sizes the airframe for physical ranges)
    torque_lag_s, torque_lag_stderr_s : s, how far the roll and pitch torques of commanded rotor speeds lag them,
        timed on the angular acceleration (:func:`uavturb.sysid.command_lag.command_lag`), and its error (nan where
        not read: measured or held speeds)
    voltage_mean, voltage_span : V, the battery's mean voltage in flight and the range its middle 90 % of rows
        span (``battery0``; nan where a recording has none)
    """

    mass: float
    rotor_count: int
    rotor_radius: float
    k_T: float
    wsum_hover: float
    speed_p90: float
    heading_span_deg: float
    has_imu: bool
    d_down_min: float
    d_up_min: float
    duration_s: float
    bias_anchored: bool = False
    arm_length: float = float("nan")
    voltage_mean: float = float("nan")
    voltage_span: float = float("nan")
    torque_lag_s: float = float("nan")
    torque_lag_stderr_s: float = float("nan")


@dataclass(frozen=True)
class PhysicalRange:
    """The range a fitted effect must lie in to be a discovery (``effects.md``: "a fit outside
    it is not a discovery"), stated on one physical quantity derived from the parameters.

    Attributes
    ----------
    quantity : str, what is compared, with its unit
    lo, hi : float, bounds of ``quantity``
    of : callable ``(params, FlightFacts) -> float``, the quantity of fitted parameters
    source : str, where the range comes from
    """

    quantity: str
    lo: float
    hi: float
    of: Callable[[dict, FlightFacts], float]
    source: str

    def violation(self, params: dict[str, float], facts: FlightFacts) -> str | None:
        """None inside the range, else one sentence saying where the fit lies."""
        q = float(self.of(params, facts))
        if self.lo <= q <= self.hi and np.isfinite(q):
            return None
        return (f"{self.quantity} = {q:.3g} lies outside its physical range [{self.lo:.3g}, {self.hi:.3g}] "
                f"({self.source})")


@dataclass(frozen=True)
class EffectSpec:
    """One entry of the ``effects.md`` vocabulary, declared once: the law, its parameters with
    units and typical values, how the gap finder fits it, its physical range with a source, and
    the sentences written about it (from :class:`FlightFacts` only).

    Attributes
    ----------
    name : str
    params : tuple of str, parameter names (verbatim from ``effects.md``)
    units : tuple of str, their units
    typical : tuple of float, magnitudes seen on 1-2 kg multirotors (defaults)
    force : callable ``(EffectInputs, **params) -> (K, 3)`` world force [N]
    linear : bool, force linear in the parameters (a linear least-squares fit suffices)
    summary : str, one line
    physical_range : PhysicalRange
    explain : callable ``(params, FlightFacts) -> str``, one or two sentences
    search : (lo, hi) bounds of the 1-D search of a nonlinear parameter (None for linear laws)
    along_thrust : the force acts along the rotor axis (it scales or lags the thrust)
    surface : ``"d_down"`` / ``"d_up"`` for surface effects (they need flights near that surface)
    positive : the parameters are positive by physics
    manoeuvre : str, the flight that excites this effect apart from the others (for ``ambiguous``)
    ratio : surface laws only: ``(d, param, r, **geometry) -> T_IGE/T_OGE`` [-], the thrust per rotor
        speed squared over its value far from the surface at rotor-plane height ``d`` [m] (``nan``
        where the law does not hold); ``param`` is the parameter's value, or the tuple of all of them
        for a law with several (in ``params``' order); ``geometry`` holds ``arm_length`` [m] and
        ``rotor_count`` (laws that do not need them ignore them). Used by :mod:`uavturb.gap.surface_laws`.
    bounds : surface laws with several parameters: the ``(lo, hi)`` bounds of each (in ``params``' order)
        within which a fit to the measured curve searches (one-parameter laws use ``search``)
    alternative_to : another law of the same physics (``ground_effect_multirotor`` for ``ground_effect``):
        the finder names at most one of them, the alternative only where it beats the other on
        held-out data beyond noise
    absent_at_zero : parameters all zero mean no effect (False for the multirotor law, whose rotor images
        act at ``K_b = 0``): only then does a parameter within noise of zero say the effect is not there
    thrust_factor : a law that scales the thrust coefficient as ``k_T (1 + p x)`` (battery sag, ``x = -t``; the
        battery's voltage, ``x = V - V_mean``): ``(EffectInputs) -> x`` (K,); the finder fits ``k_T*p`` as a column
        along the thrust (it follows the motor lag's speeds); None for every other law
    simulated : the simulator applies it as a force of its physics (``battery_voltage`` is what logged commands
        mean on a sagging battery: ``generate flight`` writes it into the commands, and ``gap --apply`` leaves it
        out of a physics config)
    amplitude : a surface law with two parameters whose ``ratio - 1`` is proportional to one of them (the
        exponential law's ``A``): the finder fits that one by least squares, as a column along the thrust whose
        coefficient carries ``k_T`` (``k_T*A``, as battery sag's ``k_T*s``), and searches the other over
        ``search``; None for every other law
    """

    name: str
    params: tuple[str, ...]
    units: tuple[str, ...]
    typical: tuple[float, ...]
    force: Callable[..., np.ndarray]
    linear: bool
    summary: str
    physical_range: PhysicalRange
    explain: Callable[[dict, FlightFacts], str]
    search: tuple[float, float] | None = None
    along_thrust: bool = False
    surface: str | None = None
    positive: bool = True
    manoeuvre: str = ""
    ratio: Callable[..., np.ndarray] | None = None
    alternative_to: str | None = None
    absent_at_zero: bool = True
    bounds: tuple[tuple[float, float], ...] = ()
    amplitude: str | None = None
    thrust_factor: Callable[[EffectInputs], np.ndarray] | None = None
    simulated: bool = True

    @property
    def presence_params(self) -> tuple[str, ...]:
        """The parameters whose distance from zero says whether the effect is there: the ``amplitude`` of a law
        that has one (the exponential law's decay length is never near zero, whatever the lift), else all."""
        return (self.amplitude,) if self.amplitude is not None else self.params

    @property
    def searched_param(self) -> str:
        """The parameter a nonlinear law's fit searches over ``search``: the one that is not its ``amplitude``."""
        return next(p for p in self.params if p != self.amplitude)

    @property
    def shape_bounds(self) -> tuple[tuple[float, float], ...]:
        """The ``(lo, hi)`` search bounds of each parameter of a surface law (``bounds``, or ``search`` for a
        one-parameter law); ``()`` for other effects."""
        return self.bounds or ((self.search,) if self.search is not None else ())

    def ratio_at(self, d: np.ndarray, values, rotor_radius: float, **geometry) -> np.ndarray:
        """(K,) -, ``T_IGE/T_OGE`` of this surface law at heights ``d`` [m] with ``values`` (a sequence in
        ``params``' order, or one number for a one-parameter law)."""
        v = np.atleast_1d(np.asarray(values, float))
        param = float(v[0]) if len(self.params) == 1 else tuple(float(x) for x in v[:len(self.params)])
        return np.asarray(self.ratio(np.asarray(d, float), param, rotor_radius, **geometry), float)

    def strongest_ratio(self, d: np.ndarray, rotor_radius: float, **geometry) -> np.ndarray:
        """(K,) -, ``T_IGE/T_OGE`` of this surface law at the top of its physical range at rotor-plane
        heights ``d`` [m] (K,): the most it could raise the thrust there (``inf`` where the law does not
        hold, e.g. inside the Cheeseman-Bennett clip). The range of a one-parameter surface law is on its one
        parameter; laws with several (their range bounds a derived quantity) have no top and give 1."""
        if self.surface is None or self.ratio is None or len(self.params) != 1:
            return np.ones(np.shape(d))
        with np.errstate(divide="ignore", invalid="ignore"):
            r = np.asarray(self.ratio(np.asarray(d, float), self.physical_range.hi, rotor_radius, **geometry), float)
        return np.where(np.isfinite(r) & (r > 0), r, np.inf)

    def surface_reach(self, rotor_radius: float, share: float = 0.01, **geometry) -> float:
        """m, the height under which this surface law, at the top of its physical range, adds at
        least ``share`` of the thrust: flights that never come closer cannot decide it.

        By bisection on the law's ``ratio`` with ``geometry`` (``arm_length``, ``rotor_count``); the
        Cheeseman-Bennett closed form without them, or where the law cannot be evaluated (arm unknown)."""
        if self.surface is None:
            return float("inf")
        if len(self.params) != 1:
            raise ValueError(f"{self.name} has several parameters: no top of its range to reach from")
        rho = share / (1.0 + share)  # rho/(1-rho) = share
        closed = rotor_radius / 4.0 * float(np.sqrt(self.physical_range.hi / rho))
        if self.ratio is None or not geometry:
            return closed
        lo, hi = np.log(rotor_radius / 4.0), np.log(1000.0 * rotor_radius)

        def extra(z: float) -> float:
            return float(self.ratio(np.array([np.exp(z)]), self.physical_range.hi, rotor_radius, **geometry)[0]) - 1.0

        if not np.isfinite(extra(hi)):
            return closed
        for _ in range(60):  # the law falls with height: the highest height where it still adds ``share``
            mid = 0.5 * (lo + hi)
            lo, hi = (mid, hi) if not np.isfinite(extra(mid)) or extra(mid) >= share else (lo, mid)
        return float(np.exp(hi))


def body_drag_max(f: FlightFacts) -> float:
    """kg/m, the largest plausible quadratic drag coefficient of the airframe: ``0.5 rho C_D A`` with
    ``rho = 1.2`` kg/m^3, ``C_D = 1.5`` and ``A = (2 (arm_length + r))^2`` m^2 (the square spanned by
    the rotor tips: no frontal area is larger); 1 kg/m where the arm length is unknown."""
    if not np.isfinite(f.arm_length):
        return 1.0
    return 0.5 * 1.2 * 1.5 * (2.0 * (f.arm_length + f.rotor_radius)) ** 2


def _heading_clause(f: FlightFacts) -> str:
    if not f.has_imu:
        return "these recordings have no accelerometer, so it is no sensor bias"
    if f.bias_anchored:
        return "the accelerometer's bias was measured against the motion capture, so it is no sensor bias"
    if f.heading_span_deg >= 30.0:
        return (f"it stays fixed in the world while the heading changed by {f.heading_span_deg:.0f} deg, "
                "so it is no accelerometer bias")
    return f"the heading changed by only {f.heading_span_deg:.0f} deg"


def _explain_ground(p: dict, f: FlightFacts) -> str:
    d = 2 * f.rotor_radius
    rho = p["mu"] * (f.rotor_radius / (4 * d)) ** 2
    return (f"Extra lift near the surface below follows the Cheeseman-Bennett law with mu = {p['mu']:.3g} "
            f"(+{100 * rho / (1 - rho):.1f} % thrust at two rotor radii; these flights came within "
            f"{f.d_down_min:.2f} m of it). Switch ground_effect on in the simulator.")


def _explain_ground_multirotor(p: dict, f: FlightFacts) -> str:
    return (f"Extra lift near the surface below follows Sanchez-Cuevas et al.'s multirotor law (the images of "
            f"all rotors and the lift of the body in their meeting flows) with body-lift coefficient "
            f"K_b = {p['K_b']:.3g}; these flights came within {f.d_down_min:.2f} m of it. Model the ground "
            f"effect with this law rather than the single-rotor Cheeseman-Bennett law.")


def _cheeseman_bennett_ratio(d: np.ndarray, mu: float, r: float, **geometry) -> np.ndarray:
    """``T_IGE/T_OGE`` of the Cheeseman-Bennett law (``geometry`` unused)."""
    return ge.thrust_ratio(d, mu, r)


def _multirotor_ratio(d: np.ndarray, K_b: float, r: float, *, arm_length: float, rotor_count: int,
                      **_) -> np.ndarray:
    """``T_IGE/T_OGE`` of Sanchez-Cuevas et al.'s law for the vehicle's rotor spacing."""
    spacing, opposite = ge.rotor_spacing(arm_length, rotor_count)
    return ge.multirotor_thrust_ratio(d, K_b, r, spacing, opposite)


def _exponential_ratio(d: np.ndarray, params: tuple[float, float], r: float, **geometry) -> np.ndarray:
    """``T_IGE/T_OGE`` of the exponential law at ``params = (A, lam)`` (``geometry`` unused)."""
    A, lam = params
    return ge.exponential_thrust_ratio(d, A, lam, r)


def _explain_ground_exponential(p: dict, f: FlightFacts) -> str:
    extra = p["A"] * np.exp(-2.0 / p["lam"]) if p["lam"] > 0 else float("nan")
    return (f"Extra lift near the surface below fades exponentially with height (after He et al. 2019): "
            f"+{100 * extra:.1f} % thrust at two rotor radii, with a decay length of {p['lam']:.2g} rotor radii "
            f"({100 * p['lam'] * f.rotor_radius:.1f} cm); these flights came within {f.d_down_min:.2f} m of it. "
            f"Model the ground effect with this law.")


def _explain_ceiling(p: dict, f: FlightFacts) -> str:
    d = 2 * f.rotor_radius
    rho = p["kappa"] * (f.rotor_radius / (4 * d)) ** 2
    return (f"Suction towards the surface above follows the ceiling law with kappa = {p['kappa']:.3g} "
            f"(+{100 * rho / (1 - rho):.1f} % thrust at two rotor radii; these flights came within "
            f"{f.d_up_min:.2f} m of it). Switch ceiling_effect on in the simulator.")


def _explain_rotor_drag(p: dict, f: FlightFacts) -> str:
    per = p["k_d"] * f.wsum_hover
    return (f"Horizontal drag proportional to rotor speed and body-horizontal airspeed is missing: about "
            f"{per:.3g} N per m/s at hover ({per * f.speed_p90:.2g} N at these flights' 90th-percentile "
            f"{f.speed_p90:.2g} m/s). Add RotorS-style rotor drag with k_d = {p['k_d']:.3g} N s^2/m.")


def _explain_body_drag(p: dict, f: FlightFacts) -> str:
    return (f"The airframe's quadratic drag is missing: {p['c_d'] * f.speed_p90**2:.2g} N at these flights' "
            f"90th-percentile {f.speed_p90:.2g} m/s, growing with the square of speed. "
            f"Add body drag with c_d = {p['c_d']:.3g} kg/m.")


def _explain_wind(p: dict, f: FlightFacts) -> str:
    mag = float(np.hypot(p["f_x"], p["f_y"]))
    towards = float(np.degrees(np.arctan2(p["f_y"], p["f_x"])))
    return (f"A steady horizontal push of {mag:.2g} N ({100 * mag / (f.mass * GRAVITY):.1f} % of the weight) towards "
            f"{towards:.0f} deg in the world frame; {_heading_clause(f)}: a draught or steady wind "
            f"(drag on the airspeed).")


def _explain_battery(p: dict, f: FlightFacts) -> str:
    return (f"Thrust per rotor speed falls as the flight goes on, by {100 * p['s'] * 60:.2g} % per minute "
            f"(s = {p['s']:.3g} 1/s, {100 * p['s'] * f.duration_s:.2g} % over these {f.duration_s:.0f} s): "
            f"battery voltage sag. Model it, or feed the controller the voltage. (A mass that grows by "
            f"{100 * p['s'] * f.duration_s:.2g} % over the flight, a payload taken on, reads alike on commanded "
            f"speeds.)")


def _explain_battery_voltage(p: dict, f: FlightFacts) -> str:
    return (f"Thrust per commanded rotor speed squared follows the battery's voltage: {100 * p['k_V']:.2g} % per volt "
            f"(k_V V = {p['k_V'] * f.voltage_mean:.2g} at the mean {f.voltage_mean:.3g} V, where a motor driven "
            f"at a duty cycle gives 2); the voltage spanned {f.voltage_span:.2g} V in flight. The recorded commands "
            f"act as duty cycles, not speeds: model the voltage, or feed the controller the voltage.")


def _explain_motor_lag(p: dict, f: FlightFacts) -> str:
    tau, torque, se = 1000 * p["tau"], 1000 * f.torque_lag_s, 1000 * f.torque_lag_stderr_s
    if not (np.isfinite(torque) and np.isfinite(se)):
        return (f"The rotors follow their recorded speeds with a first-order lag of {tau:.0f} ms: the recorded speeds "
                f"are commands. Add a motor time constant to the simulator and controller.")
    if tau - torque > max(TORQUE_LAG_APART * se, TORQUE_LAG_SHARE * tau):
        return (f"The thrust follows the recorded speeds with a first-order lag of {tau:.0f} ms, but the roll and "
                f"pitch torques, which the same motors make, lag them by only {torque:.0f} ± {se:.0f} ms (timed on "
                f"the angular acceleration): the motors account for that much, and the rest of the lag is along the "
                f"thrust alone, from something this vocabulary lacks (an axial inflow, thrust falling as the vehicle "
                f"climbs and rising as it descends, would read alike). Add a motor time constant of about "
                f"{torque:.0f} ms to the simulator and controller, and look along the thrust for the rest.")
    return (f"The rotors follow their recorded speeds with a first-order lag of {tau:.0f} ms: the recorded speeds are "
            f"commands (the roll and pitch torques, timed apart on the angular acceleration, lag them by {torque:.0f} "
            f"± {se:.0f} ms). Add a motor time constant to the simulator and controller.")


#: how far (in the torques' errors) and by what share of the thrust's lag the torques' lag must fall short of it for
#: the motor-lag explanation to say the rest is not the motors' (Neural-Swarm's Crazyflies: 66-77 ms on the thrust,
#: 10-23 +- 5 ms on the torques; the simulator's motors: 30 and 30.4 +- 2.5 ms)
TORQUE_LAG_APART, TORQUE_LAG_SHARE = 2.0, 0.5


_SURFACE_RANGE_SOURCE = ("Cheeseman & Bennett 1955 give mu = 1 for one rotor; 1-3 fits most small "
                         "multirotors (effects.md), up to ~6 with rotor interaction (Sanchez-Cuevas et al. 2017)")

_EXPONENTIAL_RANGE_SOURCE = ("the Cheeseman-Bennett law at the top of its range (mu = 12) adds 23 % at two rotor "
                             "radii; small multirotors show 4-11 % a rotor radius or two above the floor (effects.md)")

#: rotor radii, the exponential law's decay length ``lam`` searched, in time (``search``) and on the curve (``bounds``)
_DECAY_RADII = (0.2, 10.0)

_MULTIROTOR_RANGE_SOURCE = ("Sanchez-Cuevas, Heredia & Ollero 2017 (Int. J. Aerospace Eng., doi 10.1155/2017/1823056) "
                            "fit K_b to their quadrotor's measured curve; implementations quote 0.5-2. Far from the "
                            "ground the body term is K_b times the rotors' images: at K_b = 6 the body would lift "
                            "six times more than all rotors' images together")

EFFECTS: dict[str, EffectSpec] = {
    e.name: e
    for e in [
        EffectSpec("ground_effect", ("mu",), ("-",), (2.0,), ground_effect_force, False,
                   "Cheeseman-Bennett ground effect: extra lift near the surface below",
                   PhysicalRange("mu", 0.25, 12.0, lambda p, f: p["mu"], _SURFACE_RANGE_SOURCE),
                   _explain_ground, search=(0.05, 40.0), along_thrust=True, surface="d_down",
                   manoeuvre="hover over the floor at several heights within a few rotor radii",
                   ratio=_cheeseman_bennett_ratio),
        EffectSpec("ground_effect_multirotor", ("K_b",), ("-",), (1.0,), ground_effect_multirotor_force, False,
                   "Sanchez-Cuevas et al. 2017 multirotor ground effect: images of all rotors plus body lift",
                   PhysicalRange("K_b", 0.0, 6.0, lambda p, f: p["K_b"], _MULTIROTOR_RANGE_SOURCE),
                   _explain_ground_multirotor, search=(0.01, 20.0), along_thrust=True, surface="d_down",
                   manoeuvre="hover over the floor at several heights from one to ten rotor radii",
                   ratio=_multirotor_ratio, alternative_to="ground_effect", absent_at_zero=False),
        EffectSpec("ground_effect_exponential", ("A", "lam"), ("-", "rotor radii"), (0.4, 1.7),
                   ground_effect_exponential_force, False,
                   "ground effect fading exponentially with height (after He et al. 2019)",
                   PhysicalRange("extra thrust at two rotor radii, A exp(-2/lam) [-]", 0.0, 0.25,
                                 lambda p, f: p["A"] * np.exp(-2.0 / p["lam"]) if p["lam"] > 0 else np.nan,
                                 _EXPONENTIAL_RANGE_SOURCE),
                   _explain_ground_exponential, along_thrust=True, surface="d_down",
                   manoeuvre="hover over the floor at several heights from one to ten rotor radii",
                   search=_DECAY_RADII, ratio=_exponential_ratio, alternative_to="ground_effect",
                   bounds=((0.0, 2.0), _DECAY_RADII), amplitude="A"),
        EffectSpec("ceiling_effect", ("kappa",), ("-",), (2.0,), ceiling_effect_force, False,
                   "ceiling effect: suction towards the surface above",
                   PhysicalRange("kappa", 0.25, 12.0, lambda p, f: p["kappa"], _SURFACE_RANGE_SOURCE),
                   _explain_ceiling, search=(0.05, 40.0), along_thrust=True, surface="d_up",
                   manoeuvre="hover under the ceiling at several distances within a few rotor radii",
                   ratio=_cheeseman_bennett_ratio),
        EffectSpec("rotor_drag", ("k_d",), ("N s^2/m",), (8.06e-5,), rotor_drag_force, True,
                   "rotor drag (blade flapping, induced drag), linear in body-horizontal speed",
                   PhysicalRange("drag per unit mass at hover, k_d Wsum_hover / m [1/s]", 0.005, 1.5,
                                 lambda p, f: p["k_d"] * f.wsum_hover / f.mass,
                                 "RotorS Firefly 0.15 1/s; 0.3-0.5 1/s measured on small quadrotors "
                                 "(Faessler et al. 2018)"),
                   _explain_rotor_drag, manoeuvre="fly at several horizontal speeds in different directions"),
        EffectSpec("body_drag", ("c_d",), ("kg/m",), (0.05,), body_drag_force, True,
                   "quadratic parasitic drag of the airframe",
                   PhysicalRange("c_d over the airframe's largest plausible body drag [-]", 2e-3, 1.0,
                                 lambda p, f: p["c_d"] / body_drag_max(f),
                                 "0.5 rho C_D A with air at 1.2 kg/m^3, C_D up to 1.5 and at most the square "
                                 "spanned by the rotor tips, (2 (arm_length + r))^2, as frontal area (1 kg/m where "
                                 "the arm length is unknown)"),
                   _explain_body_drag, manoeuvre="fly faster: a quadratic drag parts from linear laws at speed"),
        EffectSpec("wind", ("f_x", "f_y"), ("N", "N"), (0.3, 0.0), wind_force, True,
                   "a steady horizontal push",
                   PhysicalRange("push / weight [-]", 0.0, 1.0,
                                 lambda p, f: float(np.hypot(p["f_x"], p["f_y"])) / (f.mass * GRAVITY),
                                 "a vehicle holding its course against a push above its weight would have "
                                 "to tilt beyond 45 deg"),
                   _explain_wind, positive=False,
                   manoeuvre="fly the same pattern at two or more headings and speeds"),
        EffectSpec("battery_sag", ("s",), ("1/s",), (1e-3,), battery_sag_force, True,
                   "thrust coefficient decaying as the battery drains",
                   PhysicalRange("s [1/s]", 0.0, 2e-3, lambda p, f: p["s"],
                                 "a LiPo pack sags by at most ~20 % of its voltage over a discharge; "
                                 "2e-3 1/s is 12 % of thrust per minute"),
                   _explain_battery, along_thrust=True,
                   manoeuvre="fly longer, or repeat the flight with a fresh and a drained battery",
                   thrust_factor=lambda x: -x.need("battery_sag", "t")),
        EffectSpec("battery_voltage", ("k_V",), ("1/V",), (0.14,), battery_voltage_force, True,
                   "thrust per commanded speed squared following the battery's voltage (battery0)",
                   PhysicalRange("k_V times the mean voltage [-]", 0.0, 3.0,
                                 lambda p, f: p["k_V"] * f.voltage_mean,
                                 "a motor driven at a duty cycle turns at duty x voltage (DC motor back-EMF), so "
                                 "thrust per command squared goes as V^2, k_V V = 2; ESCs that regulate speed "
                                 "give less; 3 allows the voltage's sag at the motor beyond the pack's"),
                   _explain_battery_voltage, along_thrust=True, alternative_to="battery_sag",
                   manoeuvre="fly thrust steps of different sizes (the voltage sags under load) and long enough "
                             "for the pack to drain",
                   thrust_factor=lambda x: x.need("battery_voltage", "voltage_dev"), simulated=False),
        EffectSpec("motor_lag", ("tau",), ("s",), (0.02,), motor_lag_force, False,
                   "rotor speeds lagging their commands with a first-order time constant",
                   PhysicalRange("tau [s]", 0.003, 0.2, lambda p, f: p["tau"],
                                 "motor time constants of 12.5-25 ms (RotorS), 45 ms actuator lag "
                                 "(Neural-Lander); effects.md"),
                   _explain_motor_lag, search=(0.002, 0.3), along_thrust=True,
                   manoeuvre="fly sharp thrust steps (climbs and stops)"),
    ]
}


def effect_force(name: str, params: dict[str, float], inputs: EffectInputs) -> np.ndarray:
    """World force [N], ``(K, 3)``, of one named effect."""
    spec = get_spec(name)
    check_params(name, params)
    return spec.force(inputs, **{k: float(params[k]) for k in spec.params})


def total_force(effects: dict[str, dict[str, float]], inputs: EffectInputs) -> np.ndarray:
    """Sum of the world forces [N], ``(K, 3)``, of several named effects."""
    total = np.zeros((inputs.K, 3))
    for name, params in effects.items():
        total += effect_force(name, params, inputs)
    return total


def force_on_state(effects: dict[str, dict[str, float]], q: np.ndarray, v: np.ndarray, rotor_speeds: np.ndarray,
                   t: float, d_down: float, d_up: float, k_T: float, rotor_radius: float,
                   R: np.ndarray | None = None, arm_length: float | None = None) -> np.ndarray:
    """World force [N], ``(3,)``, of ``effects`` on one state: what a simulator adds at each step.

    Parameters
    ----------
    q : (4,) quaternion w, x, y, z, body to world
    v : (3,) m/s, world velocity
    rotor_speeds : (N,) rad/s, actual rotor speeds
    t : s since the start; d_down, d_up : m (``inf`` where there is no surface)
    k_T : N/(rad/s)^2; rotor_radius : m
    R : (3, 3) body-to-world rotation of ``q`` when the caller has it
    arm_length : m, centre to each rotor hub (laws that use the rotor spacing)
    """
    if not effects:
        return np.zeros(3)
    inp = EffectInputs(q=np.asarray(q)[None], v=np.asarray(v)[None], rotor_speeds=np.asarray(rotor_speeds)[None],
                       k_T=k_T, rotor_radius=rotor_radius, d_down=np.array([d_down]), d_up=np.array([d_up]),
                       t=np.array([t]), R=None if R is None else np.asarray(R)[None], arm_length=arm_length)
    return total_force(effects, inp)[0]


def strongest_surface_lift(d: np.ndarray, surface: str, rotor_radius: float, **geometry) -> np.ndarray:
    """(K,) -, the most any surface law of the registry, at the top of its physical range, could raise the
    thrust at heights ``d`` [m] (K,) from ``surface`` (``"d_down"``, ``"d_up"``); its inverse is the least
    share of the weight that could hold a hover there. A law that cannot be evaluated even far from the
    surface (the multirotor law with the arm length unknown: ``geometry`` holds ``arm_length`` [m] and
    ``rotor_count``) does not count, nor do laws with several parameters (the exponential law: their range
    bounds a derived quantity, not a parameter to put at its top)."""
    d = np.asarray(d, float)
    lift = np.ones(d.shape)
    far = np.array([1000.0 * rotor_radius])
    for spec in EFFECTS.values():
        if spec.surface == surface and spec.ratio is not None and len(spec.params) == 1 and np.isfinite(
                spec.ratio(far, spec.physical_range.hi, rotor_radius, **geometry)).all():
            lift = np.maximum(lift, spec.strongest_ratio(d, rotor_radius, **geometry))
    return lift


def get_spec(name: str) -> EffectSpec:
    if name not in EFFECTS:
        raise InputError("effects", f"unknown effect '{name}' (known: {', '.join(EFFECTS)})")
    return EFFECTS[name]


def check_params(name: str, params: dict[str, float]) -> None:
    spec = get_spec(name)
    unknown = sorted(set(params) - set(spec.params))
    if unknown:
        raise InputError(f"effects.{name}",
                         f"unknown parameter(s) {', '.join(unknown)} (allowed: {', '.join(spec.params)})")
    missing = [p for p in spec.params if p not in params]
    if missing:
        raise InputError(f"effects.{name}", f"missing parameter(s) {', '.join(missing)}")


def defaults(name: str) -> dict[str, float]:
    spec = get_spec(name)
    return dict(zip(spec.params, spec.typical))


def parse_effects(text: str | None) -> dict[str, dict[str, float]]:
    """Parse ``NAME[:param=value[,param=value...]][,NAME...]``.

    A token holding ``:`` or no ``=`` starts a new effect; a bare ``param=value`` token adds
    to the current one. Parameters left out take the typical values of ``effects.md``.
    ``none`` or an empty string gives no effect. Example:
    ``"wind:f_x=0.3,f_y=-0.1,rotor_drag:k_d=8e-5,ground_effect"``.
    """
    out: dict[str, dict[str, float]] = {}
    if text is None or text.strip() in ("", "none"):
        return out
    current: str | None = None
    for raw in text.split(","):
        tok = raw.strip()
        if not tok:
            continue
        if ":" in tok or "=" not in tok:
            name, _, rest = tok.partition(":")
            name = name.strip()
            get_spec(name)
            if name in out:
                raise InputError("effects", f"effect '{name}' given twice")
            out[name] = {}
            current = name
            tok = rest.strip()
            if not tok:
                continue
        if current is None:
            raise InputError("effects", f"'{tok}' comes before any effect name")
        key, _, val = tok.partition("=")
        key = key.strip()
        try:
            out[current][key] = float(val)
        except ValueError:
            raise InputError(f"effects.{current}", f"parameter '{key}' must be a number, got '{val}'") from None
    for name, params in out.items():
        full = {**defaults(name), **params}
        check_params(name, full)
        out[name] = full
    return out


def format_effects(effects: dict[str, dict[str, float]]) -> str:
    """Inverse of :func:`parse_effects`."""
    if not effects:
        return "none"
    return ",".join(f"{n}:" + ",".join(f"{k}={v:.9g}" for k, v in p.items()) for n, p in effects.items())


#: the simulator's default physics; ``conf/physics/default.yaml`` holds the same (a test checks)
DEFAULT_EFFECTS: dict[str, dict[str, float]] = {"ground_effect": {"mu": 2.0}}


#: ground-effect law of the paper's simulated quadrotor (k_T = 5.45e-6, r = 0.01 m) and the
#: simulator's default mu: beta = mu r^2 / 16 [m^2], alpha = k_T beta [N m^2/(rad/s)^2]
BETA_PAPER = DEFAULT_EFFECTS["ground_effect"]["mu"] * QUADROTOR.rotor_radius**2 / 16.0
ALPHA_PAPER = QUADROTOR.thrust_coefficient * BETA_PAPER
