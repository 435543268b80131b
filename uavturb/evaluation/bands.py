"""Where Table 2's error comes from: the ground-effect frames cut into height bands by the law's
share of thrust (at least 20 %, 5-20 %, 2-5 %, then down to the ground-effect threshold)."""

from __future__ import annotations

from pathlib import Path
from typing import Any, Sequence

import matplotlib
import matplotlib.pyplot as plt
import numpy as np

from uavturb.evaluation.metrics import FlightResult, rmse

GE_FRACTION = 0.01
#: lower bounds of the law's share of thrust that cut the ground-effect frames into height bands
#: (:func:`band_metrics`): nearest the floor first
BAND_FRACTIONS = (0.2, 0.05, 0.02)


def ground_effect_height(beta: float, fraction: float = GE_FRACTION) -> float:
    """Height [m] under which the law ``beta / (d^2 - beta)`` is at least ``fraction`` of the thrust."""
    return float(np.sqrt(beta * (1.0 + 1.0 / fraction)))


def band_edges(beta: float, ge_fraction: float = GE_FRACTION) -> list[tuple[float, float, str]]:
    """``(d_low, d_high, label)`` [m] of the ground-effect region's height bands: where the law
    ``beta / (d^2 - beta)`` is at least 20 % of the thrust, 5-20 %, 2-5 %, then down to
    ``ge_fraction`` (bands that ``ge_fraction`` already excludes are left out)."""
    fractions = [f for f in BAND_FRACTIONS if f > ge_fraction] + [ge_fraction]
    out, low, upper = [], 0.0, None
    for f in fractions:
        high = ground_effect_height(beta, f)
        share = f">= {100 * f:g} %" if upper is None else f"{100 * f:g}-{100 * upper:g} %"
        out.append((low, high, f"{low:.3f}-{high:.3f} m (law {share} of thrust)"))
        low, upper = high, f
    return out


def band_metrics(results: Sequence["FlightResult"], beta: float, ge_fraction: float = GE_FRACTION
                 ) -> list[dict[str, Any]]:
    """Where the error comes from: the ground-effect frames of all flights by height band (:func:`band_edges`).

    Per band: ``n``, ``rmse_fa_phi``, ``rmse_fa`` [N], ``rmse_d`` and ``bias_d`` (mean predicted
    minus true height) [m], and ``share_sq_fa``: the band's part of the total squared f_a error.
    """
    cat = lambda k: np.concatenate([getattr(r, k) for r in results])  # noqa: E731
    ge, d, d_hat, fa, fa_phi, fa_model = cat("ge"), cat("d"), cat("d_hat"), cat("fa"), cat("fa_phi"), cat("fa_model")
    total = float(np.sum((fa_model[ge] - fa[ge]) ** 2))
    out = []
    for low, high, label in band_edges(beta, ge_fraction):
        m = ge & (d > low) & (d <= high)
        sq = float(np.sum((fa_model[m] - fa[m]) ** 2))
        out.append({"band": label, "d_low": low, "d_high": high, "n": int(m.sum()),
                    "rmse_fa_phi": rmse(fa_phi[m], fa[m]), "rmse_fa": rmse(fa_model[m], fa[m]),
                    "rmse_d": rmse(d_hat[m], d[m]),
                    "bias_d": float(np.mean(d_hat[m] - d[m])) if m.any() else float("nan"),
                    "share_sq_fa": sq / total if total > 0 else float("nan")})
    return out


def format_bands(bands: list[dict[str, Any]]) -> str:
    """The bands of :func:`band_metrics` as a markdown table."""
    lines = ["| height band | frames | RMSE(f_a,phi) [N] | RMSE(f_a) [N] | RMSE(d) [m] | bias(d) [m] | "
             "share of f_a error |", "|---|---:|---:|---:|---:|---:|---:|"]
    for b in bands:
        lines.append(f"| {b['band']} | {b['n']} | {b['rmse_fa_phi']:.4f} | {b['rmse_fa']:.4f} | {b['rmse_d']:.4f} | "
                     f"{b['bias_d']:+.4f} | {100 * b['share_sq_fa']:.0f} % |")
    return "\n".join(lines)


def plot_bands(rows: list[dict[str, Any]], path: Path) -> None:
    """RMSE(f_a) [N] by height band per row (error bars: std over seeds), the law on true heights dashed."""
    matplotlib.use("Agg")
    bands = [b["band"].split(" (")[0] for b in rows[0]["bands"]]
    x = np.arange(len(bands))
    width = 0.8 / max(1, len(rows))
    fig, ax = plt.subplots(figsize=(8, 4))
    for i, r in enumerate(rows):
        mean = [b["rmse_fa"] for b in r["bands"]]
        std = [b["rmse_fa_std"] if np.isfinite(b["rmse_fa_std"]) else 0.0 for b in r["bands"]]
        ax.bar(x - 0.4 + width * (i + 0.5), mean, width, yerr=std, capsize=3, label=f"{r['row']} ({r['n']} seeds)")
    ax.plot(x, [b["rmse_fa_phi"] for b in rows[0]["bands"]], "k--", marker="o", label=r"law on true heights $\phi(d)$")
    ax.set_xticks(x, bands)
    ax.set_xlabel("true height d over the surface below [m]")
    ax.set_ylabel("RMSE($f_a$) [N]")
    ax.set_title("Where the f_a error comes from")
    ax.grid(axis="y", alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
