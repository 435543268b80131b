"""``uavturb gap-proof --suite conditions``: the gap finder on flights with real recordings'
troubles, each with a known truth (``uavturb generate flight`` options, :mod:`uavturb.sim.flights.conditions`).

Each condition is two flights run blind (``--sim-effects none``). Its *target* effects are what a
flight engineer wants found (the equivalent steady push of a wind, a ground effect...); the
verdict per condition is

- ``right``: every target named with its parameters within :data:`TOLERANCE` of the truth;
- ``ambiguous``: a target not named but reported in ``ambiguous`` (the data cannot decide);
- ``missed``: a target neither named nor reported (not wrong, but not found);
- ``WRONG``: any effect named more than :data:`TOLERANCE` off its true parameters (a target, or
  one beside it that the flights' physics has, such as the rotor drag of a wind tunnel), or an
  effect named whose physics the flights do not have at all (a surface effect far from
  surfaces, a battery sag that is not there).

Before :func:`uavturb.gap.decide.airspeed_drag`, the wind-tunnel rows named rotor drag with a
``k_d`` 2.2 times the true one (body drag on the airspeed folded in): right for the target
alone, WRONG by this rule.

The effects "the flights' physics has" are those of ``truth.yaml`` less its ``invisible_effects``:
with measured rotor speeds a battery sag or a motor lag in the simulation shows in the speeds
themselves, so naming them is WRONG (``effects.md``). Rows with no target are "nothing may be
named" rows: ``right`` when nothing is named (whatever is reported ``ambiguous``), else WRONG.
Further rules for the troubles of real recordings near surfaces:

- a row whose flights carry a look-alike that is no effect of the vocabulary (a thrust axis
  tilted from the recorded attitude, :attr:`Condition.look_alikes`) is right when nothing is
  named or the look-alike itself is named or left ambiguous (for example ``wind`` vs
  ``thrust_axis_tilt``); naming the effect it imitates (``wind``, which the flights do not have)
  is WRONG;
- a row whose flights start and end on the ground (``truth.yaml``'s ``ground_contact``) also
  needs the report's ``ground_contact`` to cover at least :data:`CONTACT_COVER` of each true
  contact interval of each recording, else it is at best ``missed`` (it is the look-alike of a
  ground effect: a floor carrying the vehicle);
- the two flights of a row may differ (:attr:`Condition.second`: a thrust level 4 % apart); the
  target's truth is then the mean over them, as for every row.
"""

from __future__ import annotations

import hashlib
import time
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from uavturb.gap.finder import analyse
from uavturb.io.reader import load_recordings
from uavturb.proof.scoring import param_error, with_hidden_bias
from uavturb.proof.sindy_peer import sindy_names
from uavturb.sim.flights.condition_schema import Conditions
from uavturb.sim.flights.conditions import generate_conditioned_flight, read_truth

#: relative error within which a target counts as named right (issue: wind within 30 %)
TOLERANCE = 0.30
#: share of each true ground-contact interval the report's ``ground_contact`` must cover
CONTACT_COVER = 0.8
#: what the report may call a thrust axis tilted from the recorded attitude (no effect of ``effects.md``)
THRUST_TILT = "thrust_axis_tilt"


@dataclass(frozen=True)
class Condition:
    """One row of the conditions table."""

    name: str
    conditions: Conditions
    effects: dict[str, dict[str, float]] = field(default_factory=dict)
    targets: tuple[str, ...] = ()
    kind: str = "mixed"
    hidden_bias: bool = False  # an accelerometer bias the state file does not know (needs an IMU)
    vehicle: str = "hex"  # built-in vehicle of both flights
    second: Conditions | None = None  # the second flight's conditions (default: ``conditions``)
    look_alikes: tuple[str, ...] = ()  # names of troubles that are no effect but may be named (module docstring)

    def flight_conditions(self, k: int) -> Conditions:
        """Conditions of flight ``k`` (0 or 1)."""
        return self.second if k == 1 and self.second is not None else self.conditions


GROUND_EFFECT = {"ground_effect": {"mu": 2.0}}
#: a medium multirotor's PX4 log in a motion-capture room (the issue's first vehicle): every trouble at once
PX4_LOG = Conditions(no_imu=True, rate_hz=60, jitter_ms=3.0, position_hold_hz=9, rotor_hold_hz=3, rotor_delay_s=0.06,
                     measured_rotors=True, ground_contact_s=3.0, rotor_plane_z=0.15, battery_voltage=16.0,
                     thrust_tilt_deg=1.2)

