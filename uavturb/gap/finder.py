"""``uavturb gap``: compare, locate, name, model and close the loop (``gap-report.md``).

The analysis's stages in order, and the report they make. The rows in the air are built in
:mod:`uavturb.gap.flight_rows`, what the selection chose is kept or left undecided in
:mod:`uavturb.gap.discovery`, and the named effects get their systematic error terms in
:mod:`uavturb.gap.named_errors`."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Callable, Generator, Sequence

import numpy as np

from uavturb.errors import InputError
from uavturb.gap import locate
from uavturb.gap.decide import (
    flight_facts,
    floor_crossing,
    residual_thrust_tilt,
    surface_reach,
    tilt_per_recording,
)
from uavturb.gap.design import MIN_ANALYSIS_ROWS, GapData, apply_thrust_levels, rounding_floor
from uavturb.gap.discovery import lift_beside_unpinned, only_decided, outside_range, without_unpinned_laws
from uavturb.gap.fit import ModelFit, fit_model, forking_worth, robust_nominal
from uavturb.gap.flight_rows import flight_rows, rotor_order_lines
from uavturb.gap.named_errors import (
    at_stated_offset,
    cross_checked,
    curve_named_thrust_map,
    curves_at_open_offsets,
    effects_named,
    mass_checked,
    rate_checked,
    thrust_map_checked,
    timing_checked,
    untaken_checked,
    with_law_band,
    with_term,
)
from uavturb.gap.preparation import prepared, rotor_shifted, rotor_speeds_moved
from uavturb.gap.selection import (
    Z_DISTINCT,
    Z_IMPROVE,
    CurveEvidence,
    Selection,
    better_law_not_named,
    finish,
    folds,
    heldout,
    improvement_z,
    lift_not_named,
    look_alike_entry,
    near_misses,
    select,
    swapped_surface_law,
    untested_on_heldout,
)
from uavturb.gap.surface_curve import LIFT_RADII, lift_z
from uavturb.gap.surface_laws import (
    HeightOffset,
    finder_surface_curve,
    first_height_offset,
    law_named_from_curve,
    law_on_curve,
)
from uavturb.gap.uncertainty import HEIGHT_REFERENCE_M, Refits, command_sampling_term, thrust_map_term
from uavturb.numerics.processes import ForkedPool, forked_state, forking_possible, in_forked_child
from uavturb.numerics.stream_updates import rotor_quantum, rounding_share
from uavturb.physics.dynamics import GRAVITY
from uavturb.physics.effects import (
    DEFAULT_EFFECTS,
    EFFECTS,
    EffectInputs,
    defaults,
    total_force,
)
from uavturb.sysid.flight_data import flight_data, rotor_hold_s
from uavturb.sysid.nominal import OFFSET_DECISIVE_Z, ThrustLevels

SCHEMA = "uavturb.gap/1"
#: the stages of ``uavturb gap``, for its progress bar (:class:`uavturb.progress.Stages`); :func:`analyse`
#: announces those between the reading and the writing
#: the stage of the second pass where the recorded speeds' offset is decisive (skipped otherwise)
MOVED_SPEEDS_STAGE = "again on the speeds moved by their offset"
STAGES = ["reading the recordings", "aligning the streams", "the nominal model", "locating the mismatch",
          "selecting effects", "deciding what the data support", "the surface curve", "honest errors",
          MOVED_SPEEDS_STAGE, "writing the report", "logging the run"]
#: analyses on moved speeds at most: where the offset read on the moved speeds still counts, it is added to the moved
#: one and the analysis runs again (the records' first reading leans on what the records misread: a blind 32 g
#: vehicle's idle speed of 550 rad/s read 724 +- 38 with a 30 ms lag read as 67 ms; on the moved speeds, whose lag
#: read 21 ms, a further -73 rad/s counted)
MAX_OFFSET_MOVES = 3


def parse_sim_effects(text: str | None) -> dict[str, dict[str, float]]:
    """``--sim-effects``: comma-separated names, ``none``, or ``None`` for the simulator's default.
    Parameters come from the simulator's config where it has them, else ``effects.md``'s typical values."""
    if text is None:
        return {k: dict(v) for k, v in DEFAULT_EFFECTS.items()}
    names = [n.strip() for n in text.split(",") if n.strip()]
    if names == ["none"] or not names:
        return {}
    out = {}
    for n in names:
        if n not in EFFECTS:
            raise InputError("--sim-effects", f"unknown effect '{n}' (known: {', '.join(EFFECTS)}, or none)")
        if not EFFECTS[n].simulated:
            raise InputError("--sim-effects", f"'{n}' is not a force a simulator applies (it says what logged "
                                              f"commands mean): the simulator cannot already model it")
        out[n] = dict(DEFAULT_EFFECTS.get(n, defaults(n)))
    return out


def _sim_offset(data: GapData, sim: dict[str, dict[str, float]], k_T: float) -> np.ndarray:
    """Force [N] of the simulator's own effects at the simulator's parameters, on ``data``'s rows."""
    if not sim:
        return np.zeros((len(data), 3))
    full = data if data.contiguous is None else data.contiguous
    out = np.zeros((len(full), 3))
    for g in np.unique(full.group):
        m = full.group == g
        x = EffectInputs(q=None, v=full.v[m], rotor_speeds=full.rotor_speeds[m], k_T=k_T,
                         rotor_radius=full.rotor_radius, d_down=full.d_down[m], d_up=full.d_up[m], t=full.t[m],
                         R=full.R[m], arm_length=full.arm_length)
        out[m] = total_force(sim, x)
    return out if data.rows is None else data.gather(out)


def _open_loop(data: GapData, force: np.ndarray, horizon_s: float = 0.5, stride_s: float = 0.5) -> float:
    """RMS position error [m] of open-loop translational predictions over ``horizon_s``, started
    from the measured state every ``stride_s``, with measured attitude and rotor speeds and the
    model's force ``force (K, 3)`` [N] (thrust and effects, in W)."""
    errs = []
    g = np.array([0.0, 0.0, GRAVITY])
    for grp in np.unique(data.group):
        idx = np.flatnonzero(data.group == grp)
        if len(idx) < 3:
            continue
        dt = float(np.median(np.diff(data.t[idx])))
        n = max(2, int(round(horizon_s / dt)))
        starts = np.arange(0, len(idx) - n, max(1, int(round(stride_s / dt))))
        seg = idx[starts[:, None] + np.arange(n + 1)]  # (S, n + 1) rows of each prediction
        h = np.diff(data.t[seg], axis=1)  # (S, n) s
        ok = ~np.any(h > 3 * dt, axis=1)  # no gap (rows dropped on the ground)
        seg, h = seg[ok], h[ok, :, None]
        a = force[seg[:, :-1]] / data.mass - g  # (S, n, 3) m/s^2
        v0 = data.v[seg[:, 0]]
        v = v0[:, None, :] + np.cumsum(a * h, axis=1)
        v_before = np.concatenate([v0[:, None, :], v[:, :-1]], axis=1)
        p = data.p[seg[:, 0]] + np.sum(v_before * h + 0.5 * a * h**2, axis=1)
        errs.extend(np.sum((p - data.p[seg[:, -1]]) ** 2, axis=1))
    return float(np.sqrt(np.mean(errs))) if errs else float("nan")


