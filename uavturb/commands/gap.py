"""``uavturb gap``: read recordings, run the gap finder's analysis (:mod:`uavturb.gap.finder`),
publish the report folder and log the run to MLflow (from a second process that imports MLflow while
the analysis runs: :mod:`uavturb.runs.store_process`)."""

from __future__ import annotations

import contextlib
import sys
import time
from pathlib import Path
from typing import Sequence

from uavturb.errors import InputError
from uavturb.gap.finder import STAGES, analyse, parse_sim_effects
from uavturb.gap.report import FiguresAhead, write_json, write_markdown, write_plots
from uavturb.gap.uncertainty import HEIGHT_REFERENCE_M
from uavturb.io.physics_config import load_physics_config, write_physics_config
from uavturb.io.publish import check_apart, check_output_file, check_output_folder, publish_folder
from uavturb.io.reader import load_recordings
from uavturb.physics.effects import EFFECTS
from uavturb.progress import Stages
from uavturb.runs.store_process import StoreProcess


def gap(recordings: Sequence[str | Path], out: str | Path, *, sim_effects: str | None = None, seed: int = 0,
        apply: str | Path | None = None, vehicle: str | None = None, log_mlflow: bool = True,
        physics_config: str | Path | None = None, overwrite: bool = False,
        height_uncertainty: float = HEIGHT_REFERENCE_M) -> dict:
    """Run the gap finder on recording folders and write ``out/report.json`` and ``out/report.md``.

    ``out`` holds a complete report or none: everything is built in a temporary folder beside it
    and renamed at the end (:func:`uavturb.io.publish.publish_folder`: an existing report folder is
    replaced only with ``overwrite``; a folder uavturb did not write is never touched).
    """

    t0 = time.perf_counter()
    out = Path(out)
    sim = parse_sim_effects(sim_effects)
    if physics_config is not None:
        cfg = load_physics_config(physics_config)["effects"]
        sim = {n: cfg.get(n, p) for n, p in sim.items()} if sim_effects is not None else cfg
    if not recordings:
        raise InputError("gap", "no recording given")
    check_apart(out, recordings)
    check_output_folder(out, overwrite=overwrite)
    if apply is not None:
        check_apart(apply, recordings, what="--apply")
        if Path(apply).resolve().is_relative_to(out.resolve()):
            raise InputError(apply, f"lies inside --out {out}, which is replaced as a whole by the report: write it "
                                    "beside the report folder")
        check_output_file(apply, overwrite=overwrite)
    with Stages("uavturb gap", STAGES if log_mlflow else STAGES[:-1]) as stage:
        stage("reading the recordings")
        recs = load_recordings(recordings, vehicle)
        # MLflow's imports (~4.5 s) run in a second process while the analysis runs (uavturb.runs.store_process);
        # the figures drawn from what the analysis knows at its checkpoint are drawn while it runs to its end
        with StoreProcess() if log_mlflow else contextlib.nullcontext() as store, FiguresAhead() as ahead:
            report, ex = analyse(recs, sim, seed=seed, height_uncertainty=height_uncertainty, progress=stage,
                                 at_checkpoint=ahead.start)
            report["seconds_analysis"] = time.perf_counter() - t0
            stage("writing the report")
            _publish(out, report, ex, ahead, apply=apply, overwrite=overwrite)
            if store is not None:
                stage("logging the run")
                _log(store, report, seed, out)
    return report


def _publish(out: Path, report: dict, ex: dict, ahead: FiguresAhead, *, apply: str | Path | None,
             overwrite: bool) -> None:
    """Write the report folder (plots, ``report.md``, ``report.json``; ``ahead``: the figures started at the
    analysis's checkpoint) and the ``--apply`` physics config."""
    with publish_folder(out, overwrite=overwrite, command="uavturb gap") as tmp:
        top = ex["drivers"][0]["feature"] if ex["drivers"] else None
        surface = (ex["curve"], ex["curve_fits"], ex.get("curve_named")) if report["surface_curve"] is not None \
            else None
        plots = write_plots(tmp, ex["data"], ex["r0"], ex["rs0"], ex["rf"], ex["rsf"], ex["segs"], top,
                            ex["base_ho"], ex["final_ho"], surface=surface, ahead=ahead)
        if apply is not None:
            # the simulator's forces only: a law of what logged commands mean (battery_voltage) is not one
            fitted = {e["name"]: e["params"] for e in report["effects"] if EFFECTS[e["name"]].simulated}
            for n, p in report["sim_effect_params"].items():
                fitted[n] = p["fitted"] or p["sim"]
            write_physics_config(apply, fitted, {"thrust_coefficient": report["nominal"]["thrust_coefficient"]},
                                 source=f"uavturb gap {' '.join(report['recordings'])}", overwrite=overwrite)
            report["applied_config"] = str(apply)
        write_markdown(tmp, report, plots)
        write_json(tmp, report)


def _log(store: StoreProcess, report: dict, seed: int, out: Path) -> None:
    """The gap run in MLflow (experiment ``uavturb-gap``); a failure is a warning: the report is written."""
    try:
        store.log_run("uavturb-gap", run_name="gap " + ",".join(Path(r).name for r in report["recordings"]),
                      params={"recordings": report["recordings"], "sim_effects": report["sim_effects"], "seed": seed,
                              "protocol": report["protocol"]},
                      metrics={"gap/baseline_heldout_rmse_N": report["baseline"]["heldout_rmse_N"],
                               "gap/final_heldout_rmse_N": report["final"]["heldout_rmse_N"],
                               "gap/n_effects": len(report["effects"])},
                      tags={"effects": ",".join(e["name"] for e in report["effects"]) or "none"}, artifacts=out)
    except Exception as e:  # noqa: BLE001 - tracking must never lose a finished report
        print(f"uavturb gap: warning: MLflow logging failed ({type(e).__name__}: {e})", file=sys.stderr)

