"""``uavturb evaluate --sweep PARENT`` (or several ``--run``): Table 2 over seeds and rows.

The paper reports Table 2 for one model. One CPU-trained seed is an anecdote: here every run
of a sweep's rows (or every run given) is evaluated on the same flights, as
:func:`uavturb.experiments.evaluate.evaluate` does for one, and the table is summarised per
row over its seeds:

- per row: RMSE(f_a,phi) (the law on true heights: the same for every run), RMSE(f_a) (the law
  on the network's heights), their ratio (the paper: 0.408 / 0.243 = 1.68 on EuRoC) and
  RMSE(d), mean +- standard deviation over seeds (``n`` seeds), with the worst seed's ratio;
- where the error comes from: per row and height band
  (:func:`uavturb.experiments.evaluate.band_metrics`) RMSE(f_a), the height bias and the band's
  share of the squared f_a error, averaged over seeds, and a plot of RMSE(f_a) by band.

Flights, the vehicle and ``(alpha, beta)`` are identified once; depth frames are projected once
per camera (runs trained on data of the same camera and size share them).

Outputs (one folder, written atomically): ``summary.md``, ``summary.json``, ``bands.png`` and one
folder per run (``<row>-seed<n>``: what ``uavturb evaluate`` writes for one run); each run gets
its MLflow child run, as with one ``--run``.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from uavturb.data.recordings import recording_sequence
from uavturb.errors import InputError
from uavturb.experiments import evaluate as ev
from uavturb.experiments import tracking
from uavturb.experiments.compare import search_all_runs
from uavturb.experiments.export import get_run, load_height_module, model_camera
from uavturb.io.publish import check_output_folder, publish_folder
from uavturb.io.reader import load_recordings
from uavturb.progress import progress_bar
from uavturb.scene.camera import CameraModel

#: the paper's Table 2 on EuRoC (Total): RMSE(f_a) / RMSE(f_a,phi) = 0.4082 / 0.2433
PAPER_RATIO = 0.4082 / 0.2433


def sweep_runs(parent_run_id: str, rows: Sequence[str] | None = None) -> list[str]:
    """Run ids of a sweep's finished height runs (tag ``ablation``), those of ``rows`` only when given,
    in row then seed order.

    Raises
    ------
    InputError : no such parent run, an unknown row, or no finished height run.
    """
    client = tracking.client()
    try:
        parent = client.get_run(parent_run_id)
    except Exception:  # noqa: BLE001 - MlflowException of an unknown id
        raise InputError("--sweep", f"no run {parent_run_id!r} in {tracking.tracking_uri()}") from None
    filt = f"tags.`mlflow.parentRunId` = '{parent_run_id}' and attributes.status = 'FINISHED'"
    runs = [r for r in search_all_runs(client, parent.info.experiment_id, filt) if "ablation" in r.data.tags]
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
             f"on {info['identified_on']} (beta = {info['beta']:.3g} ± {info['beta_stderr']:.2g} m^2, noise only); mean ± std over "
             f"seeds. The paper, on EuRoC: RMSE(f_a) 0.4082 N, "
             f"RMSE(f_a,phi) 0.2433 N, ratio {PAPER_RATIO:.2f}.", "",
             "| row | seeds | RMSE(f_a,phi) [N] | RMSE(f_a) [N] | ratio RMSE(f_a)/RMSE(f_a,phi) | worst seed's ratio "
             "| RMSE(d) [m] |", "|---|---:|---:|---:|---:|---:|---:|"]
    for r in rows:
        lines.append(f"| {r['row']} | {r['n']} | {r['rmse_fa_phi']:.4f} | {_pm(r['rmse_fa'], r['rmse_fa_std'], '.4f')} | "
                     f"{_pm(r['ratio'], r['ratio_std'], '.2f')} | {r['ratio_max']:.2f} | "
                     f"{_pm(r['rmse_d'], r['rmse_d_std'], '.4f')} |")
    lines += ["", "Where the error comes from (ground-effect frames by true height, mean over seeds):", "",
              "| row | height band | frames | RMSE(f_a,phi) [N] | RMSE(f_a) [N] | bias(d) [m] | share of f_a error |",
              "|---|---|---:|---:|---:|---:|---:|"]
    for r in rows:
        for b in r["bands"]:
            lines.append(f"| {r['row']} | {b['band']} | {b['n']} | {b['rmse_fa_phi']:.4f} | "
                         f"{_pm(b['rmse_fa'], b['rmse_fa_std'], '.4f')} | {_pm(b['bias_d'], b['bias_d_std'], '+.4f')} | "
                         f"{100 * b['share_sq_fa']:.0f} % |")
    if info.get("law_check"):
        lines += ["", f"Warning: {info['law_check']}."]
    return "\n".join(lines) + "\n"


def plot_bands(rows: list[dict[str, Any]], path: Path) -> None:
    """RMSE(f_a) [N] by height band per row (error bars: std over seeds), the law on true heights dashed."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

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