def _silent(stage: str) -> None:
    """No progress shown."""


def _nothing_started(plots: dict) -> None:
    """Nothing started at the last analysis's checkpoint."""


def analyse(recordings: Sequence, sim: dict[str, dict[str, float]], *, seed: int = 0,
            height_uncertainty: float = HEIGHT_REFERENCE_M, progress: Callable[[str], None] = _silent,
            at_checkpoint: Callable[[dict], None] = _nothing_started) -> tuple[dict, dict]:
    """The analysis without any writing: returns the report dictionary and what the plots need;
    ``progress`` is called with the name of each of :data:`STAGES` it runs, as it starts.

    ``at_checkpoint`` is called once with what the plots need that the report's analysis knows at its
    :class:`Checkpoint` (:attr:`Checkpoint.plots`, the very objects the extras returned hold), before that analysis
    runs to its end, so that the figures drawn from them alone are drawn meanwhile
    (:class:`~uavturb.gap.report.FiguresAhead`). Where the speeds are moved (below), it is called at the checkpoint
    of the analysis on moved speeds that reads no offset that counts there, or of the last one allowed: the report's
    (a guess that missed calls it with objects the extras do not hold).

    Where the recorded (commanded) speeds read a decisive offset, the analysis runs again on the speeds it moves
    (:func:`_on_moved_speeds`), and the first analysis's end, which only its report needs, runs in a forked child
    meanwhile where that pays (:class:`Checkpoint`): the same report as one after the other.

    BLAS runs single-threaded: the fits are tall and thin (a few columns), where threaded
    BLAS only adds synchronisation (a threaded ``ddot`` over 50 000 rows took 15 ms instead of
    0.02 ms on a busy 2-core machine)."""
    from threadpoolctl import threadpool_limits

    with threadpool_limits(limits=1, user_api="blas"):
        aside = [False]  # the first analysis's end runs aside (in a child, or here after the others): not shown

        def shown(stage: str) -> None:
            if not aside[0] and not in_forked_child():
                progress(stage)

        steps = _analysis(recordings, sim, seed=seed, height_uncertainty=height_uncertainty, progress=shown)
        paused = next(steps)
        if not paused.moves_speeds:
            at_checkpoint(paused.plots)
            return _finished(steps)
        drawn = np.random.get_state()
        # a decisive offset: the whole analysis again, on the moved speeds. The first one's end (the surface curve,
        # the honest errors: its report, which the last one's cites) runs in a child meanwhile, where it pays
        first, report = None, None
        if forking_worth(paused.rows, paused.folds) and forking_possible():  # else in turn: less memory held
            aside[0] = True
            first = ForkedPool(steps, max_processes=1).start(_report_in_child, 0)
        else:
            report = _finished(steps)[0]
        progress(MOVED_SPEEDS_STAGE)
        try:
            again, extras, readings = _on_moved_speeds(recordings, sim, paused.offset, seed, height_uncertainty,
                                                       at_checkpoint)
        except BaseException:
            if first is not None:
                first.cancel()  # the error is this analysis's answer: not delayed by the first one's end
            raise
        if first is not None:
            report = first.result(lambda: _resumed(steps, drawn))
        return read_on_moved_speeds(report, again, readings), extras


def _resumed(steps: Generator[Checkpoint, None, tuple[dict, dict]], drawn: tuple) -> dict:
    """The report of the analysis ``steps`` paused at its checkpoint, run to its end here after other analyses ran:
    numpy's global generator put back to ``drawn``, its state at the pause, so that it draws what it would have."""
    np.random.set_state(drawn)
    return _finished(steps)[0]


def _on_moved_speeds(recordings: Sequence, sim: dict[str, dict[str, float]], offset: Any, seed: int,
                     height_uncertainty: float, at_checkpoint: Callable[[dict], None] = _nothing_started
                     ) -> tuple[dict, dict, list[float]]:
    """The analysis of ``recordings`` on their rotor speeds moved by the decisive ``offset``
    (:class:`~uavturb.sysid.nominal.SpeedOffset`), moved further while the moved speeds still read one that counts
    (:data:`MAX_OFFSET_MOVES` analyses at most): the last analysis's report and extras, and the offsets applied.
    ``at_checkpoint`` (:func:`analyse`'s) is called at the checkpoint of the analysis that looks like the last one
    there (the offset its moved speeds read does not count, or no move is left)."""
    delta, w_hover, readings = offset.delta, offset.w_hover, []
    for move in range(MAX_OFFSET_MOVES):
        moved = [rotor_speeds_moved(r, delta, w_hover) for r in recordings]
        steps = _analysis(moved, sim, seed=seed, height_uncertainty=height_uncertainty)
        paused = next(steps)
        if paused.offset is None or not paused.offset.counts or move == MAX_OFFSET_MOVES - 1:
            at_checkpoint(paused.plots)
        again, extras = _finished(steps)
        after = again["nominal"].get("rotor_speed_offset")
        readings.append(delta)
        if not after or not after["counts"] or len(readings) == MAX_OFFSET_MOVES:
            break
        delta = composed_offset(delta, w_hover, after["delta_rad_s"])
    return again, extras, readings


def composed_offset(delta: float, w_hover: float, again: float) -> float:
    """The offset [rad/s] of the recorded speeds that moving them by ``delta`` (keeping the hover speed
    ``w_hover``, :func:`~uavturb.gap.preparation.rotor_speeds_moved`) and then the moved speeds by ``again`` (read
    on them, the hover speed kept again) comes to: ``delta + again (w_hover + delta) / w_hover``. Exact: the two
    affine moves are one, ``(w + total) w_hover / (w_hover + total)``."""
    return float(delta + again * (w_hover + delta) / w_hover)


