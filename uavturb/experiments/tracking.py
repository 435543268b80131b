"""MLflow tracking, set up once for every kind of run.

The store is MLflow 3's own default: an embedded SQLite ``mlflow.db`` with artifacts under
``mlruns/`` in the working directory; ``MLFLOW_TRACKING_URI`` points elsewhere (a server).

Everyone opens the store through :func:`client`:

- *Creation is safe under concurrency.* Creating (and migrating) a SQLite store runs alembic
  migrations that two processes must not run at once; :func:`client` holds a file lock beside
  the database (``mlflow.db.lock``) while it opens the store, so one process creates it and the
  others wait. A store that cannot be opened is reported in one line with what to do
  (:class:`StoreError`).
- *Run states tell the truth.* Every run uavturb opens carries the tags ``host``, ``pid`` and
  ``pid_start`` (:func:`process_tags`) of the process that keeps it. The first :func:`client` of
  a process marks RUNNING runs whose process on this host is gone (SIGKILL, out of memory) as
  FAILED with a ``stale`` tag (:func:`mark_stale_runs`). Runs of other hosts are left alone.
- A run stopped by a signal is KILLED, by an error FAILED (:func:`close_run`).

MLflow's own conventions, so that its UI fills its columns: experiments are tagged
``mlflow.experimentKind = custom_model_development`` (the UI opens on the runs, not on MLflow 3's
GenAI overview), runs ``mlflow.source.git.commit`` (the Version column), datasets are logged
inputs with their digest (the Dataset column), descriptions are ``mlflow.note.content``. Paths
in tags and params are relative to the working folder where they lie under it
(:func:`project_path`). A run that a command logs again with the same inputs (tag
:data:`KEY_TAG`) is reused rather than duplicated (:func:`find_run`).
"""

from __future__ import annotations

import contextlib
import logging
import os
import socket
import subprocess
from pathlib import Path
from typing import Any, Iterator

from uavturb.errors import Interrupted, UavturbError

#: seconds a process waits for another one creating the store before giving up
LOCK_TIMEOUT_S = 600.0


class StoreError(UavturbError):
    """The MLflow store cannot be opened (one line naming it and what to do)."""


def tracking_uri() -> str:
    return os.environ.get("MLFLOW_TRACKING_URI", "sqlite:///mlflow.db")


def git_commit() -> str:
    try:
        out = subprocess.run(["git", "rev-parse", "HEAD"], capture_output=True, text=True, timeout=5,
                             cwd=Path(__file__).resolve().parent)
        return out.stdout.strip() or "unknown"
    except (OSError, subprocess.SubprocessError):
        return "unknown"


def sqlite_path(uri: str) -> Path | None:
    """The database file of a ``sqlite:///`` URI (relative to the working directory), else None."""
    if not uri.startswith("sqlite:///"):
        return None
    path = uri[len("sqlite:///"):].split("?", 1)[0]
    return Path(path) if path and path != ":memory:" else None


@contextlib.contextmanager
def store_lock(uri: str | None = None) -> Iterator[None]:
    """Exclusive lock on a SQLite store (file ``<db>.lock`` beside it); nothing for other stores."""
    from filelock import FileLock, Timeout

    db = sqlite_path(uri or tracking_uri())
    if db is None:
        yield
        return
    db.parent.mkdir(parents=True, exist_ok=True)
    lock = FileLock(str(db) + ".lock")
    try:
        lock.acquire(timeout=LOCK_TIMEOUT_S)
    except Timeout:
        raise StoreError(f"MLflow store {uri}: another process has held {lock.lock_file} for "
                         f"{LOCK_TIMEOUT_S:.0f} s; if none is running, delete that file") from None
    try:
        yield
    finally:
        lock.release()


