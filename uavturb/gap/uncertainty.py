"""Honest errors of the named effects' parameters (``gap-report.md``: "Stated errors are honest").

The least-squares standard error of a parameter (Newey-West, :func:`uavturb.gap.fit.fit_model`)
measures sample noise only. What really varies between flights of one vehicle is larger: sessions,
batteries and propellers, the slow update of a stream, and the height reference (where the rotor
plane and the floor really are). On real Crazyflie sessions the sample error of ``k_T`` was 0.1 %
while recordings differed by 3.6 %. The error stated for each parameter here is the largest of the
statistical terms (sample, between recordings or blocks), with each systematic term after them (surface
curve, rotor timing, command sampling, thrust map: :data:`SYSTEMATIC_TERMS`, sources independent of each
other and of the noise) added in quadrature:

- **sample**: the least-squares error, widened by the height-reference term below;
- **between recordings**: with two or more recordings that can each test the effect, the standard
  deviation of the parameter fitted on each recording alone (so a recording's own fit lands within
  about two stated errors of the joint value, as the contract asks). A recording with fewer rows in
  flight than :data:`~uavturb.gap.design.MIN_ROWS` has no fit of its own worth the name and is left out of
  the spread: a take-off whose rotor speeds
  update at 3 Hz (47 updates in flight) fitted alone an exponential ground effect's A = 1.03 where the
  two walks beside it gave 0.45 and 0.35, and its noise, counted as a spread between sessions, had
  left the law within two errors of zero. Likewise a recording that cannot test the effect: one that never comes
  within a surface law's reach, or one where the effect, at the value all recordings give it, never reaches
  :data:`~uavturb.gap.decide.PRACTICAL_SHARE` of the weight (:func:`~uavturb.gap.decide.can_test_alone`: a
  take-off that barely moves sideways has no rotor drag of its own to fit: counted as a session's spread, its fit
  had widened the error of the drag of a take-off and two walks to 1.2e-5, where the walks give
  (1.82 +- 0.23) x 1e-6, and the drag was no discovery); with fewer than two recordings that can, the spread
  between blocks stands in;
- **between blocks**: with one recording (or one long enough to be fitted alone, or one that can test the
  effect), the jackknife over
  :data:`TIME_BLOCKS` contiguous blocks of it (correlated errors within a block, independent between), each
  block's deviation weighted by one less its share of the parameter's information (Hinkley's weighted jackknife,
  :func:`_block_spread`). A block that holds nearly all of it leaves, when left out, a fit of almost none: a
  slow hexarotor flight whose near-floor hovers all fell in its first fifth read mu = 0.53 without them (truth
  2, the rest of the flight 0.3-1.3 m up), and the plain jackknife's 1.17 had rejected a lift of 72 % at 7 cm
  as within two errors of zero. The largest share is kept (``largest_block_share``): near 1, the spread between
  stretches of the flight could not be measured, and the report says so;
- **height reference** (surface effects): half the change of the parameter when every height is
  moved by ``+-`` :data:`HEIGHT_REFERENCE_M` (the rotor plane's height above the body origin and the
  floor's height are rarely known better than a centimetre), added in quadrature to the sample error;
- **surface curve** (surface laws, :func:`with_curve_check`): half the difference between the finder's
  value, fitted on every row in time, and the same law fitted to the measured thrust ratio per height
  bin, a model-free second estimate. Two estimators of one parameter that disagree say a systematic
  error is at work (a 3 Hz rotor stream interpolated between its updates, sessions' thrust levels
  pooled: 3.6 against the curve's 1.6 for a true 2.0), and the stated error must cover it. Where the
  law's shape does not fit the curve the term counts all the same: the two estimators then weigh the
  heights differently (every row in time against the bins' own errors), and which heights should
  decide is not known.
- **rotor timing** (measured rotor speeds, ESC telemetry): half the change of the parameter between fits
  with the rotor stream's delay at either end of what is still uncertain of it
  (:func:`uavturb.gap.preparation.timing_interval`: one standard error either side of a delay taken out,
  up to 80 ms where none could be timed). A thrust that is read 60 ms late moves every law that reads
  the thrust.
- **stream rate** (every named effect where the ground truth updates too slowly for a surface effect,
  :func:`stream_rate_term`: PX4's estimate written at 50-90 Hz but updated at 9 Hz): the change of the parameter
  when that stream's updates are thinned to every other one (:func:`uavturb.gap.preparation.state_thinned`). An
  error that grows with the interval between updates (heights and accelerations read between them) is at the
  recorded rate about as large as what doubling the interval adds to it, so the change is the term (not half of
  it).
- **command sampling** (``motor_lag``, :func:`command_sampling_term`): a quarter of the rotor stream's hold
  period (the interval between its updates). The lag is fitted with the commands held between rows (zero-order hold); a
  controller that changes them between rows (a ramp) leads the held values by up to half a step, which the
  time constant takes up: simulated 50 ms lags under commands logged at 100 Hz read 47.4 ms, 26 sample errors
  off. Half the half step is the term, so that two stated errors cover either convention.
- **thrust map** (commanded rotor speeds, :func:`thrust_map_term`): half the change of the parameter when
  the recorded speeds are moved by the offset that makes thrust per ``sum((w + delta)^2)`` constant at
  each height of each recording (:func:`uavturb.sysid.nominal.speed_offset`), where that offset counts (two
  errors from zero and at least 2.5 % of the hover speed, :attr:`~uavturb.sysid.nominal.SpeedOffset.counts`).
  An idle speed in the motors' command map reads as a stronger ground effect (the rotors turn slower near
  the floor); the data cannot always tell it from other physics that depends on the thrust level, so the
  named values stay and the error covers the other reading. Where it does not count, half the change between
  the refits at one standard error either side of the reading; where there is no reading (too few steady rows
  far from the floor, or a least residual at an end of the range searched), between none and
  :data:`~uavturb.sysid.nominal.UNREAD_OFFSET_SPAN` of the hover speed
  (:meth:`~uavturb.sysid.nominal.SpeedOffset.open_interval`).
- **speed offset** (commanded rotor speeds whose offset is decisive,
  :attr:`~uavturb.sysid.nominal.SpeedOffset.decisive`): the finder runs again on the speeds moved by it
  (:func:`uavturb.gap.finder.read_on_moved_speeds`), and each value's error carries half its change from the
  recorded speeds' reading.

- **mass** (parameters in newtons or kilograms: ``k_d``, ``c_d``, ``f_x``, ``f_y``; :func:`mass_term`): the
  forces are ``vehicle.yaml``'s mass times accelerations, so a mass off by 3 % (a battery swapped) scales every
  force-unit parameter by 3 %, which no fit can see: the blind probe's hexarotor read k_d 8.45e-5 +- 0.7e-6
  and a push of (0.513 +- 0.0016, -0.310 +- 0.0007) N for 8.06e-5 and (0.5, -0.3). Where ``vehicle.yaml``
  also states the thrust coefficient, the flights' own (in newtons through that mass) differs from it by the
  mass's error or by the stated coefficient's: within :data:`YAML_THRUST_DIFFERS` that difference is the term's
  share of each such parameter; beyond it the stated coefficient is no measure (rotor speeds in other units, a
  guess) and there is no term.

- **untaken candidate** (:func:`untaken_term`): half the largest change of the parameter when a candidate the
  selection did not take, but whose held-out gain at its last step reached :data:`UNTAKEN_Z` errors, is fitted
  beside the named effects (within its physical range). Two laws can share a residual that the held-out rows
  cannot split: on the blind probe's hexarotor with body drag (c_d = 0.05 kg/m) and rotor drag at about 1 m/s,
  body drag's gain read 1.9 errors, so it was not named, and rotor drag took its force: k_d 9.46e-5 +- 0.43e-5
  for 8.06e-5.

The report keeps every term (``error_budget``) and names the one that limits the parameter.
"""

