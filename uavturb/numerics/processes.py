"""Independent pieces of pure-Python-heavy work on several cores: processes forked from this one, which see its
memory as it was at the fork (nothing is pickled but each piece's small key and its result).

Threads (:mod:`uavturb.numerics.threads`) suit work that spends its time in numpy's whole-array arithmetic; the gap
finder's held-out searches spend theirs in thousands of small fits, in Python, under the GIL, where threads gain
nothing. :class:`ForkedPool` runs such pieces in forked processes instead. It is an optimisation only: a piece that
fails in a child, or a pool that cannot start or breaks (a child killed for memory), leaves that piece's result
out, and the caller computes it itself, in order, where the plain loop would have (the same numbers, the same
errors).

Forking is used only where it is safe and cheap: on Linux (macOS forks badly under system libraries), with two or
more usable cores. The children hold no thread of the parent: :mod:`uavturb.numerics.threads` forgets its
pool in a forked child (``os.register_at_fork``), so a child runs per-recording work on its own thread. A child
ignores Ctrl-C (the parent stops, and shuts the pool down).
"""

from __future__ import annotations

import platform
import signal
import warnings
from concurrent.futures import Future, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from multiprocessing import get_context
from typing import Any, Callable, Generic, Hashable, Iterable, TypeVar

from uavturb.numerics.threads import usable_cores

#: processes at most, whatever the cores: each child's own arrays come on top of the parent's (a held-out search
#: on twelve one-minute recordings allocates tens of MB), and selection steps hold 4-8 pieces
MAX_PROCESSES = 4

_K = TypeVar("_K", bound=Hashable)
_R = TypeVar("_R")

#: what the children compute from: set by :class:`ForkedPool` before it forks (read in the child by
#: :func:`forked_state`)
_state: Any = None
#: whether this process is a child that a :class:`ForkedPool` forked: it forks none of its own (a piece of work
#: started aside, :meth:`ForkedPool.start`, runs beside the parent's own pools, which already take the cores)
_in_child = False


def forked_state() -> Any:
    """The object the pool that forked this process was given (``ForkedPool(state=...)``)."""
    return _state


def forking_possible() -> bool:
    """Whether :class:`ForkedPool` forks at all here: Linux, two or more usable cores, and not in a child that a
    pool forked."""
    return not _in_child and platform.system() == "Linux" and usable_cores() >= 2


def in_forked_child() -> bool:
    """Whether this process is a child that a :class:`ForkedPool` forked (what it shows of its progress, the parent
    shows)."""
    return _in_child


def _quiet_child() -> None:
    """A child's start: Ctrl-C is the parent's to handle, and it forks no pool of its own."""
    global _in_child
    _in_child = True
    signal.signal(signal.SIGINT, signal.SIG_IGN)


class ForkedPool:
    """Processes forked from this one (at the first :meth:`map`), which compute pieces of work from ``state`` as it
    was then; a context manager that shuts them down on exit.

    Parameters
    ----------
    state : what the pieces are computed from, found in a child by :func:`forked_state`
    max_processes : processes at most (also bounded by the usable cores, :data:`MAX_PROCESSES`)
    """

    def __init__(self, state: Any, max_processes: int = MAX_PROCESSES):
        self.state = state
        self.workers = min(max_processes, MAX_PROCESSES, usable_cores()) if forking_possible() else 0
        self._pool: ProcessPoolExecutor | None = None
        self._broken = False

    def __enter__(self) -> "ForkedPool":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        """Shut the children down (those at work finish their piece first)."""
        if self._pool is not None:
            self._pool.shutdown(wait=True, cancel_futures=True)
            self._pool = None

    def terminate(self) -> None:
        """Stop the children at once, their pieces not wanted, and shut the pool down without waiting. (The
        executor's own ``shutdown`` lets running pieces finish, and it has no public way to stop its processes
        before Python 3.14's ``terminate_workers``: its ``_processes`` are read where they exist.)"""
        if self._pool is not None:
            for process in list(getattr(self._pool, "_processes", {}).values()):
                process.terminate()
            self._pool.shutdown(wait=False, cancel_futures=True)
            self._pool = None

    def map(self, func: Callable[[_K], _R], keys: Iterable[_K]) -> dict[_K, _R]:
        """``func(key)`` of each of ``keys``, computed in the children (``func`` a module-level function, which
        finds what it computes from in :func:`forked_state`); only the keys whose piece succeeded are in the
        result. Nothing is computed where fewer than two pieces or two processes would run (the caller's own
        loop is as fast)."""
        keys = list(dict.fromkeys(keys))
        if self.workers < 2 or len(keys) < 2:
            return {}
        futures = self._submitted(func, keys)
        if futures is None:
            return {}
        wait(futures.values())  # a broken pool finishes every future with BrokenProcessPool (_succeeded)
        out = {k: f.result() for k, f in futures.items() if self._succeeded(f)}
        if self._broken:
            self.close()
        return out

    def start(self, func: Callable[[_K], _R], key: _K) -> "Started[_R]":
        """``func(key)`` started in a child now, while the caller goes on with other work: :meth:`Started.result`
        waits for it. Where no child can compute it (no fork here, a pool that cannot start or breaks, the piece
        failing), :meth:`Started.result` computes it in the caller instead."""
        futures = self._submitted(func, [key]) if self.workers >= 1 else None
        return Started(self, None if futures is None else futures[key])

    def _submitted(self, func: Callable[[_K], _R], keys: list[_K]) -> dict[_K, Future] | None:
        """The futures of ``func(key)`` for ``keys``, the children forked at the first call; None where the pool
        is broken or cannot start."""
        if self._broken:
            return None
        global _state
        try:
            # Python 3.12 and later warn on forking a process that has threads: the children here hold none of them
            # (module docstring); the pool forks its children at the first submit
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", DeprecationWarning)
                if self._pool is None:
                    _state = self.state
                    self._pool = ProcessPoolExecutor(self.workers, mp_context=get_context("fork"),
                                                     initializer=_quiet_child)
                return {k: self._pool.submit(func, k) for k in keys}
        except (BrokenProcessPool, OSError, NotImplementedError, ImportError):
            # a pool that breaks or cannot fork; or no working semaphores, which the pool's queues need
            # (``NotImplementedError`` from ``ProcessPoolExecutor``'s check of the system, ``ImportError`` from
            # ``multiprocessing.synchronize``, ``OSError`` where ``/dev/shm`` is missing, as on some serverless hosts)
            self._broke()
            return None

    def _succeeded(self, future: Future) -> bool:
        """Whether the finished ``future``'s piece succeeded (a broken pool marked as such)."""
        if future.cancelled():
            return False
        if isinstance(future.exception(), BrokenProcessPool):
            self._broken = True
        return future.exception() is None

    def _broke(self) -> None:
        """Mark the pool broken and shut it down."""
        self._broken = True
        self.close()


class Started(Generic[_R]):
    """A piece of work :meth:`ForkedPool.start` started in a child."""

    def __init__(self, pool: ForkedPool, future: Future | None):
        self._pool, self._future = pool, future

    def result(self, compute: Callable[[], _R]) -> _R:
        """The child's result, waited for; ``compute()``, called here, where no child computed it. The pool is shut
        down either way."""
        try:
            if self._future is not None:
                wait([self._future])
                if self._pool._succeeded(self._future):
                    return self._future.result()
        finally:
            self._pool.close()
        return compute()

    def cancel(self) -> None:
        """Stop the child now, its result not wanted (the caller failed meanwhile): it is not waited for."""
        self._pool.terminate()
