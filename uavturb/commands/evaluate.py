"""``uavturb evaluate``: the paper's Table 2 -- the height model and the ground-effect law on
EuRoC-layout flights.

Protocol (paper, "Predicting turbulences" and "Sim2real transfer"):

1. Every flight becomes a sequence of camera frames (:mod:`uavturb.data.recordings`): depth
   images from the point cloud projected into ``cam0``, true heights ``d`` from the cloud,
   ground-truth ``f_a`` as the world-z residual force of the identified model [N].
2. The vehicle's constants (``k_T``, ``k_M``, inertia) are identified by least squares on the
   **first** flight (:func:`uavturb.sysid.identification.identify`); where it has no free
   flight to identify on, the first flight's ``vehicle.yaml`` constants are used (said so), and
   so are those the flight does not determine (:mod:`uavturb.sysid.identifiability`; said so).
3. ``(alpha, beta)`` of ``f = alpha sum(Omega^2) / (d^2 - beta)`` are identified by BFGS on the
   **first** flight with its true heights (:func:`uavturb.physics.ground_effect.identify_alpha_beta`),
   as the paper does on V1_01_easy.
4. Per flight: ``RMSE(f_a,phi)`` -- the law on true heights vs GT; ``RMSE(f_a)`` -- the law on
   the network's heights (GRU state carried over the whole flight from zeros) vs GT. A
   ``Total`` row pools the samples of all flights.

Samples used: the paper "focused the evaluation on selected parts of the flights where the
ground effect is significant". Our rule: airborne frames (rotor thrust >= 0.3 m g; below that
the vehicle rests on a surface and the residual is a contact force) whose true height makes
the identified law worth at least ``ge_fraction`` (1 %) of the thrust,
``beta / (d^2 - beta) >= ge_fraction``, i.e. ``d <= sqrt(beta (1 + 1 / ge_fraction))`` (about
0.35 m for the hexarotor with mu = 2). The table also reports every airborne frame with a
surface below ("all"). ``(alpha, beta)`` are fitted on the first flight's airborne frames.

Outputs (folder written atomically): ``table.md``, ``table.csv``, ``fa_<flight>.png`` (f_a over
time: GT blue, model red, phi on true heights green -- the paper's sim2real figure -- and
predicted vs true heights), ``series_<flight>.csv``, ``evaluation.json``; an MLflow child run
of the training run with the metrics, tagged ``evaluation=table2``.

Over runs (``uavturb evaluate --sweep PARENT`` or several ``--run``, :func:`evaluate_runs`): one
CPU-trained seed is an anecdote, so every run of a sweep's rows (or every run given) is evaluated
on the same flights and the table is summarised per row over its seeds: RMSE(f_a,phi),
RMSE(f_a), their ratio (the paper: 0.408 / 0.243 = 1.68 on EuRoC) and RMSE(d), mean +- standard
deviation over seeds, with the worst seed's ratio; and per row and height band RMSE(f_a), the
height bias and the band's share of the squared f_a error, with a plot of RMSE(f_a) by band.
Flights, the vehicle and ``(alpha, beta)`` are identified once; depth frames are projected once
per camera. Outputs (one folder, written atomically): ``summary.md``, ``summary.json``,
``bands.png`` and one folder per run (``<row>-seed<n>``: what one run's evaluation writes); each
run gets its MLflow child run.

The science (metrics, height bands, the law fit, the report's files) is
:mod:`uavturb.evaluation`; this module reads the runs and the recordings, publishes the folder
and logs the child runs (:func:`uavturb.runs.store.log_run`).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any, Sequence

from uavturb.commands.export import load_height_module, model_camera, run_and_output
from uavturb.data.recordings import recording_sequence
from uavturb.errors import InputError
from uavturb.evaluation.bands import GE_FRACTION, band_metrics, plot_bands
from uavturb.evaluation.law import EvaluationLaw, evaluation_law, evaluation_vehicle
from uavturb.evaluation.metrics import flight_results
from uavturb.evaluation.report import format_summary, format_table, safe_filename, summarise, write_evaluation
from uavturb.io.publish import check_apart, check_output_folder, publish_folder
from uavturb.io.reader import load_recordings
from uavturb.progress import progress_bar
from uavturb.runs import store
from uavturb.scene.camera import CameraModel


def image_size_of(camera: CameraModel) -> int | list[int]:
    """A model camera's image size as evaluations report it: the side of a square image, else ``[H, W]``."""
    return camera.width if camera.width == camera.height else [camera.height, camera.width]


