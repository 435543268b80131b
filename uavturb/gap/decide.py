"""What the recordings can decide (``gap-report.md``: ``ambiguous``, physical ranges, surfaces).

The forward selection (:mod:`uavturb.gap.selection`) finds effects that improve the held-out
fit. That is necessary, not sufficient, for a discovery a flight engineer can trust:

1. **Reach.** A surface effect (ground, ceiling) is tested only where the flights come within
   reach of that surface: under the height where its law, at the top of its physical range,
   adds 1 % of the thrust (:meth:`~uavturb.physics.effects.EffectSpec.surface_reach`), for at
   least :data:`MIN_NEAR_S` seconds. Farther away the law is flat: whatever it "fits" is the
   thrust coefficient or noise.
2. **Separability.** An effect whose force, on these flights, is nearly a combination of the
   nominal model's unknowns (thrust coefficient, accelerometer bias) or of another effect's
   force cannot have its parameters pinned down: the data trade one for the other. This is
   measured on the regressors themselves (uncentred R^2 of the effect's columns on the others',
   :func:`collinearity`); above :data:`R2_AMBIGUOUS` the effect goes to ``ambiguous`` with the
   manoeuvre that would separate them. The classic case is a steady push and an accelerometer
   bias at a fixed heading: both are a constant force in the same body/world direction
   (R^2 = 0.999 with 3 deg tilts, tests/test_gap_decide.py). The threshold is a variance inflation of 100: any
   force the model does not describe (drag on the airspeed, a thrust curve) then leaks into the
   parameter amplified tenfold, beyond what its standard error shows. Milder collinearity is
   left to the standard errors: a 90 s battery-sag flight (R^2 = 0.93 against the thrust
   coefficient) pins ``s`` within 0.2 %.
3. **Physical range.** A fit outside its effect's physical range (``EffectSpec.physical_range``,
   with its source) is no discovery: the law does not describe what was found.
4. **Drag in a wind.** Real wind is drag on the airspeed ``v - v_wind`` (``effects.md``). Where a
   push and rotor drag are named together, body drag ``c_d |v_a| v_a`` linearises about the wind
   into a drag linear in the velocity that rotor drag's ``k_d`` absorbs: stronger along the push
   (``2 c_d |v_w|``) than across it (``c_d |v_w|``), while rotor drag is the same in every
   horizontal direction. :func:`airspeed_drag` measures the drag along and across the push; where
   it differs, or where the flights cannot show whether it does, ``k_d`` is not rotor drag
   alone and goes to ``ambiguous`` with what the anisotropy implies (rotor drag, body drag, wind
   speed). On the wind-tunnel conditions of ``uavturb gap-proof`` the isotropic fit gave
   ``k_d`` 2.2 times the true rotor drag at 4 m/s.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.special import chdtrc, ndtri  # chi^2 survival and the normal quantile, without scipy.stats

from uavturb.gap.design import (
    AMPLITUDE,
    THRUST_FACTOR,
    GapData,
    bias_count,
    design,
    difference_points,
    effective_S,
    stack_target,
    unstack,
)
from uavturb.gap.fit import ModelFit, _nl_values, fit_model
from uavturb.physics.dynamics import GRAVITY
from uavturb.physics.effects import EFFECTS, FlightFacts
from uavturb.sysid.flight_data import UNDER_SURFACE_M, UNDER_SURFACE_ROWS
from uavturb.sysid.least_squares import LstsqResult, lstsq

#: uncentred R^2 above which two sets of regressors are taken as indistinguishable (VIF > 100)
R2_AMBIGUOUS = 0.99
#: z-score of the along/across drag difference taken as a real anisotropy (drag on the airspeed)
ANISOTROPY_Z = 3.0
#: s, the blocks whose residuals are taken as correlated within and independent between
#: (cluster-robust standard errors of the along/across drag)
DRAG_BLOCK_S = 1.0
#: deg, the largest tilt between the thrust axis and the recorded attitude taken as plausible: motor
#: mounts, frame flex and an attitude estimate's levelling leave 1-2 deg (the 1-1.5 deg pushes of real
#: indoor sessions); a larger tilt makes a vehicle drift visibly in hover and is trimmed out in tuning
TILT_MAX_DEG = 3.0
#: standard errors a push must stand from zero beside a thrust-axis tilt to be named wind rather than taken for it
TILT_SEPARATION_Z = 4.0
#: s, correlation length of the residual for the errors of that test (the 1 s blocks of the finder's honest errors)
TILT_LAG_S = 1.0
#: share of the push under which what is left of it beside a tilt says the tilt explains it
TILT_EXPLAINS = 0.25
#: share of the weight an effect's force must reach where it acts to be a discovery (practical size): a push
#: a thousandth of the weight is none; the concealed effects of ``uavturb gap-proof`` (a 0.036 N push on a
#: 14.7 N hexarotor, 0.25 %) are the smallest the proof asks for
PRACTICAL_SHARE = 0.002
#: s of flight within reach of a surface needed to test its law
MIN_NEAR_S = 2.0
#: deg of heading change under which a body-fixed and a world-fixed force look alike
HEADING_SPAN_DEG = 30.0

NOMINAL_GROUPS = {"thrust_coefficient": ("k_T",), "accelerometer_bias": ("b_x", "b_y", "b_z")}


def heading_span_deg(data: GapData) -> float:
    """deg, the largest range of headings flown in one recording (yaw of the body x axis)."""
    span = 0.0
    for g in np.unique(data.group):
        R = data.R[data.group == g]
        yaw = np.unwrap(np.arctan2(R[:, 1, 0], R[:, 0, 0]))
        span = max(span, float(np.degrees(np.ptp(yaw))) if len(yaw) else 0.0)
    return min(span, 360.0)


def flight_facts(data: GapData, k_T: float) -> FlightFacts:
    """The facts explanations and ranges may cite, measured on ``data``."""
    n = data.rotor_speeds.shape[1]
    wsum_hover = n * float(np.sqrt(data.mass * GRAVITY / (n * k_T))) if k_T > 0 else float("nan")
    duration = float(sum(np.ptp(data.t[data.group == g]) for g in np.unique(data.group)))
    d_down = data.d_down[np.isfinite(data.d_down)]
    d_up = data.d_up[np.isfinite(data.d_up)]
    return FlightFacts(mass=data.mass, rotor_count=n, rotor_radius=data.rotor_radius, k_T=k_T,
                       wsum_hover=wsum_hover,
                       speed_p90=float(np.percentile(np.linalg.norm(data.v[:, :2], axis=1), 90)),
                       heading_span_deg=heading_span_deg(data), has_imu=data.has_imu,
                       bias_anchored=data.has_imu and not data.fits_bias, arm_length=data.arm_length,
                       d_down_min=float(d_down.min()) if len(d_down) else float("inf"),
                       d_up_min=float(d_up.min()) if len(d_up) else float("inf"), duration_s=duration,
                       **_voltage_facts(data), **_torque_facts(data))


def _torque_facts(data: GapData) -> dict[str, float]:
    """The torques' lag behind commanded rotor speeds and its error [s] (:attr:`GapData.torque_lag`; {} without)."""
    lag = data.torque_lag
    return {} if lag is None else {"torque_lag_s": lag.tau_s, "torque_lag_stderr_s": lag.stderr_s}