from __future__ import annotations

import re
from typing import Callable

import numpy as np

from uavturb.gap.design import MIN_ROWS, GapData, effective_S, surface_reach_m
from uavturb.gap.fit import ModelFit, _nl_values, fit_model, forking_worth, information_shares
from uavturb.sysid.nominal import SpeedOffset, hover_speed, offset_cells, speed_offset, unread_interval
from uavturb.numerics.blocks import contiguous_blocks, jackknife_se, weighted_jackknife_se
from uavturb.numerics.processes import ForkedPool, forked_state
from uavturb.physics.effects import EFFECTS

#: m, uncertainty of the height reference (rotor plane over the floor) assumed for surface effects
HEIGHT_REFERENCE_M = 0.01
#: contiguous blocks of a single recording for the jackknife
TIME_BLOCKS = 5
#: a block's share of a parameter's information (``largest_block_share``) from which its spread between stretches
#: of the flight is mostly unmeasured, and the report says so
ONE_STRETCH_SHARE = 0.8
#: |value| / statistical standard error (:func:`presence_z`) a parameter that says an effect is there must reach
HONEST_Z = 2.0
#: one sample's share of a parameter's information from which the parameter rests on that sample alone
#: (:func:`one_sample`): its value cannot be told from that sample's own error, which nothing else measures
ONE_SAMPLE_SHARE = 0.5
#: samples above which :func:`one_sample` is not read: its shares need three designs of every sample at once
#: (a flight-hour at 200 Hz: about 0.4 GB more at the peak), and the samples are the slowest stream's updates, so this
#: many come from streams fast enough that a pass near a surface holds many of them (a 3 Hz stream gives 10,000 an hour)
ONE_SAMPLE_MAX_ROWS = 100_000


