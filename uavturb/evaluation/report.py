"""Table 2's report: the table as text and Markdown, per-flight series and figures, the files of one
evaluation (:func:`write_evaluation`), and the summary of many runs over seeds (:func:`summarise`,
:func:`format_summary`). No MLflow here; the caller chooses the folder."""

from __future__ import annotations

import csv
import io
import json
import math
from pathlib import Path
from typing import Any

import matplotlib
import matplotlib.pyplot as plt
import numpy as np

from uavturb.evaluation.bands import format_bands
from uavturb.evaluation.metrics import FlightResult

#: the paper's Table 2 on EuRoC (Total): RMSE(f_a) / RMSE(f_a,phi) = 0.4082 / 0.2433
PAPER_RATIO = 0.4082 / 0.2433


def format_table(rows: list[tuple[str, dict[str, float]]], markdown: bool = False) -> str:
    """Table 2: per flight and Total, ground-effect frames then all frames."""
    head = ["Flight", "frames (GE)", "RMSE(f_a,phi) [N]", "RMSE(f_a) [N]", "RMSE(d) [m]", "frames (all)",
            "RMSE(f_a,phi) all [N]", "RMSE(f_a) all [N]"]
    body = [[name, f"{m['n_ge']}", f"{m['rmse_fa_phi']:.4f}", f"{m['rmse_fa']:.4f}", f"{m['rmse_d']:.4f}",
             f"{m['n_all']}", f"{m['rmse_fa_phi_all']:.4f}", f"{m['rmse_fa_all']:.4f}"] for name, m in rows]
    if markdown:
        lines = ["| " + " | ".join(head) + " |", "|" + "|".join(["---"] + ["---:"] * (len(head) - 1)) + "|"]
        for i, r in enumerate(body):
            if i == len(body) - 1:
                r = [f"**{r[0]}**"] + r[1:]
            lines.append("| " + " | ".join(r) + " |")
        return "\n".join(lines)
    w = [max(len(h), *(len(r[i]) for r in body)) for i, h in enumerate(head)]
    fmt = lambda r: "  ".join(c.ljust(w[0]) if i == 0 else c.rjust(w[i]) for i, c in enumerate(r))  # noqa: E731
    sep = "-" * len(fmt(head))
    return "\n".join([fmt(head), sep, *(fmt(r) for r in body[:-1]), sep, fmt(body[-1])])


def plot_flight(res: FlightResult, path: Path, h_ge: float) -> None:
    """f_a over time (GT, model, phi on true heights) and heights (true, predicted)."""
    matplotlib.use("Agg")
    fig, (ax1, ax2) = plt.subplots(2, 1, figsize=(10, 6), sharex=True, gridspec_kw={"height_ratios": [3, 2]})
    ax1.plot(res.t, res.fa, color="tab:blue", lw=1.0, label="GT $f_a$ (residual of the identified model)")
    ax1.plot(res.t, res.fa_model, color="tab:red", lw=1.0, label=r"model: $\phi(\hat d, \Omega)$")
    ax1.plot(res.t, res.fa_phi, color="tab:green", lw=1.0, label=r"$\phi(d, \Omega)$ on true heights")
    ax1.set_ylabel("$f_a$ [N]")
    ax1.legend(loc="upper right", fontsize=8)
    ax1.set_title(f"{res.name}: ground effect over time")
    ax2.plot(res.t, res.d, color="k", lw=1.0, label="true height $d$")
    ax2.plot(res.t, res.d_hat, color="tab:red", lw=1.0, label=r"predicted $\hat d$")
    ax2.axhline(h_ge, color="grey", ls=":", lw=0.8, label=f"GE region (d <= {h_ge:.2f} m)")
    ax2.set_ylabel("height [m]")
    ax2.set_xlabel("t [s]")
    ax2.legend(loc="upper right", fontsize=8)
    for ax in (ax1, ax2):
        ax.grid(alpha=0.3)
        # shade the ground-effect frames
        ge = res.ge.astype(int)
        edges = np.flatnonzero(np.diff(np.r_[0, ge, 0]))
        for a, b in zip(edges[::2], edges[1::2]):
            ax.axvspan(res.t[a], res.t[b - 1], color="tab:orange", alpha=0.08, lw=0)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _series_csv(res: FlightResult) -> str:
    buf = io.StringIO()
    w = csv.writer(buf)
    w.writerow(["t [s]", "d [m]", "d_hat [m]", "fa_gt [N]", "fa_phi [N]", "fa_model [N]", "ground_effect",
                "airborne"])
    for row in zip(res.t, res.d, res.d_hat, res.fa, res.fa_phi, res.fa_model, res.ge, res.airborne):
        w.writerow([f"{row[0]:.4f}", *(f"{x:.6g}" for x in row[1:6]), int(row[6]), int(row[7])])
    return buf.getvalue()


def safe_filename(name: str) -> str:
    """``name`` with every character but letters, digits, ``-_.`` replaced by ``_``."""
    return "".join(c if c.isalnum() or c in "-_." else "_" for c in name)