def _voltage_facts(data: GapData) -> dict[str, float]:
    """The battery's mean voltage in flight and the span of its middle 90 % of rows [V] (nan without one)."""
    if data.voltage_dev is None or not data.voltage_means:
        return {}
    means = np.array([data.voltage_means.get(n, np.nan) for n in data.names])
    volts = data.voltage_dev + means[data.group]
    return {"voltage_mean": float(np.nanmean(means)),
            "voltage_span": float(np.nanpercentile(volts, 95) - np.nanpercentile(volts, 5))}


@dataclass
class Reach:
    """Whether a surface effect can be tested on these flights."""

    name: str
    testable: bool
    reach_m: float
    near_s: float
    closest_m: float
    #: why no height over a surface can be trusted (:func:`floor_crossing`), or None
    heights_broken: str | None = None

    def why(self) -> str:
        where = "below" if EFFECTS[self.name].surface == "d_down" else "above"
        if self.heights_broken:
            return ("the heights over surfaces cannot be trusted: the vehicle passes under the floor (where: "
                    "surface_curve_missing, Measured surface curve)")
        if not np.isfinite(self.closest_m):
            return f"the recordings have no surface {where} the vehicle (no point cloud, or nothing there)"
        return (f"the flights came no closer than {self.closest_m:.2f} m to the surface {where} and spent "
                f"{self.near_s:.1f} s within {self.reach_m:.2f} m of it, where the law could add 1 % of the thrust "
                f"(at least {MIN_NEAR_S:.0f} s needed)")

    def to_separate(self) -> str:
        if self.heights_broken:
            return FIX_HEIGHTS
        where = "over the floor" if EFFECTS[self.name].surface == "d_down" else "under the ceiling"
        return f"hover {where} at several heights below {self.reach_m:.2f} m for a few seconds each"


#: what makes the heights over surfaces trustworthy again (:func:`floor_crossing`)
FIX_HEIGHTS = ("record a position whose height holds (motion capture; or, from a PX4 log, the height over the "
               "ground of a range sensor, vehicle_local_position's dist_bottom), or give the floor's true height "
               "(uavturb import --floor-z, the point cloud)")


def floor_crossing(data: GapData) -> str | None:
    """Why no height over a surface can be trusted on ``data``, or None.

    In flight the rotor plane cannot be under the surface it flies over: where a recording has rows over a
    surface (``d_down`` finite) and ``UNDER_SURFACE_ROWS`` rows or more where nothing is below the rotor
    plane and a surface is over ``UNDER_SURFACE_M`` above it (the bounds :mod:`uavturb.sysid.flight_data` puts
    on a ``rotor_plane_z`` that dips into the floor: a scan's noise, one bad row), the recording's height passes
    through its floor: a position that drifts in height (a barometer, an estimator without motion capture: a PX4 log's
    local position 0.42 m under its take-off floor at touch-down) or a wrong floor height. A recording never
    over any surface (a scan of a ceiling alone) shows nothing here.
    """
    under = ~np.isfinite(data.d_down) & np.isfinite(data.d_up) & (data.d_up > UNDER_SURFACE_M)
    found = []
    for g in np.unique(data.group[under]):
        mine = data.group == g
        rows = under & mine
        if rows.sum() < UNDER_SURFACE_ROWS or not np.any(np.isfinite(data.d_down[mine])):
            continue
        t = data.t[rows]
        found.append(f"{data.names[g]}: in flight the rotor plane is up to {float(np.max(data.d_up[rows])):.2f} m "
                     f"under the surface above it ({int(rows.sum())} rows between {t.min():.1f} and {t.max():.1f} s), "
                     f"a surface it flies over at other times")
    if not found:
        return None
    return ("; ".join(found) + ". The recorded height passes through the floor: the position drifts in height (a "
            "barometer, an estimator without motion capture) or the floor's height is wrong, so no height over a "
            "surface can be trusted and no surface effect is tested. To test them: " + FIX_HEIGHTS)


def surface_reach(data: GapData, name: str) -> Reach:
    """Can the surface law ``name`` be tested on ``data``? (module docstring, point 1) A law with several
    parameters, whose range bounds a derived quantity and has no top to reach from (the exponential law),
    needs the flights its standard law needs (``alternative_to``)."""
    spec = EFFECTS[name]
    d = data.d_down if spec.surface == "d_down" else data.d_up
    law = spec if len(spec.params) == 1 or spec.alternative_to is None else EFFECTS[spec.alternative_to]
    reach = law.surface_reach(data.rotor_radius, **data.geometry)
    near = np.isfinite(d) & (d <= reach)
    dt = float(np.median(np.diff(data.t))) if len(data) > 1 else 0.0
    near_s = float(near.sum()) * dt
    closest = float(np.min(d[np.isfinite(d)])) if np.any(np.isfinite(d)) else float("inf")
    broken = floor_crossing(data)
    return Reach(name, near_s >= MIN_NEAR_S and broken is None, reach, near_s, closest, broken)