def _params(fit: ModelFit, name: str) -> dict[str, float]:
    return fit.effect_params(name)[0]


def _fit_or_none(data: GapData, effects: frozenset[str]) -> ModelFit | None:
    """The model with ``effects`` fitted on ``data`` alone, or None where the fit fails."""
    try:
        return fit_model(data, effects, with_stderr=False)
    except (np.linalg.LinAlgError, ValueError):
        return None


class Refits:
    """The refits of one model on parts of one data set (each recording alone, each time block left out, every
    height moved), each computed once: the error budgets of a model's several effects, and the decision whether
    each is pinned before them, refit the same parts with the same effects (six walks' analysis: 14 budgets of
    two named effects, 112 refits, a fifth of the time). Bound to one data set: make one per data set."""

    def __init__(self) -> None:
        self._fits: dict[tuple, ModelFit | None] = {}
        self._testable: dict[tuple, bool] = {}

    def __len__(self) -> int:
        """The refits computed (each part and set of effects once)."""
        return len(self._fits)

    def cannot_test(self, key: tuple, effects: frozenset[str], name: str) -> bool:
        """Whether the part ``key`` was found unable to test ``name`` (with ``effects``) by a :meth:`params` call."""
        return self._testable.get((key, name, effects)) is False

    def params(self, key: tuple, part: Callable[[], GapData], effects: frozenset[str], name: str,
               can_test: Callable[[GapData], bool] | None = None) -> dict[str, float] | None:
        """``name``'s parameters in the model with ``effects`` fitted on the part ``key`` (built by ``part``
        where needed), or None where the fit fails, a value is not finite or ``can_test`` says the part cannot
        test the effect."""
        testable, built = self._tests(key, part, effects, name, can_test)
        if not testable:
            return None
        if (effects, key) not in self._fits:
            self._fits[effects, key] = _fit_or_none(built if built is not None else part(), effects)
        fit = self._fits[effects, key]
        if fit is None:
            return None
        p = _params(fit, name)
        return p if all(np.isfinite(v) for v in p.values()) else None

    def _tests(self, key: tuple, part: Callable[[], GapData], effects: frozenset[str], name: str,
               can_test: Callable[[GapData], bool] | None) -> tuple[bool, GapData | None]:
        """Whether the part ``key`` can test ``name`` with ``effects`` (``can_test``, asked once; True without it),
        and the part where it was built to ask (None otherwise)."""
        if can_test is None:
            return True, None
        built = None
        if (key, name, effects) not in self._testable:
            built = part()
            self._testable[key, name, effects] = bool(can_test(built))
        return self._testable[key, name, effects], built

    def prefetch(self, parts: list[tuple[tuple, Callable[[], GapData]]], effects: frozenset[str], name: str,
                 can_test: Callable[[GapData], bool] | None = None) -> None:
        """Fit the parts that :meth:`params` would fit with ``effects`` for ``name`` (``parts``: ``(key, build)``;
        those ``can_test`` accepts) side by side, in processes forked from this one
        (:class:`~uavturb.numerics.processes.ForkedPool`); :meth:`params` then finds them (a part a child could not
        fit, it fits itself: the same numbers)."""
        todo = {}
        for key, part in parts:
            if (effects, key) not in self._fits and self._tests(key, part, effects, name, can_test)[0]:
                todo[key] = part
        if len(todo) < 2:
            return
        with ForkedPool((todo, effects)) as pool:
            for key, fit in pool.map(_refit_in_child, todo).items():
                self._fits[effects, key] = fit


