"""MLflow tracking, set up once for every kind of run.

The store is MLflow 3's own default: an embedded SQLite ``mlflow.db`` with artifacts under
``mlruns/`` in the working directory; ``MLFLOW_TRACKING_URI`` points elsewhere (a server).

Everyone opens the store through :func:`client`:

- *Creation is safe under concurrency.* Creating (and migrating) a SQLite store runs alembic
  migrations that two processes must not run at once; :func:`client` holds a file lock of the
  store (:func:`uavturb.runs.mutex.store_lock`, in a cache folder) while it opens the store, so
  one process creates it and the others wait. A store that cannot be opened is reported in one line with what to do
  (:class:`StoreError`).
- *Run states tell the truth.* Every run uavturb opens carries the tags ``host``, ``pid`` and
  ``pid_start`` (:func:`uavturb.runs.processes.process_tags`) of the process that keeps it. The first :func:`client` of
  a process marks RUNNING runs whose process on this host is gone (SIGKILL, out of memory) as
  FAILED with a ``stale`` tag (:func:`mark_stale_runs`). Runs of other hosts are left alone.
- A run stopped by a signal is KILLED, by an error FAILED (:func:`close_run`).

MLflow's own conventions, so that its UI fills its columns: experiments are tagged
``mlflow.experimentKind = custom_model_development`` (the UI opens on the runs, not on MLflow 3's
GenAI overview), runs ``mlflow.source.git.commit`` (the Version column), datasets are logged
inputs with their digest (the Dataset column), descriptions are ``mlflow.note.content``. Paths
in tags and params are relative to the working folder where they lie under it
(:func:`project_path`). A run that a command logs again with the same inputs (tag
:data:`KEY_TAG`) is reused rather than duplicated (:func:`find_run`, :func:`log_run`).

This module is the one place that calls MLflow (Lightning's ``MLFlowLogger`` logs training
metrics into the run :func:`uavturb.runs.train.train` opens with :func:`start_run`): runs and their tags, the one
lookup of a run's checkpoint (:func:`run_checkpoint`), searches that page (:func:`search_runs`), one
find-or-create helper (:func:`log_run`) every command uses, one way to close a run
(:func:`close_run`, :func:`closing_run`), and one table of metric names and units
(:data:`METRICS`). The file locks it takes live in a cache folder, never in the working
directory (:func:`uavturb.runs.mutex.lock_folder`). MLflow itself is imported inside the
functions: importing it takes about a second, which commands that log nothing do not pay.
"""

from __future__ import annotations

import contextlib
import functools
import hashlib
import json
import logging
import os
import shutil
import subprocess
import tempfile
import time
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterable, Iterator

import numpy as np

from uavturb.errors import InputError, Interrupted, UavturbError, signals_deferred
from uavturb.runs.mutex import sqlite_path, store_lock
from uavturb.runs.processes import process_alive, process_tags


def whole_write(write: Any) -> Any:
    """A write to the store that SIGTERM or SIGINT does not cut in the middle (:func:`uavturb.errors.signals_deferred`:
    an SQLite transaction cut short leaves the database locked for the write that marks the run KILLED).
    Lightning's ``MLFlowLogger`` writes metrics outside this module: :class:`uavturb.runs.trainer.StageMetricsLogger`
    holds signals over its writes the same way."""
    @functools.wraps(write)
    def wrapped(*args: Any, **kwargs: Any) -> Any:
        with signals_deferred():
            return write(*args, **kwargs)
    return wrapped


class StoreError(UavturbError):
    """The MLflow store cannot be opened (one line naming it and what to do)."""


def tracking_uri() -> str:
    """The configured MLflow store: ``MLFLOW_TRACKING_URI``, else MLflow 3's default ``sqlite:///mlflow.db``."""
    return os.environ.get("MLFLOW_TRACKING_URI", "sqlite:///mlflow.db")


def git_commit() -> str:
    try:
        out = subprocess.run(["git", "rev-parse", "HEAD"], capture_output=True, text=True, timeout=5,
                             cwd=Path(__file__).resolve().parent)
        return out.stdout.strip() or "unknown"
    except (OSError, subprocess.SubprocessError):
        return "unknown"


#: tag ``mlflow.experimentKind``: MLflow 3's UI opens experiments of this kind on their runs table
EXPERIMENT_KIND = "custom_model_development"
#: a run's inputs, hashed: a command run again on the same inputs finds and reuses its run
KEY_TAG = "uavturb.key"
#: the description MLflow's UI shows on a run's page (Markdown)
NOTE_TAG = "mlflow.note.content"
#: tag of a height training run: its model's camera as JSON (:meth:`uavturb.scene.camera.CameraModel.record`),
#: the same as the checkpoint's hyperparameter ``camera``
CAMERA_TAG = "camera"
#: the tag that nests a run under its parent in MLflow's UI
PARENT_TAG = "mlflow.parentRunId"


