"""Per-recording work on several cores: threads, since what takes the time (CSV parsing, numpy's arithmetic on
whole arrays) releases Python's GIL, and threads share the arrays instead of copying them into processes.

:func:`in_threads` is ``map`` with the loop's error order: results come in the items' order and an item's error
is raised where the loop reaches it, so a caller that checks each item as it takes it raises what the plain loop
would have raised first.
"""

from __future__ import annotations

import ctypes
import functools
import os
import platform
import threading
from concurrent.futures import ThreadPoolExecutor, wait
from typing import Callable, Iterable, Iterator, TypeVar

#: glibc's mallopt parameter: how many malloc arenas (per-thread heaps) it may make
_M_ARENA_MAX = -8

#: threads at most, whatever the cores: each holds one recording's temporaries at once, and two cores already
#: read a dozen 5-minute recordings 1.46x faster than one (7.9 -> 5.4 s)
MAX_THREADS = 4

_T = TypeVar("_T")
_R = TypeVar("_R")


def usable_cores() -> int:
    """The cores this process may run on (its CPU affinity where the system tells it, else all of them)."""
    if hasattr(os, "sched_getaffinity"):
        return len(os.sched_getaffinity(0))
    return os.cpu_count() or 1


@functools.cache
def _glibc() -> ctypes.CDLL | None:
    """The C library where it is glibc (whose malloc :func:`_one_malloc_arena` and :func:`_free_pages_returned`
    tune), else None."""
    if platform.system() != "Linux" or platform.libc_ver()[0] != "glibc":
        return None
    try:
        return ctypes.CDLL("libc.so.6")
    except OSError:
        return None


@functools.cache
def _one_malloc_arena() -> bool:
    """Make glibc's malloc keep one heap for all threads (``M_ARENA_MAX`` 1; the ``MALLOC_ARENA_MAX=1`` of its
    manual, set from inside the process, before any thread of :func:`in_threads` allocates); False where the C
    library is not glibc.

    By default glibc gives threads heaps of their own, and memory freed in one is not reused by another: with the
    reading threaded, a flight-hour's analysis peaked 160 MB higher (1083 against 920 MB); with one heap, 935 MB
    and the same speed (the threads allocate a few large arrays each, so they seldom wait on its lock)."""
    libc = _glibc()
    return libc is not None and bool(libc.mallopt(_M_ARENA_MAX, 1))


def _free_pages_returned() -> None:
    """Hand the heap's free pages back to the system (glibc's ``malloc_trim(0)``), after threads have worked side
    by side: their temporaries, freed interleaved, leave holes that later large arrays do not fill, and a
    flight-hour's analysis peaked 60-75 MB higher (980-995 MB against 919-923 MB with the pages returned, the
    serial loop's 918-920 MB)."""
    libc = _glibc()
    if libc is not None:
        libc.malloc_trim(0)


def in_threads(func: Callable[[_T], _R], items: Iterable[_T], max_threads: int | None = None) -> Iterator[_R]:
    """``func`` of each of ``items``, in their order, computed on the shared pool's threads (at most
    :data:`MAX_THREADS`, no more than the usable cores) where two or more may run. ``max_threads`` 1 (or a single
    item, a single core, or a call from a pool thread itself) runs the plain loop on this thread, lazily; a larger
    value cannot give more threads than the pool has.

    Every item is computed before the first result is returned (a bounded amount of work: the items asked for);
    a failed item's exception is raised when its result is reached, after the results before it."""
    items = list(items)
    workers = min(MAX_THREADS if max_threads is None else max_threads, usable_cores(), len(items))
    # a pool thread runs its items itself: waiting on items queued behind it in its own pool could wait forever
    if workers <= 1 or threading.current_thread().name.startswith(_PREFIX):
        return (func(x) for x in items)
    _one_malloc_arena()
    pool = _shared_pool()
    futures = [pool.submit(func, x) for x in items]
    try:
        wait(futures)
    except BaseException:  # Ctrl-C: the items not started are dropped (the pool would run them all before exiting)
        for f in futures:
            f.cancel()
        raise
    _free_pages_returned()
    return (f.result() for f in futures)


#: the shared pool's threads' names start with this
_PREFIX = "uavturb-threads"
_pool: ThreadPoolExecutor | None = None
_pool_lock = threading.Lock()


def _shared_pool() -> ThreadPoolExecutor:
    """One pool of :data:`MAX_THREADS` threads at most (no more than the usable cores) for the process, started on
    first use: the motor-lag filters of a fit run per recording at each of tens of lags, and starting threads
    for each (676 thread starts on three one-minute flights) had cost more than it saved."""
    global _pool
    with _pool_lock:
        if _pool is None:
            _pool = ThreadPoolExecutor(min(MAX_THREADS, usable_cores()), thread_name_prefix=_PREFIX)
        return _pool


def _forget_pool_in_child() -> None:
    """In a forked child: the parent's pool, whose threads the child does not have (work queued there would wait
    forever), is forgotten; the child starts its own if it needs one."""
    global _pool, _pool_lock
    _pool, _pool_lock = None, threading.Lock()


if hasattr(os, "register_at_fork"):
    os.register_at_fork(after_in_child=_forget_pool_in_child)