def _refit_in_child(key: tuple) -> ModelFit | None:
    """In a child of :meth:`Refits.prefetch`: the fit of the part ``key``."""
    parts, effects = forked_state()
    return _fit_or_none(parts[key](), effects)


def _spread(values: list[dict[str, float]], keys: tuple[str, ...]) -> dict[str, float]:
    """Per parameter: the standard deviation of ``values`` (nan with fewer than two)."""
    return {k: float(np.std([v[k] for v in values], ddof=1)) if len(values) >= 2 else float("nan") for k in keys}


def _block_spread(data: GapData, final: ModelFit, name: str, block: np.ndarray,
                  kept: list[tuple[int, dict[str, float]]], keys: tuple[str, ...]
                  ) -> tuple[dict[str, float], dict[str, float]]:
    """Per parameter of ``name``: the **between blocks** term, Hinkley's weighted jackknife
    (:func:`~uavturb.numerics.blocks.weighted_jackknife_se`) of the values ``kept`` (block left out, the values
    fitted without it) about ``final``'s, each block weighted by its share of the parameter's information
    (:func:`~uavturb.gap.fit.information_shares`); and the largest block's share. The plain jackknife where the
    shares cannot be read."""
    full = _params(final, name)
    try:
        shares = information_shares(data, final, name, block)
    except (np.linalg.LinAlgError, ValueError):
        shares = {}
    spread, largest = {}, {}
    for k in keys:
        x = np.array([v[k] for _, v in kept])
        h = shares.get(k)
        if h is None or not np.all(np.isfinite(h)):
            spread[k] = float(jackknife_se(x)) if len(x) >= 2 else float("nan")
            continue
        spread[k] = weighted_jackknife_se(x, full[k], np.array([h[b] for b, _ in kept]))
        largest[k] = float(np.max(h))
    return spread, largest


