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
"""

from __future__ import annotations

import csv
import io
import json
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from uavturb.data.recordings import recording_sequence
from uavturb.errors import InputError
from uavturb.experiments import tracking
from uavturb.experiments.export import get_run, load_height_module, model_camera, run_and_output
from uavturb.io.publish import publish_folder
from uavturb.io.reader import load_recordings
from uavturb.physics.ground_effect import identify_alpha_beta
from uavturb.scene.camera import CameraModel
from uavturb.sysid.identification import identify

GE_FRACTION = 0.01
#: lower bounds of the law's share of thrust that cut the ground-effect frames into height bands
#: (:func:`band_metrics`): nearest the floor first
BAND_FRACTIONS = (0.2, 0.05, 0.02)


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
        return _metrics(self.fa, self.fa_phi, self.fa_model, self.d, self.d_hat, self.ge, self.airborne)


def _rmse(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.sqrt(np.mean((a - b) ** 2))) if len(a) else float("nan")


def _metrics(fa, fa_phi, fa_model, d, d_hat, ge, airborne) -> dict[str, float]:
    fin = np.isfinite(d) & airborne
    return {"n_ge": int(ge.sum()), "rmse_fa_phi": _rmse(fa_phi[ge], fa[ge]), "rmse_fa": _rmse(fa_model[ge], fa[ge]),
            "rmse_d": _rmse(d_hat[ge], d[ge]), "rms_fa_gt": _rmse(fa[ge], 0 * fa[ge]),
            "n_all": int(fin.sum()), "rmse_fa_phi_all": _rmse(fa_phi[fin], fa[fin]),
            "rmse_fa_all": _rmse(fa_model[fin], fa[fin]), "rmse_d_all": _rmse(d_hat[fin], d[fin])}


def predict_heights(module, depth: np.ndarray, chunk: int = 64) -> np.ndarray:
    """Heights [m] of a whole flight, ``depth (K, H, W)``, GRU state carried from zeros across chunks."""
    import torch

    out, h = [], None
    with torch.no_grad():
        for s in range(0, len(depth), chunk):
            x = torch.from_numpy(np.ascontiguousarray(depth[s:s + chunk], np.float32))[None, :, None]
            d, h = module(x, h)
            out.append(d[0].numpy())
    return np.concatenate(out).astype(float)


def ground_effect_height(beta: float, fraction: float = GE_FRACTION) -> float:
    """Height [m] under which the law ``beta / (d^2 - beta)`` is at least ``fraction`` of the thrust."""
    return float(np.sqrt(beta * (1.0 + 1.0 / fraction)))


def image_size_of(camera: CameraModel) -> int | list[int]:
    """A model camera's image size as evaluations report it: the side of a square image, else ``[H, W]``."""
    return camera.width if camera.width == camera.height else [camera.height, camera.width]


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
                    "rmse_fa_phi": _rmse(fa_phi[m], fa[m]), "rmse_fa": _rmse(fa_model[m], fa[m]),
                    "rmse_d": _rmse(d_hat[m], d[m]),
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
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

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
    return "".join(c if c.isalnum() or c in "-_." else "_" for c in name)