CONDITIONS: tuple[Condition, ...] = (
    Condition("wind tunnel: MoCap 50 Hz, no IMU, fixed heading, motor commands, 4 m/s wind",
              Conditions(no_imu=True, rate_hz=50, jitter_ms=2.0, fixed_heading=True, motor_commands=True,
                         wind_speed=(-4.0, 0.0)), targets=("wind",)),
    Condition("wind tunnel: MoCap 50 Hz, no IMU, fixed heading, 2 m/s wind",
              Conditions(no_imu=True, rate_hz=50, jitter_ms=2.0, fixed_heading=True, wind_speed=(-2.0, 0.0)),
              targets=("wind",)),
    Condition("IMU with an unknown bias, fixed heading, 3 m/s wind",
              Conditions(fixed_heading=True, wind_speed=(-3.0, 0.0)), targets=("wind",), hidden_bias=True),
    Condition("IMU bias random walk, heading turning, 3 m/s wind",
              Conditions(accel_bias_walk=0.002, wind_speed=(2.0, -2.0)), targets=("wind",)),
    Condition("EuRoC sensor frame with lever arm, ground effect mu = 2",
              Conditions(sensor_frame="euroc"), {"ground_effect": {"mu": 2.0}}, ("ground_effect",), "low_passes"),
    Condition("vehicle.yaml mass 5 % off, rotor drag",
              Conditions(mass_error=0.05), {"rotor_drag": {"k_d": 8.06e-5}}, ("rotor_drag",)),
    Condition("MoCap 50 Hz, no IMU, clean flight",
              Conditions(no_imu=True, rate_hz=50, jitter_ms=2.0)),
    # --- real flights near surfaces -------------------------------------------------------------
    Condition("on the ground 3 s at both ends (rotors at 40-70 % of hover), ground effect mu = 2",
              Conditions(ground_contact_s=3.0), GROUND_EFFECT, ("ground_effect",), "low_passes"),
    Condition("MoCap 50 Hz rows held at 9 Hz, measured rotor speeds held at 3 Hz and 60 ms late, "
              "ground effect mu = 2",
              Conditions(rate_hz=50, position_hold_hz=9, rotor_hold_hz=3, rotor_delay_s=0.06, measured_rotors=True),
              GROUND_EFFECT, ("ground_effect",), "low_passes"),
    Condition("thrust level 1.00 / 1.04 between the two flights, ground effect mu = 2",
              Conditions(), GROUND_EFFECT, ("ground_effect",), "low_passes", second=Conditions(thrust_level=1.04)),
    Condition("thrust axis tilted 1.5 deg, both flights at one fixed heading, MoCap only, indoors (no wind)",
              Conditions(thrust_tilt_deg=1.5, thrust_tilt_azimuth_deg=30.0, fixed_heading=True, heading_deg=60.0,
                         no_imu=True), look_alikes=(THRUST_TILT,)),
    Condition("rotors 15 cm above the body origin, ground effect mu = 2",
              Conditions(rotor_plane_z=0.15), GROUND_EFFECT, ("ground_effect",), "low_passes"),
    Condition("small quadrotor, rotors 2.5 cm below the body origin, ground effect mu = 2",
              Conditions(rotor_plane_z=-0.025), GROUND_EFFECT, ("ground_effect",), "low_passes", vehicle="quad"),
    Condition("small quadrotor on commands through an idle speed (w = 37.5 + 262.5 u, rounded to 1 rad/s), MoCap and "
              "commands at 100 Hz, motors 40 ms late, ground effect mu = 2",
              Conditions(motor_commands=True, rate_hz=100), {"ground_effect": {"mu": 2.0}, "motor_lag": {"tau": 0.04}},
              ("ground_effect",), "low_passes", vehicle="quad"),
    Condition("measured rotor speeds (30 ms motor lag), battery sag in the physics, battery0",
              Conditions(measured_rotors=True, battery_voltage=16.8),
              {"battery_sag": {"s": 1e-3}, "motor_lag": {"tau": 0.03}}),
    Condition("commanded rotor speeds on a 4S battery sagging 8 % at hover under load (thrust per command follows "
              "the voltage, battery0 at 10 Hz), ground effect mu = 2",
              Conditions(battery_voltage=16.8, battery_load_sag=0.08),
              {"ground_effect": {"mu": 2.0}, "battery_voltage": {"k_V": 2.0 / (16.8 * 0.92)}},
              ("ground_effect", "battery_voltage"), "low_passes"),
    Condition("all of a PX4 log at once: no IMU, state held at 9 Hz, measured rotor speeds held at 3 Hz and 60 ms "
              "late, 3 s on the landing gear at both ends, rotors 15 cm above the body origin, thrust level "
              "1.00 / 1.04 and axis tilted 1.2 deg at other azimuths, "
              "ground effect mu = 4",
              PX4_LOG, {"ground_effect": {"mu": 4.0}}, ("ground_effect",), "low_passes",
              second=replace(PX4_LOG, thrust_level=1.04, thrust_tilt_azimuth_deg=120.0),
              look_alikes=(THRUST_TILT,)),
)


