"""The named effects as the report states them (``gap-report.md``: honest errors): each chosen effect's values
with its error budget, and the systematic terms added to it (the rotor streams' timing, a slow stream's rate, the
thrust map's open offset, candidates not taken, the mass, the measured surface curve's own fit)."""

from __future__ import annotations

from typing import Any, Sequence

import numpy as np

from uavturb.errors import InputError
from uavturb.gap.design import GapData, apply_thrust_levels
from uavturb.gap.discovery import effect_budget, outside_range
from uavturb.gap.explain import explanation
from uavturb.gap.fit import ModelFit, fit_model
from uavturb.gap.flight_rows import flight_rows
from uavturb.gap.preparation import rotor_shifted, state_thinned
from uavturb.gap.selection import Selection, last_step
from uavturb.gap.surface_laws import finder_surface_curve, law_band
from uavturb.gap.uncertainty import (
    HEIGHT_REFERENCE_M,
    UNTAKEN_Z,
    Refits,
    honest_stderr,
    mass_term,
    stream_rate_term,
    timing_term,
    untaken_term,
    with_curve_check,
    with_systematic,
)
from uavturb.physics.effects import EFFECTS
from uavturb.sysid.flight_data import flight_data
from uavturb.sysid.nominal import (
    OFFSET_PRACTICAL,
    OFFSET_RADII,
    OFFSET_SPAN,
    UNREAD_OFFSET_SPAN,
    hover_speed,
    stated_offset,
)


def effects_named(data: GapData, sel: Selection, final: ModelFit, facts: Any,
                  height_uncertainty: float = HEIGHT_REFERENCE_M, refits: Refits | None = None,
                  values: ModelFit | None = None) -> list[dict[str, Any]]:
    """The report's ``effects``: each chosen effect's fitted parameters with honest errors
    (:mod:`uavturb.gap.uncertainty`: sample, height reference, between recordings or blocks), the
    explanation and the held-out gain. ``values``: the same model fitted where its values are stated (the rotor
    speeds moved to the centre of the offsets the thrust map leaves open, :func:`at_stated_offset`), ``final``
    where None; the error budgets are ``final``'s, whose spreads the offset does not move."""
    effects_out = []
    for s in sel.steps:
        params, _ = (final if values is None else values).effect_params(s.name)
        budget = effect_budget(data, final, s.name, height_uncertainty, refits)
        named_for = _named_for(s, sel.tried) if s.named_for is not None else None
        effects_out.append({
            "name": s.name, "params": params, "stderr": honest_stderr(budget),
            "explanation": explanation(s.name, params, facts) + _together(s, sel.steps)
            + _for_its_physics(s.z, named_for),
            "heldout_rmse_before_N": s.heldout_before, "heldout_rmse_after_N": s.heldout_after,
            "z_heldout": s.z, "error_budget": budget,
        } | ({"named_with": s.named_with} if s.named_with in sel.chosen else {})
          | ({"named_for": named_for} if named_for is not None else {}))
    return effects_out


def _named_for(step: Any, tried: dict[str, dict[str, float]]) -> dict[str, Any]:
    """``{"law", "z_heldout", "heldout_rmse_N", "own_heldout_rmse_N"}`` (and ``"with"``, the partner, for a law
    named together with another): the alternative law a standard law was named for
    (:attr:`~uavturb.gap.selection.Step.named_for`), the held-out gain with which it passed (with the partner
    beside it), and the held-out errors of both at the step the standard law was taken (``candidates_tried``)."""
    k = max(int(key[4:key.index("_")]) for key in tried[step.name] if key.endswith(f"_named_for_{step.named_for}"))
    rmse = f"step{k}_heldout_rmse_N" if step.named_with is None else f"step{k}_heldout_rmse_with_{step.named_with}_N"
    return {"law": step.named_for, "z_heldout": tried[step.name][f"step{k}_named_for_{step.named_for}"],
            "heldout_rmse_N": tried[step.named_for][rmse], "own_heldout_rmse_N": tried[step.name][rmse]
            } | ({"with": step.named_with} if step.named_with is not None else {})


def _for_its_physics(z: float, f: dict[str, Any] | None) -> str:
    """The sentence a standard law with held-out gain ``z`` named for an alternative of it (``f``,
    :func:`_named_for`) gets, or '' where ``f`` is None."""
    if f is None:
        return ""
    beside = "" if "with" not in f else f" beside {f['with']}"
    return (f" Named for its physics: {beside[1:] or 'alone'} this law improved the held-out fit by z = {z:.1f}, while "
            f"{f['law']}, another law of the same effect, passed{beside} with z = {f['z_heldout']:.1f} but fitted the "
            f"held-out rows no better ({f['heldout_rmse_N']:.4g} against {f['own_heldout_rmse_N']:.4g} N): "
            "another law is named instead only where it fits better.")