def effect_size(data: GapData, fit: ModelFit, effect: str) -> float:
    """N, the 99th percentile over the samples of the norm of the force ``fit`` gives ``effect``:
    its size where it acts (a ground effect acts near the floor only, a motor lag in thrust steps:
    on the lag flights of the tests its force is 0.004 N at the median, 0.23 N at the 99th percentile)."""
    without = ModelFit(fit.effects - {effect}, {e: v for e, v in fit.nonlinear.items() if e != effect}, fit.coef,
                       fit.stderr, fit.rmse)  # its columns gone (a law whose zero still acts included)
    force = fit.predict(data) - without.predict(data)
    return float(np.percentile(np.linalg.norm(force, axis=1), 99))


def can_test_alone(data: GapData, fit: ModelFit, effect: str) -> bool:
    """Whether the rows ``data`` (one recording's) can test ``effect`` on their own: a surface law needs flights
    within its reach (:func:`surface_reach`); any other effect must reach :data:`PRACTICAL_SHARE` of the weight
    there at the value ``fit`` (all recordings together) gives it. A take-off that barely moves sideways gives a
    rotor drag no force to be read from, and its own fit of it is noise, not a session's spread."""
    if EFFECTS[effect].surface is not None:
        return surface_reach(data, effect).testable
    return effect_size(data, fit, effect) >= PRACTICAL_SHARE * data.mass * GRAVITY


def too_small(data: GapData, fit: ModelFit, effect: str) -> str | None:
    """None when the effect's force reaches :data:`PRACTICAL_SHARE` of the weight where it acts, else
    why it is no discovery (a push a thousandth of the weight is none, however significant)."""
    size = effect_size(data, fit, effect)
    weight = data.mass * GRAVITY
    if size >= PRACTICAL_SHARE * weight:
        return None
    return (f"its force reaches only {size:.3g} N where it acts ({100 * size / weight:.2g} % of the weight; "
            f"{100 * PRACTICAL_SHARE:.1f} % needed to matter in a simulator)")


def _scaled(A: np.ndarray) -> np.ndarray:
    s = np.linalg.norm(A, axis=0)
    s[s == 0] = 1.0
    return A / s


def collinearity(target: np.ndarray, others: np.ndarray) -> float:
    """Smallest uncentred R^2 of each column of ``target`` (3K, p) regressed on ``others`` (3K, q):
    1 when the target's force is a combination of the others on every sample, 0 when orthogonal."""
    if target.shape[1] == 0 or others.shape[1] == 0:
        return 0.0
    O = _scaled(others)
    r2 = []
    for c in _scaled(target).T:
        beta = np.linalg.lstsq(O, c, rcond=None)[0]
        r = c - O @ beta
        r2.append(1.0 - float(r @ r) / max(float(c @ c), 1e-300))
    return min(r2)


def _columns(data: GapData, fit: ModelFit) -> tuple[np.ndarray, list[str]]:
    return design(data, set(fit.effects), _nl_values(fit.nonlinear))


def effect_columns(names: list[str], effect: str) -> list[int]:
    """Indices of the coefficients that belong to ``effect`` (a law scaling the thrust coefficient has ``k_T*s`` or
    ``k_T*k_V``, a surface law's amplitude ``k_T*A``; none for a law searched in its one parameter)."""
    if effect in THRUST_FACTOR:
        keys: tuple[str, ...] = (THRUST_FACTOR[effect],)
    elif effect in AMPLITUDE:
        keys = (AMPLITUDE[effect],)
    else:
        keys = () if EFFECTS[effect].search is not None else EFFECTS[effect].params
    return [i for i, n in enumerate(names) if n in keys]


def nonlinear_column(data: GapData, fit: ModelFit, effect: str) -> np.ndarray:
    """(3K, 1) the change of the force per unit change of a nonlinear effect's searched parameter (central
    difference at its fitted value, of the thrust column or, for a law with an amplitude, of its own column),
    i.e. how the effect shows in the data."""
    hi, lo = difference_points(effect, fit.nonlinear[effect])
    Ap, names = design(data, set(fit.effects), _nl_values(fit.nonlinear | {effect: hi}))
    Am, _ = design(data, set(fit.effects), _nl_values(fit.nonlinear | {effect: lo}))
    coef = AMPLITUDE.get(effect, "k_T")
    k = names.index(coef)
    return ((Ap[:, k] - Am[:, k]) * fit.coef[coef] / (hi - lo))[:, None]


def look_alikes(data: GapData, fit: ModelFit, effect: str) -> list[tuple[str, float]]:
    """The unknowns of ``fit`` that ``effect``'s force resembles on ``data``, with their R^2:
    the nominal groups (thrust coefficient, accelerometer bias) and every other effect of the fit,
    each alone, then all of them together (``"all"``)."""
    A, names = _columns(data, fit)
    if EFFECTS[effect].search is not None:
        own = effect_columns(names, effect)  # a law with an amplitude: its column beside its shape's change
        target = np.hstack([A[:, own], nonlinear_column(data, fit, effect)])
    else:
        own = effect_columns(names, effect)
        target = A[:, own]
    groups = {g: [names.index(k) for k in keys if k in names] for g, keys in NOMINAL_GROUPS.items()}
    for other in fit.effects - {effect}:
        groups[other] = effect_columns(names, other)
    out = [(g, collinearity(target, A[:, idx])) for g, idx in groups.items() if idx]
    rest = [i for i in range(A.shape[1]) if i not in own]
    out.append(("all", collinearity(target, A[:, rest])))
    return out


def _why(effect: str, partner: str, r2: float, facts: FlightFacts) -> str:
    alike = f"on these flights their forces are alike (R^2 = {r2:.3f} of one on the other)"
    if partner == "accelerometer_bias":
        return (f"the heading changed by only {facts.heading_span_deg:.0f} deg: a force fixed in the world and a "
                f"sensor bias fixed in the body look alike; {alike}")
    if partner == "thrust_coefficient":
        return f"{effect} scales the thrust much as the thrust coefficient does here; {alike}"
    return f"{effect} and {partner} bend the residual the same way; {alike}"


def _to_separate(effect: str, partner: str) -> str:
    if partner == "accelerometer_bias":
        return "fly the same pattern at two or more headings (90 deg apart), or rely on motion capture alone"
    if partner in EFFECTS:
        return f"{EFFECTS[effect].manoeuvre}; {EFFECTS[partner].manoeuvre}"
    return EFFECTS[effect].manoeuvre