def quiet_mlflow() -> None:
    """MLflow's and its database's INFO lines off (table creation, experiment creation), and its
    artifact download bars (``\\r`` lines in log files)."""
    os.environ.setdefault("MLFLOW_ENABLE_ARTIFACTS_PROGRESS_BAR", "false")
    for name in ("mlflow", "alembic"):
        logging.getLogger(name).setLevel(logging.ERROR)


def _store_problem(uri: str, e: Exception) -> StoreError:
    first = (str(e).strip().splitlines() or [type(e).__name__])[0]
    if "(Background on this error" in first:
        first = first.split("(Background", 1)[0].strip()
    db = sqlite_path(uri)
    if "_alembic_tmp_" in first and db is not None:
        table = first.split("table ", 1)[-1].split()[0]
        hint = (f"an earlier schema upgrade was interrupted: back up {db}, then run "
                f"`sqlite3 {db} 'DROP TABLE {table}'` and `mlflow db upgrade {uri}`")
    elif "disk is full" in first.lower() or "no space left" in first.lower():
        hint = "the disk is full: free some space and run the command again (the store itself is fine)"
    elif db is not None:
        hint = (f"run `mlflow db upgrade {uri}`; if that fails too, move {db} away and start a new store")
    else:
        hint = "check that the tracking server is up and MLFLOW_TRACKING_URI is right"
    return StoreError(f"MLflow store {uri} cannot be opened ({first}); {hint}")


_OPENED: set[str] = set()


def client():
    """The MLflow client of the configured store (:func:`tracking_uri`), the one way to get one.

    The first call of a process opens (creates, migrates) the store under :func:`store_lock` and
    marks stale runs (:func:`mark_stale_runs`); later calls reuse MLflow's cached store.

    Raises
    ------
    StoreError : the store cannot be opened (one line with what to do).
    """
    import mlflow
    from mlflow.exceptions import MlflowException

    quiet_mlflow()
    uri = tracking_uri()
    if uri in _OPENED:
        return mlflow.MlflowClient(uri)
    try:
        with store_lock(uri):
            c = mlflow.MlflowClient(uri)  # MLflow may create and migrate the store right here
            c.search_experiments(max_results=1)  # or here, lazily
    except StoreError:
        raise
    except (MlflowException, OSError, ImportError) as e:
        raise _store_problem(uri, e) from None
    except Exception as e:  # noqa: BLE001 - SQLAlchemy and alembic errors have no common base
        if type(e).__module__.split(".")[0] in ("sqlalchemy", "alembic", "sqlite3"):
            raise _store_problem(uri, e) from None
        raise
    _OPENED.add(uri)
    mark_stale_runs(c)
    return c


def experiment_id(c: Any, name: str) -> str:
    """The id of experiment ``name``, created if missing (safe when two processes race to create it)
    and tagged :data:`EXPERIMENT_KIND`."""
    from mlflow.exceptions import MlflowException

    exp = c.get_experiment_by_name(name)
    if exp is None:
        with store_lock(tracking_uri()):
            exp = c.get_experiment_by_name(name)
            if exp is None:
                try:
                    c.create_experiment(name)
                except MlflowException:  # created by a server's other client meanwhile
                    pass
                exp = c.get_experiment_by_name(name)
                if exp is None:
                    raise StoreError(f"MLflow store {tracking_uri()}: experiment {name!r} could not be created")
    if exp.tags.get("mlflow.experimentKind") != EXPERIMENT_KIND:
        on_conflict_retry(c.set_experiment_tag, exp.experiment_id, "mlflow.experimentKind", EXPERIMENT_KIND)
    return exp.experiment_id


def run_tags(tags: dict[str, str] | None = None) -> dict[str, str]:
    """Tags of a new run: MLflow's own context tags (user, source), :func:`source_tags`,
    :func:`uavturb.runs.processes.process_tags`, then ``tags``."""
    from mlflow.tracking.context.registry import resolve_tags

    return resolve_tags({**source_tags(), **process_tags(), **(tags or {})})


@whole_write
def claim_run(c: Any, run_id: str) -> None:
    """Mark ``run_id`` RUNNING and kept by this process (resuming a run, or a sweep's parent)."""
    c.update_run(run_id, status="RUNNING")
    for k, v in process_tags().items():
        c.set_tag(run_id, k, v)


#: the note an interrupted training run gets (:func:`close_run`)
TRAIN_RESUME_HINT = "run {run_id} marked {status}; continue it with `uavturb train --resume {run_id}`"


