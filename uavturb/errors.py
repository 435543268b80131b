"""Errors that reach the user as one line, never as a traceback."""

from __future__ import annotations

import contextlib
from pathlib import Path
from typing import Iterator


#: The longest file name / problem an error line shows: a value echoed from a hostile file (a
#: 100 MB CSV field) is cut in the middle, so the line stays readable and the start and end show.
MAX_WHERE = 300
MAX_PROBLEM = 600


def shorten(text: str, limit: int) -> str:
    """``text`` on one line, at most about ``limit`` characters (the middle cut out: ``[... N characters ...]``)."""
    text = text.replace("\r", " ").replace("\n", " ")
    if len(text) <= limit:
        return text
    head, tail = (2 * limit) // 3, limit // 4
    return f"{text[:head]} [... {len(text) - head - tail} characters ...] {text[-tail:]}"


class UavturbError(Exception):
    """An error the command line reports as one line and a non-zero exit status."""


class InputError(UavturbError):
    """Bad input: names the file (or config key) and the problem.

    Parameters
    ----------
    where : str or Path
        The file, folder or config key at fault.
    problem : str
        What is wrong with it, in words a user can act on.
    """

    def __init__(self, where: str | Path, problem: str):
        self.where = shorten(str(where), MAX_WHERE)
        self.problem = shorten(problem, MAX_PROBLEM)
        super().__init__(f"{self.where}: {self.problem}")


class Interrupted(BaseException):
    """A signal (SIGTERM from ``kill``, ``scancel`` or a time limit; SIGINT from Ctrl-C) stopped the work.

    A ``BaseException`` (like ``KeyboardInterrupt``) so that ``except Exception`` blocks do not swallow
    it; code that owns resources (an MLflow run, worker processes, temporary folders) closes them and
    re-raises, adding what the user should know to :attr:`notes` (e.g. how to resume). The command
    line reports it as one line and exits ``128 + signum`` (143 for SIGTERM, 130 for SIGINT).
    """

    def __init__(self, signum: int):
        import signal

        self.signum = int(signum)
        self.signame = signal.Signals(self.signum).name
        self.notes: list[str] = []
        super().__init__(self.signame)

    @property
    def exit_status(self) -> int:
        return 128 + self.signum

    def message(self) -> str:
        return "; ".join([f"interrupted by {self.signame}", *self.notes])


#: depth of :func:`signals_deferred` blocks, and a signal that arrived in one (raised when it ends)
_DEFERRING = [0]
_PENDING: list[int] = []
#: the signals :func:`raise_on_signals` has raised (a second one ends the process at once)
_SEEN: list[int] = []


@contextlib.contextmanager
def signals_deferred() -> Iterator[None]:
    """Under :func:`raise_on_signals`, hold SIGTERM and SIGINT until the block ends, then raise
    :class:`Interrupted`: a write to the run store (an SQLite transaction) cut in the middle leaves its
    database locked, and the write that marks the run KILLED then fails ("database is locked"). A second
    signal still ends the process at once."""
    _DEFERRING[0] += 1
    try:
        yield
    finally:
        _DEFERRING[0] -= 1
        if not _DEFERRING[0] and _PENDING:
            signum = _PENDING.pop()
            _SEEN.append(signum)
            raise Interrupted(signum)


@contextlib.contextmanager
def raise_on_signals() -> Iterator[None]:
    """While the block runs, SIGTERM and SIGINT raise :class:`Interrupted` in this (the main) process.

    Cleanup code then runs as for any exception. A second signal while cleaning up ends the
    process at once (``os._exit``). Processes forked from this one (DataLoader workers) inherit
    the handler; there it restores the default action and re-sends the signal, so they die as
    they would have. The previous handlers come back when the block ends; outside the main
    thread nothing changes.
    """
    import os
    import signal
    import sys
    import threading

    if threading.current_thread() is not threading.main_thread():
        yield
        return
    main_pid = os.getpid()
    seen = _SEEN
    seen.clear()

    def handler(signum, frame):
        if os.getpid() != main_pid:
            signal.signal(signum, signal.SIG_DFL)
            os.kill(os.getpid(), signum)
            return
        if seen or _PENDING:
            print(f"interrupted again by {signal.Signals(signum).name}: stopping without cleaning up",
                  file=sys.stderr, flush=True)
            os._exit(128 + signum)
        if _DEFERRING[0]:  # a write to the run store is under way: it ends first (signals_deferred)
            _PENDING.append(signum)
            return
        seen.append(signum)
        raise Interrupted(signum)

    old = {sig: signal.signal(sig, handler) for sig in (signal.SIGTERM, signal.SIGINT)}
    try:
        yield
    finally:
        for sig, h in old.items():
            signal.signal(sig, h)