def ambiguity(data: GapData, fit: ModelFit, effect: str, facts: FlightFacts) -> dict | None:
    """An ``ambiguous`` entry when ``effect`` cannot be told apart from the other unknowns of
    ``fit`` on ``data`` (R^2 above :data:`R2_AMBIGUOUS`), else None."""
    found = look_alikes(data, fit, effect)
    overall = dict(found)["all"]
    if overall < R2_AMBIGUOUS:
        return None
    singles = sorted((x for x in found if x[0] != "all"), key=lambda x: -x[1])
    partners = [g for g, r2 in singles if r2 >= R2_AMBIGUOUS] or [singles[0][0]]
    main = partners[0]
    return {"candidates": [effect, *partners], "why": _why(effect, main, overall, facts),
            "to_separate": _to_separate(effect, main), "r2": round(overall, 4)}


#: rounds of the alternating fit of each recording's own thrust level beside the effects (:func:`level_alike`)
LEVEL_ROUNDS = 4


def free_levels(data: GapData, fit: ModelFit) -> tuple[ModelFit, np.ndarray]:
    """``fit``'s effects refitted with each recording's own thrust level (G,) [-] (mean 1), found by alternating
    least squares: the level of each recording scales its thrust so that the force along the thrust left by the
    fit is least, then the effects are fitted again (:data:`LEVEL_ROUNDS` rounds; the last with errors)."""
    groups = np.unique(data.group)
    level = np.ones(int(groups.max()) + 1)
    moved = data
    for _ in range(LEVEL_ROUNDS):
        f = fit_model(moved, fit.effects, with_stderr=False)
        thrust = f.coef["k_T"] * effective_S(moved, set(f.effects), _nl_values(f.nonlinear))
        along = np.einsum("ki,ki->k", f.residual(moved), moved.R[:, :, 2])
        for g in groups:
            m = moved.group == g
            level[g] *= 1.0 + float(np.sum(along[m] * thrust[m]) / max(np.sum(thrust[m] ** 2), 1e-300))
        level /= level[groups].mean()
        moved = data.with_levels(level)
    return fit_model(moved, fit.effects), level[groups]


def level_alike(data: GapData, fit: ModelFit, effect: str, levels_read: bool) -> dict | None:
    """An ``ambiguous`` entry (with ``thrust_coefficient``) for a surface law that the recordings' thrust levels
    would explain as well, else None.

    Where two or more recordings share one thrust coefficient only because their levels could not be measured
    apart (``levels_read`` False: no far hovers, no heights flown in two of them), a surface law is refitted with
    each recording's own level (:func:`free_levels`); where its presence parameter then falls within two errors of
    zero, or moves by more than two of its errors, a session's thrust level and the surface's lift look alike on
    these flights. The sixth blind probe's two sessions 3-5 % apart in thrust level, one flown near the floor and a
    ceiling, the other midway only, had named a ground law and a ceiling law (mu = 3.3 +- 1.8, kappa = 3.3 +- 1.5)
    where neither acted."""
    spec = EFFECTS[effect]
    if levels_read or spec.surface is None or len(np.unique(data.group)) < 2:
        return None
    free, level = free_levels(data, fit)
    key = spec.presence_params[0]
    named, named_se = (v[key] for v in fit.effect_params(effect))
    value, se = (v[key] for v in free.effect_params(effect))
    if abs(value) > 2.0 * se and abs(value - named) <= 2.0 * max(named_se, se):
        return None
    spread = 100.0 * (float(level.max()) - float(level.min()))
    return {"candidates": [effect, "thrust_coefficient"],
            "why": (f"the recordings' thrust levels could not be measured apart (no hovers far from every surface, no "
                    f"heights flown in two of them), so they shared one thrust coefficient; with each recording's "
                    f"own (levels {spread:.2g} % apart) the law's {key} becomes {value:.3g} ± {se:.2g}, where "
                    f"{named:.3g} ± {named_se:.2g} was fitted: a session's thrust level and the surface's lift look "
                    "alike on these flights"),
            "to_separate": ("fly each recording both near the surface and far from it, or at heights another "
                            "recording flies too"),
            "params_if_named": fit.effect_params(effect)[0]}


def bias_alike(data: GapData, effect: str) -> float:
    """R^2 of a linear effect's force on the accelerometer-bias columns (0 without an IMU)."""
    if not data.fits_bias or EFFECTS[effect].search is not None or effect in THRUST_FACTOR:
        return 0.0
    fit = ModelFit(frozenset({effect}), {}, {}, {}, 0.0)
    A, names = _columns(data, fit)
    own = effect_columns(names, effect)
    nb = bias_count(data)
    return collinearity(A[:, own], A[:, 1:1 + nb])