def named_lock(name: str):
    """A :class:`filelock.FileLock` named ``name`` for the configured store, shared by the processes of
    this host (a sweep's parent and children): in ``<db>.locks/`` beside a SQLite store, else in a
    per-store folder of the temporary directory."""
    import hashlib
    import tempfile

    from filelock import FileLock

    uri = tracking_uri()
    db = sqlite_path(uri)
    if db is not None:
        folder = Path(str(db) + ".locks")
    else:
        folder = Path(tempfile.gettempdir()) / f"uavturb-mlflow-locks-{hashlib.sha1(uri.encode()).hexdigest()[:12]}"
    folder.mkdir(parents=True, exist_ok=True)
    safe = "".join(c if c.isalnum() or c in "-_." else "_" for c in name)
    return FileLock(str(folder / f"{safe}.lock"))


#: tag ``mlflow.experimentKind``: MLflow 3's UI opens experiments of this kind on their runs table
EXPERIMENT_KIND = "custom_model_development"
#: a run's inputs, hashed: a command run again on the same inputs finds and reuses its run
KEY_TAG = "uavturb.key"
#: the description MLflow's UI shows on a run's page (Markdown)
NOTE_TAG = "mlflow.note.content"
#: tag of a height training run: its model's camera as JSON (:meth:`uavturb.scene.camera.CameraModel.record`),
#: the same as the checkpoint's hyperparameter ``camera``
CAMERA_TAG = "camera"


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
        with store_lock():
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


# --- which process keeps a run -------------------------------------------------------------


