"""Ablation sweeps: the paper's Table 1 as one resumable MLflow sweep (``uavturb sweep``).

A sweep file (``sweeps/ablation.yaml``, schema :class:`SweepSpec`) declares the rows (each a
``conf/model`` choice plus overrides), the pre-training variants (each a ``conf/experiment``
bundle) and presets (config overrides for every run, the pre-training runs and the height
runs). :func:`sweep` runs, for each seed ``n = 0 .. N-1``:

1. every pre-training variant the rows need, once (stage ``pretrain``);
2. every row (stage ``height``), its encoder from that seed's pre-training checkpoint.

Tracking: one MLflow parent run per (sweep file, preset, overrides) -- tags ``sweep``,
``sweep_hash``, ``preset`` -- and one nested child per run (tag ``mlflow.parentRunId``):
height runs tagged ``ablation=<row>`` and ``seed=<n>`` with final metrics ``test/rmse_d`` [m],
``test/rmse_fa`` [N] and ``test/rmse_fa_1e-4N``, and the pre-training run they start from as tag
``pretrain_run_id``; pre-training runs tagged ``pretrain=<variant>`` and ``seed=<n>``. Every run
has a description (MLflow's ``mlflow.note.content``).

At the end the parent gets Table 1 as its description and as artifacts (``table1.md``,
``table1.csv``), and the sweep file as resolved (``sweep.yaml``). The table's means stay off the
parent's metrics: MLflow's run table then compares the children's metrics alone.

Resuming: the same command finds its parent by ``sweep_hash`` (the seed count is not part of
it, so more seeds extend a sweep) and skips every child already FINISHED with its metrics;
a finished pre-training run is reused through its checkpoint (local file, else downloaded
from the run's artifact ``checkpoints/best.ckpt``).
"""

from __future__ import annotations

import contextlib
import copy
import json
import sys
import time
from pathlib import Path
from typing import Any, Iterator

from omegaconf import DictConfig, OmegaConf

from uavturb.errors import InputError, Interrupted
from uavturb.experiments.config import load_config
from uavturb.experiments.executors import PRETRAIN_RUN, Job, make_executor
from uavturb.experiments.sweep_spec import DEFAULT_SPEC, FINAL_METRICS, load_spec, resolve_spec
from uavturb.experiments.tracking import NOTE_TAG, ui_url
from uavturb.experiments.train import CHECKPOINT_ARTIFACT, quiet_lightning, train


def _spec_name(path: Path) -> str:
    """The sweep file as logged: a shipped sweep by its name, another file relative to the working folder."""
    from uavturb.experiments.sweep_spec import SWEEPS_DIR
    from uavturb.experiments.tracking import project_path

    return f"{path.stem} (shipped)" if path.resolve().parent == SWEEPS_DIR.resolve() else project_path(path)


def _spec_hash(spec: DictConfig, preset: str, overrides: list[str]) -> str:
    from uavturb.io.shards import config_hash

    body = OmegaConf.to_container(spec)
    body["presets"] = {preset: {k: v for k, v in body["presets"][preset].items() if k != "seeds"}}
    return config_hash({"spec": body, "preset": preset, "overrides": list(overrides)})