def one_sample(data: GapData, final: ModelFit, name: str) -> str | None:
    """Why a parameter of the effect ``name`` of ``final`` rests on one sample of ``data`` (a row holding over
    :data:`ONE_SAMPLE_SHARE` of its information, :func:`~uavturb.gap.fit.information_shares` with one label a
    row), else None (also where the shares cannot be read). A hexarotor's minute of flight whose rotor speeds
    updated at 3 Hz (86 samples in flight) had one of them 7 cm over the floor, just after take-off, carry 85 % of
    what pinned an exponential ground effect's amplitude: A = 0.23 +- 0.04, truth 0.10, the row reading 4.5 % more
    thrust than the law; no spread between recordings or blocks can measure the error of one sample. None
    without reading the shares over :data:`ONE_SAMPLE_MAX_ROWS` samples."""
    if len(data) > ONE_SAMPLE_MAX_ROWS:
        return None
    try:
        shares = information_shares(data, final, name, np.arange(len(data)))
    except (np.linalg.LinAlgError, ValueError):
        return None
    surface = EFFECTS[name].surface
    for k, h in shares.items():
        if not np.all(np.isfinite(h)) or float(np.max(h)) <= ONE_SAMPLE_SHARE:
            continue
        i = int(np.argmax(h))
        where = f"{data.names[int(data.group[i])]} at t = {data.t[i]:.2f} s"
        height = getattr(data, surface) if surface is not None else None
        if height is not None and np.isfinite(height[i]):
            where += f", {height[i]:.3f} m from the surface {'below' if surface == 'd_down' else 'above'}"
        return (f"its {k} rests on one sample ({where}), which carries {100 * float(h[i]):.0f} % of what pins it "
                f"(of {len(data)} samples): a value one sample gives cannot be told from that sample's own error")
    return None


def heights_shifted(data: GapData, dz: float) -> GapData:
    """``data`` with every surface height moved by ``dz`` [m] (closer to the floor for ``dz < 0``)."""
    out = data.subset(np.ones(len(data), bool))
    out.d_down = np.maximum(data.d_down + dz, 1e-3)
    out.d_up = np.maximum(data.d_up - dz, 1e-3)
    return out


def error_budget(data: GapData, final: ModelFit, name: str,
                 can_test: Callable[[GapData], bool] = lambda d: True,
                 height_reference_m: float = HEIGHT_REFERENCE_M,
                 refits: Refits | None = None) -> dict[str, dict[str, float]]:
    """The terms of the module docstring for each parameter of the effect ``name`` of ``final``.

    Parameters
    ----------
    data : the samples ``final`` was fitted on (the simulator's own effects already taken off ``y``)
    final : the final model
    name : a named effect of ``final``
    can_test : whether a recording's own rows can test the effect (a surface effect needs flights
        within its reach)
    height_reference_m : m, uncertainty of the heights over surfaces (``uavturb gap --height-uncertainty``)
    refits : the refits of ``data``'s parts computed before (shared by the budgets of one model's effects)

    Returns
    -------
    ``{param: {"sample", "height_reference", "between_recordings" or "between_blocks", "stderr", "limited_by"}}``
    """
    keys = tuple(_params(final, name))
    _, se = final.effect_params(name)
    effects = final.effects
    refits = Refits() if refits is None else refits
    budget = {k: {"sample": float(se.get(k, np.nan))} for k in keys}
    if EFFECTS[name].surface is not None and height_reference_m == 0.0:
        for k in keys:
            budget[k]["height_reference"] = 0.0
    elif EFFECTS[name].surface is not None:
        up, down = (refits.params(("height", dz), lambda dz=dz: heights_shifted(data, dz), effects, name)
                    for dz in (height_reference_m, -height_reference_m))
        for k in keys:
            budget[k]["height_reference"] = abs(up[k] - down[k]) / 2 if up and down else float("nan")
    groups, rows = np.unique(data.group, return_counts=True)
    short = int(np.sum(rows < MIN_ROWS)) if len(groups) >= 2 else 0
    values: list[dict[str, float]] = []
    untested: list[str] = []  # recordings that cannot test the effect on their own rows
    if len(groups) - short >= 2:
        parts = [(("recording", int(g)), lambda g=g: data.subset(data.group == g)) for g in groups[rows >= MIN_ROWS]]
        label = "between_recordings"
        if forking_worth(len(data), len(parts)):
            refits.prefetch(parts, effects, name, can_test)
        values = [v for v in (refits.params(key, part, effects, name, can_test) for key, part in parts)
                  if v is not None]
        untested = [data.names[key[1]] for key, _ in parts if refits.cannot_test(key, effects, name)]
    shares: dict[str, float] = {}
    if len(values) < 2:  # one recording, or one that can test the effect: the spread between its blocks
        block = contiguous_blocks(data.t, TIME_BLOCKS)
        parts = [(("block", b), lambda b=b: data.subset(block != b)) for b in range(TIME_BLOCKS)]
        label = "between_blocks"
        if forking_worth(len(data), len(parts)):
            refits.prefetch(parts, effects, name, can_test)
        kept = [(b, v) for b, v in enumerate(refits.params(key, part, effects, name, can_test) for key, part in parts)
                if v is not None]
        values = [v for _, v in kept]
        spread, shares = _block_spread(data, final, name, block, kept, keys)
    else:
        spread = _spread(values, keys)
    for k in keys:
        b = budget[k]
        b[label] = spread[k]
        b["fits"] = len(values)
        if np.isfinite(shares.get(k, np.nan)):
            b["largest_block_share"] = shares[k]
        if short:
            b["recordings_too_short"] = short
        if untested:
            b["recordings_cannot_test"] = untested
        sample = float(np.hypot(b["sample"], b.get("height_reference", 0.0) or 0.0))
        terms = {"sample": b["sample"], "height_reference": b.get("height_reference", 0.0), label: spread[k]}
        b["stderr"] = float(np.nanmax([sample, spread[k]])) if np.isfinite(sample) or np.isfinite(spread[k]) \
            else float("nan")
        finite = {t: v for t, v in terms.items() if v is not None and np.isfinite(v)}
        b["limited_by"] = max(finite, key=finite.get) if finite else "unknown"
    return budget