def thrust_tilt_alike(data: GapData, fit: ModelFit, facts: FlightFacts) -> dict | None:
    """An ``ambiguous`` entry for a named ``wind`` that a tilt of the thrust axis explains as well
    (``effects.md``, look-alikes), else None.

    A thrust axis tilted by ``delta`` from the recorded attitude gives a horizontal force
    ``T delta`` along the body's x/y axes (columns ``T R e_x``, ``T R e_y``): it turns with the body
    and scales with the thrust, while a wind's push stays fixed in the world. The push is taken for a
    tilt where the data cannot tell them apart:

    - its columns are a combination of the tilt's and the fit's other columns (uncentred R^2 above
      :data:`R2_AMBIGUOUS`: a fixed heading and a steady thrust), or
    - with the tilt in the model beside it, what is left of the push stands fewer than
      :data:`TILT_SEPARATION_Z` standard errors from zero (:func:`push_beyond_tilt`): the headings flown
      turned the tilt too little, or too rarely, to pin a push apart from it.

    The tilt it would take is ``atan(push / T_hover)``. A tilt beyond :data:`TILT_MAX_DEG` is no
    plausible reading, and the push stays named."""
    if "wind" not in fit.effects:
        return None
    wind, _ = fit.effect_params("wind")
    push = float(np.hypot(wind["f_x"], wind["f_y"]))
    tilt = float(np.degrees(np.arctan2(push, data.mass * GRAVITY)))
    if tilt > TILT_MAX_DEG:
        return None
    A, names = _columns(data, fit)
    T = fit.coef["k_T"] * data.S * data.thrust_level  # N
    tilt_cols = np.stack([(T[:, None] * data.R[:, :, j]).T.reshape(-1) for j in (0, 1)], axis=1)
    own = effect_columns(names, "wind")
    rest = [i for i in range(A.shape[1]) if i not in own]
    r2 = collinearity(A[:, own], np.hstack([tilt_cols, A[:, rest]]))
    share = f"{push:.3g} N ({100 * push / (data.mass * GRAVITY):.2g} % of the weight)"
    if r2 >= R2_AMBIGUOUS:
        why = (f"a steady push of {share} is also what a thrust axis tilted by {tilt:.2f} deg from the recorded "
               f"attitude gives; the heading changed by {facts.heading_span_deg:.0f} deg and the thrust stayed steady, "
               f"so the two look alike (R^2 = {r2:.3f}); indoors the tilt is the likelier reading")
        found = {"r2": round(r2, 4)}
    else:
        left, left_se, z = push_beyond_tilt(data, A, tilt_cols, own)
        if z >= TILT_SEPARATION_Z:
            return _tilts_per_recording_alike(data, A, T, own, rest, wind, push)
        verdict = ("the tilt explains it" if left < TILT_EXPLAINS * push else
                   "these flights do not tell it from the tilt; indoors the tilt is the likelier reading")
        why = (f"a steady push of {share} is also what a thrust axis tilted by {tilt:.2f} deg from the recorded "
               f"attitude gives; the heading changed by {facts.heading_span_deg:.0f} deg, and with such a tilt in the "
               f"model the push left is {left:.2g} ± {left_se:.2g} N, {z:.1f} standard errors from none (a push needs "
               f"{TILT_SEPARATION_Z:.0f}): {verdict}")
        found = {"r2": round(r2, 4), "push_beyond_tilt_N": left, "push_beyond_tilt_stderr_N": left_se,
                 "push_beyond_tilt_z": round(z, 2)}
    return {"candidates": ["wind", "thrust_axis_tilt"], "why": why,
            "to_separate": "fly the same pattern at two or more headings 90 deg apart, holding each for a while (a "
                           "tilt turns with the body, a wind does not), or check the thrust axis against the attitude "
                           "on a bench",
            "params_if_named": wind, "thrust_axis_tilt_deg": tilt} | found


def _tilts_per_recording_alike(data: GapData, A: np.ndarray, T: np.ndarray, own: list[int], rest: list[int],
                               wind: dict[str, float], push: float) -> dict | None:
    """An ``ambiguous`` entry where each recording's own thrust-axis tilt explains a push named ``wind`` that one tilt
    for all recordings did not (:func:`thrust_tilt_alike`), else None.

    Markers re-placed between sessions tilt each recording's axis its own way (``effects.md``: real indoor sessions
    show 1-1.5 deg). Where each recording holds one heading most of the time and the headings and tilts happen to
    point the pushes one way in the world, a push fixed in the world fits both recordings, and one tilt for both fits
    neither. The rows where a heading turned tell them apart: a tilt turns with the body there, a wind does not. The
    push is taken for the tilts where, with one tilt per recording in the model (columns ``T R e_x``, ``T R e_y`` on
    that recording's rows), what is left of the push stands under :data:`TILT_SEPARATION_Z` standard errors, while
    the tilts stand :data:`TILT_SEPARATION_Z` beyond the push (:func:`_wald_z`: their Wald statistic on ``2 R``
    degrees of freedom, as the one-sided normal deviate of the same tail probability), and each tilt is plausible
    (:data:`TILT_MAX_DEG`). Where neither stands beyond the other (every recording at one heading throughout: a
    wind tunnel) the push stays named: one push for all recordings is then the simpler reading.

    A blind condition of ``gap-proof`` (two PX4-like flights, tilts of 1.2 deg at azimuths 0 and 120 deg, headings
    held at 39 and -79 deg for most of each flight, the pushes 2 deg apart in the world) had named a wind of
    0.29 N (z = 18)."""
    groups = np.unique(data.group)
    if len(groups) < 2:
        return None  # one recording: its tilt is the one tilt already weighed
    cols = []
    for g in groups:
        on = np.where(data.group == g, T, 0.0)
        cols += [(on[:, None] * data.R[:, :, j]).T.reshape(-1) for j in (0, 1)]
    tilts = np.stack(cols, axis=1)  # (3K, 2R)
    fit = _robust_fit(data, np.hstack([A, tilts]))  # the push and the tilts side by side
    left, left_se, z_push = _push_left(fit, own)
    if z_push >= TILT_SEPARATION_Z:
        return None
    z_tilts = _wald_z(fit, np.arange(A.shape[1], A.shape[1] + tilts.shape[1]))
    if z_tilts < TILT_SEPARATION_Z:
        return None
    d = _coefficients(data, np.hstack([A[:, rest], tilts]))[len(rest):].reshape(-1, 2)  # rad, per recording
    degrees = np.degrees(np.hypot(d[:, 0], d[:, 1]))
    if np.any(degrees > TILT_MAX_DEG):
        return None
    share = f"{push:.3g} N ({100 * push / (data.mass * GRAVITY):.2g} % of the weight)"
    names = [data.names[int(g)] for g in groups]  # a recording with no rows left has no tilt
    listed = ", ".join(f"{name} {deg:.2f} deg" for name, deg in zip(names, degrees))
    why = (f"a steady push of {share} is also what each recording's own thrust-axis tilt gives ({listed}; markers "
           f"re-placed between sessions tilt each its own way): with one tilt per recording in the model the push "
           f"left is {left:.2g} ± {left_se:.2g} N, {z_push:.1f} standard errors from none (a push needs "
           f"{TILT_SEPARATION_Z:.0f}), while the tilts stand {z_tilts:.1f} beyond the push: where a heading turned, "
           f"the force turned with the body, as a tilt's does and a wind's does not: the tilts explain it")
    return {"candidates": ["wind", "thrust_axis_tilt"], "why": why,
            "to_separate": "fly the same pattern at two or more headings 90 deg apart, holding each for a while (a "
                           "tilt turns with the body, a wind does not), or check each session's thrust axis against "
                           "the attitude on a bench",
            "params_if_named": wind, "thrust_axis_tilt_deg": float(np.max(degrees)),
            "thrust_axis_tilt_per_recording_deg": {name: float(deg) for name, deg in zip(names, degrees)},
            "push_beyond_tilts_N": left, "push_beyond_tilts_stderr_N": left_se, "push_beyond_tilts_z": round(z_push, 2),
            "tilts_beyond_push_z": round(z_tilts, 2)}