def evaluate_runs(run_ids: Sequence[str], recordings: Sequence[str | Path], *, out: str | Path = "evaluation",
                  vehicle: str | None = None, frame_dt: float | None = None, ge_fraction: float | None = None,
                  overwrite: bool = False, log: bool = True, progress: bool = True) -> dict[str, Any]:
    """Table 2 of every run in ``run_ids`` on the same flights, summarised per row over seeds.

    Parameters
    ----------
    run_ids : MLflow runs of height trainings (e.g. :func:`sweep_runs`)
    recordings, vehicle, frame_dt, ge_fraction, overwrite, log, progress : as
        :func:`uavturb.experiments.evaluate.evaluate`
    out : output folder (module docstring)

    Returns
    -------
    dict: ``rows`` (:func:`summarise`), ``runs`` (per run: ``run_id``, ``row``, ``label``, ``total``,
    ``bands``, ``mlflow_run``), ``summary`` (markdown text), ``out``.
    """
    ge_fraction = ev.GE_FRACTION if ge_fraction is None else ge_fraction
    if not recordings:
        raise InputError("REC", "at least one recording folder is needed")
    if not run_ids:
        raise InputError("--run", "at least one run is needed")
    if not 0 < ge_fraction < 1:
        raise InputError("--ge-fraction", f"must be in (0, 1), got {ge_fraction}")
    out = Path(out)
    check_output_folder(out, overwrite=overwrite)
    runs = [get_run(r) for r in run_ids]
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
            r["mlflow_run"] = ev.log_evaluation(r["run_id"], out / r["folder"], r["table"], flights.law.params())
    if progress:
        print(summary)
        print(f"wrote {out}/summary.md, summary.json, bands.png and a folder per run")
    return {"rows": rows, "runs": per_run, "summary": summary, "out": str(out)}


class _SharedFlights:
    """What every run's evaluation shares: the flights, the vehicle identified on the first, the depth
    frames per camera (projected once) and the law (:class:`~uavturb.experiments.evaluate.EvaluationLaw`,
    fitted on the first call of :meth:`sequences`)."""

    def __init__(self, recs: list[Any], ge_fraction: float, progress: bool):
        self.recs, self.ge_fraction, self.progress = recs, ge_fraction, progress
        self.vehicle, self.vehicle_source = ev.evaluation_vehicle(recs[0], progress)
        self._by_camera: dict[str, list[Any]] = {}
        self.law: Any = None

    def sequences(self, camera: CameraModel, frame_dt: float | None) -> list[Any]:
        """The flights' frames through a model's ``camera``; the law fitted on the first call."""
        key = json.dumps({"camera": camera.record(), "frame_dt": frame_dt}, sort_keys=True)
        if key not in self._by_camera:
            self._by_camera[key] = [recording_sequence(r, self.vehicle, camera, frame_dt=frame_dt,
                                                       progress=self.progress) for r in self.recs]
        seqs = self._by_camera[key]
        if self.law is None:  # the law depends on the first flight's frames, not on the camera
            self.law = ev.evaluation_law(self.recs, seqs[0], self.vehicle, self.vehicle_source, self.ge_fraction,
                                         self.progress)
        return seqs


def _evaluate_run(run: Any, row: str, label: str, flights: _SharedFlights, frame_dt: float | None, tmp: Path
                  ) -> dict[str, Any]:
    """One run's Table 2 into ``tmp/<label>/`` (as ``uavturb evaluate`` writes it); its figures."""
    module = load_height_module(run.info.run_id)
    camera = model_camera(module, run)
    seqs = flights.sequences(camera, frame_dt if frame_dt is not None else camera.frame_dt)
    law = flights.law
    results, table = ev.flight_results(module, seqs, law.fit, law.h_ge)
    bands = ev.band_metrics(results, law.fit.beta, law.ge_fraction)
    folder = ev.safe_filename(label.replace("/", "_").replace(" ", "-"))
    info = {"run_id": run.info.run_id, "row": row, "label": label, **law.info(),
            "image_size": ev.image_size_of(camera), "camera": seqs[0].camera.source,
            "rows": [{"flight": n, **m} for n, m in table], "bands": bands}
    (tmp / folder).mkdir()
    ev.write_evaluation(tmp / folder, table, results, info)
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
