"""Ablation sweeps: the paper's Table 1 as one resumable MLflow sweep (``uavturb sweep``).

A sweep file (``sweeps/ablation.yaml``, schema :class:`SweepSpec`) declares the rows (each a
``conf/model`` choice plus overrides), the pre-training variants (each a ``conf/experiment``
bundle) and profiles (config overrides for every run, the pre-training runs and the height
runs). :func:`sweep` runs, for each seed ``n = 0 .. N-1``:

1. every pre-training variant the rows need, once (stage ``pretrain``);
2. every row (stage ``height``), its encoder from that seed's pre-training checkpoint.

Tracking: one MLflow parent run per (sweep file, profile, overrides) -- tags ``sweep``,
``sweep_hash``, ``preset`` (the profile's name: the tag and the parent's param keep the name they had
before profiles were called so, for the stores that exist) -- and one nested child per run (tag ``mlflow.parentRunId``):
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
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterator

from filelock import Timeout
from omegaconf import DictConfig, OmegaConf

from uavturb.errors import InputError, Interrupted
from uavturb.io.shards import config_hash, dataset_hash
from uavturb.runs import store
from uavturb.runs.config import DEFAULT_SPEC, SWEEPS_DIR, load_config, load_spec, resolve_spec
from uavturb.runs.executors import PRETRAIN_RUN, Job, make_executor
from uavturb.runs.mutex import named_lock
from uavturb.runs.processes import process_alive
from uavturb.runs.table1 import compare
from uavturb.runs.train import quiet_lightning, train
from uavturb.runs.training_data import stage_data_root


def _spec_name(path: Path) -> str:
    """The sweep file as logged: a shipped sweep by its name, another file relative to the working folder."""
    return f"{path.stem} (shipped)" if path.resolve().parent == SWEEPS_DIR.resolve() else store.project_path(path)


def _spec_hash(spec: DictConfig, profile: str, overrides: list[str]) -> str:
    body = OmegaConf.to_container(spec)
    # hashed under the keys' names before profiles were called so: a sweep's hash (its resumption) is unchanged
    body["presets"] = {profile: {k: v for k, v in body.pop("profiles")[profile].items() if k != "seeds"}}
    return config_hash({"spec": body, "preset": profile, "overrides": list(overrides)})


#: parent-run tag naming the training data a sweep's runs were trained on (:func:`_data_key`)
DATA_TAG = "data_key"


#: the note an interrupted sweep gets (:func:`uavturb.runs.store.close_run`)
SWEEP_RESUME_HINT = "sweep parent run {run_id} marked {status}; run the same command again to resume it"


class _SweepRuns:
    """The sweep's MLflow experiment: parent run, and children looked up by tags (:mod:`uavturb.runs.store`)."""

    def __init__(self, experiment: str):
        self.experiment_id = store.ensure_experiment(experiment)
        self.experiment = experiment

    def parent(self, name: str, sweep_hash: str, profile: str, params: dict[str, Any], data_key: str = ""
               ) -> tuple[str, bool]:
        """(run id, resumed): the latest parent of this sweep hash trained on the same data, else a new
        one. Two sweeps started together find the same parent (a lock per sweep hash).

        ``data_key`` (:func:`_data_key`) names the training data as it is now; a parent whose data differ
        is not resumed (its finished runs would be reused, and Table 1 computed from models of other
        data: a store kept across ``make demo`` builds did so). A parent that names no data (its sweep
        made its own synthetic data, or an older store) is resumed, and takes the data's name."""
        with named_lock(f"sweep-{sweep_hash}", store.tracking_uri()):
            run = store.latest_run(self.experiment_id, f"tags.sweep = '{name}' and tags.sweep_hash = '{sweep_hash}'")
            known = run.data.tags.get(DATA_TAG, "") if run is not None else ""
            if run is not None and (not known or not data_key or known == data_key):
                store.reopen_run(run.info.run_id, resume_hint=SWEEP_RESUME_HINT)
                if data_key and not known:
                    store.set_tags(run.info.run_id, {DATA_TAG: data_key})
                return run.info.run_id, True
            if run is not None:
                _say(f"sweep {name}: the training data changed since parent run {run.info.run_id} (data {known}, "
                     f"now {data_key}): a new parent run, every row trained again")
            tags = {"sweep": name, "sweep_hash": sweep_hash, "preset": profile,  # its old name: existing stores
                    DATA_TAG: data_key, store.NOTE_TAG: f"Sweep `{name}`, profile `{profile}`: running."}
            return store.start_run(self.experiment_id, f"sweep-{name}-{profile}", tags, params=params,
                                   experiment_is_id=True, resume_hint=SWEEP_RESUME_HINT), False

    def children(self, parent_id: str, status: str | None = None) -> list[Any]:
        """Child runs of a parent (nested through tag ``mlflow.parentRunId``), latest first; only
        those of ``status`` if given."""
        return store.child_runs(self.experiment_id, parent_id, status, ["attributes.start_time DESC"])

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
    lock = named_lock(f"child-{parent_id}-{label}", store.tracking_uri())
    try:
        lock.acquire(timeout=0)
    except Timeout:
        _say(f"  {label}: another sweep is working on it; waiting")
        lock.acquire()
    try:
        yield
    finally:
        lock.release()


