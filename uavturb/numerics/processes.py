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
from concurrent.futures import ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from multiprocessing import get_context
from typing import Any, Callable, Hashable, Iterable, TypeVar

from uavturb.numerics.threads import usable_cores

#: processes at most, whatever the cores: each child's own arrays come on top of the parent's (a held-out search
#: on twelve one-minute recordings allocates tens of MB), and selection steps hold 4-8 pieces
MAX_PROCESSES = 4

_K = TypeVar("_K", bound=Hashable)
_R = TypeVar("_R")

#: what the children compute from: set by :class:`ForkedPool` before it forks (read in the child by
#: :func:`forked_state`)
_state: Any = None


def forked_state() -> Any:
    """The object the pool that forked this process was given (``ForkedPool(state=...)``)."""
    return _state


def forking_possible() -> bool:
    """Whether :class:`ForkedPool` forks at all here: Linux, two or more usable cores."""
    return platform.system() == "Linux" and usable_cores() >= 2


def _quiet_child() -> None:
    """A child's start: Ctrl-C is the parent's to handle."""
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

    def map(self, func: Callable[[_K], _R], keys: Iterable[_K]) -> dict[_K, _R]:
        """``func(key)`` of each of ``keys``, computed in the children (``func`` a module-level function, which
        finds what it computes from in :func:`forked_state`); only the keys whose piece succeeded are in the
        result. Nothing is computed where fewer than two pieces or two processes would run (the caller's own
        loop is as fast)."""
        keys = list(dict.fromkeys(keys))
        if self.workers < 2 or len(keys) < 2 or self._broken:
            return {}
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
                futures = {k: self._pool.submit(func, k) for k in keys}
            wait(futures.values())
        except (BrokenProcessPool, OSError, NotImplementedError, ImportError):
            # a pool that breaks or cannot fork; or no working semaphores, which the pool's queues need
            # (``NotImplementedError`` from ``ProcessPoolExecutor``'s check of the system, ``ImportError`` from
            # ``multiprocessing.synchronize``, ``OSError`` where ``/dev/shm`` is missing, as on some serverless hosts)
            self._broken = True
            self.close()
            return {}
        out = {}
        for k, f in futures.items():
            if f.exception() is None:
                out[k] = f.result()
            elif isinstance(f.exception(), BrokenProcessPool):
                self._broken = True
        if self._broken:
            self.close()
        return out