def _named_on_curve(curve_report: dict | None, curve, data: GapData) -> tuple[str, Callable] | None:
    """``(label, d [m] -> ratio)`` of the law the report names at its named values, normalised as the measured
    curve is (for the curve's plot); None where the report names none."""
    named = (curve_report or {}).get("named")
    if curve is None or not named:
        return None
    spec = EFFECTS[named["law"]]
    values = [named["params"][k] for k in spec.params]
    label = f"named: {named['law']}, " + ", ".join(f"{k} = {v:.3g}" for k, v in named["params"].items())
    return label, law_on_curve(curve, named["law"], values, data.rotor_radius, **data.geometry)


def read_on_moved_speeds(recorded: dict, moved: dict, applied: Sequence[float] | None = None) -> dict:
    """The report ``moved`` of the analysis run again on rotor speeds moved by the decisive offset that the
    analysis ``recorded`` of the recorded speeds read (:attr:`~uavturb.sysid.nominal.SpeedOffset.decisive`: an idle
    speed in the command map). Each named effect's error carries half its change from the recorded speeds'
    reading (**speed offset**): the value the recorded speeds named, or for a surface law they did not name, its
    fit to their measured curve (:func:`_curve_readings`; nan where neither is there), and
    ``nominal.rotor_speed_offset`` says what was read, what was moved and what the recorded speeds named.

    ``applied``: the offsets [rad/s] the recorded speeds were moved by, one per analysis on moved speeds, the last
    ``moved``'s (:data:`MAX_OFFSET_MOVES`); the recorded speeds' reading alone where None. The offset reported is the
    last, and its error carries what the last analysis still read on its speeds (in the records' units), beside
    that reading's own jackknife: an offset whose reading moves with what else is read is no better known than
    the last move."""
    offset = recorded["nominal"]["rotor_speed_offset"]
    applied = [float(offset["delta_rad_s"])] if not applied else [float(a) for a in applied]
    before = {e["name"]: e["params"] for e in recorded["effects"]}
    same_law = _curve_readings(recorded.get("surface_curve")) | before
    for e in moved["effects"]:
        was = same_law.get(e["name"])
        term = {k: abs(float(v) - float(was[k])) / 2.0 if was and k in was else float("nan")
                for k, v in e["params"].items()}
        e.update(with_term(e, "speed_offset", term))
    named = "; ".join(f"{n} ({', '.join(f'{k} = {v:.3g}' for k, v in p.items())})" for n, p in before.items()) \
        or "nothing"
    after = moved["nominal"].get("rotor_speed_offset")
    note = (f"the recorded (commanded) speeds read an offset of {offset['delta_rad_s']:.4g} ± "
            f"{offset['stderr_rad_s']:.2g} rad/s ({100 * offset['share_of_hover_speed']:+.0f} % of the hover speed, "
            f"{offset['z']:.0f} errors from zero: an idle speed in the "
            f"command map, {OFFSET_DECISIVE_Z:.0f} errors or more), so the analysis ran again on the speeds moved by "
            f"it (scaled to keep the hover speed)")
    if len(applied) > 1:
        note += (f"; the moved speeds still read an offset that counts, so the analysis ran {len(applied)} times, on "
                 f"the speeds moved by {', then '.join(f'{a:.4g}' for a in applied)} rad/s")
    note += (f", and this report is the last analysis; on the recorded speeds it named {named}, and each value's "
             f"error carries half its change (speed offset)")
    w_hover, delta = float(offset["hover_speed_rad_s"]), applied[-1]
    stderr = float(offset["stderr_rad_s"])
    if after is not None:
        note += f"; on the moved speeds {after['note']}"
        scale = (w_hover + delta) / w_hover  # rad/s of the moved speeds -> of the recorded ones
        stderr = float(np.hypot(after["stderr_rad_s"], after["delta_rad_s"]) * scale)
        note += (f"; the offset applied, {delta:.4g} rad/s, is stated ± {stderr:.2g} rad/s: the last reading's "
                 f"error and what it still reads on the moved speeds")
    moved["nominal"]["rotor_speed_offset"] = offset | {
        "delta_rad_s": delta, "stderr_rad_s": stderr, "share_of_hover_speed": delta / w_hover,
        "z": abs(delta) / stderr if stderr > 0 else float("inf"),
        "read_on_recorded_speeds": {k: offset[k] for k in ("delta_rad_s", "stderr_rad_s", "z")},
        "moves_rad_s": applied, "applied": True, "after": after,
        "named_on_recorded_speeds": recorded["effects"], "note": note}
    return moved


def _curve_readings(curve: dict | None) -> dict[str, dict[str, float]]:
    """``{law: params}`` of each surface law fitted to a report's measured curve (its law and alternatives): where
    the moved speeds name a surface law that the recorded speeds did not (a 67 g vehicle's walks: Cheeseman-
    Bennett on the recorded speeds, the exponential law fitted to the curve on speeds moved by +46 % of the hover
    speed, A = 0.25 where the recorded speeds' curve gives 0.5), the recorded speeds' reading of that law is its
    fit to their curve."""
    if not curve or not curve.get("params"):
        return {}
    fits = {curve["law"]: curve["params"]}
    fits |= {a["law"]: a["params"] for a in curve.get("alternatives", []) if a.get("params")}
    return fits


@dataclass
class Checkpoint:
    """Where :func:`_analysis` pauses: the effects decided and the recorded speeds' offset read (``offset``: None
    with measured rotor speeds or where none was read), on ``rows`` rows in ``folds`` held-out folds. What is left
    (the surface curve, the honest errors, the report) needs nothing that runs after it."""

    offset: Any
    rows: int
    folds: int
    #: what the plots need that is known here (data, r0, rs0, rf, rsf, segs, drivers, base_ho, final_ho): the
    #: figures drawn from it alone may be drawn while the analysis runs to its end (``analyse``'s ``at_checkpoint``)
    plots: dict = field(default_factory=dict)

    @property
    def moves_speeds(self) -> bool:
        """Whether the offset is decisive, so that the analysis runs again on the speeds it moves
        (:func:`analyse`)."""
        return self.offset is not None and bool(self.offset.decisive)


def _finished(steps: Generator[Checkpoint, None, tuple[dict, dict]]) -> tuple[dict, dict]:
    """The report and extras of the analysis ``steps``, paused at its :class:`Checkpoint`, run to its end."""
    try:
        next(steps)
    except StopIteration as done:
        return done.value
    raise RuntimeError("an analysis paused twice")  # _analysis yields once


def _report_in_child(_: object) -> dict:
    """In a child of :func:`analyse`: the report of the analysis paused at its checkpoint when the child was
    forked, run to its end (its plots' data are not needed: the next pass's replace them)."""
    return _finished(forked_state())[0]