def _child_state(runs_of: _SweepRuns, parent_id: str, done: Any, **tags: str) -> tuple[Any | None, str | None]:
    """(finished run to reuse, id of an interrupted run to resume) of the child with ``tags``.

    A finished run counts where ``done(run)`` holds. A run still RUNNING in a live process of this
    host (a ``uavturb train --resume`` started by hand) is waited for. An interrupted one (KILLED,
    FAILED, or RUNNING whose process is gone) that :func:`uavturb.runs.train.train` opened is
    resumed in place rather than trained again beside it.
    """
    said = False
    while True:
        runs = [r for r in runs_of.children(parent_id) if all(r.data.tags.get(k) == v for k, v in tags.items())]
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
    """Local path of a finished run's checkpoint (:func:`uavturb.runs.store.run_checkpoint`), None
    where it is gone (then it is trained again)."""
    try:
        return str(store.run_checkpoint(run, cache_dir))
    except InputError:
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


@dataclass
class _Plan:
    """A sweep resolved before anything runs: every run's config (a typo fails here)."""

    spec_path: Path
    spec: DictConfig
    profile: str
    seeds: int
    overrides: list[str]
    experiment: str
    rows: list[Any]
    base_height: dict[str, DictConfig]  # row name -> its height config
    variants: dict[str, str]  # row name -> its model.pretraining ("none": from scratch)
    base_pretrain: dict[str, DictConfig]  # pre-training variant -> its config

    def for_run(self, base: DictConfig, seed: int, run_name: str) -> DictConfig:
        """``base`` as the child ``run_name`` of seed ``seed``: seeded and tracked in the sweep's experiment."""
        cfg = copy.deepcopy(base)
        cfg.trainer.seed, cfg.tracking.experiment, cfg.tracking.enabled = seed, self.experiment, True
        cfg.tracking.run_name = run_name
        return cfg


def _resolve_plan(spec: str | Path, profile: str, seeds: int | None, overrides: list[str] | None,
                  experiment: str | None, conf_dir: str | Path | None) -> _Plan:
    """Read the sweep file and resolve every run's config; raises :class:`InputError` before anything runs."""
    spec_path = resolve_spec(spec)
    sp = load_spec(spec_path)
    if profile not in sp.profiles:
        raise InputError("--profile", f"no profile {profile!r} in {spec_path}; choices: {', '.join(sp.profiles)}")
    pre = sp.profiles[profile]
    n_seeds = int(seeds if seeds is not None else pre.seeds)
    if n_seeds < 1:
        raise InputError("--seeds", f"must be at least 1, got {n_seeds}")
    overrides = list(overrides or [])
    rows = list(sp.rows)
    base_height = {r.name: load_config([f"model={r.model}", *pre.overrides, *pre.height, *r.overrides, *overrides],
                                       conf_dir=conf_dir) for r in rows}
    variants = {name: str(cfg.model.pretraining) for name, cfg in base_height.items()}
    base_pretrain = {}
    for v in sorted({v for v in variants.values() if v != "none"}):
        if v not in sp.pretraining:
            raise InputError(f"{spec_path}: pretraining", f"no bundle for model.pretraining={v}; "
                             f"has {', '.join(sp.pretraining) or 'none'}")
        base_pretrain[v] = load_config([*pre.overrides, *pre.pretrain, *overrides], experiment=sp.pretraining[v],
                                       conf_dir=conf_dir)
        base_pretrain[v].model.pretraining = v
    return _Plan(spec_path, sp, profile, n_seeds, overrides, experiment or sp.experiment, rows, base_height,
                 variants, base_pretrain)