def presence_z(budget: dict[str, dict[str, float]], params: dict[str, float], keys) -> float:
    """The largest ``|value| / error`` over the parameters ``keys`` (those that say an effect is there,
    :attr:`~uavturb.physics.effects.EffectSpec.presence_params`), the error the budget's statistical terms only
    (sample, between recordings, between blocks): the height reference moves a surface law's parameter but
    cannot make a lift near the floor disappear."""
    se = statistical_errors(budget)
    return max(abs(params[k]) / se[k] if se[k] > 0 else np.inf for k in keys)


def statistical_errors(budget: dict[str, dict[str, float]]) -> dict[str, float]:
    """``{param: the largest of its sample, between-recordings and between-blocks terms}`` of an error budget."""
    return {k: float(np.nanmax([b["sample"], b.get("between_recordings", np.nan), b.get("between_blocks", np.nan)]))
            for k, b in budget.items()}


def honest_stderr(budget: dict[str, dict[str, float]]) -> dict[str, float]:
    """``{param: stated standard error}`` of an :func:`error_budget`."""
    return {k: b["stderr"] for k, b in budget.items()}


#: the terms of a budget that are systematic (their sources independent of each other and of the sample
#: noise): a stated error adds each in quadrature to what was stated before it
SYSTEMATIC_TERMS = ("surface_curve", "rotor_timing", "stream_rate", "thrust_map", "command_sampling", "speed_offset",
                    "mass", "untaken_candidate")
#: held-out errors of gain, at its last step, from which a candidate not taken counts in the named effects' errors
UNTAKEN_Z = 1.0
#: relative difference between the flights' thrust coefficient and ``vehicle.yaml``'s beyond which the stated one
#: is read as no measure of the mass (report.md then says they differ)
YAML_THRUST_DIFFERS = 0.15
#: every term a budget may hold, in the order they are added
BUDGET_TERMS = ("sample", "height_reference", "between_recordings", "between_blocks", *SYSTEMATIC_TERMS)