def _analysis(recordings: Sequence, sim: dict[str, dict[str, float]], *, seed: int = 0,
              height_uncertainty: float = HEIGHT_REFERENCE_M, progress: Callable[[str], None] = _silent
              ) -> Generator[Checkpoint, None, tuple[dict, dict]]:
    """The analysis of ``recordings``, paused once (it yields a :class:`Checkpoint`) where the effects are decided
    and the offset of the recorded speeds is read; it returns the report and what the plots need."""
    if not (0.0 <= height_uncertainty <= 0.5):
        raise InputError("--height-uncertainty", f"must be between 0 and 0.5 m, got {height_uncertainty:.3g}")
    np.random.seed(seed)
    vehicle = recordings[0].vehicle
    paths = [str(r.path) if r.path else r.name for r in recordings]
    progress("aligning the streams")
    recordings, fds, held = prepared(recordings, paths)
    data, contact_report, landed = flight_rows(fds, [r.vehicle for r in recordings], paths, sim_forces=bool(sim),
                                               read_order=True)
    held["streams"] += rotor_order_lines(data.rotor_order, recordings)
    # emptied as the rows were built; what they keep lives on in ``data`` (memory: a flight-hour at 200 Hz is 720k rows)
    del fds
    _check_enough_rows(data, recordings, paths, held["slowest_update_hz"])
    progress("the nominal model")
    levels = apply_thrust_levels(data)

    base = _simulator_baseline(data, sim)
    protocol, fm = folds(data)
    base_ho = heldout(data, frozenset(), fm, offset=base.offset)
    progress("locating the mismatch")
    step = 1.0 / held["slowest_update_hz"] if np.isfinite(held["slowest_update_hz"]) else 0.0
    segs, rs0, sigma = locate.segments(data, base.r0, update_step_s=step)
    drv = locate.drivers(data, rs0)

    heights_broken = floor_crossing(data)  # a height through the floor: no surface effect, no curve
    candidates, not_testable, sim_fit_base = _testable_candidates(data, sim, measured_rotor_speeds(recordings))
    quantum = max((rotor_quantum(r.rotors.speeds) for r in recordings), default=0.0)
    data.rotor_quantum = quantum  # the surface curve's bins carry what it leaves unresolved
    floor = rounding_floor(data, base.nominal.coef["k_T"], quantum)
    progress("selecting effects")
    evidence = nominal_curve_evidence(data, base.least_squares, heights_broken is None)

    def selected(among: list[str], after: Selection | None = None) -> Selection:
        """The selection among ``among``; ``after``: one made before on the same data, whose evaluations it reuses."""
        return select(data, among, base=sim_fit_base, thrust_floor=floor, curve=evidence,
                      unphysical=lambda fit, name: outside_range(data, fit, name),
                      known=None if after is None else after.known)

    sel, candidates = _with_surface_law_swapped(selected(candidates), candidates, selected,
                                                float(np.sqrt(np.sum(sigma**2))))
    progress("deciding what the data support")
    refits = Refits()  # the error budgets' refits of data's parts, shared by the decisions and the named effects

    def decided(chosen: Selection, among: list[str]) -> tuple[Selection, list[dict], list[dict]]:
        return only_decided(data, chosen, among, refits, levels_read=levels.basis != "none")

    sel, ambiguous, rejected = without_unpinned_laws(decided(sel, candidates), candidates,
                                                     lambda among: selected(among, after=sel), decided)
    rejected = lift_beside_unpinned(rejected, sel.chosen, evidence.lift_z)
    sel = _timing_robust(data, sel, ambiguous, recordings, paths, held["delays"], sim, base.offset)
    final: ModelFit = sel.final
    facts = flight_facts(data, final.coef["k_T"])
    rf = final.residual(data)
    _, rsf, _ = locate.segments(data, rf, update_step_s=step)
    _, draws = locate.window_rows(data, 0.5, step)
    noise2 = float(np.sum(sigma**2) / draws)  # N^2, the noise left in a 0.5 s window's smoothed residual
    beyond = float(np.sqrt(max(0.0, np.mean(np.sum(rsf**2, axis=1)) - noise2)))
    unexplained = {"rms_N": beyond, "drivers": locate.drivers(data, rsf)}
    height_driver = max((d["score"] for d in unexplained["drivers"] if d["feature"] == "d_down"), default=0.0)
    ambiguous += near_misses(sel.tried, set(sel.chosen) | {r["name"] for r in rejected}
                             | {c for a in ambiguous for c in a["candidates"]},
                             height_driver=height_driver if heights_broken is None else 0.0, beyond_noise_N=beyond)
    not_testable += untested_on_heldout(data, final, fm, candidates,
                                        set(sel.chosen) | {r["name"] for r in rejected}
                                        | {c for a in ambiguous for c in a["candidates"]},
                                        lambda fit, name: outside_range(data, fit, name), protocol)
    unexplained = _thrust_axis_tilts(unexplained, ambiguous, data, final, rf, facts, paths, noise2, step)
    thrust_map = thrust_map_term(data, final, rf) if not measured_rotor_speeds(recordings) else None
    plots = dict(data=data, r0=base.r0, rs0=rs0, rf=rf, rsf=rsf, segs=segs, drivers=drv, base_ho=base_ho,
                 final_ho=sel.final_heldout)
    yield Checkpoint(None if thrust_map is None else thrust_map[0], len(data), len(fm), plots)
    progress("the surface curve")
    stated, data_at, final_at = at_stated_offset(data, final, thrust_map)  # where the thrust map is left open
    curve_report, curve, curve_fits = (finder_surface_curve(data_at, final_at) if heights_broken is None
                                       else (None, None, {}))
    progress("honest errors")
    offset = _height_offset(curve, curve_fits, sel.chosen, data_at)
    if offset is not None:  # every stated error covers heights off by as much as the curve's shape reads
        height_uncertainty = max(height_uncertainty, abs(offset.dz_m))
    # a lever arm read from the motion: the rotor plane is counted from the recorded origin or from the centre of
    # mass (preparation._lever_line), which lie r_z apart
    height_uncertainty = max([height_uncertainty] + [abs(lever["r_m"][2]) for lever in held["lever_arms"]]
                             + held["levelled_m"]  # a tilted scan, levelled (preparation.prepared)
                             + [landed.uncertainty_m])  # recordings landing apart, some not moved (landed_heights)
    named = cross_checked(effects_named(data, sel, final, facts, height_uncertainty, refits, values=final_at),
                          curve_fits)
    named = timing_checked(named, final, recordings, paths, held["delays"])
    named = rate_checked(named, final, recordings, paths, held["state_too_slow"])
    named = [e | with_term(e, "command_sampling", command_sampling_term(
        [rotor_hold_s(r.rotors) for r in recordings])) if e["name"] == "motor_lag" else e
             for e in named]
    named, speed_map = thrust_map_checked(named, data, thrust_map, stated)
    named, curve_report = law_named_from_curve(named, curve_report, curve, curve_fits, data, facts,
                                               height_uncertainty)
    named, curve_report = curve_named_thrust_map(named, curve_report, curves_at_open_offsets(data, final, speed_map))
    named = [mass_checked(e, final.coef["k_T"], vehicle.thrust_coefficient) for e in named]
    if curve_report is None:  # no measured curve judged the law's shape: said, with the margin of a better one
        named = _law_shapes_open(named, sel.tried, evidence)
    named = untaken_checked(named, data, final, sel.tried, {e["name"] for e in rejected + not_testable}
                            | {c for a in ambiguous for c in a["candidates"]})
    if curve_report is not None:
        curve_report = with_law_band(curve_report, curve, named, data)
        decided = ({e["name"] for e in named + rejected + not_testable}
                   | {c for a in ambiguous for c in a["candidates"]})
        curve_report["not_named"] = lift_not_named(evidence, sel.tried, decided, *_held_out_near_s(data, fm),
                                                   protocol)
    report = {
        "schema": SCHEMA,
        "recordings": paths,
        "sim_effects": list(sim),
        "protocol": protocol,
        "residual_source": data.source,
        "baseline": {"rmse_N": base.least_squares.rmse, "heldout_rmse_N": base_ho.rmse,
                     "robust_rmse_N": float(np.sqrt(np.mean(np.sum(base.r0**2, 1))))},
        "noise": {"sigma_N": [float(s) for s in sigma], "rms_N": float(np.sqrt(np.sum(sigma**2))),
                  "rotor_speed_quantum": quantum, "rounding_floor_N2": floor},
        # segments name their recording as given on the command line (gap-report.md: "path")
        "mismatch": {"segments": [{"recording": paths[s.group], "t_start": s.t_start, "t_end": s.t_end,
                                   "axis": s.axis, "rms_N": s.rms_N} for s in segs],
                     "drivers": drv},
        "effects": named,
        "height_uncertainty_m": height_uncertainty,
        "height_reference": height_reference(vehicle.rotor_plane_z, height_uncertainty, any(
            EFFECTS[n].surface for n in [e["name"] for e in named + rejected]
            + [c for a in ambiguous for c in a["candidates"] if c in EFFECTS])) | {"passes_floor": heights_broken}
        | {"landed_heights": landed.as_report(paths)}
        | {"offset_read_from_curve": None if offset is None else {
            "law": offset.law, "dz_m": offset.dz_m, "chi2_dof": offset.chi2_dof,
            "chi2_dof_as_measured": offset.chi2_dof_as_measured, "params": offset.params, "why": offset.sentence()}},
        "sim_effect_params": {name: {"sim": p, "fitted": final_at.effect_params(name)[0] if name in final.effects
                                     else {}} for name, p in sim.items()},
        "nominal": _nominal(data, final, levels, _thrust_laws_left_open(ambiguous))
        | {"thrust_coefficient_vehicle_yaml": vehicle.thrust_coefficient}
        | {"rotor_speed_offset": speed_map},
        "ambiguous": ambiguous,
        "ground_contact": contact_report,
        "surface_curve": curve_report,
        # why no curve was measured, where the flights had a floor below them (its notes: who was left out)
        "surface_curve_missing": heights_broken or (("; ".join(curve.notes) or None) if curve_report is None
                                                    and curve is not None else None),
        "streams": held,
        "rejected": rejected,
        "not_testable": not_testable,
        "facts": {"weight_N": facts.mass * GRAVITY, "heading_span_deg": facts.heading_span_deg,
                  "speed_p90_m_s": facts.speed_p90,
                  "d_down_min_m": facts.d_down_min, "d_up_min_m": facts.d_up_min, "has_imu": facts.has_imu,
                  "duration_s": facts.duration_s}
        | ({"torque_lag": data.torque_lag.to_dict()} if data.torque_lag is not None else {})
        | ({"rotor_order": data.rotor_order.to_dict()} if data.rotor_order is not None else {}),
        "final": {"heldout_rmse_N": sel.final_heldout.rmse, "rmse_N": float(np.sqrt(np.mean(np.sum(rf**2, 1))))},
        "unexplained": unexplained,
        "open_loop": {"horizon_s": 0.5, "before_m": _open_loop(data, base.force),
                      "after_m": _open_loop(data, final.predict(data))},
        "candidates_tried": sel.tried,
    }
    extras = plots | dict(final=final, curve=curve, curve_fits=curve_fits,
                          curve_named=_named_on_curve(curve_report, curve, data))
    return report, extras