def _data_key(plan: _Plan) -> str:
    """The training data the sweep's runs read, as the folders are now: a hash of the existing data
    folders' content hashes (:func:`uavturb.io.shards.dataset_hash`; their paths left out, so a clone
    elsewhere names the same data alike), ``""`` where none exists yet (the runs make their synthetic
    data from their configs)."""
    hashes: dict[str, str] = {}
    for cfg in [*plan.base_pretrain.values(), *plan.base_height.values()]:
        root = stage_data_root(cfg).resolve()
        if str(root) in hashes or not root.is_dir():
            continue
        try:
            hashes[str(root)] = dataset_hash(root)
        except InputError:  # no dataset files yet: the runs write them
            continue
    return config_hash(sorted(hashes.values())) if hashes else ""


def _open_parent(plan: _Plan, runs_of: _SweepRuns, sweep_hash: str) -> tuple[str, bool]:
    """(parent run id, resumed): the sweep's parent run found or created, with its seed count and sweep file."""
    params = {"sweep_file": _spec_name(plan.spec_path), "preset": plan.profile,  # its old name: existing stores
              "overrides": json.dumps(plan.overrides), "rows": json.dumps([r.name for r in plan.rows])}
    parent_id, resumed = runs_of.parent(plan.spec.name, sweep_hash, plan.profile, params, _data_key(plan))
    store.set_tags(parent_id, {"seeds": str(plan.seeds)})
    store.log_texts(parent_id, {"sweep.yaml": OmegaConf.to_yaml(plan.spec)})
    _say(f"sweep {plan.spec.name} ({plan.profile}, {plan.seeds} seed(s), {len(plan.rows)} rows): MLflow experiment "
         f"{plan.experiment!r}, parent run {parent_id}{' (resumed)' if resumed else ''}")
    return parent_id, resumed


def _has_final_metrics(run: Any) -> bool:
    return all(k in run.data.metrics for k in store.TABLE1_METRICS)


class _Progress:
    """``[done/total] label: took  metrics  (sweep ETA)`` lines on stderr, the ETA from the runs trained now."""

    def __init__(self, total: int):
        self.total, self.done, self.t_run, self.n_run = total, 0, 0.0, 0

    def started(self, label: str, resume: str | None) -> None:
        _say(f"[{self.done + 1}/{self.total}] {label} ..." + (f" (resuming run {resume})" if resume else ""))

    def finished(self, label: str, reused: bool, dt: float, metrics: dict[str, float]) -> None:
        self.done += 1
        if not reused:
            self.t_run, self.n_run = self.t_run + dt, self.n_run + 1
        shown = "  ".join(f"{k} {metrics[k]:.4g}" for k in (store.RMSE_D, store.RMSE_FA_SCALED, "test/loss")
                          if k in metrics)
        took = "already done" if reused else f"{dt:.0f} s"
        eta = (f"  (sweep ETA {self.t_run / self.n_run * (self.total - self.done):.0f} s)"
               if self.n_run and self.done < self.total else "")
        _say(f"[{self.done}/{self.total}] {label}: {took}  {shown}{eta}")