def _robust_fit(data: GapData, J: np.ndarray) -> LstsqResult:
    """The stacked target of ``data`` fitted on the columns ``J`` (3K, p) with Newey-West errors over
    :data:`TILT_LAG_S`, recordings and axes independent (:func:`~uavturb.sysid.least_squares.lstsq`)."""
    step = float(np.median(np.diff(data.t))) if len(data) > 1 else 1.0
    lag = max(1, int(round(TILT_LAG_S / max(step, 1e-6))))
    groups = np.concatenate([data.group + 1000 * k for k in range(3)])
    return lstsq(J, stack_target(data.y), lag=lag, groups=groups)


def _coefficients(data: GapData, J: np.ndarray) -> np.ndarray:
    """Least-squares coefficients of the stacked target of ``data`` on the columns ``J`` (3K, p)."""
    return np.linalg.lstsq(J, stack_target(data.y), rcond=None)[0]


def _wald_z(fit: LstsqResult, idx: np.ndarray) -> float:
    """How far the coefficients ``idx`` of ``fit`` (thrust-axis tilts fitted beside the model's columns, a push
    among them) stand from zero: their Wald statistic on ``len(idx)`` degrees of freedom, given as the one-sided
    normal deviate with the same tail probability (comparable with a z of one parameter)."""
    f, C = fit.coef[idx], fit.cov[np.ix_(idx, idx)]
    wald = float(max(f @ np.linalg.pinv(C) @ f, 0.0))
    return float(-ndtri(max(float(chdtrc(len(idx), wald)), 1e-300)))


#: deg: the smallest tilt of the thrust axis left in the residual worth a line of the report (0.3 deg is a push of
#: 0.5 % of the weight, about what the finder's practical size asks of a named effect)
TILT_REPORT_MIN_DEG = 0.3
#: contiguous blocks of a recording for the jackknife of its thrust-axis tilt
TILT_BLOCKS = 5


def residual_thrust_tilt(data: GapData, fit: ModelFit, residual: np.ndarray, facts: FlightFacts
                         ) -> tuple[dict, np.ndarray] | None:
    """A tilt of the thrust axis from the recorded attitude in what the named effects leave, per recording.

    ``effects.md`` names a thrust-axis tilt as a look-alike, not an effect: a push ``T delta`` along the body's
    x/y axes that turns with the body (motion-capture markers or an IMU mounted a degree off the rotors' axis;
    real indoor sessions show 1-1.5 deg, and re-placed markers change it between sessions). Where a push was
    named or left ambiguous, :func:`thrust_tilt_alike` weighs the two (the caller skips this); here the
    residual's horizontal part of each recording is regressed on its tilt columns ``T R e_x``, ``T R e_y``.
    A recording's error is the larger of the Newey-West error (over :data:`TILT_LAG_S`) and the jackknife over
    ``TIME_BLOCKS`` contiguous blocks of it (a tilt that holds through the flight, not in one stretch). The tilt
    is reported where one recording's stands :data:`TILT_SEPARATION_Z` errors from none, is at least
    :data:`TILT_REPORT_MIN_DEG` and at most :data:`TILT_MAX_DEG` (beyond, no plausible mounting explains it).

    Parameters
    ----------
    residual : (K, 3) N, world frame, the measured force less the final model's

    Returns
    -------
    ``(entry, force)`` or None: the report's ``unexplained.thrust_axis_tilt`` entry (recordings by their
    ``data.group`` index) and (K, 3) N the force the tilts give (world frame), for what is left beyond them.
    """
    if "wind" in fit.effects or len(data) < 10:
        return None
    per, force = tilt_per_recording(data, fit, residual)
    strongest = max((e["tilt_deg"] for e in per if e["z"] >= TILT_SEPARATION_Z
                     and TILT_REPORT_MIN_DEG <= e["tilt_deg"] <= TILT_MAX_DEG), default=0.0)
    if strongest == 0.0:
        return None
    before = float(np.sum(residual[:, :2] ** 2))
    after = float(np.sum((residual[:, :2] - force[:, :2]) ** 2))
    turned = facts.heading_span_deg >= HEADING_SPAN_DEG
    entry = {"per_recording": per, "explains_share": 1.0 - after / before if before > 0 else 0.0,
             "heading_span_deg": facts.heading_span_deg,
             "why": ("a push along the body's x/y axes that turns with the body and scales with the thrust: the "
                     "thrust axis leans from the recorded attitude (motion-capture markers or the IMU mounted off "
                     "the rotors' axis); not an effect of effects.md, a calibration: correct the attitude, or "
                     "tilt the thrust axis in the simulator" if turned else
                     f"the heading changed by {facts.heading_span_deg:.0f} deg only, so a steady push at this heading "
                     "looks alike (effects.md, look-alikes), though none improved the held-out fit enough to be "
                     "named; indoors the tilt is the likelier reading")}
    return entry, force