class _Store:
    """The sweep's MLflow experiment: parent run, and children looked up by tags."""

    def __init__(self, experiment: str):
        from uavturb.experiments.tracking import client, experiment_id

        self.client = client()
        self.experiment_id = experiment_id(self.client, experiment)
        self.experiment = experiment

    def parent(self, name: str, sweep_hash: str, preset: str, params: dict[str, Any]) -> tuple[str, bool]:
        """(run id, resumed): the latest parent of this sweep hash, else a new one. Two sweeps started
        together find the same parent (a lock per sweep hash)."""
        from uavturb.experiments.tracking import claim_run, named_lock, run_tags

        with named_lock(f"sweep-{sweep_hash}"):
            runs = self.client.search_runs([self.experiment_id],
                                           filter_string=f"tags.sweep = '{name}' and tags.sweep_hash = '{sweep_hash}'",
                                           order_by=["attributes.start_time DESC"], max_results=1)
            if runs:
                run_id = runs[0].info.run_id
                claim_run(self.client, run_id)
                return run_id, True
            run = self.client.create_run(self.experiment_id, run_name=f"sweep-{name}-{preset}",
                                         tags=run_tags({"sweep": name, "sweep_hash": sweep_hash, "preset": preset,
                                                        NOTE_TAG: f"Sweep `{name}`, preset `{preset}`: running."}))
        for k, v in params.items():
            self.client.log_param(run.info.run_id, k, v)
        return run.info.run_id, False

    def children(self, parent_id: str, status: str | None = None) -> list[Any]:
        """Child runs of a parent (nested through tag ``mlflow.parentRunId``), latest first; only
        those of ``status`` if given."""
        filt = f"tags.`mlflow.parentRunId` = '{parent_id}'"
        if status is not None:
            filt += f" and attributes.status = '{status}'"
        out, token = [], None
        while True:
            page = self.client.search_runs([self.experiment_id], filter_string=filt, max_results=1000,
                                           order_by=["attributes.start_time DESC"], page_token=token)
            out.extend(page)
            token = page.token
            if not token:
                return out

    def finished_children(self, parent_id: str) -> list[Any]:
        return self.children(parent_id, "FINISHED")


def _find(children: list[Any], **tags: str) -> Any | None:
    for run in children:
        if all(run.data.tags.get(k) == v for k, v in tags.items()):
            return run
    return None


@contextlib.contextmanager
def _child_lock(parent_id: str, label: str) -> Iterator[None]:
    """Only one sweep process of this host works on a child at a time; the others wait, then
    find it finished (two identical sweeps started together do not train it twice)."""
    from filelock import Timeout

    from uavturb.experiments.tracking import named_lock

    lock = named_lock(f"child-{parent_id}-{label}")
    try:
        lock.acquire(timeout=0)
    except Timeout:
        _say(f"  {label}: another sweep is working on it; waiting")
        lock.acquire()
    try:
        yield
    finally:
        lock.release()


def _child_state(store: _Store, parent_id: str, done: Any, **tags: str) -> tuple[Any | None, str | None]:
    """(finished run to reuse, id of an interrupted run to resume) of the child with ``tags``.

    A finished run counts where ``done(run)`` holds. A run still RUNNING in a live process of this
    host (a ``uavturb train --resume`` started by hand) is waited for. An interrupted one (KILLED,
    FAILED, or RUNNING whose process is gone) that :func:`uavturb.experiments.train.train` opened is
    resumed in place rather than trained again beside it.
    """
    from uavturb.experiments.tracking import process_alive

    said = False
    while True:
        runs = [r for r in store.children(parent_id) if all(r.data.tags.get(k) == v for k, v in tags.items())]
        for run in runs:
            if run.info.status == "FINISHED" and done(run):
                return run, None
        live = [r for r in runs if r.info.status == "RUNNING" and process_alive(r.data.tags)]
        if not live:
            break
        if not said:
            _say(f"  waiting for run {live[0].info.run_id} (pid {live[0].data.tags.get('pid')}) to end")
            said = True
        time.sleep(5.0)
    for run in runs:  # latest first
        unfinished = run.info.status in ("KILLED", "FAILED") or (
            run.info.status == "RUNNING" and process_alive(run.data.tags) is False)
        if unfinished and "checkpoint_dir" in run.data.tags:
            return None, run.info.run_id
    return None, None


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