def _together(step: Any, steps: Sequence[Any]) -> str:
    """The sentence an effect named together with another still among ``steps`` gets
    (:func:`~uavturb.gap.selection._thrust_laws_together`), or ''. Where one of the two was named for an
    alternative law of its physics, the pair's gain is that alternative's (the sentence of
    :func:`_for_its_physics` says why)."""
    partner = next((s for s in steps if s.name == step.named_with), None)
    if partner is None:
        return ""
    both = {EFFECTS[step.name].surface, EFFECTS[step.named_with].surface}
    how = ("with surfaces both below and above, both lifts raise the thrust per rotor speed squared" if both == {
        "d_down", "d_up"} else "the battery lowers the thrust per rotor speed squared as it sags, while the surface "
           "raises it where the flights came near, so each law alone takes part of the other")
    standard = step if step.named_for is not None else partner if partner.named_for is not None else None
    gain = (f"together they do (z = {step.z:.1f})" if standard is None else
            f"together they gain z = {step.z:.1f}, and {standard.named_for} in the place of {standard.name} passed "
            "with the other")
    return (f" Named together with {step.named_with}: {how}, and neither law alone improved the held-out fit beyond "
            f"noise; {gain}.")


def cross_checked(effects: list[dict[str, Any]], curve_fits: dict) -> list[dict[str, Any]]:
    """``effects`` with each surface law's error covering its disagreement with the same law fitted to the
    measured surface curve (:func:`uavturb.gap.uncertainty.with_curve_check`), whether or not the law's shape
    fits the curve: where it does not, the two estimators weigh the heights differently, and what they
    disagree by is not known either."""
    for e in effects:
        fit = curve_fits.get(e["name"])
        if fit is None or not np.isfinite(fit.value) or fit.param not in e["params"]:
            continue
        e["error_budget"] = with_curve_check(e["error_budget"], e["params"], fit.param, fit.value)
        e["stderr"] = honest_stderr(e["error_budget"])
    return effects


def _refit_on(recordings: Sequence, paths: Sequence[str], final: ModelFit) -> ModelFit | None:
    """``final``'s effects fitted on the flights of ``recordings`` (streams changed for a systematic term: rotor
    timing, stream rate), each recording's thrust level its own where levels differ; None where that fails."""
    try:
        data, _, _ = flight_rows([flight_data(r) for r in recordings], [r.vehicle for r in recordings], paths)
        apply_thrust_levels(data)
        return fit_model(data, final.effects, with_stderr=False)
    except (InputError, np.linalg.LinAlgError, ValueError):
        return None