@whole_write
def close_run(c: Any, run_id: str, exc: BaseException | None = None, *, note: str | None = None,
              resume_hint: bool | str = False) -> str:
    """End a run: FINISHED without ``exc``, KILLED for :class:`~uavturb.errors.Interrupted` (and
    KeyboardInterrupt), FAILED for any other error. Returns the status set.

    ``note``: the run's description (:data:`NOTE_TAG`) set first. ``resume_hint``: an
    Interrupted ``exc`` gets the note how to continue the run (True: ``uavturb train --resume``; a text:
    that note, with ``{run_id}`` and ``{status}`` filled in).
    """
    if exc is None:
        status = "FINISHED"
    elif isinstance(exc, (Interrupted, KeyboardInterrupt)):
        status = "KILLED"
    else:
        status = "FAILED"
    if note is not None:
        c.set_tag(run_id, NOTE_TAG, note)
    c.set_terminated(run_id, status)
    if resume_hint and isinstance(exc, Interrupted):
        hint = TRAIN_RESUME_HINT if resume_hint is True else str(resume_hint)
        exc.notes.append(hint.format(run_id=run_id, status=status))
    return status


@contextlib.contextmanager
def closing_run(c: Any, run_id: str, *, resume_hint: bool | str = False) -> Iterator[None]:
    """The block's run closed by :func:`close_run` on an error (and the error raised again), FINISHED
    when the block completes."""
    try:
        yield
    except BaseException as e:
        close_run(c, run_id, e, resume_hint=resume_hint)
        raise
    close_run(c, run_id)


def mark_stale_runs(c: Any) -> list[str]:
    """Mark RUNNING runs whose process on this host has ended (killed, crashed) as FAILED.

    Returns the ids of the runs marked; each gets the tag ``stale`` saying which process
    left it.
    """
    from mlflow.entities import ViewType

    ids = [e.experiment_id for e in c.search_experiments(view_type=ViewType.ALL, max_results=1000)]
    marked = []
    for run in search_runs(ids, "attributes.status = 'RUNNING'") if ids else []:
        if process_alive(run.data.tags) is False:
            t = run.data.tags
            c.set_tag(run.info.run_id, "stale", f"process {t['pid']} on {t['host']} ended without closing the "
                                                "run (killed or crashed)")
            c.set_terminated(run.info.run_id, "FAILED")
            marked.append(run.info.run_id)
    return marked


def source_tags() -> dict[str, str]:
    """``mlflow.source.git.commit`` (when the package runs from a git checkout)."""
    commit = git_commit()
    return {"mlflow.source.git.commit": commit} if commit != "unknown" else {}


def project_path(path: str | Path) -> str:
    """``path`` relative to the working folder where it lies under it, else absolute."""
    p = Path(path).resolve()
    try:
        return str(p.relative_to(Path.cwd().resolve()))
    except ValueError:
        return str(p)


def input_key(**inputs: Any) -> str:
    """A short hash of a run's inputs (the value of :data:`KEY_TAG`)."""
    return hashlib.sha256(json.dumps(inputs, sort_keys=True, default=str).encode()).hexdigest()[:16]


def find_run(mlflow_client, experiment_id: str, key: str, parent_run_id: str | None = None) -> Any | None:
    """The latest live run of an experiment tagged :data:`KEY_TAG` = ``key`` (and child of ``parent_run_id``)."""
    filt = f"tags.`{KEY_TAG}` = '{key}'"
    if parent_run_id is not None:
        filt += f" and tags.`mlflow.parentRunId` = '{parent_run_id}'"
    runs = mlflow_client.search_runs([experiment_id], filter_string=filt, order_by=["attributes.start_time DESC"],
                                     max_results=1)
    return runs[0] if runs else None


#: attempts of a store write that another process's identical write can collide with
CONFLICT_ATTEMPTS = 5


def on_conflict_retry(write: Any, *args: Any, **kwargs: Any) -> Any:
    """``write(*args, **kwargs)``, again when it collides with the same write of another process.

    Writes that insert a row keyed by its content (an experiment tag, a dataset) fail with a
    UNIQUE-constraint error when two processes make them at the same instant (two sweeps saving
    their Table 1 view, two Ray tasks logging one dataset to a server); the second attempt then
    finds the row and updates or links it. Other errors are raised at once.
    """
    from mlflow.exceptions import MlflowException

    for attempt in range(CONFLICT_ATTEMPTS - 1):
        try:
            return write(*args, **kwargs)
        except MlflowException as e:
            if "UNIQUE constraint" not in str(e) and "IntegrityError" not in str(e):
                raise
            time.sleep(0.05 * (attempt + 1))
    return write(*args, **kwargs)  # the last attempt: its error, whatever it is, is the caller's


