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


def _quiet() -> None:
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

    _quiet()
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
    """The id of experiment ``name``, created if missing (safe when two processes race to create it)."""
    from mlflow.exceptions import MlflowException

    exp = c.get_experiment_by_name(name)
    if exp is not None:
        return exp.experiment_id
    with store_lock():
        exp = c.get_experiment_by_name(name)
        if exp is not None:
            return exp.experiment_id
        try:
            return c.create_experiment(name)
        except MlflowException:  # created by a server's other client meanwhile
            exp = c.get_experiment_by_name(name)
            if exp is None:
                raise
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
    """Tags of a new run: MLflow's own context tags (user, source), ``git_commit``,
    :func:`process_tags`, then ``tags``."""
    from mlflow.tracking.context.registry import resolve_tags

    return resolve_tags({"git_commit": git_commit(), **process_tags(), **(tags or {})})


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


def log_run(experiment: str, *, run_name: str, params: dict[str, Any], metrics: dict[str, float],
            tags: dict[str, str] | None = None, artifacts: Path | None = None) -> str:
    """One MLflow run with params, metrics, tags and a folder of artifacts; returns its id."""
    c = client()
    import time

    from mlflow.entities import Metric, Param

    run = c.create_run(experiment_id(c, experiment), run_name=run_name, tags=run_tags(tags))
    rid = run.info.run_id
    try:
        now = int(time.time() * 1000)
        c.log_batch(rid, params=[Param(k, str(v)[:500]) for k, v in params.items()],
                    metrics=[Metric(k, float(v), now, 0) for k, v in metrics.items() if v is not None])
        if artifacts is not None:
            c.log_artifacts(rid, str(artifacts))
    except BaseException as e:
        close_run(c, rid, e)
        raise
    close_run(c, rid)
    return rid