def _process_start(pid: int) -> str:
    """Start time of process ``pid`` (clock ticks since boot, Linux), "" where unknown: tells a
    live process from a later one that reuses its pid."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
        return stat.rsplit(")", 1)[1].split()[19]
    except (OSError, IndexError):
        return ""


def process_tags() -> dict[str, str]:
    """Tags ``host``, ``pid`` and ``pid_start`` naming this process as the one keeping a run."""
    pid = os.getpid()
    return {"host": socket.gethostname(), "pid": str(pid), "pid_start": _process_start(pid)}


def process_alive(tags: dict[str, str]) -> bool | None:
    """Whether the process named by a run's :func:`process_tags` still runs: True or False on this
    host, None where that cannot be told (another host, no tags)."""
    if tags.get("host") != socket.gethostname() or not str(tags.get("pid", "")).isdigit():
        return None
    pid = int(tags["pid"])
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        pass  # exists, another user's
    start = tags.get("pid_start", "")
    return not (start and _process_start(pid) and _process_start(pid) != start)


def run_tags(tags: dict[str, str] | None = None) -> dict[str, str]:
    """Tags of a new run: MLflow's own context tags (user, source), :func:`source_tags`,
    :func:`process_tags`, then ``tags``."""
    from mlflow.tracking.context.registry import resolve_tags

    return resolve_tags({**source_tags(), **process_tags(), **(tags or {})})


def claim_run(c: Any, run_id: str) -> None:
    """Mark ``run_id`` RUNNING and kept by this process (resuming a run, or a sweep's parent)."""
    c.update_run(run_id, status="RUNNING")
    for k, v in process_tags().items():
        c.set_tag(run_id, k, v)


def close_run(c: Any, run_id: str, exc: BaseException | None = None) -> str:
    """End a run: FINISHED without ``exc``, KILLED for :class:`~uavturb.errors.Interrupted` (and
    KeyboardInterrupt), FAILED for any other error. Returns the status set."""
    if exc is None:
        status = "FINISHED"
    elif isinstance(exc, (Interrupted, KeyboardInterrupt)):
        status = "KILLED"
    else:
        status = "FAILED"
    c.set_terminated(run_id, status)
    return status


def mark_stale_runs(c: Any) -> list[str]:
    """Mark RUNNING runs whose process on this host has ended (killed, crashed) as FAILED.

    Returns the ids of the runs marked; each gets the tag ``stale`` saying which process
    left it.
    """
    from mlflow.entities import ViewType

    ids = [e.experiment_id for e in c.search_experiments(view_type=ViewType.ALL, max_results=1000)]
    marked, token = [], None
    while ids:
        page = c.search_runs(ids, filter_string="attributes.status = 'RUNNING'", max_results=1000,
                             page_token=token)
        for run in page:
            if process_alive(run.data.tags) is False:
                t = run.data.tags
                c.set_tag(run.info.run_id, "stale", f"process {t['pid']} on {t['host']} ended without closing the "
                                                    "run (killed or crashed)")
                c.set_terminated(run.info.run_id, "FAILED")
                marked.append(run.info.run_id)
        token = page.token
        if not token:
            break
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
    import hashlib
    import json

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
    import time

    from mlflow.exceptions import MlflowException

    for attempt in range(CONFLICT_ATTEMPTS - 1):
        try:
            return write(*args, **kwargs)
        except MlflowException as e:
            if "UNIQUE constraint" not in str(e) and "IntegrityError" not in str(e):
                raise
            time.sleep(0.05 * (attempt + 1))
    return write(*args, **kwargs)  # the last attempt: its error, whatever it is, is the caller's


def log_dataset(mlflow_client, run_id: str, root: str | Path, digest: str, context: str = "training") -> None:
    """The dataset folder as the run's input (name, digest, local source): the UI's Dataset column."""
    import json

    from mlflow.entities import Dataset, DatasetInput, InputTag

    root = Path(root)
    dataset = Dataset(name=root.parent.name if root.name == "pairs" else root.name, digest=digest[:36],
                      source_type="local", source=json.dumps({"uri": project_path(root)}))
    on_conflict_retry(mlflow_client.log_inputs, run_id,
                      datasets=[DatasetInput(dataset, [InputTag("mlflow.data.context", context)])])


def log_run(experiment: str, *, run_name: str, params: dict[str, Any], metrics: dict[str, float],
            tags: dict[str, str] | None = None, artifacts: Path | None = None) -> str:
    """One MLflow run with params, metrics, tags and a folder of artifacts; returns its id.

    A run of the same experiment, name and params already logged is reused (its metrics
    and artifacts written again), so a command run twice on the same inputs keeps one run.
    """
    import time

    from mlflow.entities import Metric, Param, RunTag

    c = client()
    exp_id = experiment_id(c, experiment)
    params = {k: str(v)[:500] for k, v in params.items()}
    key = input_key(run_name=run_name, params=params)
    previous = find_run(c, exp_id, key)
    if previous is not None:
        rid = previous.info.run_id
        claim_run(c, rid)
    else:
        rid = c.create_run(exp_id, run_name=run_name, tags=run_tags({KEY_TAG: key})).info.run_id
    try:
        now = int(time.time() * 1000)
        c.log_batch(rid, params=[] if previous is not None else [Param(k, v) for k, v in params.items()],
                    metrics=[Metric(k, float(v), now, 0) for k, v in metrics.items() if v is not None],
                    tags=[RunTag(k, str(v)) for k, v in (tags or {}).items()])
        if artifacts is not None:
            c.log_artifacts(rid, str(artifacts))
    except BaseException as e:
        close_run(c, rid, e)
        raise
    close_run(c, rid)
    return rid


#: MLflow UI's saved views: an experiment tag with this prefix holds a view of the runs table
VIEW_TAG_PREFIX = "mlflow.sharedViewState."


def save_view(mlflow_client, experiment_id: str, key: str, name: str, *, search_filter: str,
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
    import json
    import time

    state = {"searchFilter": search_filter, "orderByKey": order_by or "attributes.start_time",
             "orderByAsc": ascending if order_by else False, "startTime": "ALL", "lifecycleFilter": "Active",
             "modelVersionFilter": "All Runs", "datasetsFilter": [], "selectedColumns": list(columns),
             "runsExpanded": {}, "runsPinned": [], "runsHidden": [], "viewMaximized": False, "runListHidden": False}
    now = int(time.time() * 1000)
    envelope = {"name": name, "createdAt": now, "updatedAt": now, "state": json.dumps(state)}
    on_conflict_retry(mlflow_client.set_experiment_tag, experiment_id, VIEW_TAG_PREFIX + key, json.dumps(envelope))
    return f"#/experiments/{experiment_id}/runs?workflowType=machine_learning&viewStateShareKey={key}"


def ui_url(fragment: str) -> str:
    """The address of a UI page of :func:`save_view` on ``mlflow ui``'s default port (``make ui``)."""
    return f"http://127.0.0.1:5000/{fragment}"
