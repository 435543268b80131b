"""Table 1 from the MLflow store (``uavturb compare``): mean +- std over seeds per ablation row.

Rows are the height runs tagged ``ablation=<row>`` (and ``seed=<n>``) by :func:`uavturb.runs.sweep.sweep`,
FINISHED, with metrics ``test/rmse_d`` [m] and ``test/rmse_fa`` [N]. By default the children of
the latest sweep parent run of the experiment are used; with no sweep parent at all, every
such run of the experiment. Where a (row, seed) pair has several runs, the latest counts.
The standard deviation is the sample one (``ddof=1``); with one seed it is undefined (``nan``,
and the table prints the mean alone). Every column has one number of decimals, enough for three
significant digits of its smallest value. Rows come in the sweep file's order (the paper's), next
to the paper's values.
"""

from __future__ import annotations

import csv
import io
import math
from pathlib import Path
from typing import Any

import numpy as np

from uavturb.errors import InputError
from uavturb.io.publish import check_output_file, write_text_atomic
from uavturb.runs import store
from uavturb.runs.config import DEFAULT_SPEC, load_spec


def _mean_std(values: list[float]) -> tuple[float, float]:
    a = np.asarray(values, float)
    return float(a.mean()), float(a.std(ddof=1)) if len(a) > 1 else math.nan


def table_rows(runs: list[Any], spec_rows: list[Any] | None = None) -> list[dict[str, Any]]:
    """Aggregate finished ablation runs into table rows.

    Parameters
    ----------
    runs : MLflow runs (``.data.tags``, ``.data.metrics``, ``.info``), tags ``ablation``, ``seed``.
    spec_rows : the sweep file's rows (order and paper values).

    Returns
    -------
    list of dicts: ``row``, ``pretraining``, ``model``, ``n``, ``seeds``, ``rmse_d_mean``,
    ``rmse_d_std``, ``rmse_fa_mean``, ``rmse_fa_std`` (N), ``paper_rmse_d``, ``paper_rmse_fa``,
    ``run_ids``.
    """
    latest: dict[tuple[str, str], Any] = {}
    for r in sorted(runs, key=lambda r: r.info.start_time or 0):
        tags, m = r.data.tags, r.data.metrics
        if "ablation" in tags and all(k in m for k in store.TABLE1_METRICS):
            latest[(tags["ablation"], tags.get("seed", "?"))] = r
    by_row: dict[str, list[Any]] = {}
    for (row, _), r in latest.items():
        by_row.setdefault(row, []).append(r)
    spec = {s.name: s for s in (spec_rows or [])}
    order = [s.name for s in (spec_rows or []) if s.name in by_row] + sorted(set(by_row) - set(spec))
    out = []
    for row in order:
        rs = sorted(by_row[row], key=lambda r: r.data.tags.get("seed", ""))
        d_mean, d_std = _mean_std([r.data.metrics[store.RMSE_D] for r in rs])
        fa_mean, fa_std = _mean_std([r.data.metrics[store.RMSE_FA] for r in rs])
        pre, _, model = row.partition("/")
        s = spec.get(row)
        out.append({"row": row, "pretraining": pre, "model": model or "-", "n": len(rs),
                    "seeds": [r.data.tags.get("seed", "?") for r in rs], "rmse_d_mean": d_mean, "rmse_d_std": d_std,
                    "rmse_fa_mean": fa_mean, "rmse_fa_std": fa_std,
                    "paper_rmse_d": getattr(s, "paper_rmse_d", None),
                    "paper_rmse_fa": getattr(s, "paper_rmse_fa", None),
                    "run_ids": [r.info.run_id for r in rs]})
    return out


def decimals(values: list[float | None], significant: int = 3) -> int:
    """Decimals that show ``significant`` digits of the smallest nonzero finite value (0 to 6)."""
    finite = [abs(v) for v in values if v is not None and math.isfinite(v) and v != 0]
    if not finite:
        return 3
    return int(min(6, max(0, significant - 1 - math.floor(math.log10(min(finite))))))


def _pm(mean: float, std: float, places: int) -> str:
    """``mean ± std`` with ``places`` decimals; the mean alone where the std is undefined (one seed)."""
    return f"{mean:.{places}f}" if math.isnan(std) else f"{mean:.{places}f} ± {std:.{places}f}"


def _paper(x: float | None, places: int) -> str:
    return "-" if x is None else f"{x:.{places}f}"


HEADER = ("Pre-training", "Model", "Seeds", "RMSE(d) [m]", "RMSE(f_a) [1e-4 N]", "Paper RMSE(d)",
          "Paper RMSE(f_a) [1e-4 N]")


def _cells(rows: list[dict[str, Any]]) -> list[tuple[str, ...]]:
    fa = [{k: (None if r[k] is None else r[k] * store.FA_SCALE)
           for k in ("rmse_fa_mean", "rmse_fa_std", "paper_rmse_fa")}
          for r in rows]
    d_places = decimals([r["rmse_d_mean"] for r in rows])
    fa_places = decimals([f["rmse_fa_mean"] for f in fa])
    paper_d, paper_fa = decimals([r["paper_rmse_d"] for r in rows], 4), decimals([f["paper_rmse_fa"] for f in fa], 4)
    return [(r["pretraining"], r["model"], str(r["n"]), _pm(r["rmse_d_mean"], r["rmse_d_std"], d_places),
             _pm(f["rmse_fa_mean"], f["rmse_fa_std"], fa_places), _paper(r["paper_rmse_d"], paper_d),
             _paper(f["paper_rmse_fa"], paper_fa)) for r, f in zip(rows, fa)]