def log_evaluation(run_id: str, folder: Path, results: list[tuple[str, dict[str, float]]],
                   params: dict[str, Any]) -> str:
    """A child run of the training run: params, Table 2's Total as ``eval/<metric>``, the folder as artifacts.

    Per-flight figures stay in the artifacts (``evaluation/table.csv``): one metric column per
    flight and figure would crowd MLflow's run table. The same evaluation again (same run,
    recordings and settings) reuses its child run instead of adding one (:func:`uavturb.runs.store.log_run`).
    """
    total = dict(results[-1][1])
    note = (f"Table 2 of run `{run_id}` on {params['recordings']}: RMSE(f_a) {total['rmse_fa']:.4f} N "
            f"(law on true heights {total['rmse_fa_phi']:.4f} N), RMSE(d) {total['rmse_d']:.3f} m over "
            f"{int(total['n_ge'])} ground-effect frames.")
    return store.log_run(None, run_name=f"evaluate-{run_id[:8]}", params=params, parent_run_id=run_id,
                         metrics={store.EVAL_PREFIX + k: v for k, v in total.items()},
                         tags={"evaluation": "table2"}, artifacts=folder, artifact_path="evaluation", note=note)


def evaluate(run_id: str | None, recordings: Sequence[str | Path], *, out: str | Path = "evaluation",
             checkpoint: str | Path | None = None, vehicle: str | None = None, frame_dt: float | None = None,
             ge_fraction: float = GE_FRACTION, overwrite: bool = False, log: bool = True, progress: bool = True
             ) -> dict[str, Any]:
    """``uavturb evaluate``: Table 2 on EuRoC-layout flights (see the module docstring).

    Parameters
    ----------
    run_id : MLflow run of a height training (its checkpoint; ``checkpoint`` overrides)
    recordings : recording folders; the first identifies the vehicle and ``(alpha, beta)``
    out : output folder (replaced when ``overwrite``)
    vehicle : built-in vehicle, shipped (firefly) or vehicle.yaml for folders without one (raw EuRoC)
    frame_dt : s, frame period where a recording has no cam0 frames (default: the model
        camera's, the training data's; else 0.05)
    ge_fraction : the ground-effect region's threshold (law / thrust)
    log : log a child run of ``run_id`` with the metrics and the output folder
    progress : print progress to stderr and the table to stdout

    Returns
    -------
    dict: ``rows`` [(flight, metrics)] with ``Total`` last, ``alpha``, ``beta``, ``h_ge``,
    ``vehicle_source``, ``out``, ``mlflow_run`` (child run id or None), ``table`` (text).

    The depth frames are seen through the model's own camera (:func:`uavturb.commands.export.model_camera`:
    its checkpoint, else its run); a model that carries none is refused in one line, before any work.
    """
    if not recordings:
        raise InputError("REC", "at least one recording folder is needed")
    if not 0 < ge_fraction < 1:
        raise InputError("--ge-fraction", f"must be in (0, 1), got {ge_fraction}")
    out = Path(out)
    run = run_and_output(run_id, checkpoint, out, overwrite)
    module = load_height_module(run_id, checkpoint)
    camera = model_camera(module, run, checkpoint)
    size = image_size_of(camera)

    recs = load_recordings(recordings, vehicle)
    veh, vehicle_source, read = evaluation_vehicle(recs[0], progress)
    seqs = [recording_sequence(r, veh, camera, frame_dt=frame_dt if frame_dt is not None else camera.frame_dt,
                               speeds_read=read, progress=progress) for r in recs]
    law = evaluation_law(recs, seqs[0], veh, vehicle_source, ge_fraction, progress)
    fit, h_ge = law.fit, law.h_ge
    results, rows = flight_results(module, seqs, fit, h_ge)
    table = format_table(rows)

    info = {"run_id": run_id, "checkpoint": str(checkpoint) if checkpoint else None, **law.info(),
            "image_size": size, "camera": seqs[0].camera.source, "rows": [{"flight": n, **m} for n, m in rows],
            "bands": band_metrics(results, fit.beta, ge_fraction)}
    with publish_folder(out, overwrite=overwrite, command="uavturb evaluate") as tmp:
        write_evaluation(tmp, rows, results, info)

    child = None
    if log and run_id is not None:
        child = log_evaluation(run_id, out, rows, {**law.params(), "image_size": size})
    if progress:
        print(table)
        print(f"wrote {out}/table.md, table.csv, fa_*.png" + (f"; MLflow child run {child}" if child else ""))
    return {"rows": rows, "alpha": fit.alpha, "beta": fit.beta, "h_ge": h_ge, "vehicle_source": vehicle_source,
            "out": str(out), "mlflow_run": child, "table": table, "results": results}