def with_systematic(budget: dict[str, dict[str, float]], term: str, values: dict[str, float]
                    ) -> dict[str, dict[str, float]]:
    """``budget`` with a systematic ``term`` (``{param: value}``, e.g. **surface curve** or **rotor timing**
    of the module docstring) beside the others. Its source is independent of the others', so each
    parameter's stated error becomes the root sum of squares of what was stated and the term (a 7.5 ms
    command-sampling term beside a 7.9 ms thrust-map term is 10.9 ms, not 7.9 ms), and ``limited_by`` names
    the largest term."""
    out = dict(budget)
    for param, value in values.items():
        b = dict(budget[param])
        b[term] = float(value)
        if np.isfinite(b[term]):
            b["stderr"] = float(np.hypot(b["stderr"], b[term])) if np.isfinite(b["stderr"]) else b[term]
            terms = {t: b[t] for t in BUDGET_TERMS if t in b and b[t] is not None and np.isfinite(b[t])}
            b["limited_by"] = max(terms, key=terms.get)
        out[param] = b
    return out


def with_curve_check(budget: dict[str, dict[str, float]], params: dict[str, float], param: str,
                     curve_value: float) -> dict[str, dict[str, float]]:
    """``budget`` with the **surface curve** term of the module docstring for ``param``: half the
    difference between the finder's value ``params[param]`` and ``curve_value``, the same law fitted to
    the measured curve, added in quadrature to the stated error (:func:`with_systematic`)."""
    return with_systematic(budget, "surface_curve", {param: abs(float(params[param]) - float(curve_value)) / 2.0})


def command_sampling_term(hold_periods_s: list[float]) -> dict[str, float]:
    """The **command sampling** term of ``motor_lag``'s ``tau`` [s]: a quarter of the longest of the
    recordings' rotor-stream hold periods ``hold_periods_s`` [s] (the median interval between a rotor's own
    updates as the stream is read, :func:`uavturb.sysid.flight_data.rotor_hold_s`; nan with none)."""
    held = [p for p in hold_periods_s if p > 0 and np.isfinite(p)]
    return {"tau": max(held) / 4.0 if held else float("nan")}


def scales_with_mass(unit: str) -> bool:
    """Whether a parameter in ``unit`` (an :class:`~uavturb.physics.effects.EffectSpec`'s) is a force's: newtons
    or kilograms among its factors."""
    return bool({"N", "kg"} & set(re.split(r"[\s/^*()]+", unit)))


def mass_term(params: dict[str, float], units: dict[str, str], k_T: float, k_T_yaml: float | None
              ) -> dict[str, float]:
    """The **mass** term of each force-unit parameter in ``params`` (``units`` theirs): its value times the
    relative difference between the flights' thrust coefficient ``k_T`` and ``vehicle.yaml``'s ``k_T_yaml``
    [N/(rad/s)^2], where that is stated and within :data:`YAML_THRUST_DIFFERS`; empty otherwise."""
    if not k_T_yaml or not np.isfinite(k_T) or k_T <= 0:
        return {}
    share = abs(k_T / k_T_yaml - 1.0)
    if share > YAML_THRUST_DIFFERS:
        return {}
    return {k: abs(float(v)) * share for k, v in params.items() if scales_with_mass(units[k])}


def untaken_term(final: ModelFit, beside: list[ModelFit], name: str) -> dict[str, float]:
    """The **untaken candidate** term of the named effect ``name``'s parameters: half the largest change from
    ``final`` among the fits ``beside`` (``final``'s effects and one candidate more); empty without any."""
    if not beside:
        return {}
    params, _ = final.effect_params(name)
    return {k: max(abs(fit.effect_params(name)[0][k] - v) for fit in beside) / 2.0 for k, v in params.items()}


def timing_term(low: dict[str, float] | None, high: dict[str, float] | None, keys: tuple[str, ...]
                ) -> dict[str, float]:
    """The **rotor timing** term: half the change of each parameter between the fits at the two ends of
    the rotor stream's timing interval (nan where a fit failed)."""
    if low is None or high is None:
        return {k: float("nan") for k in keys}
    return {k: abs(float(high[k]) - float(low[k])) / 2.0 for k in keys}