def log_evaluation(run_id: str, folder: Path, results: list[tuple[str, dict[str, float]]], params: dict[str, Any]) -> str:
    """A child run of the training run: params, Table 2's Total as ``eval/<metric>``, the folder as artifacts.

    Per-flight figures stay in the artifacts (``evaluation/table.csv``): one metric column per
    flight and figure would crowd MLflow's run table. The same evaluation again (same run,
    recordings and settings) reuses its child run instead of adding one.
    """
    import warnings

    parent = get_run(run_id)
    client = tracking.client()
    params = {k: str(v)[:500] for k, v in params.items()}
    key = tracking.input_key(parent=run_id, **params)
    previous = tracking.find_run(client, parent.info.experiment_id, key, parent_run_id=run_id)
    total = dict(results[-1][1])
    note = (f"Table 2 of run `{run_id}` on {params['recordings']}: RMSE(f_a) {total['rmse_fa']:.4f} N "
            f"(law on true heights {total['rmse_fa_phi']:.4f} N), RMSE(d) {total['rmse_d']:.3f} m over "
            f"{int(total['n_ge'])} ground-effect frames.")
    if previous is not None:
        cid = previous.info.run_id
        tracking.claim_run(client, cid)
    else:
        cid = client.create_run(parent.info.experiment_id, run_name=f"evaluate-{run_id[:8]}",
                                tags=tracking.run_tags({"mlflow.parentRunId": run_id, "evaluation": "table2",
                                                        tracking.KEY_TAG: key})).info.run_id
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            if previous is None:
                for k, v in params.items():
                    client.log_param(cid, k, v)
            client.set_tag(cid, tracking.NOTE_TAG, note)
            for mk, mv in total.items():
                if np.isfinite(mv):
                    client.log_metric(cid, f"eval/{mk}", float(mv))
            client.log_artifacts(cid, str(folder), "evaluation")
    except BaseException as e:
        tracking.close_run(client, cid, e)
        raise
    tracking.close_run(client, cid)
    return cid


def evaluation_vehicle(first: Any, progress: bool) -> tuple[Any, str]:
    """(vehicle, where its constants come from): identified on the first flight, else (said so) its
    ``vehicle.yaml``'s constants."""
    try:
        ident = identify([first], first.vehicle)
        veh = ident.apply(first.vehicle)
        vehicle_source = f"identified on {first.name}"
        if ident.fallbacks(first.vehicle):
            vehicle_source += "; " + "; ".join(ident.fallbacks(first.vehicle))
    except InputError as e:
        if not first.vehicle.is_complete():
            raise InputError(f"{first.path}/vehicle.yaml", f"cannot identify the vehicle ({e.problem}) and "
                                                             "its constants are incomplete") from None
        veh = first.vehicle
        vehicle_source = f"{first.name}/vehicle.yaml (identification impossible: {e.problem})"
    if progress:
        print(f"vehicle constants: {vehicle_source}", file=sys.stderr)
    return veh, vehicle_source


def fit_ground_effect_law(first: Any, path: Any, ge_fraction: float, progress: bool) -> tuple[Any, float]:
    """(``(alpha, beta)`` fit by BFGS on the first flight's airborne frames with their true heights,
    the ground-effect region's height [m])."""
    if not first.airborne.any():
        raise InputError(str(path), "no airborne frame (rotor thrust >= 0.3 m g) to identify (alpha, beta) on")
    air = first.airborne
    fit = identify_alpha_beta(first.fa[air], first.d[air], first.sum_omega2[air])
    h_ge = ground_effect_height(fit.beta, ge_fraction)
    if progress:
        print(f"(alpha, beta) by BFGS on {first.name}: alpha = {fit.alpha:.4g} +- {fit.stderr_alpha:.2g} N m^2/(rad/s)^2, "
              f"beta = {fit.beta:.4g} +- {fit.stderr_beta:.2g} m^2 (fit RMSE {fit.rmse:.4f} N, {fit.n} frames); "
              f"ground-effect region d <= {h_ge:.3f} m "
              f"(law >= {100 * ge_fraction:g} % of thrust)", file=sys.stderr)
    return fit, h_ge


#: the law's own k_T (alpha / beta) may differ from the vehicle's by this factor before it is flagged
LAW_K_T_TOLERANCE = 1.25


