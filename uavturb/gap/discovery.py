"""Which chosen effects are discoveries (``gap-report.md``: "what these recordings cannot decide is not a
discovery"): each effect the selection chose is kept, rejected (outside its physical range, too small to matter, not
pinned by the data) or left ``ambiguous`` with what it trades against, and the selection refitted without what
leaves."""

from __future__ import annotations

from typing import Any, Callable, Sequence

import numpy as np

from uavturb.gap.decide import (
    R2_AMBIGUOUS,
    airspeed_drag,
    ambiguity,
    bias_alike,
    can_test_alone,
    flight_facts,
    level_alike,
    thrust_tilt_alike,
    too_small,
)
from uavturb.gap.design import GapData
from uavturb.gap.fit import ModelFit
from uavturb.gap.selection import LIFT_Z, Selection, finish, look_alike_entry
from uavturb.gap.uncertainty import (
    HEIGHT_REFERENCE_M,
    HONEST_Z,
    Refits,
    error_budget,
    one_sample,
    presence_z,
    statistical_errors,
)
from uavturb.physics.effects import EFFECTS


def outside_range(data: GapData, fit: ModelFit, name: str, facts: Any = None) -> str | None:
    """Why the effect ``name`` as ``fit`` has it lies outside its physical range on ``data``'s vehicle and flights
    (``EffectSpec.physical_range``, read on ``facts``: :func:`~uavturb.gap.decide.flight_facts` with ``fit``'s thrust
    coefficient where None), None where it lies inside."""
    params, _ = fit.effect_params(name)
    return EFFECTS[name].physical_range.violation(params, facts or flight_facts(data, fit.coef["k_T"]))


def no_discovery(data: GapData, fit: ModelFit, name: str, facts: Any, refits: Refits | None = None
                 ) -> tuple[str | None, str | None]:
    """(why the effect ``name`` as ``fit`` has it is no discovery, which check says so: ``outside_range``,
    ``too_small`` or ``not_pinned``), or (None, None); the checks in that order, the costly one last."""
    for reason, check in (("outside_range", lambda: outside_range(data, fit, name, facts)),
                          ("too_small", lambda: too_small(data, fit, name)),
                          ("not_pinned", lambda: not_pinned(data, fit, name, refits))):
        why = check()
        if why is not None:
            return why, reason
    return None, None


def effect_budget(data: GapData, final: ModelFit, name: str, height_uncertainty: float = HEIGHT_REFERENCE_M,
                  refits: Refits | None = None) -> dict[str, dict[str, float]]:
    """:func:`uavturb.gap.uncertainty.error_budget` of ``name`` in ``final``: the recordings that count are those
    that can test it alone (:func:`uavturb.gap.decide.can_test_alone`)."""
    return error_budget(data, final, name, can_test=lambda d: can_test_alone(d, final, name),
                        height_reference_m=height_uncertainty, refits=refits)


def _held_beside(data: GapData, fit: ModelFit, name: str) -> bool:
    """Whether ``name`` is in ``fit`` (the fit before effects were left undecided) within its physical range and
    large enough to matter."""
    return name in fit.effects and outside_range(data, fit, name) is None and too_small(data, fit, name) is None


def _hangs_on(fit: ModelFit, name: str, undecided: list[str], without: str) -> dict[str, Any]:
    """The ``ambiguous`` entry of an effect whose fit holds beside the ``undecided`` effects (as in ``fit``) and
    fails without them (``without``: why): which it is hangs on what the flights leave undecided (real wind at a
    fixed heading: rotor drag beside the push read k_d = 8.4e-5, without it -5.2e-5, and had been "rejected" as
    outside its range)."""
    params, _ = fit.effect_params(name)
    values = ", ".join(f"{k} = {v:.3g}" for k, v in params.items())
    entry = look_alike_entry(name, undecided[0], f"beside {' and '.join(undecided)}, left undecided, {name} reads "
                                                 f"{values}; without {'them' if len(undecided) > 1 else 'it'}, "
                                                 f"{without}: its value hangs on what is undecided")
    return entry | {"candidates": [name, *undecided], "params_if_named": params}


def not_pinned(data: GapData, final: ModelFit, name: str, refits: Refits | None = None) -> str | None:
    """Why ``name`` is no discovery when none of its parameters that say it is there
    (:attr:`~uavturb.physics.effects.EffectSpec.presence_params`) stands :data:`HONEST_Z` honest standard errors
    from zero (the spread between recordings or blocks counted), or when one of its parameters rests on one sample
    (:func:`~uavturb.gap.uncertainty.one_sample`), else None."""
    if not EFFECTS[name].absent_at_zero:
        return None
    params, _ = final.effect_params(name)
    budget = effect_budget(data, final, name, height_uncertainty=0.0, refits=refits)
    z = presence_z(budget, params, EFFECTS[name].presence_params)
    if not np.isfinite(z) or z >= HONEST_Z:
        return one_sample(data, final, name)
    se = statistical_errors(budget)
    return (f"its fitted value ({', '.join(f'{k} = {v:.3g} ± {se[k]:.2g}' for k, v in params.items())}) lies within "
            f"{HONEST_Z:.0f} standard errors of zero once the spread between recordings or blocks is counted")