@whole_write
def log_dataset(mlflow_client, run_id: str, root: str | Path, digest: str, context: str = "training") -> None:
    """The dataset folder as the run's input (name, digest, local source): the UI's Dataset column."""
    from mlflow.entities import Dataset, DatasetInput, InputTag

    root = Path(root)
    dataset = Dataset(name=root.parent.name if root.name == "pairs" else root.name, digest=digest[:36],
                      source_type="local", source=json.dumps({"uri": project_path(root)}))
    on_conflict_retry(mlflow_client.log_inputs, run_id,
                      datasets=[DatasetInput(dataset, [InputTag("mlflow.data.context", context)])])


@whole_write
def log_run(experiment: str | None, *, run_name: str, params: dict[str, Any], metrics: dict[str, float],
            tags: dict[str, str] | None = None, artifacts: Path | None = None, artifact_path: str | None = None,
            parent_run_id: str | None = None, note: str | None = None) -> str:
    """One finished MLflow run with params, metrics, tags and a folder of artifacts; returns its id.

    The one find-or-create helper of the commands that log a result (``gap``, ``evaluate``): a
    run of the same experiment (with ``parent_run_id``: the parent's experiment, the run nested
    under it), name and params already logged is reused (its metrics, tags and artifacts written
    again), so a command run twice on the same inputs keeps one run. Non-finite metrics and
    ``None`` are left out; ``note`` is the run's description (:data:`NOTE_TAG`).
    """
    from mlflow.entities import Metric, Param, RunTag

    c = client()
    exp_id = get_run(parent_run_id).info.experiment_id if parent_run_id else experiment_id(c, experiment)
    params = {k: str(v)[:500] for k, v in params.items()}
    key = input_key(run_name=run_name, params=params, **({"parent": parent_run_id} if parent_run_id else {}))
    previous = find_run(c, exp_id, key, parent_run_id=parent_run_id)
    if previous is not None:
        rid = previous.info.run_id
        claim_run(c, rid)
    else:
        nested = {PARENT_TAG: parent_run_id} if parent_run_id else {}
        rid = c.create_run(exp_id, run_name=run_name, tags=run_tags({KEY_TAG: key, **nested})).info.run_id
    tags = {**(tags or {}), **({NOTE_TAG: note} if note else {})}
    with closing_run(c, rid), warnings.catch_warnings():
        warnings.simplefilter("ignore")
        now = int(time.time() * 1000)
        c.log_batch(rid, params=[] if previous is not None else [Param(k, v) for k, v in params.items()],
                    metrics=[Metric(k, float(v), now, 0) for k, v in metrics.items()
                             if v is not None and np.isfinite(v)],
                    tags=[RunTag(k, str(v)) for k, v in tags.items()])
        if artifacts is not None:
            c.log_artifacts(rid, str(artifacts), artifact_path)
    return rid


#: MLflow UI's saved views: an experiment tag with this prefix holds a view of the runs table
VIEW_TAG_PREFIX = "mlflow.sharedViewState."


@whole_write
def save_view(experiment_id: str, key: str, name: str, *, search_filter: str,
              columns: list[str], order_by: str | None = None, ascending: bool = True) -> str:
    """A saved view of the experiment's runs table (the UI's "Views" menu); returns its URL fragment.

    Parameters
    ----------
    key : the view's share key (letters, digits, ``-``, ``_``)
    name : the view's name in the UI
    search_filter : MLflow search syntax; a filter also lists nested runs flat, not under their parent
    columns : columns shown, in MLflow's canonical form (``metrics.`test/rmse_d```, ``tags.`seed```)
    order_by : a column to sort by (canonical form)

    Returns
    -------
    ``#/experiments/<id>/runs?workflowType=machine_learning&viewStateShareKey=<key>``: append it to
    the UI's address. ``workflowType`` opens the model-training pages: MLflow 3.17's UI decides
    between its GenAI and model-training pages by a switch of its own (stored in the browser), not
    by the experiment's ``mlflow.experimentKind``, so a fresh browser opens on the GenAI overview.
    """
    state = {"searchFilter": search_filter, "orderByKey": order_by or "attributes.start_time",
             "orderByAsc": ascending if order_by else False, "startTime": "ALL", "lifecycleFilter": "Active",
             "modelVersionFilter": "All Runs", "datasetsFilter": [], "selectedColumns": list(columns),
             "runsExpanded": {}, "runsPinned": [], "runsHidden": [], "viewMaximized": False, "runListHidden": False}
    now = int(time.time() * 1000)
    envelope = {"name": name, "createdAt": now, "updatedAt": now, "state": json.dumps(state)}
    on_conflict_retry(client().set_experiment_tag, experiment_id, VIEW_TAG_PREFIX + key, json.dumps(envelope))
    return f"#/experiments/{experiment_id}/runs?workflowType=machine_learning&viewStateShareKey={key}"