def stream_rate_term(recorded: dict[str, float], thinned: dict[str, float] | None) -> dict[str, float]:
    """The **stream rate** term: the change of each parameter when the slow stream runs at half its update rate
    (``thinned``, None where that fit failed: nan)."""
    if thinned is None:
        return {k: float("nan") for k in recorded}
    return {k: abs(float(thinned[k]) - float(v)) for k, v in recorded.items()}


def thrust_map_term(data: GapData, final: ModelFit, residual: np.ndarray | None = None
                    ) -> tuple[SpeedOffset | None, tuple[float, float], dict[str, dict[str, float]]]:
    """The **thrust map** term of commanded rotor speeds: the recorded speeds' offset (None where too few rows are at
    least :data:`~uavturb.sysid.nominal.OFFSET_RADII` rotor radii over the floor), the offsets it leaves open [rad/s]
    (:meth:`~uavturb.sysid.nominal.SpeedOffset.open_interval`; :func:`~uavturb.sysid.nominal.unread_interval` where
    there is no reading), and ``{effect: {param: half the change}}`` of every effect of ``final`` between its refits
    on ``data`` with the speeds moved by either end of them (the hover speed kept: laws linear in the speeds keep
    their scale).

    ``data``: the rows ``final`` was fitted on (the simulator's own effects among its effects). The thrust
    the rotors make is the measured force along the body z axis less every other force of ``final`` (the motor
    lag's included: the offset is read on the lagged speeds' sums); a surface's lift stays in it, constant
    within each cell of one height. ``residual``: ``final.residual(data)`` where the caller has it (K, 3) N."""
    cells = offset_cells(data.group, data.d_down, data.d_up, data.rotor_radius, surface_reach_m(data))
    volts = [v for v in data.voltage_means.values() if np.isfinite(v)]
    sag = "battery_sag" in final.effects and not volts
    read = final
    if sag:  # the offset is read with the sag, not on thrusts the sag's own fit (biased by the offset) took out
        read = fit_model(data, set(final.effects) - {"battery_sag"}, with_stderr=False)
        residual = None
    nl = _nl_values(read.nonlinear)
    S_thrust = effective_S(data, set(read.effects), nl)  # lagged, times each row's level
    rest = read.residual(data) if residual is None else residual
    y_thrust = np.einsum("ki,ki->k", rest, data.R[:, :, 2]) + read.coef["k_T"] * S_thrust
    middle = np.zeros(len(data.t))
    for g in np.unique(data.group):
        rows = data.group == g
        middle[rows] = 0.5 * (data.t[rows].min() + data.t[rows].max())
    noise = np.array([data.voltage_noise.get(name, 0.0) for name in data.names])[data.group] if volts else None
    found = speed_offset(y_thrust, data.rotor_speeds, cells, data.t, S=S_thrust / data.thrust_level,
                         voltage_dev=data.voltage_dev, voltage_mean=float(np.mean(volts)) if volts else float("nan"),
                         sag_time=data.t - middle if sag else None, voltage_var=noise)
    ends = found.open_interval() if found is not None else unread_interval(hover_speed(data.rotor_speeds))
    if not final.effects or not all(np.isfinite(ends)) or ends[0] == ends[1]:
        return found, ends, {}
    effects = frozenset(final.effects)
    w_hover = found.w_hover if found is not None else hover_speed(data.rotor_speeds)
    try:
        lo, hi = (fit_model(data.with_speed_offset(d, w_hover) if d != 0.0 else data, effects, with_stderr=False)
                  for d in ends)
    except (np.linalg.LinAlgError, ValueError):
        return found, ends, {name: {k: float("nan") for k in _params(final, name)} for name in effects}
    return found, ends, {name: {k: abs(float(hi.effect_params(name)[0][k]) - float(v)) / 2.0
                                for k, v in _params(lo, name).items()} for name in effects}