def _thrust_axis_tilts(unexplained: dict[str, Any], ambiguous: list[dict], data: GapData, final: ModelFit,
                       rf: np.ndarray, facts: Any, paths: Sequence[str], noise2: float, step: float
                       ) -> dict[str, Any]:
    """The report's ``unexplained`` with what a thrust axis tilted from the recorded attitude reads in the final
    residual ``rf`` [N] (:func:`~uavturb.gap.decide.residual_thrust_tilt`: each recording's tilt, and the drivers
    of what is left beyond it: a tilt had read as d_up on x); where the push is already left undecided between
    wind and a tilt (an ``ambiguous`` entry with ``thrust_axis_tilt``), that entry gets each recording's tilt with
    its error instead (modified in place). ``noise2`` [N^2]: the noise left in a smoothed residual's window,
    ``step`` [s] the slowest stream's update step (:func:`~uavturb.gap.locate.segments`)."""
    look_alike = next((a for a in ambiguous if "thrust_axis_tilt" in a["candidates"]), None)
    if look_alike is not None:  # the push left undecided: each recording's tilt, with its error, for the reader
        per, _ = tilt_per_recording(data, final, rf)
        look_alike["per_recording"] = [e | {"recording": paths[e["recording"]]} for e in per]
        return unexplained
    tilt = residual_thrust_tilt(data, final, rf, facts)
    if tilt is None:
        return unexplained
    entry, force = tilt
    for e in entry["per_recording"]:
        e["recording"] = paths[e["recording"]]
    _, rst, _ = locate.segments(data, rf - force, update_step_s=step)
    entry["rms_beyond_tilt_N"] = float(np.sqrt(max(0.0, np.mean(np.sum(rst**2, axis=1)) - noise2)))
    return unexplained | {"drivers": locate.drivers(data, rst), "thrust_axis_tilt": entry}