def law_consistency(fit: Any, k_T: float) -> str | None:
    """A warning when the fitted law contradicts the vehicle: the paper's form has ``alpha = k_T beta``,
    so ``alpha / beta`` must be the thrust coefficient; ``None`` when it agrees within a factor
    :data:`LAW_K_T_TOLERANCE`. Where it does not, ``alpha`` and ``beta`` traded off against each
    other (flights at few heights) or the identified ``k_T`` took part of the law (its far tail is
    nearly a constant share of thrust), and ``mu = 16 beta / r^2`` is not to be read off."""
    ratio = fit.k_T() / k_T
    if 1 / LAW_K_T_TOLERANCE <= ratio <= LAW_K_T_TOLERANCE:
        return None
    return (f"the fitted law implies k_T = alpha / beta = {fit.k_T():.3g} N/(rad/s)^2, {ratio:.2f} times the vehicle's "
            f"{k_T:.3g}: alpha and beta are traded off (few heights, or the identified k_T absorbed the law's far tail); "
            f"the law still scores RMSE(f_a,phi), but its beta (hence mu and the ground-effect region) is not reliable")


@dataclass(frozen=True)
class EvaluationLaw:
    """What every run of an evaluation is scored with: the flights, the vehicle identified on the
    first, the ground-effect law fitted on the first flight's true heights and its check against
    the vehicle (:func:`law_consistency`)."""

    recordings: list[Any]
    vehicle_source: str
    fit: Any
    h_ge: float
    law_check: str | None
    ge_fraction: float

    def info(self) -> dict[str, Any]:
        """The law and where it comes from, for ``evaluation.json`` and ``summary.json``."""
        f = self.fit
        return {"recordings": [str(r.path) for r in self.recordings], "alpha": f.alpha, "beta": f.beta,
                "alpha_beta_fit_rmse": f.rmse, "alpha_stderr": f.stderr_alpha, "beta_stderr": f.stderr_beta,
                "law_check": self.law_check, "identified_on": self.recordings[0].name,
                "vehicle_constants": self.vehicle_source, "ge_fraction": self.ge_fraction, "h_ge": self.h_ge}

    def params(self) -> dict[str, Any]:
        """The MLflow params of an evaluation's child run."""
        return {"alpha": self.fit.alpha, "beta": self.fit.beta, "h_ge": self.h_ge, "ge_fraction": self.ge_fraction,
                "identified_on": self.recordings[0].name,
                "recordings": ",".join(r.name for r in self.recordings), "vehicle_constants": self.vehicle_source}


def evaluation_law(recs: Sequence[Any], first: Any, vehicle: Any, vehicle_source: str, ge_fraction: float,
                   progress: bool) -> EvaluationLaw:
    """:func:`fit_ground_effect_law` on ``first`` (the first flight's sequence) and :func:`law_consistency`
    against ``vehicle``, warned on stderr when it fails."""
    fit, h_ge = fit_ground_effect_law(first, recs[0].path, ge_fraction, progress)
    law_check = law_consistency(fit, vehicle.thrust_coefficient)
    if law_check and progress:
        print(f"warning: {law_check}", file=sys.stderr)
    return EvaluationLaw(list(recs), vehicle_source, fit, h_ge, law_check, ge_fraction)


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
    rows.append(("Total", _metrics(cat("fa"), cat("fa_phi"), cat("fa_model"), cat("d"), cat("d_hat"), cat("ge"),
                                  cat("airborne"))))
    return results, rows


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
    vehicle : preset or vehicle.yaml for folders without one (raw EuRoC)
    frame_dt : s, frame period where a recording has no cam0 frames (default: the model
        camera's, the training data's; else 0.05)
    ge_fraction : the ground-effect region's threshold (law / thrust)
    log : log a child run of ``run_id`` with the metrics and the output folder
    progress : print progress to stderr and the table to stdout

    Returns
    -------
    dict: ``rows`` [(flight, metrics)] with ``Total`` last, ``alpha``, ``beta``, ``h_ge``,
    ``vehicle_source``, ``out``, ``mlflow_run`` (child run id or None), ``table`` (text).

    The depth frames are seen through the model's own camera (:func:`model_camera`: its checkpoint,
    else its run); a model that carries none is refused in one line, before any work.
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
    veh, vehicle_source = evaluation_vehicle(recs[0], progress)
    seqs = [recording_sequence(r, veh, camera, frame_dt=frame_dt if frame_dt is not None else camera.frame_dt,
                               progress=progress) for r in recs]
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
