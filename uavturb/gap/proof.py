"""``uavturb gap-proof``: the gap finder run blind on flights with concealed effects.

For every effect of ``effects.md`` alone, for pairs, and for clean flights, two flights are
generated with ``uavturb generate flight`` physics at magnitudes where the effect hides:
per sample below the accelerometer noise (about 0.04 N per axis on the 1.5 kg hexarotor),
present only in some segments (surface effects act only near the floor, table or ceiling),
or masked by a larger effect. The finder sees only the recordings (``--sim-effects none``).

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

from uavturb.gap.design import GapData, design, lagged_S, stack_target
from uavturb.gap.finder import analyse
from uavturb.physics.effects import EFFECTS

#: concealed magnitudes (see the module docstring)
CONCEALED: dict[str, dict[str, float]] = {
    "rotor_drag": {"k_d": 2.0e-5},
    "body_drag": {"c_d": 0.03},
    "wind": {"f_x": 0.03, "f_y": -0.02},
    "battery_sag": {"s": 1.0e-4},
    "ground_effect": {"mu": 2.0},
    "ceiling_effect": {"kappa": 3.0},
    "motor_lag": {"tau": 0.03},
}
PAIRS = [("rotor_drag", "body_drag"), ("ground_effect", "battery_sag"), ("wind", "rotor_drag"),
         ("motor_lag", "ground_effect")]


@dataclass
class Case:
    name: str
    effects: dict[str, dict[str, float]]


def cases(singles: list[str] | None = None, pairs: bool = True, clean: int = 2) -> list[Case]:
    out = [Case(f"clean-{i}", {}) for i in range(clean)]
    for e in singles or list(CONCEALED):
        out.append(Case(e, {e: CONCEALED[e]}))
    if pairs:
        for a, b in PAIRS:
            # a masking pair: the first at a typical (large) magnitude, the second concealed
            big = {k: v * 4 for k, v in CONCEALED[a].items()} if a not in ("ground_effect", "motor_lag") \
                else dict(CONCEALED[a])
            out.append(Case(f"{a}+{b}", {a: big, b: CONCEALED[b]}))
    return out


def sindy_names(data: GapData, threshold: float = 0.05) -> dict[str, float]:
    """Named terms by PySINDy's STLSQ on the nominal model's candidate library.

    The library's columns are the regressors of :func:`uavturb.gap.design.design` with every
    effect in, surface laws at ``mu = kappa = 2``, plus the lag column; columns are scaled to
    unit norm so the threshold is relative. Returns effect → its coefficient (in effects.md units
    where the library is linear in it).
    """
    import pysindy as ps

    effects = set(EFFECTS) - {"motor_lag"}
    A, names = design(data, effects, {"mu": 2.0, "kappa": 2.0, "tau": 0.0})
    # ground and ceiling columns split out of the thrust column, so the library can name them
    base, _ = design(data, set(), {"mu": 0.0, "kappa": 0.0, "tau": 0.0})
    Ag, _ = design(data, {"ground_effect"}, {"mu": 2.0, "kappa": 0.0, "tau": 0.0})
    Ac, _ = design(data, {"ceiling_effect"}, {"mu": 0.0, "kappa": 2.0, "tau": 0.0})
    ground_col = Ag[:, 0] - base[:, 0]
    ceil_col = Ac[:, 0] - base[:, 0]
    dS = (lagged_S(data, 1e-9) - lagged_S(data, 0.01)) / 0.01  # ~ d(sum w^2)/dt: first order in tau
    zb = data.R[:, :, 2]
    lag_col = stack_target(-dS[:, None] * zb)
    cols = [base[:, 0]] + [A[:, i] for i, n in enumerate(names) if n != "k_T"] + [ground_col, ceil_col, lag_col]
    labels = ["k_T"] + [n for n in names if n != "k_T"] + ["ground_effect", "ceiling_effect", "motor_lag"]
    Theta = np.stack(cols, 1)
    scale = np.linalg.norm(Theta, axis=0)
    scale[scale == 0] = 1.0
    y = stack_target(data.y)
    opt = ps.STLSQ(threshold=threshold * np.linalg.norm(y) / np.sqrt(len(y)) , alpha=0.0, normalize_columns=False)
    opt.fit(Theta / scale, y)
    coef = np.asarray(opt.coef_).ravel() / scale
    kT = coef[0]
    named: dict[str, float] = {}
    label_to_effect = {"k_d": "rotor_drag", "c_d": "body_drag", "f_x": "wind", "f_y": "wind",
                       "k_T*s": "battery_sag", "ground_effect": "ground_effect", "ceiling_effect": "ceiling_effect",
                       "motor_lag": "motor_lag"}
    for lab, c in zip(labels, coef):
        if lab in label_to_effect and c != 0:
            eff = label_to_effect[lab]
            if eff == "ground_effect" or eff == "ceiling_effect":
                c = 2.0 * c / kT  # the column is k_T S rho(2)/(1-rho(2)): coefficient ~ k_T mu / 2
            elif eff == "battery_sag":
                c = c / kT
            elif eff == "motor_lag":
                c = c / kT
            named.setdefault(eff, c)
    return named


def run_proof(out: Path, *, duration: float = 90.0, seed: int = 0, singles: list[str] | None = None,
              pairs: bool = True, clean: int = 2, progress=print) -> dict:
    """Generate the cases, run the finder blind on each (two flights per case), and tabulate."""
    from uavturb.sim.flight import SensorNoise, generate_flight
    from uavturb.io.reader import read_recording

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    rows = []
    all_cases = cases(singles, pairs, clean)
    t_start = time.perf_counter()
    for i, case in enumerate(all_cases):
        recs = []
        for k in range(2):
            path = out / "flights" / f"{case.name}-{k}"
            if not (path / "vehicle.yaml").exists():
                generate_flight(vehicle="hex", effects=case.effects, duration=duration, kind="mixed",
                                seed=seed + 100 * i + k, noise=SensorNoise(), out=path, overwrite=True)
            recs.append(read_recording(path))
        t0 = time.perf_counter()
        report, ex = analyse(recs, {}, seed=seed)
        secs = time.perf_counter() - t0
        named = {e["name"]: e for e in report["effects"]}
        errors = {}
        for eff, params in case.effects.items():
            if eff in named:
                errors[eff] = max(abs(named[eff]["params"][p] / v - 1) for p, v in params.items() if v != 0)
        improved = all(e["heldout_rmse_after_N"] < e["heldout_rmse_before_N"] for e in report["effects"])
        sindy = sindy_names(ex["data"])
        row = {"case": case.name, "truth": sorted(case.effects), "named": sorted(named),
               "exact": sorted(case.effects) == sorted(named), "param_errors": errors,
               "max_param_error": max(errors.values()) if errors else 0.0, "heldout_improved": improved,
               "heldout_before_N": report["baseline"]["heldout_rmse_N"], "heldout_after_N": report["final"]["heldout_rmse_N"],
               "sindy_named": sorted(sindy), "sindy_exact": sorted(sindy) == sorted(case.effects),
               "seconds": secs}
        rows.append(row)
        elapsed = time.perf_counter() - t_start
        eta = elapsed / (i + 1) * (len(all_cases) - i - 1)
        progress(f"[{i + 1}/{len(all_cases)}] {case.name:<28} named {','.join(row['named']) or '-':<30} "
                 f"{'OK ' if row['exact'] else 'MISS'} max err {100 * row['max_param_error']:5.1f} %  "
                 f"sindy {','.join(row['sindy_named']) or '-'}  ({secs:.1f} s; ETA {eta:.0f} s)")
    summary = {
        "cases": len(rows),
        "exact": sum(r["exact"] for r in rows),
        "sindy_exact": sum(r["sindy_exact"] for r in rows),
        "params_within_15pct": sum(r["max_param_error"] <= 0.15 for r in rows),
        "heldout_improved": sum(r["heldout_improved"] for r in rows),
        "false_discoveries_on_clean": sum(bool(r["named"]) for r in rows if not r["truth"]),
        "max_analysis_seconds": max(r["seconds"] for r in rows),
    }
    return {"rows": rows, "summary": summary}


def confusion_table(rows: list[dict]) -> str:
    """Markdown confusion table: truth (rows) against named (columns), ours and PySINDy's."""
    names = list(EFFECTS)
    head = "| case | truth | named (uavturb) | named (PySINDy) | max param error | held-out RMSE before → after [N] |"
    lines = [head, "|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['case']} | {', '.join(r['truth']) or '—'} | {', '.join(r['named']) or '—'}"
                     f"{'' if r['exact'] else ' ✗'} | {', '.join(r['sindy_named']) or '—'}"
                     f"{'' if r['sindy_exact'] else ' ✗'} | {100 * r['max_param_error']:.1f} % | "
                     f"{r['heldout_before_N']:.4f} → {r['heldout_after_N']:.4f} |")
    counts = np.zeros((len(names) + 1, len(names) + 1), int)  # truth x named, last = none
    for r in rows:
        truth = r["truth"] or ["none"]
        named = r["named"] or ["none"]
        for t in truth:
            for n in named:
                counts[(names + ["none"]).index(t), (names + ["none"]).index(n)] += 1
    lines += ["", "| truth \\ named | " + " | ".join(names + ["none"]) + " |",
              "|---" * (len(names) + 2) + "|"]
    for i, t in enumerate(names + ["none"]):
        lines.append(f"| {t} | " + " | ".join(str(c) if c else "·" for c in counts[i]) + " |")
    return "\n".join(lines)