def _law_shapes_open(named: list[dict[str, Any]], tried: dict[str, dict[str, float]], evidence: CurveEvidence
                     ) -> list[dict[str, Any]]:
    """``named`` with ``law_shape_open`` on each ground law, where no measured curve judged the law's shape: the
    better law not named (:func:`~uavturb.gap.selection.better_law_not_named`), by how much it fitted the held-out
    rows better, the bar the selection asked of it (:data:`~uavturb.gap.selection.Z_DISTINCT` where no curve judged
    the two shapes) and whether the heights pinned it (modified in place)."""
    for e in named:
        if EFFECTS[e["name"]].surface == "d_down":
            found = better_law_not_named(e["name"], tried)
            needed = Z_IMPROVE if found and evidence.judges(found[0], e["name"]) else Z_DISTINCT
            unpinned = bool(found) and any(k.endswith("_not_pinned_by_heights") for k in tried[found[0]])
            e["law_shape_open"] = {"law": found[0] if found else None,
                                   "heldout_z_over": found[1] if found else None, "needed": needed,
                                   "not_pinned_by_heights": unpinned}
    return named


def _with_surface_law_swapped(sel: Selection, candidates: list[str],
                              selected: Callable[[list[str], Selection | None], Selection], noise_rms: float
                              ) -> tuple[Selection, list[str]]:
    """``(sel, candidates)``, or the selection made again without a chosen surface law, and the candidates without it,
    where one of its alternatives with a thrust-scaling law beside it fits the held-out data better
    (:func:`~uavturb.gap.selection.swapped_surface_law`) and the selection made again ends better than ``sel`` by
    :data:`~uavturb.gap.selection.Z_IMPROVE` standard errors; the law left out says so in ``candidates_tried``
    (``swapped_out_z``). ``noise_rms`` [N]: the noise floor's RMS (where the final model leaves little beyond it,
    nothing is looked for)."""
    swap = swapped_surface_law(sel, candidates, noise_rms)
    if swap is None:
        return sel, candidates
    law, z = swap
    among = [c for c in candidates if c != law]
    again = selected(among, sel)
    if improvement_z(sel.final_heldout, again.final_heldout) < Z_IMPROVE:
        return sel, candidates
    again.tried[law] = sel.tried.get(law, {}) | {"swapped_out_z": z}
    return again, among


def _check_enough_rows(data: GapData, recordings: Sequence, paths: Sequence[str], slowest_update_hz: float
                       ) -> None:
    """Refused in one line where ``data`` holds fewer than :data:`~uavturb.gap.design.MIN_ANALYSIS_ROWS` rows in
    flight: rotor speeds that update too slowly (``slowest_update_hz``, the slowest stream's updates), that never
    change, or too little flight."""
    if len(data) < MIN_ANALYSIS_ROWS and data.dense is not None:
        where = f"{recordings[0].path or recordings[0].name}/mav0/rotors0/data.csv"
        raise InputError(where, f"only {len(data)} rotor-speed updates in flight (the stream updates at "
                                f"{slowest_update_hz:.2g} Hz or slower, and the thrust is known only at its "
                                f"updates); too few to analyse: longer or more flights, or faster rotor telemetry")
    if len(data) < MIN_ANALYSIS_ROWS:
        frozen = [p for r, p in zip(recordings, paths)
                  if r.rotors is not None and not np.ptp(r.rotors.speeds, axis=0).any()]
        if frozen:
            raise InputError(f"{frozen[0]}/mav0/rotors0/data.csv",
                             "holds the same rotor speeds in every row: a stream that never changes is read as one "
                             "update its logger held (recordings.md: what a stream holds is its updates), which "
                             "tells the thrust at no time in flight; rotor speeds as they vary (commands or "
                             "telemetry) are needed")
        where = paths[0] if len(paths) == 1 else ", ".join(paths)
        raise InputError(where, f"only {len(data)} samples in flight (rotors carrying over 30 % of the weight, "
                                f"off the ground, away from stream dropouts) in {len(paths)} recording(s); too "
                                "few to analyse")


def _timing_robust(data: GapData, sel: Selection, ambiguous: list[dict], recordings: Sequence, paths: Sequence[str],
                   delays: list[dict[str, Any]], sim: dict[str, dict[str, float]], offset: np.ndarray | None
                   ) -> Selection:
    """``sel`` without the chosen effects whose choice over their rival (:attr:`Selection.rivals`: a law of other
    physics that explained the same residual, beaten beyond noise on the held-out data) does not hold over what is
    uncertain of the measured rotor streams' delays: at either end of that interval
    (:func:`uavturb.gap.preparation.timing_interval`) the chosen law must still beat the rival by
    :data:`~uavturb.gap.selection.Z_DISTINCT` standard errors. Where it does not, both go to ``ambiguous``
    (appended) and neither is named. Two flights of a 2.5 kg hexarotor whose ESCs reported at 3 Hz, 60-80 ms
    late (read as not resolvable, 0-0.08 s), named a body drag over their true rotor drag by z = 3.7 on the
    recorded timing; with 0.08 s of delay taken out, the rotor drag won by 4.0. ``offset``: the simulator's own
    effects' force on ``data``'s rows (taken off as the selection did)."""
    interval = {d["recording"]: d["uncertain_s"] for d in delays if d.get("uncertain_s")}
    rivals = sel.chosen_rivals
    if not rivals or not any(hi > lo for lo, hi in interval.values()):
        return sel
    ends = []
    for side in (0, 1):
        recs = [rotor_shifted(r, interval[p][side]) if p in interval else r for r, p in zip(recordings, paths)]
        try:
            shifted, _, _ = flight_rows([flight_data(r) for r in recs], [r.vehicle for r in recs], paths)
        except InputError:
            continue
        apply_thrust_levels(shifted)
        ends.append((side, shifted, _simulator_baseline(shifted, sim).offset if sim else None))
    current = frozenset(sel.final.effects)
    steps = list(sel.steps)
    for chosen, rival in rivals.items():
        for side, shifted, offset in ends:
            _, fm = folds(shifted)
            ho = heldout(shifted, current, fm, offset=offset)
            rival_ho = heldout(shifted, (current - {chosen}) | {rival}, fm, offset=offset)
            z_pair = improvement_z(rival_ho, ho)
            if z_pair >= Z_DISTINCT:
                continue
            late = ", ".join(sorted({f"{interval[p][side]:+.3g} s" for p in paths if p in interval}))
            ambiguous.append(look_alike_entry(chosen, rival, (
                f"{chosen} and {rival} explain the same residual, and which fits better turns on the rotor speeds' "
                f"timing: on it as recorded {chosen} won, but with {late} of delay taken out of the rotor speeds' "
                f"timestamps (within what their delay may still be) the held-out error is {ho.rmse:.4g} N with "
                f"{chosen} and {rival_ho.rmse:.4g} N with {rival} ({chosen} ahead by {z_pair:.1f} standard errors, "
                f"under {Z_DISTINCT:g})"), first="rotor speeds logged faster, or their delay known"))
            steps = [s for s in steps if s.name != chosen]
            break
    if len(steps) == len(sel.steps):
        return sel
    out = finish(data, sel.base, steps, offset=offset, tried=sel.tried)
    out.rejected, out.look_alikes = sel.rejected, sel.look_alikes
    out.rivals = sel.rivals
    return out