def without_unpinned_laws(decided: tuple[Selection, list[dict], list[dict]], candidates: list[str],
                          selected: Callable[[list[str]], Selection],
                          decide: Callable[[Selection, list[str]], tuple[Selection, list[dict], list[dict]]]
                          ) -> tuple[Selection, list[dict], list[dict]]:
    """``decided`` (the selection, ``ambiguous``, ``rejected`` after :func:`only_decided`), or, where it rejected an
    alternative surface law (``EffectSpec.alternative_to``) as not pinned (:func:`not_pinned`: its parameters trade
    against each other on these heights) and names no law of that surface, the selection and decisions made again
    without that law, where they name one. A law the data do not pin is no candidate: taken first, it had kept out
    the laws that pass with other effects beside them. A 50 g quadrotor's 40 s flight under Cheeseman-Bennett
    (mu = 3), its commands following a sagging battery (k_V = 0.05), had the exponential law taken at the first step
    on the curve's support (A = 0.38 +- 0.23, lam = 0.98 +- 1.1), rejected, and the battery's law after it: nothing
    named, the curve 49 standard errors above 1. Without it, Cheeseman-Bennett passes together with the battery's
    sag in time: mu = 2.96 +- 2.7 (the flight's last analysis, on the speeds its commands' offset moved). The law
    rejected stays in ``rejected``, saying what was named instead; its held-out figures stay in
    ``candidates_tried``."""
    sel, ambiguous, rejected = decided
    named_surfaces = {EFFECTS[n].surface for n in sel.chosen}
    unpinned = [r for r in rejected if r.get("reason") == "not_pinned" and EFFECTS[r["name"]].alternative_to
                and EFFECTS[r["name"]].surface not in named_surfaces]
    if not unpinned:
        return decided
    left_out = {r["name"] for r in unpinned}
    among = [c for c in candidates if c not in left_out]
    again, ambiguous_again, rejected_again = decide(selected(among), among)
    found = [n for n in again.chosen if EFFECTS[n].surface in {EFFECTS[r["name"]].surface for r in unpinned}]
    if not found:
        return decided
    for name in left_out:
        again.tried[name] = sel.tried.get(name, {}) | {"not_pinned_selected_again": 1.0}
    said = [r | {"why": f"{r['why']}; the selection made again without it names {', '.join(f'`{n}`' for n in found)}"}
            for r in unpinned]
    return again, ambiguous_again, rejected_again + said


def lift_beside_unpinned(rejected: list[dict], chosen: Sequence[str], lift: float) -> list[dict]:
    """``rejected`` with the entry of each ground law rejected as not pinned, while no ground law is named, saying
    the lift the measured surface curve shows (``lift``: its standard errors above 1 near the floor, at
    :data:`~uavturb.gap.selection.LIFT_Z` or more): "within two standard errors of zero" alone reads as no lift,
    where a curve 49 standard errors above 1 says there is one whose law these flights leave open."""
    if lift < LIFT_Z or any(EFFECTS[n].surface == "d_down" for n in chosen):
        return rejected
    return [r | {"why": f"{r['why']}; yet the measured surface curve stands {lift:.0f} standard errors above 1 near "
                        "the floor: a lift is there, whose law's values these flights leave open (hover over the "
                        "floor at several heights within a few rotor radii to pin them)"}
            if r.get("reason") == "not_pinned" and EFFECTS[r["name"]].surface == "d_down" else r for r in rejected]


