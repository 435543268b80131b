"""``uavturb gap-proof``: the gap finder run blind on flights with concealed effects.

For every effect of ``effects.md`` alone, for pairs, and for clean flights, two flights are
generated with ``uavturb generate flight`` physics at magnitudes where the effect hides:
per sample below the accelerometer noise (about 0.04 N per axis on the 1.5 kg hexarotor),
present only in some segments (surface effects act only near the floor, table or ceiling),
or masked by a larger effect. Every flight also carries an accelerometer bias the state file
does not know (a look-alike of a steady wind). The finder sees only the recordings
(``--sim-effects none``).

Beside it, the same residuals go through PySINDy (sequentially thresholded least squares,
STLSQ) over the same candidate features, the sparse-regression peer baseline: surface laws
enter its library at a fixed typical coefficient and motor lag as its first-order
expansion ``-tau d(sum w^2)/dt``, since a library is linear.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from uavturb.errors import InputError
from uavturb.gap.finder import analyse
from uavturb.io.reader import read_recording
from uavturb.physics.effects import EFFECTS
from uavturb.proof.conditions import conditions_table, run_conditions
from uavturb.proof.scoring import param_error, with_hidden_bias
from uavturb.proof.sindy_peer import sindy_names
from uavturb.sim.flights.sensors import SensorNoise
from uavturb.sim.flights.simulate import generate_flight

#: concealed magnitudes. Sensor noise is about 0.042 N per axis and sample (EuRoC's ADIS16448
#: accelerometer on the 1.5 kg hexarotor); hover rotor-speed sum about 3200 rad/s.
CONCEALED: dict[str, dict[str, float]] = {
    "rotor_drag": {"k_d": 2.0e-5},           # 0.064 N per m/s: below the noise under 0.6 m/s
    "body_drag": {"c_d": 0.03},              # 0.03 N at 1 m/s
    "wind": {"f_x": 0.03, "f_y": -0.02},     # 0.036 N: below the noise on every sample
    "battery_sag": {"s": 5.0e-5},            # thrust down 0.45 % after 90 s: 0.066 N at the end
    "ground_effect": {"mu": 1.0},            # only in the low hovers and passes (some segments)
    "ceiling_effect": {"kappa": 1.5},        # only in the hovers under the ceiling (some segments)
    "motor_lag": {"tau": 0.015},             # RotorS's fastest motors
}
#: (masking effect at a typical, larger magnitude, concealed effect)
PAIRS = [("rotor_drag", "body_drag"), ("wind", "rotor_drag"), ("ground_effect", "battery_sag"),
         ("motor_lag", "ground_effect"), ("body_drag", "wind"), ("battery_sag", "motor_lag")]
#: magnitudes of the masking effects (effects.md's typical values)
TYPICAL: dict[str, dict[str, float]] = {
    "rotor_drag": {"k_d": 8.06e-5}, "body_drag": {"c_d": 0.1}, "wind": {"f_x": 0.3, "f_y": -0.1},
    "battery_sag": {"s": 1.0e-3}, "ground_effect": {"mu": 2.0}, "ceiling_effect": {"kappa": 2.0},
    "motor_lag": {"tau": 0.03},
}
#: the mixed flight plans hovers under the ceiling from 100 s on (uavturb.sim.flights.plans.mixed)
CEILING_DURATION = 100.0




@dataclass
class Case:
    name: str
    effects: dict[str, dict[str, float]]


def cases(singles: list[str] | None = None, pairs: bool = True, clean: int = 2) -> list[Case]:
    """Clean flights, every effect alone at a concealed magnitude, and masking pairs (a typical
    effect hiding a concealed one)."""
    out = [Case(f"clean-{i}", {}) for i in range(clean)]
    for e in singles or list(CONCEALED):
        out.append(Case(e, {e: dict(CONCEALED[e])}))
    if pairs:
        for a, b in PAIRS:
            if singles and not (a in singles or b in singles):
                continue
            out.append(Case(f"{a}+{b}", {a: dict(TYPICAL[a]), b: dict(CONCEALED[b])}))
    return out














def run_proof(out: Path, *, duration: float = 90.0, seed: int = 0, singles: list[str] | None = None,
              pairs: bool = True, clean: int = 2, progress=print) -> dict:
    """Generate the cases, run the finder blind on each (two flights per case, leave-one-recording-
    out), run PySINDy on the same samples, and tabulate. Cases with the ceiling effect fly
    :data:`CEILING_DURATION` s (the plan's hovers under the ceiling need it); the others
    ``duration``. ``seconds`` times reading both recordings and the analysis. Every flight
    carries :data:`uavturb.proof.scoring.HIDDEN_BIAS`."""

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    rows = []
    all_cases = cases(singles, pairs, clean)
    t_start = time.perf_counter()
    for i, case in enumerate(all_cases):
        dur = max(duration, CEILING_DURATION) if "ceiling_effect" in case.effects else duration
        paths = []
        for k in range(2):
            path = out / "flights" / f"{case.name}-{k}-{dur:.0f}s"
            if not (path / "vehicle.yaml").exists():
                generate_flight(vehicle="hex", effects=case.effects, duration=dur, kind="mixed",
                                seed=seed + 100 * i + k, noise=SensorNoise(), out=path, overwrite=True)
            paths.append(path)
        t0 = time.perf_counter()
        recs = [with_hidden_bias(read_recording(p)) for p in paths]
        report, ex = analyse(recs, {}, seed=seed)
        secs = time.perf_counter() - t0
        named = {e["name"]: e for e in report["effects"]}
        errors = {eff: param_error(p, named[eff]["params"] if eff in named else None)
                  for eff, p in case.effects.items()}
        sindy = sindy_names(ex["data"])
        sindy_errors = {eff: param_error(p, sindy.get(eff)) for eff, p in case.effects.items()}
        sindy_named = sorted(sindy)
        improved = all(e["heldout_rmse_after_N"] < e["heldout_rmse_before_N"] for e in report["effects"])
        row = {"case": case.name, "duration_s": dur, "truth": sorted(case.effects), "true_params": case.effects,
               "named": sorted(named), "fitted": {n: e["params"] for n, e in named.items()},
               "stderr": {n: e["stderr"] for n, e in named.items()},
               "exact": sorted(case.effects) == sorted(named), "param_errors": errors,
               "max_param_error": max(errors.values()) if errors else 0.0,
               "heldout_improved": improved and (bool(named) or not case.effects),
               "heldout_before_N": report["baseline"]["heldout_rmse_N"],
               "heldout_after_N": report["final"]["heldout_rmse_N"],
               "steps": [(e["name"], e["heldout_rmse_before_N"], e["heldout_rmse_after_N"], e["z_heldout"])
                         for e in report["effects"]],
               "sindy_named": sindy_named, "sindy_exact": sindy_named == sorted(case.effects),
               "sindy_param_errors": sindy_errors,
               "sindy_max_param_error": max(sindy_errors.values()) if sindy_errors else 0.0,
               "seconds": secs}
        rows.append(row)
        elapsed = time.perf_counter() - t_start
        eta = elapsed / (i + 1) * (len(all_cases) - i - 1)
        progress(f"[{i + 1}/{len(all_cases)}] {case.name:<28} named {','.join(row['named']) or '-':<30} "
                 f"{'OK ' if row['exact'] else 'MISS'} max err {100 * row['max_param_error']:5.1f} %  "
                 f"sindy {','.join(row['sindy_named']) or '-'}  (analysis {secs:.1f} s; ETA {eta:.0f} s)")
    secs90 = [r["seconds"] for r in rows if r["duration_s"] == duration]
    summary = {
        "cases": len(rows),
        "exact": sum(r["exact"] for r in rows),
        "sindy_exact": sum(r["sindy_exact"] for r in rows),
        "params_within_15pct": sum(r["exact"] and r["max_param_error"] <= 0.15 for r in rows),
        "sindy_params_within_15pct": sum(r["sindy_exact"] and r["sindy_max_param_error"] <= 0.15 for r in rows),
        "heldout_improved": sum(r["heldout_improved"] for r in rows),
        "false_discoveries_on_clean": sum(bool(r["named"]) for r in rows if not r["truth"]),
        "sindy_false_discoveries_on_clean": sum(bool(r["sindy_named"]) for r in rows if not r["truth"]),
        "max_analysis_seconds": max(secs90 or [r["seconds"] for r in rows]),
        "median_analysis_seconds": float(np.median(secs90 or [r["seconds"] for r in rows])),
        "duration_s": duration,
    }
    return {"rows": rows, "summary": summary}


def _pct(e: float) -> str:
    return "—" if not np.isfinite(e) else f"{100 * e:.1f} %"


def confusion_table(rows: list[dict]) -> str:
    """Markdown tables: every case (truth, named by uavturb and by PySINDy, parameter errors,
    held-out RMSE), then per effect how often it was named when present and when absent."""
    names = list(EFFECTS)
    lines = ["| case | truth | named (uavturb) | param. error | named (PySINDy) | param. error (PySINDy) | "
             "held-out RMSE before → after [N] |", "|---|---|---|---|---|---|---|"]
    for r in rows:
        errs = ", ".join(_pct(r["param_errors"][t]) for t in r["truth"]) or "—"
        serrs = ", ".join(_pct(r["sindy_param_errors"][t]) for t in r["truth"]) or "—"
        lines.append(f"| {r['case']} | {', '.join(r['truth']) or '—'} | {', '.join(r['named']) or '—'}"
                     f"{'' if r['exact'] else ' ✗'} | {errs} | {', '.join(r['sindy_named']) or '—'}"
                     f"{'' if r['sindy_exact'] else ' ✗'} | {serrs} | "
                     f"{r['heldout_before_N']:.4f} → {r['heldout_after_N']:.4f} |")
    lines += ["", "| effect | named when present: uavturb | PySINDy | named when absent: uavturb | PySINDy |",
              "|---|---|---|---|---|"]
    for n in names:
        present = [r for r in rows if n in r["truth"]]
        absent = [r for r in rows if n not in r["truth"]]
        lines.append(f"| {n} | {sum(n in r['named'] for r in present)}/{len(present)} | "
                     f"{sum(n in r['sindy_named'] for r in present)}/{len(present)} | "
                     f"{sum(n in r['named'] for r in absent)}/{len(absent)} | "
                     f"{sum(n in r['sindy_named'] for r in absent)}/{len(absent)} |")
    # a truth x named confusion matrix over the clean and single-effect cases
    singles = [r for r in rows if len(r["truth"]) <= 1]
    labels = names + ["none"]
    counts = np.zeros((len(labels), len(labels)), int)
    for r in singles:
        t = (r["truth"] or ["none"])[0]
        for n in r["named"] or ["none"]:
            counts[labels.index(t), labels.index(n)] += 1
    lines += ["", "Clean and single-effect cases, truth (rows) against named by uavturb (columns):", "",
              "| truth \\ named | " + " | ".join(labels) + " |", "|---" * (len(labels) + 1) + "|"]
    for i, t in enumerate(labels):
        lines.append(f"| {t} | " + " | ".join(str(c) if c else "·" for c in counts[i]) + " |")
    return "\n".join(lines)


def gap_proof(out: Path, *, duration: float = 90.0, seed: int = 0, singles: list[str] | None = None,
              pairs: bool = True, suite: str = "all") -> dict:
    """``uavturb gap-proof``: the finder blind on concealed effects (``suite`` ``concealed``) and on
    flights with real recordings' troubles (``conditions``, :mod:`uavturb.proof.conditions`);
    writes ``out/proof.md`` and ``proof.json``."""
    import json

    if suite not in ("all", "concealed", "conditions"):
        raise InputError("--suite", f"unknown suite '{suite}' (allowed: all, concealed, conditions)")
    for s in singles or []:
        if s not in EFFECTS:
            raise InputError("--effects", f"unknown effect '{s}' (known: {', '.join(EFFECTS)})")
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    result: dict = {}
    parts: list[str] = []
    if suite in ("all", "concealed"):
        result = run_proof(out, duration=duration, seed=seed, singles=singles, pairs=pairs)
        s = result["summary"]
        parts.append(
            f"{confusion_table(result['rows'])}\n\n{s['exact']}/{s['cases']} cases named exactly (PySINDy: "
            f"{s['sindy_exact']}/{s['cases']}); {s['params_within_15pct']}/{s['cases']} named exactly with every "
            f"parameter within 15 % (PySINDy: {s['sindy_params_within_15pct']}/{s['cases']}); "
            f"{s['heldout_improved']}/{s['cases']} with every held-out fit improved; "
            f"{s['false_discoveries_on_clean']} false discoveries on clean flights "
            f"(PySINDy: {s['sindy_false_discoveries_on_clean']}); analysis of two {duration:.0f} s flights at 200 Hz "
            f"(reading included): median {s['median_analysis_seconds']:.1f} s, slowest "
            f"{s['max_analysis_seconds']:.1f} s\n")
    if suite in ("all", "conditions"):
        cond = run_conditions(out, duration=min(duration, 60.0), seed=seed)
        c = cond["summary"]
        result["conditions"] = cond
        parts.append(f"{conditions_table(cond['rows'])}\n\n{c['right']}/{c['conditions']} conditions right, "
                     f"{c['ambiguous']} reported ambiguous, {c['missed']} missed, {c['wrong']} wrong "
                     f"(PySINDy tuned: {c['sindy_right']} right, {c['sindy_wrong']} wrong)\n")
    text = "\n".join(parts)
    print(text)
    (out / "proof.md").write_text(text)
    (out / "proof.json").write_text(json.dumps(result, indent=2, default=float))
    return result