def timing_checked(effects: list[dict[str, Any]], final: ModelFit, recordings: Sequence, paths: Sequence[str],
                   delays: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """``effects`` with the **rotor timing** term of :mod:`uavturb.gap.uncertainty` in each budget: the named
    model refitted with every measured rotor stream's delay at the earliest, then at the latest, end of what is
    still uncertain of it (:func:`uavturb.gap.preparation.timing_interval`). Recordings with commanded rotor
    speeds have no term (their lag is the ``motor_lag`` effect)."""
    if not effects or not delays:
        return effects
    interval = {d["recording"]: d["uncertain_s"] for d in delays}
    ends = []
    for side in (0, 1):
        recs = [rotor_shifted(r, interval[p][side]) if p in interval else r for r, p in zip(recordings, paths)]
        ends.append(_refit_on(recs, paths, final))
    for e in effects:
        low, high = (None if f is None else f.effect_params(e["name"])[0] for f in ends)
        e.update(with_term(e, "rotor_timing", timing_term(low, high, tuple(e["params"]))))
    return effects


def rate_checked(effects: list[dict[str, Any]], final: ModelFit, recordings: Sequence, paths: Sequence[str],
                 state_too_slow: Sequence[str]) -> list[dict[str, Any]]:
    """``effects`` with the **stream rate** term of :mod:`uavturb.gap.uncertainty` in each named effect's budget,
    where some recording's ground truth updates too slowly for a surface effect (``state_too_slow``, its paths):
    the named model refitted with those recordings' ground truth at half its update rate
    (:func:`uavturb.gap.preparation.state_thinned`). Every effect of the model gets it, not only the surface laws
    for which "too slow" is judged: the residual force is the ground truth's derivative, and a drag or a lag read on
    it moves with its rate as well (by as much as the refit shows; nothing where it does not move)."""
    if not effects or not state_too_slow:
        return effects
    thinned = _refit_on([state_thinned(r) if p in state_too_slow else r for r, p in zip(recordings, paths)], paths,
                        final)
    for e in effects:
        e.update(with_term(e, "stream_rate", stream_rate_term(
            e["params"], None if thinned is None else thinned.effect_params(e["name"])[0])))
    return effects


def untaken_checked(named: list[dict[str, Any]], data: GapData, final: ModelFit, tried: dict[str, dict[str, float]],
                    decided: set[str]) -> list[dict[str, Any]]:
    """``named`` with the **untaken candidate** term of :mod:`uavturb.gap.uncertainty` in each budget: the
    candidates not taken (nor ``decided`` otherwise) whose last held-out gain reached ``UNTAKEN_Z`` errors,
    each fitted beside ``final``'s effects, within its physical range. A surface law where a law of its surface is
    named is an alternative to that one, not a candidate beside it."""
    surfaces = {EFFECTS[n].surface for n in final.effects if EFFECTS[n].surface}
    beside, names = [], {}
    for name, entry in tried.items():
        last = last_step(entry)
        if (name in final.effects or name in decided or EFFECTS[name].surface in surfaces or last is None
                or not last[1] >= UNTAKEN_Z):
            continue
        fit = fit_model(data, set(final.effects) | {name}, with_stderr=False)
        if outside_range(data, fit, name) is None:
            beside.append(fit)
            names[name] = round(last[1], 2)
    if not beside:
        return named
    return [e | with_term(e, "untaken_candidate", untaken_term(final, beside, e["name"]))
            | {"untaken_candidates": names} if e["name"] in final.effects else e for e in named]


def mass_checked(effect: dict[str, Any], k_T: float, k_T_yaml: float | None) -> dict[str, Any]:
    """A named ``effect`` entry with the **mass** term of :mod:`uavturb.gap.uncertainty` where it has one (force-unit
    parameters, ``vehicle.yaml`` stating a thrust coefficient ``k_T_yaml`` near the flights' ``k_T``)."""
    spec = EFFECTS[effect["name"]]
    terms = mass_term(effect["params"], dict(zip(spec.params, spec.units)), k_T, k_T_yaml)
    return effect | with_term(effect, "mass", terms) if terms else effect


def with_term(effect: dict[str, Any], term: str, values: dict[str, float]) -> dict[str, Any]:
    """``error_budget`` and ``stderr`` of a named ``effect`` entry with a systematic ``term``
    (:func:`uavturb.gap.uncertainty.with_systematic`)."""
    budget = with_systematic(effect["error_budget"], term, values)
    return {"error_budget": budget, "stderr": honest_stderr(budget)}


def at_stated_offset(data: GapData, final: ModelFit, thrust_map: tuple | None
                     ) -> tuple[float, GapData, ModelFit]:
    """``(offset [rad/s], data, final)`` where the named effects and the measured surface curve are stated: the
    recorded speeds (0, ``data``, ``final``) unless the thrust map (``thrust_map``: what
    :func:`~uavturb.gap.uncertainty.thrust_map_term` returned; None with measured rotor speeds) leaves offsets open,
    then ``data`` with its speeds moved to their centre (:func:`~uavturb.sysid.nominal.stated_offset`, the hover
    speed kept) and ``final``'s effects refitted there. The effects chosen stay ``final``'s."""
    if thrust_map is None:
        return 0.0, data, final
    found, ends, _ = thrust_map
    stated = stated_offset(found, ends)
    if stated == 0.0:
        return 0.0, data, final
    moved = data.with_speed_offset(stated, found.w_hover)  # a stated offset has a reading (stated_offset)
    try:
        return stated, moved, fit_model(moved, final.effects, with_stderr=False)
    except (np.linalg.LinAlgError, ValueError):
        return 0.0, data, final


def thrust_map_checked(effects: list[dict[str, Any]], data: GapData, thrust_map: tuple | None, stated: float
                       ) -> tuple[list[dict[str, Any]], dict[str, Any] | None]:
    """``effects`` with the **thrust map** term of :mod:`uavturb.gap.uncertainty` in each budget, and the
    report's ``nominal.rotor_speed_offset`` (None with measured rotor speeds, which are the rotors' own:
    ``thrust_map`` None). ``stated``: the offset [rad/s] the named values are stated at (:func:`at_stated_offset`)."""
    if thrust_map is None:
        return effects, None
    found, ends, terms = thrust_map
    carried = (f"the named effects' errors, and the measured surface curve's, carry what moving the recorded speeds "
               f"from {ends[0]:.4g} to {ends[1]:.4g} rad/s changes (thrust map)")
    at = "" if stated == 0.0 else (
        f"; the named values and the measured surface curve are stated at the centre of what is left open, the "
        f"speeds moved by {stated:.4g} rad/s (the hover speed kept), so that their error bars centre on it")
    if found is None:
        w_hover = hover_speed(data.rotor_speeds)
        low, high = (100 * x for x in UNREAD_OFFSET_SPAN)
        note = (f"too few rows fly {OFFSET_RADII:.0f} rotor radii or more over the floor, at steady heights, to read "
                f"the offset of the recorded (commanded) speeds, so the thrust the rotors make per command is not "
                f"known apart from a surface's lift: an idle speed of {low:.0f} to {high:.0f} % of the hover speed "
                f"({w_hover:.4g} rad/s) is left open, and {carried}. To read it: hover at two or more heights far "
                f"from the floor")
        return _with_thrust_map(effects, terms), {
            "delta_rad_s": None, "stderr_rad_s": None, "share_of_hover_speed": None, "hover_speed_rad_s": w_hover,
            "rows": 0, "cells": 0, "sse_ratio": None, "voltage_k_V": None, "voltage_noise_rad_s": None, "z": None,
            "counts": False,
            "decisive": False, "applied": False, "open_interval_rad_s": [float(x) for x in ends],
            "stated_at_rad_s": stated, "note": note}
    share = found.delta / found.w_hover
    note = (f"at each height ({found.rows} rows in {found.cells} cells of one recording and one height, from "
            f"{OFFSET_RADII:.0f} rotor radii up) thrust per sum((w + delta)^2) is steadiest at delta = "
            f"{found.delta:.4g} ± {found.stderr:.2g} rad/s ({100 * share:+.0f} % of the hover speed, "
            f"{found.w_hover:.4g} rad/s; it leaves {100 * found.sse_ratio:.0f} % of the scatter at delta = 0)")
    if data.voltage_dev is not None:
        note += (f", read with the thrust following the battery's voltage at k_V = {found.k_V:.3g} /V (the slope of "
                 f"least residual with it)")
    if found.voltage_noise > 0:
        note += (f"; its error carries {found.voltage_noise:.3g} rad/s of voltage noise: the battery stream's own "
                 f"noise (read from its samples) pulls that slope towards 0, and read with the noise taken into "
                 f"account the slope is {found.k_V_noise_free:.3g} /V and the offset moves by that much")
    if found.at_bound:
        low, high = (100 * x for x in OFFSET_SPAN)
        open_low, open_high = (100 * x for x in UNREAD_OFFSET_SPAN)
        note += (f": that is an end of the range searched ({low:+.0f} to {high:+.0f} % of the hover speed), so no "
                 "offset within it steadies the thrust: no reading (something else moves the thrust per speed "
                 "squared: another vehicle's downwash, a thrust that does not follow the speed squared, too few "
                 f"heights); an idle speed of {open_low:.0f} to {open_high:.0f} % of the hover speed is left open, "
                 f"and {carried}")
    elif found.counts:
        note += (": the recorded (commanded) speeds may be off by an offset, as commands with an idle speed are; the "
                 "named effects' errors carry what that reading changes (thrust map)")
    elif ends[1] - ends[0] >= 2 * OFFSET_PRACTICAL * found.w_hover:
        note += (f": no offset that counts (two errors from zero and 2.5 % of the hover speed), but the reading "
                 f"leaves one standard error either side of it open: {carried}")
    else:
        note += (": no offset that matters (two errors from zero and 2.5 % of the hover speed), the recorded speeds' "
                 "squares carry the thrust")
    return _with_thrust_map(effects, terms), {
        "delta_rad_s": found.delta, "stderr_rad_s": found.stderr, "share_of_hover_speed": share,
        "hover_speed_rad_s": found.w_hover, "rows": found.rows, "cells": found.cells, "sse_ratio": found.sse_ratio,
        "voltage_k_V": found.k_V if data.voltage_dev is not None else None,
        "voltage_noise_rad_s": found.voltage_noise if data.voltage_dev is not None else None, "z": found.z,
        "counts": found.counts,
        "decisive": found.decisive, "applied": False, "open_interval_rad_s": [float(x) for x in ends],
        "stated_at_rad_s": stated, "note": note + at}


def with_law_band(curve_report: dict, curve: Any, named: list[dict[str, Any]], data: GapData) -> dict:
    """``curve_report`` with each bin's ``law_stderr``, how far the named surface law moves there within its stated
    errors (:func:`~uavturb.gap.surface_laws.law_band`), and the largest under ``named.largest_band``: beside the
    measured ratio it says whether the law is known to 2 % of thrust in a bin."""
    law = (curve_report.get("named") or {}).get("law")
    entry = next((e for e in named if e["name"] == law), None)
    if entry is None or curve is None:
        return curve_report
    band = law_band(curve, law, entry["params"], entry.get("stderr") or {}, data.rotor_radius, **data.geometry)
    for b, x in zip(curve_report["bins"], band):
        b["law_stderr"] = float(x)
    curve_report["named"]["largest_band"] = float(np.nanmax(band)) if np.any(np.isfinite(band)) else None
    return curve_report


def _with_thrust_map(effects: list[dict[str, Any]], terms: dict[str, dict[str, float]]) -> list[dict[str, Any]]:
    for e in effects:
        if e["name"] in terms:
            e.update(with_term(e, "thrust_map", terms[e["name"]]))
    return effects


def curves_at_open_offsets(data: GapData, final: ModelFit, speed_map: dict[str, Any] | None
                           ) -> list[tuple[Any, dict[str, Any]]]:
    """The measured surface curve and its laws' fits on the speeds moved to either end of the offsets the thrust
    map leaves open (``speed_map``: the report's ``nominal.rotor_speed_offset``); [] where none are open."""
    ends = (speed_map or {}).get("open_interval_rad_s")
    if not ends or ends[0] == ends[1]:
        return []
    out, w_hover = [], speed_map.get("hover_speed_rad_s")
    for d in ends:
        moved = data.with_speed_offset(d, w_hover) if d != 0.0 else data
        try:
            _, curve, fits = finder_surface_curve(moved, fit_model(moved, final.effects, with_stderr=False),
                                                  resample=False)
        except (InputError, np.linalg.LinAlgError, ValueError):
            return []
        if curve is None:
            return []
        out.append((curve, fits))
    return out


def curve_named_thrust_map(effects: list[dict[str, Any]], curve_report: dict | None,
                           at_ends: list[tuple[Any, dict[str, Any]]]) -> tuple[list[dict[str, Any]], dict | None]:
    """``effects`` with the **thrust map** term for a law named from the measured surface curve (its values are
    the curve's, which the speeds' offset moves too), and ``curve_report`` with it in its law's errors and each
    bin's (``stderr_thrust_map``): half the change of the law fitted to the curve, and of each bin's ratio, measured
    on the speeds moved to either end of the offsets the thrust map leaves open (``at_ends``:
    :func:`curves_at_open_offsets`). A curve read on commanded speeds whose offset is not known is no better known
    than that offset: the blind probe's Crazyflie-like flights near the floor, commands with an idle of a third of
    the hover speed, read mu = 2.60 +- 0.034 on the curve for a true 2."""
    if len(at_ends) != 2:
        return effects, curve_report
    (c_lo, f_lo), (c_hi, f_hi) = at_ends

    def half_change(law: str, params: dict[str, float]) -> dict[str, float]:
        a, b = f_lo.get(law), f_hi.get(law)
        return {k: abs(float(b.params[k]) - float(a.params[k])) / 2.0 if a and b else float("nan") for k in params}

    for e in effects:
        if e.get("named_from") == "surface_curve":
            e.update(with_term(e, "thrust_map", half_change(e["name"], e["params"])))
    if curve_report is None:
        return effects, curve_report
    law = curve_report.get("law")
    terms = half_change(law, {k: v for k, v in curve_report["params"].items() if k != "level"}) if law else {}
    curve_report["thrust_map"] = terms
    curve_report["stderr"] = {k: float(np.hypot(v, terms[k])) if np.isfinite(terms.get(k, np.nan)) else v
                              for k, v in curve_report["stderr"].items()}
    d = np.array([b["d_m"] for b in curve_report["bins"]])
    lo, hi = (np.interp(d, [b.d_m for b in c.bins], [b.ratio for b in c.bins]) for c in (c_lo, c_hi))
    for b, x, y in zip(curve_report["bins"], lo, hi):  # each bin's ratio at its height on either moved curve
        b["stderr_thrust_map"] = abs(float(y) - float(x)) / 2.0
    return effects, curve_report