class _Children:
    """The sweep's child runs: each reused where finished, else submitted to the executor."""

    def __init__(self, plan: _Plan, runs_of: _SweepRuns, parent_id: str, sweep_hash: str, ex: Any):
        self.plan, self.runs_of, self.parent_id, self.sweep_hash, self.ex = plan, runs_of, parent_id, sweep_hash, ex
        finished = runs_of.finished_children(parent_id)

        def finished_row(row: Any, seed: int) -> bool:
            run = _find(finished, ablation=row.name, seed=str(seed))
            return run is not None and _has_final_metrics(run)

        # per seed, the pre-training variants the unfinished rows still need
        self.todo = {seed: sorted({plan.variants[r.name] for r in plan.rows if not finished_row(r, seed)} - {"none"})
                     for seed in range(plan.seeds)}
        self.progress = _Progress(sum(len(v) for v in self.todo.values()) + len(plan.rows) * plan.seeds)
        self.results: list[dict[str, Any]] = []
        self.pretrain_ckpt: dict[tuple[str, int], Any] = {}  # a Job, or a finished run's checkpoint and run id
        self.jobs: list[tuple[dict[str, Any], Job]] = []  # (result row to fill, its job) of the runs trained now
        self.cache = (Path(next(iter(plan.base_height.values())).trainer.default_root_dir) / "checkpoints"
                      / "downloaded")

    def submit_all(self) -> None:
        """Per seed: the pre-training variants still needed, then every row."""
        for seed in range(self.plan.seeds):
            for v in self.todo[seed]:
                self.pretraining(v, seed)
            for row in self.plan.rows:
                self.height(row, seed)

    def _job(self, label: str, cfg: DictConfig, tags: dict[str, str], resume: str | None,
             encoder: Any = None) -> Job:
        return Job(label, cfg, {store.PARENT_TAG: self.parent_id, **tags, "sweep_hash": self.sweep_hash},
                   encoder, resume=resume, on_start=lambda: self.progress.started(label, resume),
                   on_done=lambda out, dt: self.progress.finished(label, False, dt, out["metrics"]))

    def pretraining(self, v: str, seed: int) -> None:
        """The pre-training run of variant ``v`` and ``seed``: its finished run's checkpoint, or a job."""
        label = f"pretrain {v} seed {seed}"
        with _child_lock(self.parent_id, label):
            found, resume = _child_state(self.runs_of, self.parent_id,
                                         lambda r: _checkpoint_of(r, self.cache) is not None, pretrain=v,
                                         seed=str(seed))
            if found is not None:
                self.pretrain_ckpt[(v, seed)] = {"checkpoint": _checkpoint_of(found, self.cache),
                                                 "run_id": found.info.run_id}
                self.progress.finished(label, True, 0.0, dict(found.data.metrics))
                return
            note = f"Pre-training for Table 1 (seed {seed}): depth encoder, depth → {v} transcoder."
            self.pretrain_ckpt[(v, seed)] = self.ex.submit(train, self._job(
                label, self.plan.for_run(self.plan.base_pretrain[v], seed, label),
                {"pretrain": v, "seed": str(seed), store.NOTE_TAG: note}, resume))

    def height(self, row: Any, seed: int) -> None:
        """The Table 1 run of ``row`` and ``seed``: its finished run's result, or a job."""
        label = f"{row.name} seed {seed}"
        with _child_lock(self.parent_id, label):
            found, resume = _child_state(self.runs_of, self.parent_id, _has_final_metrics, ablation=row.name,
                                         seed=str(seed))
            if found is not None:
                self.results.append({"row": row.name, "seed": seed, "run_id": found.info.run_id,
                                     "metrics": dict(found.data.metrics),
                                     "checkpoint": found.data.tags.get("checkpoint"), "reused": True})
                self.progress.finished(label, True, 0.0, dict(found.data.metrics))
                return
            cfg = self.plan.for_run(self.plan.base_height[row.name], seed, label)
            variant = self.plan.variants[row.name]
            encoder = self.pretrain_ckpt[(variant, seed)] if variant != "none" else None
            note = _row_note(row, cfg, seed, PRETRAIN_RUN if encoder is not None else None)
            self.results.append({"row": row.name, "seed": seed, "reused": False})
            self.jobs.append((self.results[-1], self.ex.submit(train, self._job(
                label, cfg, {"ablation": row.name, "seed": str(seed), store.NOTE_TAG: note}, resume, encoder))))

    def collect(self) -> tuple[list[dict[str, Any]], dict[tuple[str, int], Any]]:
        """(one result a row and seed, ``{(variant, seed): checkpoint}``) once the executor is done."""
        for res, j in self.jobs:
            res.update(run_id=j.result["run_id"], metrics=j.result["metrics"], checkpoint=j.result["checkpoint"])
        pretrain = {k: (v.result if isinstance(v, Job) else v)["checkpoint"] for k, v in self.pretrain_ckpt.items()}
        return self.results, pretrain