def only_decided(data: GapData, sel: Selection, candidates: list[str], refits: Refits | None = None,
                 levels_read: bool = True) -> tuple[Selection, list[dict], list[dict]]:
    """Keep only what the data decide (:mod:`uavturb.gap.decide`): a chosen effect outside its
    physical range is rejected, one its data cannot tell from the other unknowns goes to
    ``ambiguous``; the selection is then refitted without them (as are the look-alikes the selection found,
    :attr:`~uavturb.gap.selection.Selection.look_alikes`). A candidate not chosen whose force
    is an accelerometer bias on these flights, while the fitted bias is significant, is reported
    as ambiguous too (a steady push may hide in the bias)."""
    ambiguous: list[dict] = list(sel.look_alikes)  # pairs the held-out data could not tell apart
    rejected: list[dict] = list(sel.rejected)  # outside their range when the selection would have taken them
    steps, rivals = list(sel.steps), sel.rivals
    undecided: list[str] = []  # effects dropped to ``ambiguous`` so far, and the fit that still held them
    with_undecided: ModelFit | None = None
    while True:
        drop, as_ambiguous, as_rejected = _first_undecided(data, sel.final, steps, refits, levels_read,
                                                           with_undecided, undecided)
        if drop is None:
            break
        ambiguous += as_ambiguous
        rejected += as_rejected
        if any(drop.name in a["candidates"] for a in ambiguous) and drop.name not in undecided:
            if with_undecided is None:
                with_undecided = sel.final  # the fit that still held it
            undecided.append(drop.name)
        steps.remove(drop)
        for s in [s for s in steps if s.named_with == drop.name]:  # it passed only together with the one dropped
            steps.remove(s)
            sel.tried.setdefault(s.name, {})[f"dropped_with_{drop.name}"] = 1.0
        # as select() fitted it (sim effects in the base), reusing its fits of the same effect sets
        sel = finish(data, sel.base, steps, tried=sel.tried, known=sel.known)
    sel.known = None  # its folds' rows and fits are not needed past the decisions (memory)
    sel.rivals = rivals  # finish() starts a Selection afresh
    named = {a for entry in ambiguous for a in entry["candidates"]}
    return sel, ambiguous + _bias_look_alikes(data, sel.final, [c for c in candidates if c not in named]), rejected


def _first_undecided(data: GapData, final: ModelFit, steps: list[Any], refits: Refits | None, levels_read: bool,
                     with_undecided: ModelFit | None, undecided: list[str]) -> tuple[Any, list[dict], list[dict]]:
    """``(step, ambiguous entries, rejected entries)`` of the first chosen effect (``steps``, as fitted in ``final``)
    that the data do not decide, with what the report says of it; ``(None, [], [])`` where they decide them all.

    In the order checked, per effect: no discovery (:func:`no_discovery`; where it held beside an effect left
    undecided before, in ``with_undecided``, and fails without it, its value hangs on that one: ``ambiguous``, else
    ``rejected``), traded against the nominal model's unknowns (``decide.ambiguity``), or against the recordings'
    thrust levels (``decide.level_alike``; ``levels_read``: the levels were measured apart); then, over all of
    them, a push that a thrust-axis tilt also gives (``wind``) and a drag on the airspeed (``rotor_drag``)."""
    facts = flight_facts(data, final.coef["k_T"])
    for s in steps:
        params, _ = final.effect_params(s.name)
        bad, reason = no_discovery(data, final, s.name, facts, refits)
        if bad is not None and with_undecided is not None and _held_beside(data, with_undecided, s.name):
            # it held beside an effect left undecided, and fails without it: its value hangs on that one
            return s, [_hangs_on(with_undecided, s.name, undecided, bad)], []
        if bad is not None:
            return s, [], [{"name": s.name, "params": params, "reason": reason, "why": bad}]
        amb = ambiguity(data, final, s.name, facts)
        if amb is not None:
            return s, [amb | {"params_if_named": params}], []
        amb = level_alike(data, final, s.name, levels_read)
        if amb is not None:
            return s, [amb], []
    for name, alike in (("wind", thrust_tilt_alike), ("rotor_drag", airspeed_drag)):
        if name in {s.name for s in steps}:
            amb = alike(data, final, facts)
            if amb is not None:
                return next(s for s in steps if s.name == name), [amb], []
    return None, [], []


def _bias_look_alikes(data: GapData, final: ModelFit, candidates: list[str]) -> list[dict]:
    """``ambiguous`` entries for the ``candidates`` not named whose force is an accelerometer bias on these flights
    (``decide.bias_alike``), where ``final``'s fitted horizontal bias stands over 4 standard errors from zero: a
    steady push may hide in the bias."""
    facts = flight_facts(data, final.coef["k_T"])
    out = []
    for c in candidates:
        if c in final.effects or bias_alike(data, c) < R2_AMBIGUOUS:
            continue
        b = np.array([final.coef[f"b_{a}"] for a in "xy"])
        se = np.array([final.stderr.get(f"b_{a}", np.inf) for a in "xy"])
        if np.max(np.abs(b) / se) > 4.0:
            push = data.mass * float(np.hypot(*b))
            out.append({
                "candidates": [c, "accelerometer_bias"],
                "why": (f"the heading changed by only {facts.heading_span_deg:.0f} deg: the fitted accelerometer bias "
                        f"({b[0]:.3g}, {b[1]:.3g}) m/s^2 (body x, y) could as well be a steady push of about "
                        f"{push:.3g} N fixed in the world"),
                "to_separate": "fly the same pattern at two or more headings (90 deg apart), or rely on motion "
                               "capture alone"})
    return out
