"""Ablation sweeps: the paper's Table 1 as one resumable MLflow sweep (``uavturb sweep``).

A sweep file (``sweeps/ablation.yaml``, schema :class:`SweepSpec`) declares the rows (each a
``conf/model`` choice plus overrides), the pre-training variants (each a ``conf/experiment``
bundle) and presets (config overrides for every run, the pre-training runs and the height
runs). :func:`sweep` runs, for each seed ``n = 0 .. N-1``:

1. every pre-training variant the rows need, once (stage ``pretrain``);
2. every row (stage ``height``), its encoder from that seed's pre-training checkpoint.

Tracking: one MLflow parent run per (sweep file, preset, overrides) -- tags ``sweep``,
``sweep_hash``, ``preset`` -- and one nested child per run (tag ``mlflow.parentRunId``):
height runs tagged ``ablation=<row>`` and ``seed=<n>`` with final metrics ``test/rmse_d`` and
``test/rmse_fa``; pre-training runs tagged ``pretrain=<variant>`` and ``seed=<n>``.

At the end the parent gets Table 1 (artifacts ``table1.md``, ``table1.csv``; metrics
``<row>/test/rmse_d_mean`` etc.) and the sweep file as resolved (``sweep.yaml``).

Resuming: the same command finds its parent by ``sweep_hash`` (the seed count is not part of
it, so more seeds extend a sweep) and skips every child already FINISHED with its metrics;
a finished pre-training run is reused through its checkpoint (local file, else downloaded
from the run's artifact ``checkpoints/best.ckpt``).
"""

from __future__ import annotations

import copy
import json
import logging
import math
import sys
import time
from pathlib import Path
from typing import Any

from omegaconf import DictConfig, OmegaConf

from uavturb.errors import InputError
from uavturb.experiments.config import load_config
from uavturb.experiments.executors import Job, RunsFailed, make_executor
from uavturb.experiments.sweep_spec import DEFAULT_SPEC, FINAL_METRICS, load_spec
from uavturb.experiments.train import CHECKPOINT_ARTIFACT, train


def _spec_hash(spec: DictConfig, preset: str, overrides: list[str]) -> str:
    from uavturb.io.shards import config_hash

    body = OmegaConf.to_container(spec)
    body["presets"] = {preset: {k: v for k, v in body["presets"][preset].items() if k != "seeds"}}
    return config_hash({"spec": body, "preset": preset, "overrides": list(overrides)})


class _Store:
    """The sweep's MLflow experiment: parent run, and finished children looked up by tags."""

    def __init__(self, experiment: str):
        import mlflow

        from uavturb.experiments.tracking import tracking_uri

        for name in ("mlflow", "alembic"):
            logging.getLogger(name).setLevel(logging.ERROR)
        self.client = mlflow.MlflowClient(tracking_uri())
        exp = self.client.get_experiment_by_name(experiment)
        self.experiment_id = exp.experiment_id if exp else self.client.create_experiment(experiment)
        self.experiment = experiment

    def parent(self, name: str, sweep_hash: str, preset: str, params: dict[str, Any]) -> tuple[str, bool]:
        """(run id, resumed): the latest parent of this sweep hash, else a new one."""
        from uavturb.experiments.tracking import git_commit

        runs = self.client.search_runs([self.experiment_id],
                                       filter_string=f"tags.sweep = '{name}' and tags.sweep_hash = '{sweep_hash}'",
                                       order_by=["attributes.start_time DESC"], max_results=1)
        if runs:
            run_id = runs[0].info.run_id
            self.client.update_run(run_id, status="RUNNING")
            return run_id, True
        run = self.client.create_run(self.experiment_id, run_name=f"sweep-{name}-{preset}",
                                     tags={"sweep": name, "sweep_hash": sweep_hash, "preset": preset,
                                           "git_commit": git_commit()})
        for k, v in params.items():
            self.client.log_param(run.info.run_id, k, v)
        return run.info.run_id, False

    def finished_children(self, parent_id: str) -> list[Any]:
        """FINISHED child runs of a parent (nested through tag ``mlflow.parentRunId``)."""
        out, token = [], None
        while True:
            page = self.client.search_runs(
                [self.experiment_id], filter_string=f"tags.`mlflow.parentRunId` = '{parent_id}' and "
                                                    "attributes.status = 'FINISHED'",
                max_results=1000, page_token=token)
            out.extend(page)
            token = page.token
            if not token:
                return out


def _find(children: list[Any], **tags: str) -> Any | None:
    for run in children:
        if all(run.data.tags.get(k) == v for k, v in tags.items()):
            return run
    return None


def _checkpoint_of(run: Any, cache_dir: Path) -> str | None:
    """Local path of a finished run's checkpoint: its tag, else its artifact downloaded."""
    local = run.data.tags.get("checkpoint")
    if local and Path(local).is_file():
        return local
    try:
        import mlflow

        from uavturb.experiments.tracking import tracking_uri

        dst = cache_dir / run.info.run_id
        dst.mkdir(parents=True, exist_ok=True)
        return mlflow.artifacts.download_artifacts(run_id=run.info.run_id, artifact_path=CHECKPOINT_ARTIFACT,
                                                   dst_path=str(dst), tracking_uri=tracking_uri())
    except Exception:  # noqa: BLE001 - gone: train it again
        return None