def _row_note(row: Any, cfg: DictConfig, seed: int, pretrain_run: str | None) -> str:
    """A child's description: its Table 1 row, seed and the pre-training run it starts from."""
    m = cfg.model
    what = f"Table 1 row `{row.name}` (seed {seed}): {'GRU' if m.use_gru else 'no GRU'}"
    if m.pretraining == "none":
        return f"{what}, encoder trained from scratch."
    return (f"{what}, encoder pre-trained on depth → {m.pretraining} (run `{pretrain_run}`), "
            f"{'fine-tuned from epoch ' + str(m.unfreeze_at_epoch) if m.finetune else 'frozen'}.")


def _say(msg: str) -> None:
    print(msg, file=sys.stderr, flush=True)


def sweep(spec: str | Path = DEFAULT_SPEC, preset: str = "quick", seeds: int | None = None,
          overrides: list[str] | None = None, experiment: str | None = None,
          conf_dir: str | Path | None = None, executor: str = "sequential", address: str | None = None,
          max_retries: int = 1) -> dict[str, Any]:
    """Run (or resume) an ablation sweep.

    Parameters
    ----------
    spec : the sweep file, or a shipped sweep's name (default: the shipped ``ablation``).
    preset : a key of the file's ``presets`` (``quick``, ``paper``).
    seeds : number of seeds ``0 .. seeds-1`` (default: the preset's).
    overrides : ``key=value`` config overrides for every run (after the preset's).
    experiment : MLflow experiment (default: the file's ``experiment``).
    conf_dir : a user's config folder, searched before the shipped one.
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
    from uavturb.experiments.tracking import close_run

    spec_path = resolve_spec(spec)
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
    quiet_lightning()
    sweep_hash = _spec_hash(sp, preset, overrides)
    store = _Store(experiment)
    params = {"sweep_file": _spec_name(spec_path), "preset": preset, "overrides": json.dumps(overrides),
              "rows": json.dumps([r.name for r in rows])}
    parent_id, resumed = store.parent(sp.name, sweep_hash, preset, params)
    store.client.set_tag(parent_id, "seeds", str(n_seeds))
    store.client.log_text(parent_id, OmegaConf.to_yaml(sp), "sweep.yaml")
    children = store.finished_children(parent_id)
    _say(f"sweep {sp.name} ({preset}, {n_seeds} seed(s), {len(rows)} rows): MLflow experiment {experiment!r}, "
         f"parent run {parent_id}{' (resumed)' if resumed else ''}")

    def has_metrics(run: Any) -> bool:
        return all(k in run.data.metrics for k in FINAL_METRICS)

    def finished_row(row: Any, seed: int) -> Any | None:
        run = _find(children, ablation=row.name, seed=str(seed))
        return run if run is not None and has_metrics(run) else None

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
        shown = "  ".join(f"{k} {metrics[k]:.4g}" for k in ("test/rmse_d", "test/rmse_fa_1e-4N", "test/loss")
                          if k in metrics)
        took = "already done" if reused else f"{dt:.0f} s"
        eta = f"  (sweep ETA {t_run / n_run * (total - done):.0f} s)" if n_run and done < total else ""
        _say(f"[{done}/{total}] {label}: {took}  {shown}{eta}")

    jobs: list[tuple[dict[str, Any], Job]] = []  # (result row to fill, its job) of the runs trained now

    def job(label: str, cfg: DictConfig, tags: dict[str, str], resume: str | None, encoder: Any = None) -> Job:
        def start() -> None:
            _say(f"[{done + 1}/{total}] {label} ..." + (f" (resuming run {resume})" if resume else ""))

        return Job(label, cfg, {"mlflow.parentRunId": parent_id, **tags, "sweep_hash": sweep_hash}, encoder,
                   resume=resume, on_start=start, on_done=lambda out, dt: progress(label, False, dt, out["metrics"]))

    try:
        with ex:
            for seed in range(n_seeds):
                for v in todo[seed]:
                    label = f"pretrain {v} seed {seed}"
                    with _child_lock(parent_id, label):
                        found, resume = _child_state(store, parent_id, lambda r: _checkpoint_of(r, cache) is not None,
                                                     pretrain=v, seed=str(seed))
                        if found is not None:
                            pretrain_ckpt[(v, seed)] = {"checkpoint": _checkpoint_of(found, cache),
                                                        "run_id": found.info.run_id}
                            progress(label, True, 0.0, dict(found.data.metrics))
                            continue
                        note = f"Pre-training for Table 1 (seed {seed}): depth encoder, depth → {v} transcoder."
                        pretrain_ckpt[(v, seed)] = ex.submit(train, job(
                            label, for_run(base_pretrain[v], seed, label),
                            {"pretrain": v, "seed": str(seed), NOTE_TAG: note}, resume))
                for row in rows:
                    label = f"{row.name} seed {seed}"
                    with _child_lock(parent_id, label):
                        found, resume = _child_state(store, parent_id, has_metrics, ablation=row.name, seed=str(seed))
                        if found is not None:
                            results.append({"row": row.name, "seed": seed, "run_id": found.info.run_id,
                                            "metrics": dict(found.data.metrics),
                                            "checkpoint": found.data.tags.get("checkpoint"), "reused": True})
                            progress(label, True, 0.0, dict(found.data.metrics))
                            continue
                        cfg = for_run(base_height[row.name], seed, label)
                        encoder = pretrain_ckpt[(variants[row.name], seed)] if variants[row.name] != "none" else None
                        note = _row_note(row, cfg, seed, PRETRAIN_RUN if encoder is not None else None)
                        results.append({"row": row.name, "seed": seed, "reused": False})
                        jobs.append((results[-1], ex.submit(train, job(
                            label, cfg, {"ablation": row.name, "seed": str(seed), NOTE_TAG: note}, resume, encoder))))
            ex.wait()
    except BaseException as e:
        status = close_run(store.client, parent_id, e)
        if isinstance(e, Interrupted):
            e.notes.append(f"sweep parent run {parent_id} marked {status}; run the same command again to resume it")
        raise
    for res, j in jobs:
        res.update(run_id=j.result["run_id"], metrics=j.result["metrics"], checkpoint=j.result["checkpoint"])
    pretrain_ckpt = {k: (v.result if isinstance(v, Job) else v)["checkpoint"] for k, v in pretrain_ckpt.items()}
    table = compare(experiment=experiment, parent_run_id=parent_id, spec=spec_path, out=None)
    store.client.log_text(parent_id, table["markdown_text"], "table1.md")
    store.client.log_text(parent_id, table["csv_text"], "table1.csv")
    store.client.set_tag(parent_id, NOTE_TAG, f"Sweep `{sp.name}`, preset `{preset}`, {n_seeds} seed(s); "
                                              f"one child run per row and seed.\n\n{table['markdown_text']}")
    close_run(store.client, parent_id)
    view = table1_view(store, sp.name, preset, sweep_hash)
    _say(f"Table 1 in the MLflow UI: {ui_url(view)}")
    return {"parent_run_id": parent_id, "experiment": experiment, "resumed": resumed, "runs": results,
            "pretrain": pretrain_ckpt, "table": table["table"], "view": view}


#: the columns of the UI's Table 1 view: the row, the seed, RMSE(d) [m] and RMSE(f_a) [1e-4 N], [N]
TABLE1_COLUMNS = ["tags.`ablation`", "tags.`seed`", "metrics.`test/rmse_d`", "metrics.`test/rmse_fa_1e-4N`",
                  "metrics.`test/rmse_fa`"]


def table1_view(store: _Store, name: str, preset: str, sweep_hash: str) -> str:
    """A saved view of the experiment listing this sweep's Table 1 runs with their test metrics."""
    from uavturb.experiments.tracking import save_view

    return save_view(store.client, store.experiment_id, f"table1-{sweep_hash}", f"Table 1 ({name}, {preset})",
                     search_filter=f"tags.sweep_hash = '{sweep_hash}' and tags.ablation LIKE '%'",
                     columns=TABLE1_COLUMNS, order_by="tags.`ablation`")