def ui_url(fragment: str) -> str:
    """The address of a UI page of :func:`save_view` on ``mlflow ui``'s default port (``make ui``)."""
    return f"http://127.0.0.1:5000/{fragment}"


# --- metric names and units: the one table every module reads ------------------------------


@dataclass(frozen=True)
class MetricSpec:
    """A metric as logged to MLflow: its name, unit and meaning."""

    name: str
    unit: str
    meaning: str


#: RMSE(f_a) is logged in N and, under :data:`FA_SCALED_SUFFIX`, in the 1e-4 N of the paper's
#: Table 1 (N values of ~5e-4 read 0.001 in a three-decimal column)
FA_SCALE, FA_SCALED_SUFFIX = 1e4, "_1e-4N"
#: the metrics of Table 1 (``uavturb compare``) and of a sweep's finished run
RMSE_D, RMSE_FA = "test/rmse_d", "test/rmse_fa"
RMSE_FA_SCALED = RMSE_FA + FA_SCALED_SUFFIX
TABLE1_METRICS = (RMSE_D, RMSE_FA)
#: the checkpoint monitor of the height stage and of pre-training
HEIGHT_MONITOR, PRETRAIN_MONITOR = "val/rmse_d", "val/loss"
#: the exported model's largest difference to the Lightning module
EXPORT_DIFF = "export/max_abs_diff"
#: prefix of Table 2's Total figures in an evaluation's child run (``eval/rmse_fa`` ...)
EVAL_PREFIX = "eval/"
#: the registry alias :data:`BEST_ALIAS` follows the version whose run has the lowest of this
BEST_ALIAS, BEST_METRIC = "best", RMSE_D

METRICS: dict[str, MetricSpec] = {m.name: m for m in (
    MetricSpec(RMSE_D, "m", "height RMSE on the test scenes (Table 1)"),
    MetricSpec(RMSE_FA, "N", "RMSE of f_a from the predicted heights on the test scenes (Table 1)"),
    MetricSpec(RMSE_FA_SCALED, "1e-4 N", f"{RMSE_FA} x {FA_SCALE:g}: the unit of the paper's Table 1"),
    MetricSpec("test/loss", "-", "test loss of the stage"),
    MetricSpec(HEIGHT_MONITOR, "m", "validation height RMSE: the height stage's checkpoint monitor"),
    MetricSpec(PRETRAIN_MONITOR, "-", "validation transcoder loss: pre-training's checkpoint monitor"),
    MetricSpec("pretrain/test/loss", "-", "pre-training's test loss (the transcoder's, not a height loss)"),
    MetricSpec(EXPORT_DIFF, "m and N", "largest difference of the exported model to the Lightning module"),
    MetricSpec(EVAL_PREFIX + "rmse_fa", "N", "Table 2 Total: the law on the network's heights vs ground truth"),
    MetricSpec(EVAL_PREFIX + "rmse_fa_phi", "N", "Table 2 Total: the law on true heights vs ground truth"),
    MetricSpec(EVAL_PREFIX + "rmse_d", "m", "Table 2 Total: height RMSE in the ground-effect region"),
    MetricSpec("gap/baseline_heldout_rmse_N", "N", "gap finder: held-out RMSE of the nominal model"),
    MetricSpec("gap/final_heldout_rmse_N", "N", "gap finder: held-out RMSE with the effects found"),
    MetricSpec("gap/n_effects", "-", "gap finder: effects found"),
)}


def with_scaled_fa(metrics: dict[str, float]) -> dict[str, float]:
    """``metrics`` and every ``*rmse_fa`` [N] also as ``*rmse_fa_1e-4N`` (:data:`FA_SCALE`)."""
    out = dict(metrics)
    for k, v in metrics.items():
        if k.endswith("rmse_fa"):
            out[k + FA_SCALED_SUFFIX] = v * FA_SCALE
    return out


# --- runs: look-up, search, start, artifacts ---------------------------------------------


def get_run(run_id: str, option: str = "--run") -> Any:
    """The MLflow run ``run_id`` of the configured store; InputError naming ``option`` if absent."""
    from mlflow.exceptions import MlflowException

    try:
        return client().get_run(run_id)
    except MlflowException:
        raise InputError(option, f"no run '{run_id}' in the MLflow store {tracking_uri()}") from None


def ensure_experiment(name: str) -> str:
    """The id of experiment ``name``, created if missing (:func:`experiment_id`)."""
    return experiment_id(client(), name)


def find_experiment(name: str) -> str | None:
    """The id of experiment ``name``, None if the store has none of that name."""
    exp = client().get_experiment_by_name(name)
    return None if exp is None else exp.experiment_id


def create_experiment(name: str, artifact_location: str | None = None) -> str:
    """A new experiment (artifacts at ``artifact_location``); its id."""
    return client().create_experiment(name, artifact_location=artifact_location)