def true_effects(recording_truths: list[dict]) -> tuple[dict, set[str]]:
    """Every effect's true parameters in the vocabulary's laws (mean over the flights) and every
    effect in the physics that the recordings can show (``invisible_effects`` left out)."""
    eq = [t["equivalent_effects"] for t in recording_truths]
    known = {n: {k: float(np.mean([e[n][k] for e in eq])) for k in eq[0][n]} for n in eq[0]}
    invisible = {n for t in recording_truths for n in t.get("invisible_effects", [])}
    physics = (set(recording_truths[0]["effects"]) | set(eq[0])) - invisible
    return known, physics


def contact_intervals(paths: list[Path], recording_truths: list[dict]) -> dict[str, list[list[float]]]:
    """``{recording folder name: [[t_start, t_end] s, ...]}`` of the flights that start and end on the ground."""
    return {Path(p).name: t["conditions"]["ground_contact"]["intervals_s"]
            for p, t in zip(paths, recording_truths) if "ground_contact" in t.get("conditions", {})}


def contact_found(truth: dict[str, list[list[float]]], reported: list[dict]) -> bool:
    """Whether the report's ``ground_contact`` covers :data:`CONTACT_COVER` of each true interval."""
    for name, intervals in truth.items():
        found = [(float(c["t_start"]), float(c["t_end"])) for c in reported if Path(str(c["recording"])).name == name]
        for a, b in intervals:
            covered = sum(max(0.0, min(b, e) - max(a, s)) for s, e in found)
            if covered < CONTACT_COVER * (b - a):
                return False
    return True


def verdict(targets: dict[str, dict[str, float]], physics: set[str], report: dict,
            known: dict[str, dict[str, float]] | None = None, *, look_alikes: tuple[str, ...] = (),
            contact: dict[str, list[list[float]]] | None = None) -> tuple[str, dict]:
    """The row's verdict (module docstring) and the errors of the targets; ``known``: the true
    parameters of every effect of the physics (default: the targets'); ``look_alikes``: troubles
    that may be named although no effect; ``contact``: the true ground-contact intervals
    (:func:`contact_intervals`), which the report must find."""

    named = {e["name"]: e["params"] for e in report["effects"]}
    undecided = {c for a in report.get("ambiguous", []) for c in a["candidates"]}
    errors = {n: param_error(p, named.get(n)) for n, p in targets.items()}
    wrong_extra = sorted(n for n in named if n not in physics and n not in look_alikes)
    off = {n: param_error(p, named[n]) for n, p in (known or targets).items() if n in named}
    if wrong_extra or any(e > TOLERANCE for e in [*errors.values(), *off.values()] if np.isfinite(e)):
        return "WRONG", errors
    states = ["right" if n in named else ("ambiguous" if n in undecided else "missed") for n in targets]
    if contact:
        states.append("right" if contact_found(contact, report.get("ground_contact") or []) else "missed")
    for state in ("missed", "ambiguous", "right"):
        if state in states:
            return state, errors
    return "right", errors