def format_text(rows: list[dict[str, Any]], title: str = "") -> str:
    """Fixed-width Table 1."""
    cells = [HEADER, *_cells(rows)]
    w = [max(len(c[i]) for c in cells) for i in range(len(HEADER))]
    lines = [title] if title else []
    for k, c in enumerate(cells):
        lines.append("  ".join(x.ljust(w[i]) for i, x in enumerate(c)).rstrip())
        if k == 0:
            lines.append("  ".join("-" * x for x in w))
    return "\n".join(lines)


def format_markdown(rows: list[dict[str, Any]], title: str = "") -> str:
    lines = [f"**{title}**", ""] if title else []
    lines += ["| " + " | ".join(HEADER) + " |", "|" + "|".join(["---"] * 2 + ["---:"] * (len(HEADER) - 2)) + "|"]
    lines += ["| " + " | ".join(c) + " |" for c in _cells(rows)]
    return "\n".join(lines) + "\n"


def format_csv(rows: list[dict[str, Any]]) -> str:
    buf = io.StringIO()
    cols = ["row", "pretraining", "model", "n", "seeds", "rmse_d_mean", "rmse_d_std", "rmse_fa_mean", "rmse_fa_std",
            "paper_rmse_d", "paper_rmse_fa", "run_ids"]
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(cols)
    for r in rows:
        w.writerow([";".join(map(str, r[c])) if isinstance(r[c], list) else ("" if r[c] is None else r[c])
                    for c in cols])
    return buf.getvalue()


def compare(experiment: str | None = None, parent_run_id: str | None = None, out: str | Path | None = "outputs",
            spec: str | Path | None = None, overwrite: bool = False) -> dict[str, Any]:
    """Table 1 of an ablation sweep from the MLflow store.

    Parameters
    ----------
    experiment : MLflow experiment (default: the sweep file's, ``uavturb-ablation``).
    parent_run_id : the sweep's parent run (default: the latest sweep parent of the experiment;
        without one, every finished ablation run of the experiment).
    out : folder for ``table1.md`` and ``table1.csv`` (written atomically; existing ones are replaced
        only with ``overwrite``); None writes nothing.
    spec : sweep file giving the row order and the paper's values (default ``sweeps/ablation.yaml``).

    Returns
    -------
    dict with ``rows`` (see :func:`table_rows`), ``table`` (text), ``markdown_text``,
    ``csv_text``, ``markdown`` and ``csv`` (paths written, or None), ``parent_run_id``,
    ``experiment``.

    Raises
    ------
    InputError : no such experiment or parent run, or no finished ablation run in it.
    """
    if out is not None:  # before any query: existing tables are replaced only with overwrite
        for name in ("table1.md", "table1.csv"):
            check_output_file(Path(out) / name, overwrite=overwrite)
    sp = load_spec(spec if spec is not None else DEFAULT_SPEC)
    experiment = experiment or sp.experiment
    uri = store.tracking_uri()
    exp_id = store.find_experiment(experiment)
    if exp_id is None:
        raise InputError("--mlflow-experiment",
                         f"no MLflow experiment {experiment!r} in {uri} (run `uavturb sweep` first)")
    if parent_run_id is None:
        parent = store.latest_run(exp_id, "tags.sweep_hash LIKE '%' and tags.sweep LIKE '%'")
        parent_run_id = parent.info.run_id if parent else None
    if parent_run_id is not None:
        store.get_run(parent_run_id, "--parent")
        runs = store.child_runs(exp_id, parent_run_id, "FINISHED")
    else:
        runs = store.search_runs([exp_id], "attributes.status = 'FINISHED'")
    runs = [r for r in runs if "ablation" in r.data.tags]
    rows = table_rows(runs, list(sp.rows))
    if not rows:
        raise InputError("--mlflow-experiment", f"no finished ablation run with {', '.join(store.TABLE1_METRICS)} "
                         f"in experiment {experiment!r}" + (f", sweep {parent_run_id}" if parent_run_id else ""))
    title = (f"Table 1: test scenes, mean ± std over seeds (experiment {experiment}"
             + (f", sweep {parent_run_id})" if parent_run_id else ")"))
    res: dict[str, Any] = {"rows": rows, "table": format_text(rows, title),
                           "markdown_text": format_markdown(rows, title), "csv_text": format_csv(rows),
                           "markdown": None, "csv": None,
                           "parent_run_id": parent_run_id, "experiment": experiment}
    if out is not None:
        out = Path(out)
        res["markdown"] = str(write_text_atomic(out / "table1.md", res["markdown_text"], overwrite=overwrite))
        res["csv"] = str(write_text_atomic(out / "table1.csv", res["csv_text"], overwrite=overwrite))
    return res