def search_runs(experiment_ids: Iterable[str], filter_string: str = "", order_by: list[str] | None = None,
                max_results: int | None = None) -> list[Any]:
    """Every run of the experiments matching ``filter_string`` (all of them: MLflow's own paging,
    ``mlflow.search_runs(..., output_format="list")``), or the first ``max_results``."""
    import mlflow

    client()  # the store opened (created, migrated) under its lock first
    mlflow.set_tracking_uri(tracking_uri())
    kwargs = {} if max_results is None else {"max_results": max_results}
    return mlflow.search_runs(experiment_ids=list(experiment_ids), filter_string=filter_string,
                              order_by=order_by, output_format="list", **kwargs)


def child_runs(experiment_id: str, parent_run_id: str, status: str | None = None,
               order_by: list[str] | None = None) -> list[Any]:
    """The runs nested under ``parent_run_id`` (tag :data:`PARENT_TAG`), those of ``status`` if given."""
    filt = f"tags.`{PARENT_TAG}` = '{parent_run_id}'"
    if status is not None:
        filt += f" and attributes.status = '{status}'"
    return search_runs([experiment_id], filt, order_by)


def latest_run(experiment_id: str, filter_string: str) -> Any | None:
    """The latest run of an experiment matching ``filter_string``, or None."""
    runs = search_runs([experiment_id], filter_string, ["attributes.start_time DESC"], max_results=1)
    return runs[0] if runs else None


def start_run(experiment: str, run_name: str, tags: dict[str, str], *, params: dict[str, Any] | None = None,
              texts: dict[str, str] | None = None, dataset: tuple[Path, str, str] | None = None,
              experiment_is_id: bool = False, resume_hint: bool | str = True) -> str:
    """A new RUNNING run kept by this process (:func:`run_tags`) with its params (in batches of 100),
    text artifacts ``{path: text}`` and dataset ``(root, digest, context)`` (:func:`log_dataset`);
    its id. A failure while it is being filled closes it (:func:`close_run`); so does a signal, held until
    the run is written whole (:func:`uavturb.errors.signals_deferred`) and raised here, where the run's id
    is known (raised after the return, it had left the caller without the id: no "continue it with" hint);
    ``resume_hint`` as :func:`close_run`'s."""
    from mlflow.entities import Param

    c = client()
    run_id = None
    try:
        with signals_deferred():
            exp_id = experiment if experiment_is_id else experiment_id(c, experiment)
            run_id = c.create_run(exp_id, run_name=run_name, tags=run_tags(tags)).info.run_id
            batch = [Param(k, str(v)) for k, v in (params or {}).items()]
            for i in range(0, len(batch), 100):
                c.log_batch(run_id, params=batch[i:i + 100])
            for path, text in (texts or {}).items():
                c.log_text(run_id, text, path)
            if dataset is not None:
                log_dataset(c, run_id, *dataset)
    except BaseException as e:
        if run_id is not None:
            close_run(c, run_id, e, resume_hint=resume_hint)
        raise
    return run_id


def reopen_run(run_id: str, tags: dict[str, str] | None = None, *, resume_hint: bool | str = True) -> None:
    """Mark ``run_id`` RUNNING and kept by this process again (:func:`claim_run`), with ``tags`` set; a signal
    held over these writes ends the run KILLED here, with ``resume_hint`` (as :func:`start_run`)."""
    c = client()
    try:
        with signals_deferred():
            claim_run(c, run_id)
            for k, v in (tags or {}).items():
                c.set_tag(run_id, k, str(v))
    except Interrupted as e:
        close_run(c, run_id, e, resume_hint=resume_hint)
        raise


@whole_write
def set_tags(run_id: str, tags: dict[str, str]) -> None:
    """Tags of a run, set (or replaced)."""
    c = client()
    for k, v in tags.items():
        c.set_tag(run_id, k, str(v))


@whole_write
def log_params(run_id: str, params: dict[str, Any]) -> None:
    """Params of a run."""
    c = client()
    for k, v in params.items():
        c.log_param(run_id, k, v)


@whole_write
def finish_run(run_id: str, exc: BaseException | None = None, *, note: str | None = None,
               resume_hint: bool | str = False) -> str:
    """:func:`close_run` on the configured store: the run's end, with its description ``note``."""
    return close_run(client(), run_id, exc, note=note, resume_hint=resume_hint)


@whole_write
def log_texts(run_id: str, texts: dict[str, str]) -> None:
    """Text artifacts ``{path: text}`` of a run."""
    c = client()
    for path, text in texts.items():
        c.log_text(run_id, text, path)