def sweep_runs(parent_run_id: str, rows: Sequence[str] | None = None) -> list[str]:
    """Run ids of a sweep's finished height runs (tag ``ablation``), those of ``rows`` only when given,
    in row then seed order.

    Raises
    ------
    InputError : no such parent run, an unknown row, or no finished height run.
    """
    parent = store.get_run(parent_run_id, "--sweep")
    runs = [r for r in store.child_runs(parent.info.experiment_id, parent_run_id, "FINISHED")
            if "ablation" in r.data.tags]
    known = sorted({r.data.tags["ablation"] for r in runs})
    if rows:
        unknown = [r for r in rows if r not in known]
        if unknown:
            raise InputError("--rows", f"no finished runs of {', '.join(unknown)} in sweep {parent_run_id} "
                             f"(rows: {', '.join(known) or 'none'})")
        runs = [r for r in runs if r.data.tags["ablation"] in rows]
    if not runs:
        raise InputError("--sweep", f"sweep {parent_run_id} has no finished height run")
    order = {name: i for i, name in enumerate(rows or known)}
    runs.sort(key=lambda r: (order[r.data.tags["ablation"]], int(r.data.tags.get("seed", "0") or 0)))
    return [r.info.run_id for r in runs]


def _label(run: Any) -> tuple[str, str]:
    """(row name, run label): the run's ``ablation`` row and ``seed`` tags, else its name or id."""
    tags = run.data.tags
    row = tags.get("ablation") or tags.get("mlflow.runName") or run.info.run_id[:8]
    seed = tags.get("seed")
    return row, f"{row} seed {seed}" if seed is not None else f"{row} {run.info.run_id[:8]}"


def evaluate_runs(run_ids: Sequence[str], recordings: Sequence[str | Path], *, out: str | Path = "evaluation",
                  vehicle: str | None = None, frame_dt: float | None = None, ge_fraction: float | None = None,
                  overwrite: bool = False, log: bool = True, progress: bool = True) -> dict[str, Any]:
    """Table 2 of every run in ``run_ids`` on the same flights, summarised per row over seeds.

    Parameters
    ----------
    run_ids : MLflow runs of height trainings (e.g. :func:`sweep_runs`)
    recordings, vehicle, frame_dt, ge_fraction, overwrite, log, progress : as
        :func:`evaluate`
    out : output folder (module docstring)

    Returns
    -------
    dict: ``rows`` (:func:`summarise`), ``runs`` (per run: ``run_id``, ``row``, ``label``, ``total``,
    ``bands``, ``mlflow_run``), ``summary`` (markdown text), ``out``.
    """
    ge_fraction = GE_FRACTION if ge_fraction is None else ge_fraction
    if not recordings:
        raise InputError("REC", "at least one recording folder is needed")
    if not run_ids:
        raise InputError("--run", "at least one run is needed")
    if not 0 < ge_fraction < 1:
        raise InputError("--ge-fraction", f"must be in (0, 1), got {ge_fraction}")
    out = Path(out)
    check_apart(out, recordings)
    check_output_folder(out, overwrite=overwrite)
    runs = [store.get_run(r) for r in run_ids]
    labels = [_label(r) for r in runs]
    if len({lab for _, lab in labels}) < len(labels):
        raise InputError("--run", "the same run (row and seed) is given twice")
    flights = _SharedFlights(load_recordings(recordings, vehicle), ge_fraction, progress)
    per_run = []
    with publish_folder(out, overwrite=overwrite, command="uavturb evaluate") as tmp:
        with progress_bar(len(runs), "evaluate runs", "runs", disable=not progress) as bar:
            for run, (row, label) in zip(runs, labels):
                per_run.append(_evaluate_run(run, row, label, flights, frame_dt, tmp))
                bar.update(1)
        rows, summary = _write_summary(tmp, per_run, flights)
    for r in per_run:
        r["mlflow_run"] = None
        if log:
            r["mlflow_run"] = log_evaluation(r["run_id"], out / r["folder"], r["table"], flights.law.params())
    if progress:
        print(summary)
        print(f"wrote {out}/summary.md, summary.json, bands.png and a folder per run")
    return {"rows": rows, "runs": per_run, "summary": summary, "out": str(out)}


