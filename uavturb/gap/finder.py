"""``uavturb gap``: compare, locate, name, model and close the loop (``gap-report.md``)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Callable, Generator, Sequence

import numpy as np

from uavturb.errors import InputError
from uavturb.gap import locate
from uavturb.gap.decide import (
    R2_AMBIGUOUS,
    airspeed_drag,
    ambiguity,
    bias_alike,
    can_test_alone,
    flight_facts,
    floor_crossing,
    level_alike,
    residual_thrust_tilt,
    surface_reach,
    thrust_tilt_alike,
    tilt_per_recording,
    too_small,
)
from uavturb.gap.design import (
    MIN_ANALYSIS_ROWS,
    GapData,
    apply_thrust_levels,
    gap_data,
    rounding_floor,
)
from uavturb.gap.explain import explanation
from uavturb.gap.fit import ModelFit, fit_model, forking_worth, robust_nominal
from uavturb.sysid.nominal import (
    OFFSET_DECISIVE_Z,
    OFFSET_PRACTICAL,
    OFFSET_RADII,
    OFFSET_SPAN,
    UNREAD_OFFSET_SPAN,
    ThrustLevels,
    hover_speed,
    stated_offset,
)
from uavturb.gap.landed_heights import LandedHeights
from uavturb.gap.preparation import (
    contact_masks,
    landings_aligned,
    prepared,
    rotor_shifted,
    rotor_speeds_moved,
    state_thinned,
)
from uavturb.gap.selection import (
    LIFT_Z,
    Z_DISTINCT,
    Z_IMPROVE,
    CurveEvidence,
    Selection,
    better_law_not_named,
    finish,
    folds,
    heldout,
    improvement_z,
    last_step,
    lift_not_named,
    look_alike_entry,
    near_misses,
    select,
    untested_on_heldout,
)
from uavturb.gap.surface_curve import LIFT_RADII, lift_z
from uavturb.gap.surface_laws import (
    HeightOffset,
    finder_surface_curve,
    first_height_offset,
    law_band,
    law_named_from_curve,
    law_on_curve,
)
from uavturb.gap.uncertainty import (
    HEIGHT_REFERENCE_M,
    HONEST_Z,
    UNTAKEN_Z,
    Refits,
    command_sampling_term,
    error_budget,
    honest_stderr,
    mass_term,
    one_sample,
    presence_z,
    statistical_errors,
    stream_rate_term,
    thrust_map_term,
    timing_term,
    untaken_term,
    with_curve_check,
    with_systematic,
)
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
from uavturb.sysid.command_lag import CommandLag, command_lag
from uavturb.sysid.flight_data import flight_data, rotor_hold_s
from uavturb.sysid.rotor_order import OTHER as OTHER_ORDER
from uavturb.sysid.rotor_order import REORDER, RotorOrder, rotor_order

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
        e.update(_with_term(e, "speed_offset", term))
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
    data, contact_report, landed = _flight_rows(fds, [r.vehicle for r in recordings], paths, sim_forces=bool(sim),
                                                read_order=True)
    held["streams"] += _rotor_order_lines(data.rotor_order, recordings)
    # emptied as the rows were built; what they keep lives on in ``data`` (memory: a flight-hour at 200 Hz is 720k rows)
    del fds
    if len(data) < MIN_ANALYSIS_ROWS and data.dense is not None:
        where = f"{recordings[0].path or recordings[0].name}/mav0/rotors0/data.csv"
        raise InputError(where, f"only {len(data)} rotor-speed updates in flight (the stream updates at "
                                f"{held['slowest_update_hz']:.2g} Hz or slower, and the thrust is known only at its "
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

    sel = selected(candidates)
    progress("deciding what the data support")
    refits = Refits()  # the error budgets' refits of data's parts, shared by the decisions and the named effects

    def decided(chosen: Selection, among: list[str]) -> tuple[Selection, list[dict], list[dict]]:
        return _decide(data, chosen, among, refits, levels_read=levels.basis != "none")

    sel, ambiguous, rejected = _without_unpinned_laws(decided(sel, candidates), candidates,
                                                      lambda among: selected(among, after=sel), decided)
    rejected = _lift_beside_unpinned(rejected, sel.chosen, evidence.lift_z)
    sel = _timing_robust(data, sel, ambiguous, recordings, paths, held["delays"], sim, base.offset)
    final: ModelFit = sel.final
    facts = flight_facts(data, final.coef["k_T"])
    rf = final.residual(data)
    _, rsf, _ = locate.segments(data, rf, update_step_s=step)
    _, draws = locate.window_rows(data, 0.5, step)
    beyond = float(np.sqrt(max(0.0, np.mean(np.sum(rsf**2, axis=1)) - np.sum(sigma**2) / draws)))
    unexplained = {"rms_N": beyond, "drivers": locate.drivers(data, rsf)}
    height_driver = max((d["score"] for d in unexplained["drivers"] if d["feature"] == "d_down"), default=0.0)
    ambiguous += near_misses(sel.tried, set(sel.chosen) | {r["name"] for r in rejected}
                             | {c for a in ambiguous for c in a["candidates"]},
                             height_driver=height_driver if heights_broken is None else 0.0, beyond_noise_N=beyond)
    not_testable += untested_on_heldout(data, final, fm, candidates,
                                        set(sel.chosen) | {r["name"] for r in rejected}
                                        | {c for a in ambiguous for c in a["candidates"]},
                                        lambda fit, name: outside_range(data, fit, name), protocol)
    look_alike = next((a for a in ambiguous if "thrust_axis_tilt" in a["candidates"]), None)
    if look_alike is not None:  # the push left undecided: each recording's tilt, with its error, for the reader
        per, _ = tilt_per_recording(data, final, rf)
        look_alike["per_recording"] = [e | {"recording": paths[e["recording"]]} for e in per]
    tilt = None if look_alike is not None else residual_thrust_tilt(data, final, rf, facts)
    if tilt is not None:  # what is left beyond the tilt drives the drivers (a tilt had read as d_up on x)
        entry, force = tilt
        for e in entry["per_recording"]:
            e["recording"] = paths[e["recording"]]
        _, rst, _ = locate.segments(data, rf - force, update_step_s=step)
        entry["rms_beyond_tilt_N"] = float(np.sqrt(max(0.0,
                                                       np.mean(np.sum(rst**2, axis=1)) - np.sum(sigma**2) / draws)))
        unexplained |= {"drivers": locate.drivers(data, rst), "thrust_axis_tilt": entry}
    thrust_map = thrust_map_term(data, final, rf) if not measured_rotor_speeds(recordings) else None
    plots = dict(data=data, r0=base.r0, rs0=rs0, rf=rf, rsf=rsf, segs=segs, drivers=drv, base_ho=base_ho,
                 final_ho=sel.final_heldout)
    yield Checkpoint(None if thrust_map is None else thrust_map[0], len(data), len(fm), plots)
    progress("the surface curve")
    stated, data_at, final_at = _at_stated_offset(data, final, thrust_map)  # where the thrust map is left open
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
    named = _cross_checked(_effects_named(data, sel, final, facts, height_uncertainty, refits, values=final_at),
                           curve_fits)
    named = _timing_checked(named, final, recordings, paths, held["delays"])
    named = _rate_checked(named, final, recordings, paths, held["state_too_slow"])
    named = [e | _with_term(e, "command_sampling", command_sampling_term(
        [rotor_hold_s(r.rotors) for r in recordings])) if e["name"] == "motor_lag" else e
             for e in named]
    named, speed_map = _thrust_map_checked(named, data, thrust_map, stated)
    named, curve_report = law_named_from_curve(named, curve_report, curve, curve_fits, data, facts,
                                               height_uncertainty)
    named, curve_report = curve_named_thrust_map(named, curve_report, _curves_at_open_offsets(data, final, speed_map))
    named = [_mass_checked(e, final.coef["k_T"], vehicle.thrust_coefficient) for e in named]
    if curve_report is None:  # no measured curve judged the law's shape: said, with the margin of a better one
        for e in named:
            if EFFECTS[e["name"]].surface == "d_down":
                found = better_law_not_named(e["name"], sel.tried)
                # the bar selection asked of it: Z_DISTINCT where no curve judged the two shapes
                needed = Z_IMPROVE if found and evidence.judges(found[0], e["name"]) else Z_DISTINCT
                unpinned = bool(found) and any(k.endswith("_not_pinned_by_heights") for k in sel.tried[found[0]])
                e["law_shape_open"] = {"law": found[0] if found else None,
                                       "heldout_z_over": found[1] if found else None, "needed": needed,
                                       "not_pinned_by_heights": unpinned}
    named = _untaken_checked(named, data, final, sel.tried, {e["name"] for e in rejected + not_testable}
                             | {c for a in ambiguous for c in a["candidates"]})
    if curve_report is not None:
        curve_report = _with_law_band(curve_report, curve, named, data)
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
        "nominal": _nominal(data, final, levels, [a["candidates"][0] for a in ambiguous
                                                  if a["candidates"][1:] == ["thrust_coefficient"]])
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


#: thrust over weight, the median while all rotors spin, above which vehicle.yaml's thrust coefficient cannot be that
#: of the recorded speeds (flights hover at about one; racing quadrotors peak at 5-10, not for most of a flight)
MAX_THRUST_TO_WEIGHT = 3.0


def _check_thrust_scale(fd: Any, vehicle: Any, path: str) -> None:
    """With vehicle.yaml's thrust coefficient, the recorded rotor speeds (``fd``'s) carry more than 30 % of the weight
    at some time and under :data:`MAX_THRUST_TO_WEIGHT` times it most of the time; otherwise refused in one line
    (rotors0 in other units than rad/s, or a thrust coefficient or mass off)."""
    weight = vehicle.mass * GRAVITY
    thrust = vehicle.thrust_coefficient * np.sum(fd.rotor_speeds**2, axis=1)
    where = f"{path}/mav0/rotors0/data.csv"
    most = float(np.max(thrust))
    if most < 0.3 * weight:
        raise InputError(where, f"its rotor speeds never carry more than {100 * most / weight:.2g} % of the weight "
                                f"with vehicle.yaml's thrust_coefficient {vehicle.thrust_coefficient:.4g} "
                                "N/(rad/s)^2: a flight that never took off, speeds in other units than rad/s (Hz, rpm: "
                                "rotor_speed_scale converts) or a thrust coefficient off")
    spinning = np.all(fd.rotor_speeds > 0, axis=1)
    typical = float(np.median(thrust[spinning])) if spinning.any() else 0.0
    if typical > MAX_THRUST_TO_WEIGHT * weight:
        raise InputError(where, f"its rotor speeds would lift {typical / weight:.3g} times the weight (the median "
                                f"while all rotors spin) with vehicle.yaml's thrust_coefficient "
                                f"{vehicle.thrust_coefficient:.4g} N/(rad/s)^2, where a flight needs about one: speeds "
                                "in other units than rad/s (rpm: rotor_speed_scale 0.10472 converts), or a thrust "
                                "coefficient or mass off")


def _flight_rows(fds: list, vehicles: Sequence[Any], paths: Sequence[str], *, sim_forces: bool = True,
                 read_order: bool = False) -> tuple[GapData, list[dict[str, Any]], LandedHeights]:
    """The flights' rows in the air (ground contact found and left out), the report's ``ground_contact`` and the
    recordings' landed heights, each flight's heights moved so that they land at one
    (:func:`~uavturb.gap.preparation.landings_aligned`), and its forces with its own vehicle.yaml's mass
    (``vehicles``, one per flight: one vehicle, io.reader checks, whose batteries may weigh differently). Rotor
    speeds at odds with vehicle.yaml's thrust coefficient are refused (:func:`_check_thrust_scale`). ``fds`` is
    emptied as the rows are built (its places set to None: :func:`~uavturb.gap.design.gap_data`'s ``release``);
    ``sim_forces``: the simulator models effects, computed on the flights at full rate (``gap_data``'s);
    ``read_order``: read which order of the rotor columns the torques follow (:func:`_rotor_columns_order`, the
    rows' :attr:`~uavturb.gap.design.GapData.rotor_order`; once, on the recordings as read)."""
    for fd, vehicle_of, path in zip(fds, vehicles, paths):
        if vehicle_of.thrust_coefficient:
            _check_thrust_scale(fd, vehicle_of, path)
    vehicle = vehicles[0]
    fds[:], landed = landings_aligned(fds, vehicle)
    contact, contact_report = contact_masks(fds, vehicle, paths)
    masses = [v.mass for v in vehicles]
    order = _rotor_columns_order(fds, vehicle, contact) if read_order else None
    torque = _torques_timed(fds, vehicle, contact) if order is None or order.verdict != OTHER_ORDER else None
    data = gap_data(fds, vehicle.mass, vehicle.rotor_radius, k_T_guess=vehicle.thrust_coefficient, release=True,
                    arm_length=vehicle.arm_length, exclude=contact, masses=None if len(set(masses)) == 1 else masses,
                    sim_forces=sim_forces)
    data.torque_lag = torque
    data.rotor_order = order
    return data, contact_report, landed


#: rows in the air at most that the rotor columns' order is read on (every k-th row beyond): a correlation over 10,000
#: rows has a standard error near 0.01-0.02 (fewer where the rows, thinned, are still correlated over about 50 ms),
#: well under the orders' margin of 0.1 (``rotor_order.ORDER_MARGIN``)
ORDER_ROWS = 10_000


def _rotor_columns_order(fds: list, vehicle: Any, contact: list[np.ndarray]) -> RotorOrder | None:
    """Which order of the rotor columns the roll and pitch accelerations follow in the air
    (:func:`uavturb.sysid.rotor_order.rotor_order`, as ``identify`` reads it). The forces do not depend on it (the
    thrust is a sum over the rotors); the torques, and the torques' timing of commanded speeds, do."""
    usable = [~c & np.isfinite(fd.dw).all(axis=1) for fd, c in zip(fds, contact)]
    stride = -(-sum(int(u.sum()) for u in usable) // ORDER_ROWS)
    if stride > 1:  # every stride-th row in the air: the time stays bounded (twelve one-minute walks: 0.44 -> 0.07 s)
        usable = [u & (np.cumsum(u) % stride == 0) for u in usable]
    return rotor_order([fd.matched(fd.rotor_speeds**2) for fd in fds], [fd.dw for fd in fds], vehicle.mixer(),
                       dt=[fd.dt for fd in fds], usable=usable)


def _rotor_order_lines(order: RotorOrder | None, recordings: Sequence) -> list[str]:
    """The streams' line where the rotor columns follow another order than vehicle.yaml's angles: what it changes
    (the torques' timing, not the forces) and the fix; nothing otherwise (the order is in ``facts.rotor_order``)."""
    if order is None or order.verdict != OTHER_ORDER:
        return []
    names = list(dict.fromkeys(r.name for r in recordings))
    where = f"{names[0]}/mav0/rotors0" if len(names) == 1 else f"mav0/rotors0 of {', '.join(names)} (read together)"
    return [f"{where}: {order.sentence()}. The forces read here do not depend on it (the thrust is a sum over the "
            f"rotors); the torques do, so the commands' timing is not read on them: {REORDER}"]


def _torques_timed(fds: list, vehicle: Any, contact: list[np.ndarray]) -> CommandLag | None:
    """How far the roll and pitch torques lag commanded rotor speeds, timed on the angular acceleration in the air
    (:func:`uavturb.sysid.command_lag.command_lag`, as ``identify`` reads it): a motor-lag explanation checks its
    thrust's lag against it. None for measured speeds (the rotors' own) and held streams (a hold reads as a lag)."""
    if vehicle.rotor_speed_source == "measured" or any(fd.rotor_fresh is not None for fd in fds):
        return None
    masks = [~c & np.isfinite(fd.dw).all(axis=1) for fd, c in zip(fds, contact)]
    return command_lag(fds, masks, vehicle)


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
            shifted, _, _ = _flight_rows([flight_data(r) for r in recs], [r.vehicle for r in recs], paths)
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


def _refit_on(recordings: Sequence, paths: Sequence[str], final: ModelFit) -> ModelFit | None:
    """``final``'s effects fitted on the flights of ``recordings`` (streams changed for a systematic term: rotor
    timing, stream rate), each recording's thrust level its own where levels differ; None where that fails."""
    try:
        data, _, _ = _flight_rows([flight_data(r) for r in recordings], [r.vehicle for r in recordings], paths)
        apply_thrust_levels(data)
        return fit_model(data, final.effects, with_stderr=False)
    except (InputError, np.linalg.LinAlgError, ValueError):
        return None


def _timing_checked(effects: list[dict[str, Any]], final: ModelFit, recordings: Sequence, paths: Sequence[str],
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
        e.update(_with_term(e, "rotor_timing", timing_term(low, high, tuple(e["params"]))))
    return effects


def _rate_checked(effects: list[dict[str, Any]], final: ModelFit, recordings: Sequence, paths: Sequence[str],
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
        e.update(_with_term(e, "stream_rate", stream_rate_term(
            e["params"], None if thinned is None else thinned.effect_params(e["name"])[0])))
    return effects


def _untaken_checked(named: list[dict[str, Any]], data: GapData, final: ModelFit, tried: dict[str, dict[str, float]],
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
    return [e | _with_term(e, "untaken_candidate", untaken_term(final, beside, e["name"]))
            | {"untaken_candidates": names} if e["name"] in final.effects else e for e in named]


def _mass_checked(effect: dict[str, Any], k_T: float, k_T_yaml: float | None) -> dict[str, Any]:
    """A named ``effect`` entry with the **mass** term of :mod:`uavturb.gap.uncertainty` where it has one (force-unit
    parameters, ``vehicle.yaml`` stating a thrust coefficient ``k_T_yaml`` near the flights' ``k_T``)."""
    spec = EFFECTS[effect["name"]]
    terms = mass_term(effect["params"], dict(zip(spec.params, spec.units)), k_T, k_T_yaml)
    return effect | _with_term(effect, "mass", terms) if terms else effect


def _with_term(effect: dict[str, Any], term: str, values: dict[str, float]) -> dict[str, Any]:
    """``error_budget`` and ``stderr`` of a named ``effect`` entry with a systematic ``term``
    (:func:`uavturb.gap.uncertainty.with_systematic`)."""
    budget = with_systematic(effect["error_budget"], term, values)
    return {"error_budget": budget, "stderr": honest_stderr(budget)}


def _at_stated_offset(data: GapData, final: ModelFit, thrust_map: tuple | None
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


def _thrust_map_checked(effects: list[dict[str, Any]], data: GapData, thrust_map: tuple | None, stated: float
                        ) -> tuple[list[dict[str, Any]], dict[str, Any] | None]:
    """``effects`` with the **thrust map** term of :mod:`uavturb.gap.uncertainty` in each budget, and the
    report's ``nominal.rotor_speed_offset`` (None with measured rotor speeds, which are the rotors' own:
    ``thrust_map`` None). ``stated``: the offset [rad/s] the named values are stated at (:func:`_at_stated_offset`)."""
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


def _with_law_band(curve_report: dict, curve: Any, named: list[dict[str, Any]], data: GapData) -> dict:
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
            e.update(_with_term(e, "thrust_map", terms[e["name"]]))
    return effects


def _curves_at_open_offsets(data: GapData, final: ModelFit, speed_map: dict[str, Any] | None
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
    :func:`_curves_at_open_offsets`). A curve read on commanded speeds whose offset is not known is no better known
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
            e.update(_with_term(e, "thrust_map", half_change(e["name"], e["params"])))
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


def _budget(data: GapData, final: ModelFit, name: str, height_uncertainty: float = HEIGHT_REFERENCE_M,
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
    budget = _budget(data, final, name, height_uncertainty=0.0, refits=refits)
    z = presence_z(budget, params, EFFECTS[name].presence_params)
    if not np.isfinite(z) or z >= HONEST_Z:
        return one_sample(data, final, name)
    se = statistical_errors(budget)
    return (f"its fitted value ({', '.join(f'{k} = {v:.3g} ± {se[k]:.2g}' for k, v in params.items())}) lies within "
            f"{HONEST_Z:.0f} standard errors of zero once the spread between recordings or blocks is counted")


def _effects_named(data: GapData, sel: Selection, final: ModelFit, facts: Any,
                   height_uncertainty: float = HEIGHT_REFERENCE_M, refits: Refits | None = None,
                   values: ModelFit | None = None) -> list[dict[str, Any]]:
    """The report's ``effects``: each chosen effect's fitted parameters with honest errors
    (:mod:`uavturb.gap.uncertainty`: sample, height reference, between recordings or blocks), the
    explanation and the held-out gain. ``values``: the same model fitted where its values are stated (the rotor
    speeds moved to the centre of the offsets the thrust map leaves open, :func:`_at_stated_offset`), ``final``
    where None; the error budgets are ``final``'s, whose spreads the offset does not move."""
    effects_out = []
    for s in sel.steps:
        params, _ = (final if values is None else values).effect_params(s.name)
        budget = _budget(data, final, s.name, height_uncertainty, refits)
        effects_out.append({
            "name": s.name, "params": params, "stderr": honest_stderr(budget),
            "explanation": explanation(s.name, params, facts) + _together(s, sel.chosen),
            "heldout_rmse_before_N": s.heldout_before, "heldout_rmse_after_N": s.heldout_after,
            "z_heldout": s.z, "error_budget": budget,
        } | ({"named_with": s.named_with} if s.named_with in sel.chosen else {}))
    return effects_out


def _together(step: Any, chosen: Sequence[str]) -> str:
    """The sentence an effect named together with another still ``chosen`` gets
    (:func:`~uavturb.gap.selection._thrust_laws_together`), or ''."""
    if step.named_with not in chosen:
        return ""
    both = {EFFECTS[step.name].surface, EFFECTS[step.named_with].surface}
    how = ("with surfaces both below and above, both lifts raise the thrust per rotor speed squared" if both == {
        "d_down", "d_up"} else "the battery lowers the thrust per rotor speed squared as it sags, while the surface "
           "raises it where the flights came near, so each law alone takes part of the other")
    return (f" Named together with {step.named_with}: {how}, and neither law alone improved the held-out fit beyond "
            f"noise; together they do (z = {step.z:.1f}).")


def _cross_checked(effects: list[dict[str, Any]], curve_fits: dict) -> list[dict[str, Any]]:
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


def outside_range(data: GapData, fit: ModelFit, name: str, facts: Any = None) -> str | None:
    """Why the effect ``name`` as ``fit`` has it lies outside its physical range on ``data``'s vehicle and flights
    (``EffectSpec.physical_range``, read on ``facts``: :func:`~uavturb.gap.decide.flight_facts` with ``fit``'s thrust
    coefficient where None), None where it lies inside."""
    params, _ = fit.effect_params(name)
    return EFFECTS[name].physical_range.violation(params, facts or flight_facts(data, fit.coef["k_T"]))


def _no_discovery(data: GapData, fit: ModelFit, name: str, facts: Any, refits: Refits | None = None
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


def _without_unpinned_laws(decided: tuple[Selection, list[dict], list[dict]], candidates: list[str],
                           selected: Callable[[list[str]], Selection],
                           decide: Callable[[Selection, list[str]], tuple[Selection, list[dict], list[dict]]]
                           ) -> tuple[Selection, list[dict], list[dict]]:
    """``decided`` (the selection, ``ambiguous``, ``rejected`` after :func:`_decide`), or, where it rejected an
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


def _lift_beside_unpinned(rejected: list[dict], chosen: Sequence[str], lift: float) -> list[dict]:
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


def _decide(data: GapData, sel: Selection, candidates: list[str], refits: Refits | None = None,
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
        final = sel.final
        facts = flight_facts(data, final.coef["k_T"])
        drop = None
        for s in steps:
            params, _ = final.effect_params(s.name)
            bad, reason = _no_discovery(data, final, s.name, facts, refits)
            if bad is not None and with_undecided is not None and _held_beside(data, with_undecided, s.name):
                # it held beside an effect left undecided, and fails without it: its value hangs on that one
                ambiguous.append(_hangs_on(with_undecided, s.name, undecided, bad))
                drop = s
                break
            if bad is not None:
                rejected.append({"name": s.name, "params": params, "reason": reason, "why": bad})
                drop = s
                break
            amb = ambiguity(data, final, s.name, facts)
            if amb is not None:
                ambiguous.append(amb | {"params_if_named": params})
                drop = s
                break
            amb = level_alike(data, final, s.name, levels_read)  # levels_read: the recordings' levels measured apart
            if amb is not None:
                ambiguous.append(amb)
                drop = s
                break
        if drop is None and "wind" in {s.name for s in steps}:
            amb = thrust_tilt_alike(data, final, facts)
            if amb is not None:
                ambiguous.append(amb)
                drop = next(s for s in steps if s.name == "wind")
        if drop is None and "rotor_drag" in {s.name for s in steps}:
            amb = airspeed_drag(data, final, facts)
            if amb is not None:
                ambiguous.append(amb)
                drop = next(s for s in steps if s.name == "rotor_drag")
        if drop is None:
            break
        if any(drop.name in a["candidates"] for a in ambiguous) and drop.name not in undecided:
            if with_undecided is None:
                with_undecided = final
            undecided.append(drop.name)
        steps.remove(drop)
        for s in [s for s in steps if s.named_with == drop.name]:  # it passed only together with the one dropped
            steps.remove(s)
            sel.tried.setdefault(s.name, {})[f"dropped_with_{drop.name}"] = 1.0
        # as select() fitted it (sim effects in the base), reusing its fits of the same effect sets
        sel = finish(data, sel.base, steps, tried=sel.tried, known=sel.known)
    sel.known = None  # its folds' rows and fits are not needed past the decisions (memory)
    sel.rivals = rivals  # finish() starts a Selection afresh
    final = sel.final
    facts = flight_facts(data, final.coef["k_T"])
    named = {a for entry in ambiguous for a in entry["candidates"]}
    for c in candidates:
        if c in final.effects or c in named or bias_alike(data, c) < R2_AMBIGUOUS:
            continue
        b = np.array([final.coef[f"b_{a}"] for a in "xy"])
        se = np.array([final.stderr.get(f"b_{a}", np.inf) for a in "xy"])
        if np.max(np.abs(b) / se) > 4.0:
            push = data.mass * float(np.hypot(*b))
            ambiguous.append({
                "candidates": [c, "accelerometer_bias"],
                "why": (f"the heading changed by only {facts.heading_span_deg:.0f} deg: the fitted accelerometer bias "
                        f"({b[0]:.3g}, {b[1]:.3g}) m/s^2 (body x, y) could as well be a steady push of about "
                        f"{push:.3g} N fixed in the world"),
                "to_separate": "fly the same pattern at two or more headings (90 deg apart), or rely on motion "
                               "capture alone"})
    return sel, ambiguous, rejected