def tilt_per_recording(data: GapData, fit: ModelFit, residual: np.ndarray) -> tuple[list[dict], np.ndarray]:
    """Each recording's thrust-axis tilt in ``residual`` (K, 3) [N, world frame] with its error
    (:func:`residual_thrust_tilt`; the thrust from ``fit``'s ``k_T``): ``([{recording (data.group index),
    tilt_deg, stderr_deg, azimuth_deg (from body +x to +y), z}], force (K, 3) [N] the tilts give)``. A recording
    with fewer than ``5 TILT_BLOCKS`` rows, or whose fit fails, is left out."""
    T = fit.coef["k_T"] * data.S * data.thrust_level  # (K,) N
    force = np.zeros_like(residual)
    per = []
    for g in np.unique(data.group):
        rows = np.flatnonzero(data.group == g)
        if len(rows) < 5 * TILT_BLOCKS:
            continue
        cols = np.concatenate([T[rows, None] * data.R[rows, 0, :2], T[rows, None] * data.R[rows, 1, :2]])  # (2n, 2)
        target = np.concatenate([residual[rows, 0], residual[rows, 1]])
        d, C = _tilt_fit(cols, target, data.t[rows])
        if d is None:
            continue
        force[rows, :2] = (cols @ d).reshape(2, -1).T
        size = float(np.hypot(*d))
        along = d / size if size > 0 else np.array([1.0, 0.0])
        z = float(np.sqrt(max(d @ np.linalg.pinv(C) @ d, 0.0)))
        deg = float(np.degrees(size))  # rad, small angles: the thrust axis leans by d along body x, y
        per.append({"recording": int(g), "tilt_deg": deg, "stderr_deg": float(np.degrees(np.sqrt(max(
            along @ C @ along, 0.0)))), "azimuth_deg": float(np.degrees(np.arctan2(d[1], d[0]))), "z": round(z, 2)})
    return per, force


