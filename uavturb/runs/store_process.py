"""Log a run from a second process that imports MLflow while the caller computes.

Opening the MLflow store is slow on every start of a command: ``import mlflow`` takes 2.3 s and the SQL
store's modules and ORM set-up another 2.1 s on this project's 2-core CI machine (measured with
``-X importtime`` and cProfile), as long as the whole analysis of ``uavturb gap`` on three one-minute
flights. :class:`StoreProcess` starts ``python -m uavturb.runs.store_process`` at once; that process
does those imports while the caller computes, touches no store until it is asked to log, then logs one
run with :func:`uavturb.runs.store.log_run` (the same find-or-create, tags and artifacts) and exits.
The caller waits for it, so a command still returns with its run logged.

The child runs in its own session: a Ctrl-C at the terminal reaches only the caller, whose end closes
the pipe; a child that was never asked to log then exits without having opened the store (nothing
written), one that was asked finishes its short write first.
"""

from __future__ import annotations

import importlib
import json
import os
import subprocess
import sys
from pathlib import Path
from typing import Any

from uavturb.errors import raise_on_signals
from uavturb.runs.store import StoreError, log_run

#: seconds to wait for the logging process once it has its request (it waits for the store's lock)
LOG_TIMEOUT_S = 600.0


class StoreProcess:
    """A second process, started now, that will log one run (:func:`uavturb.runs.store.log_run`).

    Use it as a context manager around the work whose result it logs: leaving the block without
    :meth:`log_run` (an error) lets the process end without opening the store. Where no second process can
    be started, :meth:`log_run` logs in this one.
    """

    def __init__(self) -> None:
        try:
            self._proc: subprocess.Popen | None = subprocess.Popen(
                [sys.executable, "-m", "uavturb.runs.store_process"], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                stderr=subprocess.PIPE, text=True, start_new_session=True)
        except OSError:  # no second process here (no interpreter path, process limits): log in this one
            self._proc = None

    def __enter__(self) -> StoreProcess:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def log_run(self, experiment: str | None, *, artifacts: str | Path | None = None, **kwargs: Any) -> str:
        """:func:`uavturb.runs.store.log_run` in the second process (same arguments, JSON-serialisable);
        returns the run id.

        Raises
        ------
        StoreError : the run could not be logged (one line: the other process's error)
        """
        if self._proc is None:
            return log_run(experiment, artifacts=None if artifacts is None else Path(artifacts), **kwargs)
        request = json.dumps({"experiment": experiment, "artifacts": None if artifacts is None else str(artifacts),
                              **kwargs})
        try:
            out, err = self._proc.communicate(request, timeout=LOG_TIMEOUT_S)
        except subprocess.TimeoutExpired:
            self._proc.kill()
            self._proc.communicate()
            raise StoreError(f"MLflow logging did not finish within {LOG_TIMEOUT_S:.0f} s (is the store locked "
                             f"by another process?)") from None
        lines = [ln for ln in out.splitlines() if ln.strip()]
        try:
            answer = json.loads(lines[-1]) if lines else {}
        except json.JSONDecodeError:
            answer = {}
        if "run_id" in answer:
            return answer["run_id"]
        why = answer.get("error") or next((ln for ln in reversed(err.splitlines()) if ln.strip()),
                                          f"the logging process exited with {self._proc.returncode}")
        raise StoreError(why)

    def close(self) -> None:
        """Let the process end without logging (no-op once it has logged)."""
        if self._proc is None:
            return
        if self._proc.poll() is None and self._proc.stdin is not None and not self._proc.stdin.closed:
            try:
                self._proc.stdin.close()
            except OSError:
                pass
        # its output pipes are closed by the garbage collector; it exits on its own after its imports


#: modules that opening a SQLite store and logging a run import on first use (MLflow 3.x; listed from
#: ``sys.modules`` before and after a ``log_run``): imported during the warm-up instead, ~0.5 s
WARM_MODULES = ("mlflow", "mlflow.store.tracking.sqlalchemy_store", "mlflow.store.tracking.sqlalchemy_workspace_store",
                "mlflow.tracing.processor.otel", "mlflow.tracing.export", "alembic.command", "alembic.config",
                "sqlalchemy.dialects.sqlite", "opentelemetry.sdk.metrics")


def _warm_up() -> None:
    """Import what opening and writing the store needs, without touching any store."""
    for name in WARM_MODULES:
        try:
            importlib.import_module(name)
        except ImportError:  # another MLflow version: that module is then imported when it is needed
            pass
    from sqlalchemy.orm import configure_mappers

    configure_mappers()


def _serve() -> int:
    """The second process: warm up, read one request on stdin (none: exit), log it, answer on stdout."""
    _warm_up()
    text = sys.stdin.read()
    if not text.strip():
        return 0
    request = json.loads(text)
    experiment = request.pop("experiment")
    artifacts = request.pop("artifacts")
    try:
        with raise_on_signals():  # a SIGTERM waits for a store write to end (errors.signals_deferred)
            run_id = log_run(experiment, artifacts=None if artifacts is None else Path(artifacts), **request)
    except Exception as e:  # noqa: BLE001 - the caller reports any failure as one line
        print(json.dumps({"error": f"{type(e).__name__}: {str(e).splitlines()[0] if str(e) else ''}"}), flush=True)
        return 1
    print(json.dumps({"run_id": run_id}), flush=True)
    return 0


if __name__ == "__main__":
    code = _serve()
    # the run is written and the answer flushed: skip the interpreter's teardown of MLflow, SQLAlchemy and
    # OpenTelemetry (~0.5 s the caller would wait for)
    sys.stderr.flush()
    os._exit(code)
