"""``make demo``: the project's main job end to end, on data it generates itself.

Steps (each prints its progress; a re-run reuses what is finished):

1. Simulator: training shards (``generate sim --preset quick``, 32x32 depth to fit the CPU
   budget) and depth/normal pre-training pairs (``generate normals``).
2. Table 1: the paper's ablation sweep with one seed (``sweep sweeps/ablation.yaml``), tracked
   in MLflow; ``compare`` prints the table.
3. "Real" flights: two hexarotor flights in the EuRoC layout with a Cheeseman-Bennett ground
   effect and realistic sensor noise (``generate flight``): the stand-in for EuRoC V1.
4. Physics on the first flight: the paper's least-squares identification, the ground-truth
   turbulence as the residual force, ``(alpha, beta)`` by BFGS, a plot of residual vs law.
5. Table 2: the Depth->Normal fine-tuned model of the sweep on the flights (``evaluate``).
6. Export of that model for onboard use (``.pt2`` and ONNX, checked against the module).
7. The sim-to-real gap finder on the flights, told that the simulator models nothing
   (``gap --sim-effects none``): it should name the ground effect and fit its ``mu``.
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np

from uavturb.commands.evaluate import evaluate
from uavturb.commands.export import export
from uavturb.commands.gap import gap
from uavturb.commands.generate import generate_flight_command, generate_normals, generate_sim
from uavturb.commands.identify import format_identification, identify_recordings
from uavturb.gap.report import format_effect
from uavturb.io.reader import load_recordings
from uavturb.physics import ground_effect as ge
from uavturb.physics.constants import GRAVITY
from uavturb.physics.vehicle import HEXAROTOR
from uavturb.runs.store import METRICS, RMSE_D, RMSE_FA_SCALED, ui_url
from uavturb.runs.sweep import sweep
from uavturb.runs.table1 import compare
from uavturb.sysid.flight_data import flight_data
from uavturb.sysid.residuals import residual_forces, write_residuals

TRUE_MU = 2.0
#: the demo's Table 1 data: the quick preset's scenes and trajectories at 32x32 px
IMAGE_SIZE = 32
#: sweep overrides that point the quick sweep at the simulator's shards instead of box rooms
SWEEP_DATA = ["data=shards", f"data.image_size={IMAGE_SIZE}", "data.stride=4", "data.eval_stride=8",
              "data.num_workers=0"]
FLIGHT_SECONDS = 60.0
STEPS = 7


def _say(msg: str) -> None:
    print(f"[demo] {msg}", flush=True)


def _step(k: int, what: str) -> float:
    _say(f"step {k}/{STEPS}: {what}")
    return time.perf_counter()


def physics_on_flight(rec_path: Path, out: Path) -> dict:
    """Identification, residual turbulence and the BFGS ground-effect fit on one flight, with a plot."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ident = identify_recordings([rec_path])
    print(format_identification(ident))
    truth = HEXAROTOR
    err_kT = ident.thrust_coefficient / truth.thrust_coefficient - 1
    err_ratio = ident.theta[3] / (truth.inertia[2] / truth.inertia[0]) - 1
    _say(f"k_T error {100 * err_kT:+.2f} %, J_z/J_x error {100 * err_ratio:+.2f} % (true values from the simulator)")

    (rec,) = load_recordings([rec_path])
    how = ident.speeds_read_note()
    if how:
        _say(f"rotor speeds read as identified: {how}")
    res = residual_forces(ident.flight_data_read(flight_data(rec)), ident.apply(rec.vehicle))
    csv = write_residuals(res, out / "residuals.csv", overwrite=True)
    _say(f"residual force series ({res.source}) -> {csv}, RMS {res.rmse:.3f} N")

    d = res.data.d_down
    ok = np.isfinite(d) & (d > 0.05) & (res.thrust > 0.3 * rec.vehicle.mass * GRAVITY)
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
    return {"identification": ident.to_dict(), "k_T_error_percent": 100 * err_kT,
            "Jz_over_Jx_error_percent": 100 * err_ratio, "residual_rms_N": res.rmse,
            "ground_effect": {"alpha": fit.alpha, "beta": fit.beta, "mu": mu_hat, "mu_true": TRUE_MU,
                              "rmse_N": fit.rmse}}