def _tilt_fit(cols: np.ndarray, target: np.ndarray, t: np.ndarray) -> tuple[np.ndarray | None, np.ndarray]:
    """One recording's tilt (2,) rad and its 2x2 covariance: the larger (by trace) of the Newey-West one and
    the jackknife over :data:`TILT_BLOCKS` blocks. ``cols`` (2n, 2) and ``target`` (2n,) hold the x rows,
    then the y rows, of the recording's ``n`` samples at times ``t`` (n,)."""
    n = len(t)
    step = float(np.median(np.diff(t))) if n > 1 else 1.0
    lag = max(1, int(round(TILT_LAG_S / max(step, 1e-6))))
    axis = np.repeat([0, 1000], n)
    try:
        full = lstsq(cols, target, lag=lag, groups=axis)
        block = np.tile(np.arange(n) * TILT_BLOCKS // n, 2)
        leave = [np.linalg.lstsq(cols[block != b], target[block != b], rcond=None)[0] for b in range(TILT_BLOCKS)]
    except (np.linalg.LinAlgError, ValueError):
        return None, np.zeros((2, 2))
    leave = np.array(leave)
    jack = (TILT_BLOCKS - 1) / TILT_BLOCKS * (leave - leave.mean(0)).T @ (leave - leave.mean(0))
    return full.coef, full.cov if np.trace(full.cov) >= np.trace(jack) else jack


def push_beyond_tilt(data: GapData, A: np.ndarray, tilt_cols: np.ndarray, own: list[int]) -> tuple[float, float, float]:
    """How far a steady push stands apart from a thrust-axis tilt on these rows: the model's columns ``A``
    (3K, p), whose ``own`` columns are the push's, refitted with the tilt's columns ``tilt_cols`` (3K, 2)
    beside them (Newey-West errors over :data:`TILT_LAG_S`, recordings independent).

    Returns
    -------
    push : N, the size of the push left beside the tilt
    stderr : N, its standard error (along the push)
    z : the push's Wald statistic's square root, ``sqrt(f^T C^-1 f)`` (C: the push's 2x2 covariance)
    """
    return _push_left(_robust_fit(data, np.hstack([A, tilt_cols])), own)


def _push_left(fit: LstsqResult, own: list[int]) -> tuple[float, float, float]:
    """``(push [N], its standard error along itself [N], z)`` of the push's columns ``own`` in ``fit``
    (:func:`push_beyond_tilt`)."""
    f = fit.coef[own]
    C = fit.cov[np.ix_(own, own)]
    push = float(np.hypot(*f))
    z = float(np.sqrt(max(f @ np.linalg.pinv(C) @ f, 0.0)))
    along = f / push if push > 0 else np.array([1.0, 0.0])
    return push, float(np.sqrt(max(along @ C @ along, 0.0))), z


def _drag_gains(x: list[np.ndarray], y: list[np.ndarray], cluster: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares gains of ``y[i] ~ g_i x[i] + c_i`` (one regression per direction ``i``) and
    their cluster-robust covariance (clusters: ``cluster`` labels). Returns ``(g, cov)``."""
    n, k = len(cluster), len(x)
    X = np.zeros((k * n, 2 * k))
    for i in range(k):
        X[i * n:(i + 1) * n, 2 * i] = x[i]
        X[i * n:(i + 1) * n, 2 * i + 1] = 1.0
    Y = np.concatenate(y)
    beta, *_ = np.linalg.lstsq(X, Y, rcond=None)
    e = Y - X @ beta
    bread = np.linalg.pinv(X.T @ X)
    labels = np.tile(cluster, k)
    _, inv = np.unique(labels, return_inverse=True)
    scores = np.zeros((inv.max() + 1, X.shape[1]))
    np.add.at(scores, inv, X * e[:, None])
    cov = bread @ (scores.T @ scores) @ bread
    idx = [2 * i for i in range(k)]
    return beta[idx], cov[np.ix_(idx, idx)]


def _airspeed_reading(g: np.ndarray, cov: np.ndarray, push: float, wsum: float
                      ) -> tuple[dict[str, float], dict[str, float]]:
    """Rotor drag, body drag and wind speed read from the gains along and across the push, ``g`` (2,) [N s^2/m]
    with covariance ``cov`` (2, 2), the push [N] and the rotor speeds' sum at hover ``wsum`` [rad/s]
    (:func:`airspeed_drag`), and their standard errors from the gains' (first order; the push's own error left
    out)."""
    def read(gg: np.ndarray) -> np.ndarray:
        v_w = push / (gg[1] * wsum)
        return np.array([2 * gg[1] - gg[0], (gg[0] - gg[1]) * wsum / v_w, v_w])

    x = read(g)
    J = np.empty((3, 2))
    for j in range(2):
        h = 1e-6 * max(abs(g[j]), 1e-12)
        J[:, j] = (read(g + h * np.eye(2)[j]) - read(g - h * np.eye(2)[j])) / (2 * h)
    se = np.sqrt(np.clip(np.diag(J @ cov @ J.T), 0.0, None))
    names = ("k_d", "c_d", "wind_speed_m_s")
    return dict(zip(names, map(float, x))), dict(zip(names, map(float, se)))


def _airspeed_gains(data: GapData, fit: ModelFit) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """``(g, cov, push)`` of :func:`airspeed_drag`: the gains along and across the push (2,) [N s^2/m], their
    covariance, and the push (2,) [N, world x, y]; None without a push or a positive rotor drag."""
    wind, _ = fit.effect_params("wind")
    push = np.array([wind["f_x"], wind["f_y"]])
    if np.hypot(*push) <= 0 or fit.coef["k_d"] <= 0:
        return None
    u = np.array([*push, 0.0]) / np.hypot(*push)
    w = np.array([-u[1], u[0], 0.0])
    A, names = _columns(data, fit)
    col = unstack(A[:, names.index("k_d")])  # (K, 3) N per unit k_d, world
    # every drag force the fit attributes goes back into what the gains read: a body drag fitted beside rotor drag
    # (on the ground speed) had taken part of the anisotropy, and the reading came out at half the rotor drag
    # and 1.4 times the wind (gap-proof's 4 m/s wind-tunnel row once the thrust map's offset was corrected)
    drags = [n for n in ("k_d", "c_d") if n in names]
    r = fit.residual(data) + sum(fit.coef[n] * unstack(A[:, names.index(n)]) for n in drags)
    cluster = data.group.astype(np.int64) * 10**7 + np.floor(data.t / DRAG_BLOCK_S).astype(np.int64)
    g, cov = _drag_gains([col @ u, col @ w], [r @ u, r @ w], cluster)
    return g, cov, push


def _readings_apart(data: GapData, fit: ModelFit, wsum: float) -> dict[str, float]:
    """The standard deviation of :func:`_airspeed_reading`'s values over the recordings, each refitted alone
    (``gap-report.md``'s honest errors: sessions differ); {} with fewer than two recordings that give one."""
    values = []
    for g in np.unique(data.group):
        sub = data.subset(data.group == g)
        if len(sub) < 10:
            continue
        found = _airspeed_gains(sub, fit_model(sub, fit.effects, with_stderr=False))
        if found is not None and found[0][1] > 0:
            values.append(_airspeed_reading(found[0], found[1], float(np.hypot(*found[2])), wsum)[0])
    if len(values) < 2:
        return {}
    return {k: float(np.std([v[k] for v in values], ddof=1)) for k in values[0]}


def airspeed_drag(data: GapData, fit: ModelFit, facts: FlightFacts) -> dict | None:
    """An ``ambiguous`` entry for rotor drag named beside a push, where its ``k_d`` may hold body
    drag on the airspeed (module docstring, point 4); None where the flights show it does not.

    The drag forces the fit attributes (rotor drag, and body drag where it is fitted too) are added back to the
    residual and regressed, along and across the push's direction separately, on that direction's part of the
    rotor-drag column (with an intercept each): gains ``g_along``, ``g_across`` [N s^2/m] with
    cluster-robust standard errors over :data:`DRAG_BLOCK_S` blocks. With drag on the airspeed
    at a wind speed ``v_w`` above the flight speeds: ``g_across = k_d + c_d v_w / W``,
    ``g_along = k_d + 2 c_d v_w / W`` (``W``: sum of the rotor speeds at hover, rad/s), so ``k_d = 2 g_across -
    g_along``, and the push ``k_d W v_w + c_d v_w^2`` gives ``v_w = push / (g_across W)``. Each value's error is
    the larger of the gains' and the spread of the values read on each recording alone.
    """
    if not {"wind", "rotor_drag"} <= set(fit.effects):
        return None
    k_d = fit.coef["k_d"]
    S = facts.wsum_hover
    found = _airspeed_gains(data, fit) if np.isfinite(S) else None
    if found is None:
        return None
    g, cov, push_xy = found
    push = float(np.hypot(*push_xy))
    se = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    diff = float(g[0] - g[1])
    se_diff = float(np.sqrt(max(cov[0, 0] + cov[1, 1] - 2 * cov[0, 1], 0.0)))
    v_low = push / (k_d * S)  # m/s: the wind speed if all the push were rotor drag (a lower bound)
    c_d_typ = EFFECTS["body_drag"].typical[0]
    typical_diff = c_d_typ * v_low / S  # the along/across difference a typical body drag would make
    gains = (f"the drag on the velocity is {g[0] * S:.3g} ± {se[0] * S:.2g} N per m/s along the push and "
             f"{g[1] * S:.3g} ± {se[1] * S:.2g} N per m/s across it")
    wind_speed = f"a wind of at least {v_low:.2g} m/s (the push over the fitted linear drag)"
    if abs(diff) > ANISOTROPY_Z * se_diff and g[1] > 0:
        values, errors = _airspeed_reading(g, cov, push, S)
        apart = _readings_apart(data, fit, S)
        errors = {k: max(e, apart.get(k, 0.0)) for k, e in errors.items()}
        reading = values | {"stderr": errors}
        why = (f"{gains}: drag on the airspeed v - v_wind, where body drag adds to rotor drag in {wind_speed}. "
               f"Read as such: rotor drag k_d = {values['k_d']:.3g} ± {errors['k_d']:.2g} N s^2/m, body drag "
               f"c_d = {values['c_d']:.3g} ± {errors['c_d']:.2g} kg/m, wind {values['wind_speed_m_s']:.2g} ± "
               f"{errors['wind_speed_m_s']:.2g} m/s; the isotropic k_d = {k_d:.3g} is their blend, not rotor drag")
    elif typical_diff > ANISOTROPY_Z * se_diff:
        return None  # a typical body drag on the airspeed would have shown: k_d is rotor drag
    else:
        reading = None
        why = (f"{gains}; in {wind_speed} a typical body drag (c_d = {c_d_typ:g} kg/m) on the airspeed would "
               f"add {typical_diff * S:.2g} N per m/s more along the push than across, which these flights "
               f"cannot resolve (± {se_diff * S:.2g}): the fitted k_d = {k_d:.3g} may be rotor drag plus body drag")
    return {"candidates": ["rotor_drag", "body_drag"], "why": why,
            "to_separate": ("fly at ground speeds up to and beyond the wind's, along and across it, or the same "
                            "pattern at two wind speeds"),
            "params_if_named": {"k_d": k_d}, "if_drag_on_airspeed": reading}