def download_artifact(run_id: str, path: str, dst: str | Path) -> Path:
    """The artifact ``path`` of a run downloaded into ``dst``; its local path."""
    return Path(client().download_artifacts(run_id, path, str(dst)))


@whole_write
def log_figure(run_id: str, figure: Any, path: str) -> None:
    """A matplotlib figure as the run's artifact ``path`` (``plots/test_heights.png``)."""
    client().log_figure(run_id, figure, path)


@whole_write
def record_failure(experiment: str, tags: dict[str, str], since_ms: int, error: BaseException, message: str,
                   traceback_text: str, run_name: str | None) -> None:
    """Leave the runs tagged ``tags`` and started since ``since_ms`` FAILED (KILLED when interrupted),
    never RUNNING, with the tag ``error`` (``message``) and the artifact ``error.txt``; without
    one (the attempt failed before its run was opened) a FAILED run is created, so that the
    failure shows in the MLflow UI."""
    status = "KILLED" if isinstance(error, (Interrupted, KeyboardInterrupt)) else "FAILED"
    exp_id = find_experiment(experiment)
    if exp_id is None:
        return
    c = client()
    match = " and ".join(f"tags.`{k}` = '{v}'" for k, v in tags.items())
    runs = search_runs([exp_id], f"{match} and attributes.start_time >= {since_ms}", max_results=10)
    if not runs and status == "FAILED":
        runs = [c.create_run(exp_id, run_name=run_name, tags=run_tags(tags))]
    for run in runs:
        rid = run.info.run_id
        c.set_tag(rid, "error", message[:4000])
        c.log_text(rid, traceback_text, "error.txt")
        if run.info.status in ("RUNNING", "SCHEDULED"):
            close_run(c, rid, error)


# --- checkpoints ---------------------------------------------------------------------------

#: MLflow artifact path of a run's best checkpoint (the local file: tag ``checkpoint``)
CHECKPOINT_ARTIFACT = "checkpoints/best.ckpt"


def _artifact_ckpts(c: Any, run_id: str, path: str | None = None, depth: int = 0) -> list[str]:
    out = []
    for a in c.list_artifacts(run_id, path):
        if a.is_dir and depth < 4:
            out += _artifact_ckpts(c, run_id, a.path, depth + 1)
        elif a.path.endswith(".ckpt"):
            out.append(a.path)
    return out


def run_checkpoint(run: str | Any, cache_dir: str | Path | None = None, local: str | Path | None = None,
                   option: str = "--run") -> Path:
    """The checkpoint of a training run (its id or the run), wherever the run keeps it: the one lookup.

    Looked up in order: ``local`` (a path the caller knows, e.g. a pre-training's result), the
    run's ``checkpoint`` tag or param, where the file exists; its artifact
    :data:`CHECKPOINT_ARTIFACT` or another ``*.ckpt`` artifact (``best*`` preferred), downloaded
    into ``cache_dir/<run_id>/`` (default: a new temporary folder; a Ray task on another node
    than the training needs a shared store); the folder :func:`uavturb.runs.train.train` writes
    to, ``<trainer.default_root_dir>/checkpoints/<run_id>/``.

    Raises
    ------
    InputError : no such run, or no checkpoint found (naming where it looked, under ``option``).
    """
    run = get_run(run, option) if isinstance(run, str) else run
    run_id = run.info.run_id
    for value in (local, run.data.tags.get("checkpoint"), run.data.params.get("checkpoint")):
        if value and Path(value).is_file():
            return Path(value)
    c = client()
    try:
        arts = _artifact_ckpts(c, run_id)
    except Exception:  # noqa: BLE001 - an artifact store that cannot be listed: the local folder next
        arts = []
    if arts:
        arts.sort(key=lambda p: (p != CHECKPOINT_ARTIFACT, not Path(p).name.startswith("best"), p))
        dst = Path(cache_dir) / run_id if cache_dir is not None else Path(tempfile.mkdtemp(prefix="uavturb-ckpt-"))
        dst.mkdir(parents=True, exist_ok=True)
        return Path(c.download_artifacts(run_id, arts[0], str(dst)))
    folder = Path(run.data.params.get("trainer.default_root_dir", "runs")) / "checkpoints" / run_id
    found = sorted(folder.glob("*.ckpt"), key=lambda p: (not p.name.startswith("best"), -p.stat().st_mtime))
    if found:
        return found[0]
    raise InputError(option, f"run {run_id} has no checkpoint ({f'{local} is not here, ' if local else ''}"
                             f"no 'checkpoint' tag, no .ckpt artifact, nothing in {folder})")