def run(out: Path, seed: int = 0, workers: int = 2) -> dict:
    """Run the demo into ``out``; returns the summary it also writes to ``out/summary.json``.

    MLflow runs go to the default store (``mlflow.db`` and ``mlruns/`` in the working
    directory, or ``MLFLOW_TRACKING_URI``).
    """

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    t_start = time.perf_counter()
    summary: dict = {"seconds": {}}

    t = _step(1, "simulator: training shards and pre-training pairs (quick preset, 32x32 px)")
    size = {"width": IMAGE_SIZE, "height": IMAGE_SIZE}
    _say(generate_sim("quick", out / "sim", workers=workers, seed=seed, **size))
    _say(generate_normals("quick", out / "pairs", workers=workers, seed=seed, **size))
    summary["seconds"]["simulator"] = time.perf_counter() - t

    t = _step(2, "Table 1: the paper's ablation sweep, one seed (MLflow)")
    res = sweep(profile="quick", seeds=1, overrides=[*SWEEP_DATA, f"data.root={out / 'sim'}",
                                                     f"data.pairs_root={out / 'pairs'}",
                                                     f"trainer.default_root_dir={out / 'runs'}"])
    table1 = compare(parent_run_id=res["parent_run_id"], experiment=res["experiment"], out=out / "table1",
                     overwrite=True)
    ours = next(r for r in res["runs"] if r["row"] == "normals/finetune")
    summary["table1"] = {"parent_run_id": res["parent_run_id"], "experiment": res["experiment"],
                         "rows": table1["rows"]}
    summary["seconds"]["sweep"] = time.perf_counter() - t

    t = _step(3, f"two {FLIGHT_SECONDS:.0f} s hexarotor flights in the EuRoC layout, ground_effect:mu={TRUE_MU}")
    flights = []
    for k in range(2):
        path = out / "flights" / f"hex_ground_effect_{k}"
        if not (path / "mav0").is_dir():
            generate_flight_command(vehicle="hex", effects=f"ground_effect:mu={TRUE_MU}", duration=FLIGHT_SECONDS,
                                    kind="mixed", seed=seed + k, noise="realistic", out=path)
        flights.append(path)
        _say(f"  {path}")
    summary["seconds"]["flights"] = time.perf_counter() - t

    t = _step(4, "physics on the first flight: identification, residual turbulence, ground-effect law")
    summary["physics"] = physics_on_flight(flights[0], out)
    summary["seconds"]["physics"] = time.perf_counter() - t

    t = _step(5, f"Table 2: model {ours['run_id']} (Depth->Normal, fine-tuned) on the flights")
    table2 = evaluate(ours["run_id"], flights, out=out / "table2", overwrite=True)
    summary["table2"] = {"rows": table2["rows"], "alpha": table2["alpha"], "beta": table2["beta"]}
    summary["seconds"]["evaluate"] = time.perf_counter() - t

    t = _step(6, "export for onboard use (.pt2 and ONNX)")
    exported = export(ours["run_id"], out / "export", overwrite=True)
    summary["export"] = {k: exported[k] for k in ("max_abs_diff",) if k in exported}
    summary["seconds"]["export"] = time.perf_counter() - t

    t = _step(7, "sim-to-real gap finder on the flights, simulator effects: none")
    report = gap([str(f) for f in flights], out / "gap", sim_effects="none", seed=seed, overwrite=True)
    named = ", ".join(format_effect(e) for e in report["effects"]) or "none"
    _say(f"effects named: {named}; held-out residual RMSE {report['baseline']['heldout_rmse_N']:.4f} N -> "
         f"{report['final']['heldout_rmse_N']:.4f} N; report {out / 'gap' / 'report.md'}")
    summary["gap"] = {"effects": report["effects"], "baseline": report["baseline"], "final": report["final"]}
    summary["seconds"]["gap"] = time.perf_counter() - t

    summary["seconds"]["total"] = time.perf_counter() - t_start
    (out / "summary.json").write_text(json.dumps(summary, indent=2, default=str))
    print()
    print(table1["table"])
    print()
    print(table2["table"])
    print()
    _say(f"done in {summary['seconds']['total'] / 60:.1f} min; summary {out / 'summary.json'}")
    _say("browse every run: `make ui` (or .venv/bin/mlflow ui --backend-store-uri sqlite:///mlflow.db), then open "
         f"{ui_url(res['view'])} (Table 1: the seven rows with {RMSE_D} [{METRICS[RMSE_D].unit}] and {RMSE_FA_SCALED})")
    return summary
