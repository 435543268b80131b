"""Table 2's figures of a flight (paper, "Predicting turbulences" and "Sim2real transfer"): the
network's heights over a whole flight, the ground-effect law on true and on predicted heights,
and their RMSEs against ground truth [N], [m], per flight and pooled (``Total``).

Samples used: airborne frames (rotor thrust >= 0.3 m g) whose true height makes the identified
law worth at least ``ge_fraction`` (1 %) of the thrust (the ground-effect, "GE", frames), and every
airborne frame with a surface below ("all")."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np
import torch


@dataclass
class FlightResult:
    """Table 2 figures and series of one flight (``K`` frames).

    Attributes
    ----------
    name : flight name
    t : (K,) s; d, d_hat : (K,) true and predicted heights [m]
    fa, fa_phi, fa_model : (K,) GT, law on true heights, law on predicted heights [N]
    ge : (K,) bool, frames in the ground-effect region (see the module docstring)
    airborne : (K,) bool, frames in flight (the "all" columns use these)
    """

    name: str
    t: np.ndarray
    d: np.ndarray
    d_hat: np.ndarray
    fa: np.ndarray
    fa_phi: np.ndarray
    fa_model: np.ndarray
    ge: np.ndarray
    airborne: np.ndarray

    def metrics(self) -> dict[str, float]:
        return flight_metrics(self.fa, self.fa_phi, self.fa_model, self.d, self.d_hat, self.ge, self.airborne)


def rmse(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.sqrt(np.mean((a - b) ** 2))) if len(a) else float("nan")


def flight_metrics(fa, fa_phi, fa_model, d, d_hat, ge, airborne) -> dict[str, float]:
    """Table 2's columns from (K,) series: GE frames (``ge``) and every airborne frame with a height."""
    fin = np.isfinite(d) & airborne
    return {"n_ge": int(ge.sum()), "rmse_fa_phi": rmse(fa_phi[ge], fa[ge]), "rmse_fa": rmse(fa_model[ge], fa[ge]),
            "rmse_d": rmse(d_hat[ge], d[ge]), "rms_fa_gt": rmse(fa[ge], 0 * fa[ge]),
            "n_all": int(fin.sum()), "rmse_fa_phi_all": rmse(fa_phi[fin], fa[fin]),
            "rmse_fa_all": rmse(fa_model[fin], fa[fin]), "rmse_d_all": rmse(d_hat[fin], d[fin])}


def predict_heights(module, depth: np.ndarray, chunk: int = 64) -> np.ndarray:
    """Heights [m] of a whole flight, ``depth (K, H, W)``, GRU state carried from zeros across chunks."""
    out, h = [], None
    with torch.no_grad():
        for s in range(0, len(depth), chunk):
            x = torch.from_numpy(np.ascontiguousarray(depth[s:s + chunk], np.float32))[None, :, None]
            d, h = module(x, h)
            out.append(d[0].numpy())
    return np.concatenate(out).astype(float)


def flight_results(module: Any, seqs: Sequence[Any], fit: Any, h_ge: float
                    ) -> tuple[list[FlightResult], list[tuple[str, dict[str, float]]]]:
    """(per flight: the model's heights and the law on true and on predicted heights; the table's
    rows, one a flight and ``Total`` pooling their samples)."""
    results: list[FlightResult] = []
    for seq in seqs:
        d_hat = predict_heights(module, seq.depth)
        ge = seq.airborne & np.isfinite(seq.d) & (seq.d <= h_ge)
        results.append(FlightResult(seq.name, seq.t, seq.d, d_hat, seq.fa, fit.predict(seq.d, seq.sum_omega2),
                                    fit.predict(d_hat, seq.sum_omega2), ge, seq.airborne))
    rows = [(r.name, r.metrics()) for r in results]
    cat = lambda k: np.concatenate([getattr(r, k) for r in results])  # noqa: E731
    rows.append(("Total", flight_metrics(cat("fa"), cat("fa_phi"), cat("fa_model"), cat("d"), cat("d_hat"), cat("ge"),
                                  cat("airborne"))))
    return results, rows