@dataclass
class _Baseline:
    """The simulator's model of the flights, before any effect is added."""

    nominal: ModelFit  # rigid body and thrust, fitted robustly on the data alone
    offset: np.ndarray  # (K, 3) N, the simulator's own effects at its parameters
    least_squares: ModelFit  # the nominal model fitted by least squares on data - offset
    r0: np.ndarray  # (K, 3) N, residual of the robust baseline
    force: np.ndarray  # (K, 3) N, the baseline's force, offset included


def _simulator_baseline(data: GapData, sim: dict[str, dict[str, float]]) -> _Baseline:
    """The simulator's model: nominal rigid body and thrust plus its own effects at its parameters;
    its thrust coefficient and bias are fitted robustly (a local mismatch must not bend them)."""
    nominal = robust_nominal(data)
    offset = _sim_offset(data, sim, nominal.coef["k_T"])
    base_data = data.subset(np.ones(len(data), bool))
    base_data.y = data.y - offset
    baseline = robust_nominal(base_data)
    baseline_ls = fit_model(base_data, set(), with_stderr=False)
    return _Baseline(nominal, offset, baseline_ls, baseline.residual(base_data),
                     baseline.predict(base_data) + offset)


def _held_out_near_s(data: GapData, fold_masks: list) -> tuple[float, float]:
    """s, the held-out rows' time within :data:`~uavturb.gap.surface_curve.LIFT_RADII` rotor radii of the surface
    below, and all of it (rows times each recording's median row period)."""
    test = np.any([t for _, t in fold_masks], axis=0)
    near = test & (data.d_down < LIFT_RADII * data.rotor_radius)
    period = np.zeros(len(data.t))
    for g in np.unique(data.group):
        m = data.group == g
        steps = np.diff(np.sort(data.t[m]))
        period[m] = float(np.median(steps[steps > 0])) if np.any(steps > 0) else 0.0
    return float(period[near].sum()), float(period[test].sum())


def nominal_curve_evidence(data: GapData, nominal: ModelFit, heights_hold: bool = True) -> CurveEvidence:
    """The measured surface curve under the nominal model (no effect named yet), as selection reads it:
    its lift near the floor and each surface law's shape fit (:class:`~uavturb.gap.selection.CurveEvidence`);
    none where the heights over surfaces do not hold (``heights_hold``: :func:`~uavturb.gap.decide.floor_crossing`)."""
    if not heights_hold:
        return CurveEvidence(0.0, {})
    _, curve, fits = finder_surface_curve(data, nominal, resample=False)  # the shape's chi^2 is all it reads
    return CurveEvidence(lift_z(curve, data.rotor_radius), {n: f.chi2 for n, f in fits.items()})


def _height_offset(curve: Any, curve_fits: dict, chosen: Sequence[str], data: GapData) -> HeightOffset | None:
    """The height offset the measured curve's shape reads (:func:`~uavturb.gap.surface_laws.height_offset`) for the
    chosen ground law, else for another law fitted to the curve (flights 5 cm low under a Cheeseman-Bennett lift had
    the exponential law named, its shape blind to a shift, where Cheeseman-Bennett fit with the heights 5 cm
    higher), where the chosen law does not fit as measured either; None where no curve, no ground law chosen, the
    chosen one fits, or none is read (on Neural-Swarm's 67 g walks, whose exponential law fits, the multirotor law
    would have read 1.7 cm at chi^2/dof 2.1)."""
    named = [n for n in chosen if EFFECTS[n].surface == "d_down" and n in curve_fits]
    if curve is None or not named or curve_fits[named[0]].law_fits:
        return None  # a chosen law that fits as measured reads no offset, whatever another law would
    return first_height_offset(curve, curve_fits, named + [n for n in curve_fits if n not in named],
                               data.rotor_radius, **data.geometry)


def height_reference(rotor_plane_z: float, uncertainty: float, surface_found: bool) -> dict[str, Any]:
    """Where the surface heights are measured from (``recordings.md``, "Heights over surfaces"): the rotor plane
    at ``rotor_plane_z`` [m] along z_B from the body origin, give or take ``uncertainty`` [m] (each stated error's
    height-reference term), and, where a surface law was found (``surface_found``: named, rejected or left
    ambiguous) and the plane is the body origin, what to check. (Neural-Swarm's 67 g walks without their
    ``rotor_plane_z``: the exponential law's lift at two rotor radii came out 0.259, outside its range, and was
    rejected; 3 cm lower, where the rotors are, it is 0.12.)"""
    out: dict[str, Any] = {"rotor_plane_z_m": float(rotor_plane_z), "uncertainty_m": float(uncertainty),
                           "note": None}
    if surface_found and rotor_plane_z == 0.0:
        out["note"] = ("vehicle.yaml's rotor_plane_z is 0 or absent: the rotor discs are taken to be at the body "
                       "origin. Where they sit elsewhere (a Crazyflie's 2.5 cm below it, a frame's motion-capture "
                       "origin 10-20 cm below them), set it: a surface law's parameters, and whether they fall "
                       f"inside its range, depend on it beyond the +-{100 * uncertainty:.0f} cm each stated error "
                       "covers.")
    return out


def measured_rotor_speeds(recordings: Sequence) -> bool:
    """Whether the recordings' rotor speeds are measured by the ESCs (``vehicle.yaml``'s
    ``rotor_speed_source``), not commanded."""
    return any(r.vehicle.rotor_speed_source == "measured" for r in recordings)


