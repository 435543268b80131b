"""``make demo``: the project's main job end to end, on data it generates itself.

Today: simulate a hexarotor flight with a known Cheeseman-Bennett ground effect and
realistic sensor noise, write it in the EuRoC layout, read it back, identify the model
(the paper's least squares), compute the ground-truth turbulence as the residual force,
identify the ground effect's ``(alpha, beta)`` by BFGS, and plot the residual against the law.
"""

from __future__ import annotations

import json
import shutil
import time
from pathlib import Path

import numpy as np

from uavturb.physics import ground_effect as ge
from uavturb.physics.vehicle import HEXAROTOR

TRUE_MU = 2.0


def _say(msg: str) -> None:
    print(f"[demo] {msg}", flush=True)


def run(out: Path, seed: int = 0) -> dict:
    """Run the demo into ``out``; returns the summary it also writes to ``out/summary.json``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from uavturb import workflows
    from uavturb.physics.residuals import residual_forces, write_residuals

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    rec_path = out / "flights" / "hex_ground_effect"
    if rec_path.exists():
        shutil.rmtree(rec_path)
    rec_path.parent.mkdir(parents=True, exist_ok=True)
    _say(f"simulating a 90 s hexarotor flight with ground_effect:mu={TRUE_MU} and realistic sensor noise ...")
    workflows.generate_flight(vehicle="hex", effects=f"ground_effect:mu={TRUE_MU}", duration=90.0, kind="mixed",
                              seed=seed, noise="realistic", out=rec_path)
    _say(f"wrote {rec_path} ({time.perf_counter() - t0:.1f} s)")

    ident = workflows.identify_recordings([rec_path])
    print(workflows.format_identification(ident))
    truth = HEXAROTOR
    err_kT = ident.thrust_coefficient / truth.thrust_coefficient - 1
    ratio_true = truth.inertia[2] / truth.inertia[0]
    err_ratio = ident.theta[3] / ratio_true - 1
    _say(f"k_T error {100 * err_kT:+.2f} %, J_z/J_x error {100 * err_ratio:+.2f} % (true values from the simulator)")

    (rec,) = workflows.load_recordings([rec_path])
    vehicle = ident.apply(rec.vehicle)
    res = residual_forces(rec, vehicle)
    csv = write_residuals(res, out / "residuals.csv")
    _say(f"residual force series ({res.source}) -> {csv}, RMS {res.rmse:.3f} N")

    d = res.data.d_down
    ok = np.isfinite(d) & (d > 0.05) & (res.thrust > 0.3 * rec.vehicle.mass * 9.81)
    fit = ge.identify_alpha_beta(res.force[ok, 2], d[ok], res.sum_omega2[ok])
    mu_hat = fit.mu(rec.vehicle.rotor_radius)
    _say(f"BFGS ground-effect fit: alpha {fit.alpha:.4g}, beta {fit.beta:.4g} m^2 -> mu {mu_hat:.3f} "
         f"(true {TRUE_MU}), fit RMS {fit.rmse:.3f} N")

    fig, axes = plt.subplots(2, 1, figsize=(11, 6.5), sharex=True)
    phi = fit.predict(d, res.sum_omega2)
    axes[0].plot(res.t, res.force[:, 2], lw=0.5, color="tab:blue", label="residual F_z (ground truth)")
    axes[0].plot(res.t, np.where(ok, phi, np.nan), lw=1.2, color="tab:green", label=r"$\phi(d, \Omega)$ identified")
    axes[0].set_ylabel("vertical force [N]")
    axes[0].legend(loc="upper right")
    axes[0].set_title("Ground-truth turbulence vs the identified Cheeseman-Bennett law")
    axes[1].plot(res.t, d, color="k", lw=1)
    axes[1].set_ylabel("d_down [m]")
    axes[1].set_xlabel("t [s]")
    axes[1].set_ylim(0, min(3.0, np.nanmax(np.where(np.isfinite(d), d, np.nan)) * 1.1))
    fig.tight_layout()
    fig.savefig(out / "residuals.png", dpi=110)
    plt.close(fig)

    summary = {
        "recording": str(rec_path),
        "identification": ident.to_dict(),
        "k_T_error_percent": 100 * err_kT,
        "Jz_over_Jx_error_percent": 100 * err_ratio,
        "residual_rms_N": res.rmse,
        "ground_effect": {"alpha": fit.alpha, "beta": fit.beta, "mu": mu_hat, "mu_true": TRUE_MU, "rmse_N": fit.rmse},
        "seconds": time.perf_counter() - t0,
    }
    (out / "summary.json").write_text(json.dumps(summary, indent=2))
    _say(f"plot {out / 'residuals.png'}, summary {out / 'summary.json'}; done in {summary['seconds']:.1f} s")
    return summary