def _quiet_lightning() -> None:
    """Keep the sweep's own progress lines readable: Lightning's per-run notices off."""
    import warnings

    import lightning  # noqa: F401 - sets its loggers' levels on import; override them after

    for name in ("lightning.pytorch", "lightning.fabric", "lightning"):
        logging.getLogger(name).setLevel(logging.WARNING)
    warnings.filterwarnings("ignore", message=r".*isinstance\(treespec, LeafSpec\).*")


def _say(msg: str) -> None:
    print(msg, file=sys.stderr, flush=True)


def sweep(spec: str | Path = DEFAULT_SPEC, preset: str = "quick", seeds: int | None = None,
          overrides: list[str] | None = None, experiment: str | None = None,
          conf_dir: str | Path | None = None, executor: str = "sequential", address: str | None = None,
          max_retries: int = 1) -> dict[str, Any]:
    """Run (or resume) an ablation sweep.

    Parameters
    ----------
    spec : the sweep file (default ``sweeps/ablation.yaml``).
    preset : a key of the file's ``presets`` (``quick``, ``paper``).
    seeds : number of seeds ``0 .. seeds-1`` (default: the preset's).
    overrides : ``key=value`` config overrides for every run (after the preset's).
    experiment : MLflow experiment (default: the file's ``experiment``).
    conf_dir : the ``conf`` folder (default: the repository's).
    executor : ``sequential`` (one run after another, here) or ``ray`` (Ray tasks;
        :mod:`uavturb.experiments.executors`).
    address : the Ray cluster (``--executor ray``; default: a local Ray instance).
    max_retries : extra attempts of a run that fails.

    Returns
    -------
    dict with ``parent_run_id``, ``experiment``, ``resumed`` (bool), ``runs`` (one dict per
    row and seed: ``row``, ``seed``, ``run_id``, ``metrics``, ``checkpoint``, ``reused``),
    ``pretrain`` (``{(variant, seed): checkpoint}``), ``table`` (Table 1 as text, from
    :func:`uavturb.compare.compare`).

    Raises
    ------
    InputError : bad sweep file, unknown preset, bad override (before anything runs).
    RunsFailed : some runs failed after their retries (the parent run is then FAILED).
    """
    from uavturb.experiments.compare import compare

    spec_path = Path(spec)
    sp = load_spec(spec_path)
    if preset not in sp.presets:
        raise InputError("--preset", f"no preset {preset!r} in {spec_path}; choices: {', '.join(sp.presets)}")
    pre = sp.presets[preset]
    n_seeds = int(seeds if seeds is not None else pre.seeds)
    if n_seeds < 1:
        raise InputError("--seeds", f"must be at least 1, got {n_seeds}")
    overrides = list(overrides or [])
    experiment = experiment or sp.experiment

    # resolve every config first: a typo fails before anything runs
    rows = list(sp.rows)
    base_height = {r.name: load_config([f"model={r.model}", *pre.overrides, *pre.height, *r.overrides, *overrides],
                                       conf_dir=conf_dir) for r in rows}
    variants = {name: str(cfg.model.pretraining) for name, cfg in base_height.items()}
    needed = sorted({v for v in variants.values() if v != "none"})
    base_pretrain = {}
    for v in needed:
        if v not in sp.pretraining:
            raise InputError(f"{spec_path}: pretraining", f"no bundle for model.pretraining={v}; "
                             f"has {', '.join(sp.pretraining) or 'none'}")
        base_pretrain[v] = load_config([*pre.overrides, *pre.pretrain, *overrides], experiment=sp.pretraining[v],
                                       conf_dir=conf_dir)
        base_pretrain[v].model.pretraining = v

    def for_run(base: DictConfig, seed: int, run_name: str) -> DictConfig:
        cfg = copy.deepcopy(base)
        cfg.trainer.seed, cfg.tracking.experiment, cfg.tracking.enabled = seed, experiment, True
        cfg.tracking.run_name = run_name
        return cfg

    ex = make_executor(executor, address=address, max_retries=max_retries)
    for cfg in [*base_pretrain.values(), *base_height.values()]:
        ex.check(cfg)  # e.g. the GPUs Ray is to reserve
    _quiet_lightning()
    sweep_hash = _spec_hash(sp, preset, overrides)
    store = _Store(experiment)
    params = {"sweep_file": str(spec_path), "preset": preset, "overrides": json.dumps(overrides),
              "rows": json.dumps([r.name for r in rows])}
    parent_id, resumed = store.parent(sp.name, sweep_hash, preset, params)
    store.client.set_tag(parent_id, "seeds", str(n_seeds))
    store.client.log_text(parent_id, OmegaConf.to_yaml(sp), "sweep.yaml")
    children = store.finished_children(parent_id)
    _say(f"sweep {sp.name} ({preset}, {n_seeds} seed(s), {len(rows)} rows): MLflow experiment {experiment!r}, "
         f"parent run {parent_id}{' (resumed)' if resumed else ''}")

    def finished_row(row: Any, seed: int) -> Any | None:
        run = _find(children, ablation=row.name, seed=str(seed))
        return run if run is not None and all(k in run.data.metrics for k in FINAL_METRICS) else None

    # per seed, the pre-training variants the unfinished rows still need
    todo = {seed: sorted({variants[r.name] for r in rows if finished_row(r, seed) is None} - {"none"})
            for seed in range(n_seeds)}
    total = sum(len(v) for v in todo.values()) + len(rows) * n_seeds
    done, t_run, n_run = 0, 0.0, 0
    results: list[dict[str, Any]] = []
    pretrain_ckpt: dict[tuple[str, int], Any] = {}  # a Job, or a finished run's checkpoint and run id
    cache = Path(next(iter(base_height.values())).trainer.default_root_dir) / "checkpoints" / "downloaded"

    def progress(label: str, reused: bool, dt: float, metrics: dict[str, float]) -> None:
        nonlocal done, t_run, n_run
        done += 1
        if not reused:
            t_run, n_run = t_run + dt, n_run + 1
        shown = "  ".join(f"{k} {metrics[k]:.4g}" for k in (*FINAL_METRICS, "test/loss") if k in metrics)
        took = "already done" if reused else f"{dt:.0f} s"
        eta = f"  (sweep ETA {t_run / n_run * (total - done):.0f} s)" if n_run and done < total else ""
        _say(f"[{done}/{total}] {label}: {took}  {shown}{eta}")

    jobs: list[tuple[dict[str, Any], Job]] = []  # (result row to fill, its job) of the runs trained now

    def job(label: str, cfg: DictConfig, tags: dict[str, str], encoder: Any = None) -> Job:
        return Job(label, cfg, {"mlflow.parentRunId": parent_id, **tags, "sweep_hash": sweep_hash}, encoder,
                   on_start=lambda: _say(f"[{done + 1}/{total}] {label} ..."),
                   on_done=lambda out, dt: progress(label, False, dt, out["metrics"]))

    try:
        with ex:
            for seed in range(n_seeds):
                for v in todo[seed]:
                    label = f"pretrain {v} seed {seed}"
                    found = _find(children, pretrain=v, seed=str(seed))
                    ckpt = _checkpoint_of(found, cache) if found is not None else None
                    if ckpt is not None:
                        pretrain_ckpt[(v, seed)] = {"checkpoint": ckpt, "run_id": found.info.run_id}
                        progress(label, True, 0.0, dict(found.data.metrics))
                        continue
                    pretrain_ckpt[(v, seed)] = ex.submit(train, job(label, for_run(base_pretrain[v], seed, label),
                                                                    {"pretrain": v, "seed": str(seed)}))
                for row in rows:
                    label = f"{row.name} seed {seed}"
                    found = finished_row(row, seed)
                    if found is not None:
                        results.append({"row": row.name, "seed": seed, "run_id": found.info.run_id,
                                        "metrics": dict(found.data.metrics),
                                        "checkpoint": found.data.tags.get("checkpoint"), "reused": True})
                        progress(label, True, 0.0, dict(found.data.metrics))
                        continue
                    encoder = pretrain_ckpt[(variants[row.name], seed)] if variants[row.name] != "none" else None
                    results.append({"row": row.name, "seed": seed, "reused": False})
                    jobs.append((results[-1], ex.submit(train, job(label, for_run(base_height[row.name], seed, label),
                                                                   {"ablation": row.name, "seed": str(seed)},
                                                                   encoder))))
            ex.wait()
    except BaseException as e:
        store.client.set_terminated(parent_id, status="FAILED" if isinstance(e, RunsFailed) else "KILLED")
        raise
    for res, j in jobs:
        res.update(run_id=j.result["run_id"], metrics=j.result["metrics"], checkpoint=j.result["checkpoint"])
    pretrain_ckpt = {k: (v.result if isinstance(v, Job) else v)["checkpoint"] for k, v in pretrain_ckpt.items()}
    table = compare(experiment=experiment, parent_run_id=parent_id, spec=spec_path, out=None)
    store.client.log_text(parent_id, table["markdown_text"], "table1.md")
    store.client.log_text(parent_id, table["csv_text"], "table1.csv")
    for r in table["rows"]:  # the table on the parent too, for the MLflow UI's run comparison
        for key in ("rmse_d_mean", "rmse_d_std", "rmse_fa_mean", "rmse_fa_std"):
            if not math.isnan(r[key]):
                store.client.log_metric(parent_id, f"{r['row']}/test/{key}", r[key])
    store.client.set_terminated(parent_id, status="FINISHED")
    return {"parent_run_id": parent_id, "experiment": experiment, "resumed": resumed, "runs": results,
            "pretrain": pretrain_ckpt, "table": table["table"]}