def _testable_candidates(data: GapData, sim: dict[str, dict[str, float]], measured: bool = False
                         ) -> tuple[list[str], list[dict[str, Any]], frozenset[str]]:
    """(effects to try: not in the simulator and testable on these flights; the effects the flights
    cannot test, with why and what would; the simulator's testable effects, fitted from the start).

    Surface effects need flights within their reach; ``battery_sag`` and ``battery_voltage`` need commanded rotor
    speeds (``effects.md``: a measured rotor speed already shows the battery's sag), ``battery_voltage`` also the
    battery's voltage over every recording's flight."""
    reach = {e: surface_reach(data, e) for e, spec in EFFECTS.items() if spec.surface is not None}
    testable = {e for e in EFFECTS if e not in reach or reach[e].testable}
    not_testable = [{"name": e, "why": r.why(), "to_separate": r.to_separate()}
                    for e, r in reach.items() if not r.testable]
    if measured:
        for name in ("battery_sag", "battery_voltage"):
            testable.discard(name)
            not_testable.append({"name": name,
                                 "why": "the rotor speeds are measured (rotor_speed_source: measured): a measured "
                                        "speed already shows the battery's sag, so there is no sag left to find",
                                 "to_separate": "record the commanded rotor speeds instead"})
    elif data.voltage_dev is None:
        testable.discard("battery_voltage")
        not_testable.append({"name": "battery_voltage",
                             "why": "a recording has no battery voltage (mav0/battery0) over its flight, so thrust "
                                    "cannot be followed with the voltage; battery_sag, a law in time, stands in",
                             "to_separate": "log the battery voltage (mav0/battery0) through the whole flight"})
    candidates = [e for e in EFFECTS if e not in sim and e in testable]
    return candidates, not_testable, frozenset(e for e in sim if e in testable)


def _per_recording_stderr(k_T: float, sample: float, levels: ThrustLevels, names: Sequence[str], stated: float
                          ) -> dict[str, float]:
    """``{recording: N/(rad/s)^2}``, the standard error of each recording's thrust coefficient ``k_T`` times its level:
    where the levels differ, the pooled fit's ``sample`` error and each level's own (its measured coefficient's
    relative error; a probe's three sessions had their coefficients stated with none; nan where a level was not
    measured); where they agree, each recording has the pooled value and its ``stated`` error."""
    if not levels.differ:
        return {n: float(stated) for n in names}
    with np.errstate(divide="ignore", invalid="ignore"):
        rel = np.asarray(levels.stderr, float) / np.asarray(levels.k_T, float)
    return {n: float(k_T * float(lv) * np.hypot(sample / k_T, r)) for n, lv, r in zip(names, levels.level, rel)}


def _thrust_laws_left_open(ambiguous: Sequence[dict]) -> list[str]:
    """The laws scaling the thrust that ``ambiguous`` leaves out of the final model: a law undecided beside the
    thrust coefficient (:func:`~uavturb.gap.selection.near_misses`), and both laws of a surface effect whose shape
    the data leave open (:func:`~uavturb.gap.selection.shape_open_entry`: the lift is there, so the thrust
    coefficient fitted without it moves as much as with either law)."""
    laws: list[str] = []
    for entry in ambiguous:
        if entry["candidates"][1:] == ["thrust_coefficient"]:
            laws.append(entry["candidates"][0])
        elif "lift_at_lowest_heights" in entry:
            laws.extend(entry["candidates"])
    return laws


def _nominal(data: GapData, final: ModelFit, levels: ThrustLevels, undecided: Sequence[str] = ()
             ) -> dict[str, Any]:
    """The report's ``nominal``: the thrust coefficient (one per recording where their levels differ,
    with the spread), and the accelerometer bias as measured against motion capture. ``undecided``: laws scaling
    the thrust (surface laws, a battery's sag) left undecided beside the thrust coefficient
    (:func:`~uavturb.gap.selection.near_misses`): its error then covers how far it moves with the law fitted beside
    it (an 8 s flight's k_T, 10 % over the truth with the lift in it, had been stated to 3.3 %)."""
    k_T = final.coef["k_T"]
    sample = float(final.stderr.get("k_T", np.nan))
    measured = levels.k_T[np.isfinite(levels.k_T)]
    # one k_T for recordings whose levels agree: its error covers their spread (each recording's own
    # level lands within about two errors of it, gap-report.md); where they differ each has its own, and the one
    # stated for the vehicle covers theirs (a probe's two sessions 8 % apart had read k_T +- 0.0094 %)
    own = k_T * np.asarray(levels.level, float)
    between = (float(np.std(own, ddof=1)) if levels.differ and len(own) >= 2 else
               float(np.std(measured, ddof=1)) if len(measured) >= 2 else 0.0)
    trade = {law: abs(fit_model(data, set(final.effects) | {law}, with_stderr=False).coef["k_T"] - k_T)
             for law in undecided}
    terms = {"sample": sample, "between_recordings": between}
    if data.rotor_quantum > 0:  # rounded rotor speeds: a steady hover keeps its rounding (rounding_share)
        terms["rotor_resolution"] = k_T * rounding_share(data.rotor_speeds, data.rotor_quantum)
    if trade:
        terms["undecided_thrust_law"] = max(trade.values())
    out: dict[str, Any] = {
        "thrust_coefficient": k_T, "thrust_coefficient_stderr": float(np.nanmax(list(terms.values()))),
        "thrust_coefficient_stderr_terms": terms,
        "thrust_levels_differ": levels.differ, "thrust_level_note": levels.why,
        "thrust_level_spread_percent": levels.spread_percent,
        "thrust_coefficient_per_recording": {n: k_T * float(lv) for n, lv in zip(data.names, levels.level)},
        "thrust_coefficient_per_recording_stderr": _per_recording_stderr(
            k_T, sample, levels, data.names, float(np.nanmax(list(terms.values())))),
        "thrust_level_basis": levels.basis,
    }
    measured_at = "thrust_coefficient_at_matched_heights" if levels.basis == "matched heights" else \
        "thrust_coefficient_far_from_surfaces"
    out[measured_at] = {n: (float(k), float(se)) for n, k, se in zip(data.names, levels.k_T, levels.stderr)}
    if data.fits_bias:
        out["accel_bias"] = [final.coef[f"b_{a}"] for a in "xyz"]
        out["accel_bias_note"] = "fitted with the model"
    elif data.anchored:
        b = np.array([a.b for a in data.anchored.values()])
        out["accel_bias"] = [float(x) for x in b.mean(axis=0)]
        out["accel_bias_per_recording"] = {n: {"b": a.b.tolist(), "stderr": a.stderr.tolist()}
                                           for n, a in data.anchored.items()}
        out["accel_bias_note"] = ("measured against motion capture (mean of a_imu - R^T (dv/dt + g e_z) in flight, "
                                  "body frame), not fitted: it cannot trade with the thrust coefficient or a law "
                                  "along the thrust")
    else:
        out["accel_bias"] = None
        out["accel_bias_note"] = "no IMU in these recordings: no accelerometer, so no accelerometer bias was estimated"
    return out