def _finish_parent(plan: _Plan, runs_of: _SweepRuns, parent_id: str, sweep_hash: str) -> tuple[dict[str, Any], str]:
    """(Table 1 from :func:`uavturb.runs.table1.compare`, the UI view's id): the table logged to the
    parent run as artifacts and description, the parent closed, the view saved."""
    table = compare(experiment=plan.experiment, parent_run_id=parent_id, spec=plan.spec_path, out=None)
    store.log_texts(parent_id, {"table1.md": table["markdown_text"], "table1.csv": table["csv_text"]})
    store.finish_run(parent_id, note=f"Sweep `{plan.spec.name}`, profile `{plan.profile}`, {plan.seeds} seed(s); one "
                                     f"child run per row and seed.\n\n{table['markdown_text']}")
    view = table1_view(runs_of, plan.spec.name, plan.profile, sweep_hash)
    _say(f"Table 1 in the MLflow UI: {store.ui_url(view)}")
    return table, view


def sweep(spec: str | Path = DEFAULT_SPEC, profile: str = "quick", seeds: int | None = None,
          overrides: list[str] | None = None, experiment: str | None = None,
          conf_dir: str | Path | None = None, executor: str = "sequential", address: str | None = None,
          max_retries: int = 1) -> dict[str, Any]:
    """Run (or resume) an ablation sweep.

    Parameters
    ----------
    spec : the sweep file, or a shipped sweep's name (default: the shipped ``ablation``).
    profile : a key of the file's ``profiles`` (``quick``, ``paper``).
    seeds : number of seeds ``0 .. seeds-1`` (default: the profile's).
    overrides : ``key=value`` config overrides for every run (after the profile's).
    experiment : MLflow experiment (default: the file's ``experiment``).
    conf_dir : a user's config folder, searched before the shipped one.
    executor : ``sequential`` (one run after another, here) or ``ray`` (Ray tasks;
        :mod:`uavturb.runs.executors`).
    address : the Ray cluster (``--executor ray``; default: a local Ray instance).
    max_retries : extra attempts of a run that fails.

    Returns
    -------
    dict with ``parent_run_id``, ``experiment``, ``resumed`` (bool), ``runs`` (one dict per
    row and seed: ``row``, ``seed``, ``run_id``, ``metrics``, ``checkpoint``, ``reused``),
    ``pretrain`` (``{(variant, seed): checkpoint}``), ``table`` (Table 1 as text, from
    :func:`uavturb.runs.table1.compare`).

    Raises
    ------
    InputError : bad sweep file, unknown profile, bad override (before anything runs).
    RunsFailed : some runs failed after their retries (the parent run is then FAILED).
    """
    plan = _resolve_plan(spec, profile, seeds, overrides, experiment, conf_dir)
    ex = make_executor(executor, address=address, max_retries=max_retries)
    for cfg in [*plan.base_pretrain.values(), *plan.base_height.values()]:
        ex.check(cfg)  # e.g. the GPUs Ray is to reserve
    quiet_lightning()
    sweep_hash = _spec_hash(plan.spec, profile, plan.overrides)
    runs_of = _SweepRuns(plan.experiment)
    parent_id, resumed = _open_parent(plan, runs_of, sweep_hash)
    children = _Children(plan, runs_of, parent_id, sweep_hash, ex)
    try:
        with ex:
            children.submit_all()
            ex.wait()
    except BaseException as e:
        status = store.finish_run(parent_id, e)
        if isinstance(e, Interrupted):
            e.notes.append(SWEEP_RESUME_HINT.format(run_id=parent_id, status=status))
        raise
    results, pretrain = children.collect()
    table, view = _finish_parent(plan, runs_of, parent_id, sweep_hash)
    return {"parent_run_id": parent_id, "experiment": plan.experiment, "resumed": resumed, "runs": results,
            "pretrain": pretrain, "table": table["table"], "view": view}


#: the columns of the UI's Table 1 view: the row, the seed, RMSE(d) [m] and RMSE(f_a) [1e-4 N], [N]
TABLE1_COLUMNS = ["tags.`ablation`", "tags.`seed`", f"metrics.`{store.RMSE_D}`", f"metrics.`{store.RMSE_FA_SCALED}`",
                  f"metrics.`{store.RMSE_FA}`"]


def table1_view(runs_of: _SweepRuns, name: str, profile: str, sweep_hash: str) -> str:
    """A saved view of the experiment listing this sweep's Table 1 runs with their test metrics."""
    return store.save_view(runs_of.experiment_id, f"table1-{sweep_hash}", f"Table 1 ({name}, {profile})",
                     search_filter=f"tags.sweep_hash = '{sweep_hash}' and tags.ablation LIKE '%'",
                     columns=TABLE1_COLUMNS, order_by="tags.`ablation`")