class _SharedFlights:
    """What every run's evaluation shares: the flights, the vehicle identified on the first, the depth
    frames per camera (projected once) and the law (:class:`~uavturb.evaluation.law.EvaluationLaw`,
    fitted on the first call of :meth:`sequences`)."""

    def __init__(self, recs: list[Any], ge_fraction: float, progress: bool):
        self.recs, self.ge_fraction, self.progress = recs, ge_fraction, progress
        self.vehicle, self.vehicle_source, self.speeds_read = evaluation_vehicle(recs[0], progress)
        self._by_camera: dict[str, list[Any]] = {}
        self.law: EvaluationLaw | None = None

    def sequences(self, camera: CameraModel, frame_dt: float | None) -> list[Any]:
        """The flights' frames through a model's ``camera``; the law fitted on the first call."""
        key = json.dumps({"camera": camera.record(), "frame_dt": frame_dt}, sort_keys=True)
        if key not in self._by_camera:
            self._by_camera[key] = [recording_sequence(r, self.vehicle, camera, frame_dt=frame_dt,
                                                       speeds_read=self.speeds_read, progress=self.progress)
                                    for r in self.recs]
        seqs = self._by_camera[key]
        if self.law is None:  # the law depends on the first flight's frames, not on the camera
            self.law = evaluation_law(self.recs, seqs[0], self.vehicle, self.vehicle_source, self.ge_fraction,
                                         self.progress)
        return seqs


def _evaluate_run(run: Any, row: str, label: str, flights: _SharedFlights, frame_dt: float | None, tmp: Path
                  ) -> dict[str, Any]:
    """One run's Table 2 into ``tmp/<label>/`` (as ``uavturb evaluate`` writes it); its figures."""
    module = load_height_module(run.info.run_id)
    camera = model_camera(module, run)
    seqs = flights.sequences(camera, frame_dt if frame_dt is not None else camera.frame_dt)
    law = flights.law
    results, table = flight_results(module, seqs, law.fit, law.h_ge)
    bands = band_metrics(results, law.fit.beta, law.ge_fraction)
    folder = safe_filename(label.replace("/", "_").replace(" ", "-"))
    info = {"run_id": run.info.run_id, "row": row, "label": label, **law.info(),
            "image_size": image_size_of(camera), "camera": seqs[0].camera.source,
            "rows": [{"flight": n, **m} for n, m in table], "bands": bands}
    (tmp / folder).mkdir()
    write_evaluation(tmp / folder, table, results, info)
    return {"run_id": run.info.run_id, "row": row, "label": label, "folder": folder, "total": table[-1][1],
            "bands": bands, "table": table}


def _write_summary(tmp: Path, per_run: list[dict[str, Any]], flights: _SharedFlights
                   ) -> tuple[list[dict[str, Any]], str]:
    """``summary.md``, ``summary.json`` and ``bands.png`` into ``tmp``; (rows, summary text)."""
    rows = summarise(per_run)
    info = {"flights": [r.name for r in flights.recs], "n_ge": int(per_run[0]["total"]["n_ge"]), **flights.law.info()}
    summary = format_summary(rows, info)
    (tmp / "summary.md").write_text(summary)
    runs = [{k: r[k] for k in ("run_id", "row", "label", "folder", "total", "bands")} for r in per_run]
    (tmp / "summary.json").write_text(json.dumps({**info, "rows": rows, "runs": runs}, indent=2, default=float))
    plot_bands(rows, tmp / "bands.png")
    return rows, summary