@whole_write
def log_checkpoint(run_id: str, best: str | None) -> None:
    """The best checkpoint as artifact :data:`CHECKPOINT_ARTIFACT`; its local path as tag ``checkpoint``."""
    if not best:
        return
    folder, name = CHECKPOINT_ARTIFACT.rsplit("/", 1)
    c = client()
    c.set_tag(run_id, "checkpoint", project_path(best))
    with tempfile.TemporaryDirectory() as tmp:
        shutil.copyfile(best, Path(tmp) / name)
        c.log_artifact(run_id, str(Path(tmp) / name), folder)


# --- MLflow's system metrics ---------------------------------------------------------------


def start_system_metrics(run_id: str) -> Any:
    """MLflow's system-metrics monitor on the run, started."""
    from mlflow.system_metrics.system_metrics_monitor import SystemMetricsMonitor

    monitor = SystemMetricsMonitor(run_id, tracking_uri=tracking_uri())
    monitor.start()
    return monitor


def finish_system_metrics(monitor: Any, run_id: str) -> None:
    """Stop MLflow's monitor; a run it logged nothing for (shorter than its sampling interval, or its
    thread gave up on a busy store) gets one sample taken now, so the run shows its system
    metrics whatever its length (what was logged is read from the run: the monitor has no
    public count)."""
    monitor.finish()
    if not any(k.startswith("system/") for k in client().get_run(run_id).data.metrics):
        monitor.collect_metrics()
        monitor.publish_metrics(monitor.aggregate_metrics())
        monitor.mlflow_logger.flush()


# --- exported models -----------------------------------------------------------------------


def tensor_signature(inputs: list[tuple[tuple[int, ...], str]], outputs: list[tuple[tuple[int, ...], str]]) -> Any:
    """An MLflow model signature of float32 tensors ``[(shape, name)]`` (-1: any size)."""
    from mlflow.models import ModelSignature
    from mlflow.types import Schema, TensorSpec

    f32 = np.dtype(np.float32)
    return ModelSignature(inputs=Schema([TensorSpec(f32, shape, name) for shape, name in inputs]),
                          outputs=Schema([TensorSpec(f32, shape, name) for shape, name in outputs]))


def _update_best_alias(c: Any, name: str) -> str | None:
    """Point :data:`BEST_ALIAS` at the registered version whose run has the lowest :data:`BEST_METRIC`."""
    scored = []
    for v in c.search_model_versions(f"name = '{name}'"):
        if v.run_id:
            value = c.get_run(v.run_id).data.metrics.get(BEST_METRIC)
            if value is not None and np.isfinite(value):
                scored.append((value, int(v.version)))
    if not scored:
        return None
    best = str(min(scored)[1])
    c.set_registered_model_alias(name, BEST_ALIAS, best)
    return best


@whole_write
def log_onnx_model(run_id: str, onnx_path: Path, *, name: str, key: str, signature: Any,
                   input_example: dict[str, np.ndarray], metadata: dict[str, Any], artifacts: list[Path],
                   artifact_path: str, metrics: dict[str, float], tags: dict[str, str],
                   registered_name: str | None) -> dict[str, Any]:
    """Log an ONNX model to a run as ``name`` (signature, input example, metadata), its other files
    as artifacts under ``artifact_path``, metrics and tags; register it as ``registered_name``
    and move :data:`BEST_ALIAS`. A model of the run with the same ``key`` (tag :data:`KEY_TAG`)
    is reused, a different one replaced.

    Returns ``{"model_uri", "registered_version", "reused"}``.
    """
    import mlflow
    import onnx

    c = client()
    mlflow.set_tracking_uri(tracking_uri())
    exp_id = c.get_run(run_id).info.experiment_id
    previous = mlflow.search_logged_models(experiment_ids=[exp_id], output_format="list",
                                           filter_string=f"source_run_id = '{run_id}' AND name = '{name}'")
    same = [m for m in previous if m.tags.get(KEY_TAG) == key]
    if same:
        versions = c.search_model_versions(f"name = '{registered_name}'") if registered_name else []
        version = next((v.version for v in versions if v.source == same[0].model_uri
                        or v.model_id == same[0].model_id), None)
        return {"model_uri": same[0].model_uri, "registered_version": version, "reused": True}
    for m in previous:  # a different export of this run replaces the one logged before
        c.delete_logged_model(m.model_id)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        with mlflow.start_run(run_id=run_id):
            info = mlflow.onnx.log_model(onnx.load(str(onnx_path)), name=name, signature=signature,
                                         input_example=input_example, metadata=metadata, tags={KEY_TAG: key},
                                         registered_model_name=registered_name)
            for path in artifacts:
                mlflow.log_artifact(str(path), artifact_path=artifact_path)
            for k, v in metrics.items():
                mlflow.log_metric(k, v)
            for k, v in tags.items():
                mlflow.set_tag(k, v)
    if registered_name:
        _update_best_alias(c, registered_name)
    return {"model_uri": info.model_uri, "registered_version": info.registered_model_version, "reused": False}