def run_conditions(out: Path, *, duration: float = 60.0, seed: int = 0, progress=print) -> dict:
    """Generate each condition's two flights under ``out/flights/``, run the finder blind, score. A flight is kept
    for a later run under a name that carries a digest of its condition (a table that gains a row renumbers the
    rows: a flight found by its number alone would be another condition's)."""

    rows = []
    for i, cond in enumerate(CONDITIONS):
        paths, truths = [], []
        digest = hashlib.sha1(repr(cond).encode()).hexdigest()[:8]
        for k in range(2):
            path = Path(out) / "flights" / f"condition{i}-{digest}-{k}-{duration:.0f}s"
            if not (path / "vehicle.yaml").exists():
                generate_conditioned_flight(cond.vehicle, cond.effects, duration=duration, kind=cond.kind,
                                            seed=seed + 1000 + 100 * i + k, conditions=cond.flight_conditions(k),
                                            out=path, overwrite=True)
            paths.append(path)
            truths.append(read_truth(path))
        t0 = time.perf_counter()
        recs = load_recordings(paths)
        if cond.hidden_bias:
            recs = [with_hidden_bias(r) for r in recs]
        report, ex = analyse(recs, {}, seed=seed)
        secs = time.perf_counter() - t0
        known, physics = true_effects(truths)
        targets = {n: known[n] for n in cond.targets}
        contact = contact_intervals(paths, truths)
        state, errors = verdict(targets, physics, report, known, look_alikes=cond.look_alikes, contact=contact)
        sindy = sindy_names(ex["data"])
        sindy_state, sindy_errors = verdict(targets, physics, {"effects": [
            {"name": n, "params": p} for n, p in sindy.items()]}, known, look_alikes=cond.look_alikes,
            contact=contact)
        row = {"condition": cond.name, "targets": targets, "physics": sorted(physics),
               "named": {e["name"]: e["params"] for e in report["effects"]},
               "ambiguous": report.get("ambiguous", []), "not_testable": [r["name"] for r in report["not_testable"]],
               "ground_contact": {"truth": contact, "reported": report.get("ground_contact") or []},
               "verdict": state, "errors": errors, "sindy_named": sindy, "sindy_verdict": sindy_state,
               "sindy_errors": sindy_errors, "residual_source": report["residual_source"],
               "accel_bias": report["nominal"]["accel_bias"], "seconds": secs}
        rows.append(row)
        progress(f"[{i + 1}/{len(CONDITIONS)}] {cond.name[:60]:<60} {state:<9} named "
                 f"{','.join(row['named']) or '-'}; ambiguous "
                 f"{';'.join('/'.join(a['candidates']) for a in row['ambiguous']) or '-'}; "
                 f"PySINDy {sindy_state} ({secs:.1f} s)")
    return {"rows": rows, "summary": {
        "conditions": len(rows),
        "wrong": sum(r["verdict"] == "WRONG" for r in rows),
        "right": sum(r["verdict"] == "right" for r in rows),
        "ambiguous": sum(r["verdict"] == "ambiguous" for r in rows),
        "missed": sum(r["verdict"] == "missed" for r in rows),
        "sindy_wrong": sum(r["sindy_verdict"] == "WRONG" for r in rows),
        "sindy_right": sum(r["sindy_verdict"] == "right" for r in rows)}}


def _fmt(params: dict[str, float]) -> str:
    return ", ".join(f"{k} = {v:.3g}" for k, v in params.items())


def conditions_table(rows: list[dict]) -> str:
    """Markdown: condition, truth, what uavturb named or left undecided, verdicts."""
    lines = ["| condition | target (truth) | uavturb named | undecided (ambiguous) | verdict | PySINDy (tuned) |",
             "|---|---|---|---|---|---|"]
    for r in rows:
        truth = "; ".join(f"{n}: {_fmt(p)}" for n, p in r["targets"].items()) or "nothing"
        named = "; ".join(f"{n}: {_fmt(p)}" for n, p in r["named"].items()) or "—"
        contact = r.get("ground_contact", {})
        if contact.get("truth"):
            truth += "; ground contact at both ends"
            found = contact_found(contact["truth"], contact["reported"])
            named += f"; ground contact {'found' if found else 'not found'} ({len(contact['reported'])} intervals)"
        amb = "; ".join(" vs ".join(a["candidates"]) for a in r["ambiguous"]) or "—"
        sindy = ", ".join(sorted(r["sindy_named"])) or "—"
        lines.append(f"| {r['condition']} | {truth} | {named} | {amb} | {r['verdict']} | "
                     f"{sindy}: {r['sindy_verdict']} |")
    return "\n".join(lines)