def write_evaluation(folder: Path, rows: list[tuple[str, dict[str, float]]], results: list[FlightResult],
                     info: dict[str, Any]) -> None:
    """Into an existing ``folder``: ``table.md`` (with the height bands), ``table.csv``,
    ``evaluation.json``, and per flight ``fa_<flight>.png`` and ``series_<flight>.csv``."""
    h_ge = info["h_ge"]
    (folder / "table.md").write_text(
        f"Table 2 (ours): (alpha, beta) identified on {info['identified_on']}; ground-effect (GE) frames: "
        f"airborne (thrust >= 0.3 m g) with d <= {h_ge:.3f} m (law >= {100 * info['ge_fraction']:g} % of "
        f"thrust); 'all': every airborne frame with a surface below.\n\n{format_table(rows, markdown=True)}\n\n"
        f"Where the error comes from (GE frames of all flights by true height):\n\n{format_bands(info['bands'])}\n"
        + (f"\nWarning: {info['law_check']}.\n" if info.get("law_check") else ""))
    with open(folder / "table.csv", "w", newline="") as f:
        w = csv.writer(f)
        keys = list(rows[0][1])
        w.writerow(["flight", *keys])
        for n, m in rows:
            w.writerow([n, *(m[k] for k in keys)])
    (folder / "evaluation.json").write_text(json.dumps(info, indent=2, default=float))
    for r in results:
        plot_flight(r, folder / f"fa_{safe_filename(r.name)}.png", h_ge)
        (folder / f"series_{safe_filename(r.name)}.csv").write_text(_series_csv(r))


def _mean_std(values: list[float]) -> tuple[float, float]:
    a = np.asarray(values, float)
    return float(a.mean()), float(a.std(ddof=1)) if len(a) > 1 else math.nan


def summarise(per_run: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Per row (in first-seen order): mean and std over its runs of the Total figures and the ratio,
    the worst ratio, and the bands' figures averaged over runs."""
    rows: dict[str, list[dict[str, Any]]] = {}
    for r in per_run:
        rows.setdefault(r["row"], []).append(r)
    out = []
    for name, runs in rows.items():
        total = [r["total"] for r in runs]
        ratio = [t["rmse_fa"] / t["rmse_fa_phi"] for t in total]
        entry = {"row": name, "n": len(runs), "runs": [r["run_id"] for r in runs], "ratio_max": max(ratio)}
        for key, values in (("rmse_fa_phi", [t["rmse_fa_phi"] for t in total]),
                            ("rmse_fa", [t["rmse_fa"] for t in total]), ("ratio", ratio),
                            ("rmse_d", [t["rmse_d"] for t in total])):
            entry[key], entry[key + "_std"] = _mean_std(values)
        bands = []
        for i, band in enumerate(runs[0]["bands"]):
            b = {"band": band["band"], "n": band["n"], "rmse_fa_phi": band["rmse_fa_phi"]}
            for key in ("rmse_fa", "rmse_d", "bias_d", "share_sq_fa"):
                b[key], b[key + "_std"] = _mean_std([r["bands"][i][key] for r in runs])
            bands.append(b)
        entry["bands"] = bands
        out.append(entry)
    return out


def _pm(mean: float, std: float, fmt: str) -> str:
    return f"{mean:{fmt}}" if not np.isfinite(std) else f"{mean:{fmt}} ± {std:{fmt.lstrip('+')}}"


def format_summary(rows: list[dict[str, Any]], info: dict[str, Any]) -> str:
    """``summary.md``: Table 2 per row over seeds, then the height bands per row."""
    lines = [f"Table 2 over seeds on {', '.join(info['flights'])} ({info['n_ge']} ground-effect frames: airborne, "
             f"d <= {info['h_ge']:.3f} m, law >= {100 * info['ge_fraction']:g} % of thrust); (alpha, beta) identified "
             f"on {info['identified_on']} (beta = {info['beta']:.3g} ± {info['beta_stderr']:.2g} m^2, noise only); "
             f"mean ± std over seeds. The paper, on EuRoC: RMSE(f_a) 0.4082 N, "
             f"RMSE(f_a,phi) 0.2433 N, ratio {PAPER_RATIO:.2f}.", "",
             "| row | seeds | RMSE(f_a,phi) [N] | RMSE(f_a) [N] | ratio RMSE(f_a)/RMSE(f_a,phi) | worst seed's ratio "
             "| RMSE(d) [m] |", "|---|---:|---:|---:|---:|---:|---:|"]
    for r in rows:
        lines.append(f"| {r['row']} | {r['n']} | {r['rmse_fa_phi']:.4f} | "
                     f"{_pm(r['rmse_fa'], r['rmse_fa_std'], '.4f')} | "
                     f"{_pm(r['ratio'], r['ratio_std'], '.2f')} | {r['ratio_max']:.2f} | "
                     f"{_pm(r['rmse_d'], r['rmse_d_std'], '.4f')} |")
    lines += ["", "Where the error comes from (ground-effect frames by true height, mean over seeds):", "",
              "| row | height band | frames | RMSE(f_a,phi) [N] | RMSE(f_a) [N] | bias(d) [m] | share of f_a error |",
              "|---|---|---:|---:|---:|---:|---:|"]
    for r in rows:
        for b in r["bands"]:
            lines.append(f"| {r['row']} | {b['band']} | {b['n']} | {b['rmse_fa_phi']:.4f} | "
                         f"{_pm(b['rmse_fa'], b['rmse_fa_std'], '.4f')} | "
                         f"{_pm(b['bias_d'], b['bias_d_std'], '+.4f')} | {100 * b['share_sq_fa']:.0f} % |")
    if info.get("law_check"):
        lines += ["", f"Warning: {info['law_check']}."]
    return "\n".join(lines) + "\n"
