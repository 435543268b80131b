"""numerics.threads: per-recording work on several threads, with the plain loop's results and error order."""

import platform
import threading
import time

import pytest

from uavturb.numerics import threads
from uavturb.numerics.threads import in_threads


@pytest.fixture
def two_cores(monkeypatch):
    monkeypatch.setattr(threads, "usable_cores", lambda: 2)


def test_results_in_the_items_order_whatever_finishes_first(two_cores):
    def slow_first(x):
        time.sleep(0.02 * (5 - x))  # the first items finish last
        return x * x

    assert list(in_threads(slow_first, range(6))) == [0, 1, 4, 9, 16, 25]


def test_work_runs_on_the_pool_threads_with_two_cores(two_cores):
    names = list(in_threads(lambda _: threading.current_thread().name, range(4)))
    assert all(n.startswith("uavturb-threads") for n in names)
    assert len(set(names)) <= threads.MAX_THREADS


def test_a_pool_thread_asking_for_threads_runs_its_items_itself(two_cores):
    """No pool thread waits on items queued behind it (a nested call would deadlock a full pool)."""
    def outer(x):
        here = threading.current_thread().name
        return [n == here for n in in_threads(lambda _: threading.current_thread().name, range(3))]

    assert list(in_threads(outer, range(4))) == [[True] * 3] * 4


def test_one_thread_is_the_plain_lazy_loop(monkeypatch):
    monkeypatch.setattr(threads, "usable_cores", lambda: 8)
    seen = []
    results = in_threads(lambda x: seen.append(x) or x, [1, 2, 3], max_threads=1)
    assert seen == []  # nothing computed before it is asked for
    assert next(results) == 1 and seen == [1]
    assert threading.current_thread() is threading.main_thread()


def test_first_failing_item_in_order_is_raised_after_the_results_before_it(two_cores):
    def f(x):
        if x == 3:
            time.sleep(0.05)  # fails last in time, first in order
            raise ValueError("three")
        if x == 4:
            raise KeyError("four")
        return x

    results = in_threads(f, range(6))
    assert [next(results) for _ in range(3)] == [0, 1, 2]
    with pytest.raises(ValueError, match="three"):
        next(results)


def test_a_caller_checking_each_item_raises_its_own_error_first(two_cores):
    """As the loop would: the caller's check of item 0 fails before item 1's error is reached."""
    def f(x):
        if x == 1:
            raise KeyError("item 1")
        return x

    with pytest.raises(RuntimeError, match="check of 0"):
        for x in in_threads(f, range(3)):
            raise RuntimeError(f"check of {x}")


def test_no_items_gives_no_results(two_cores):
    assert list(in_threads(lambda x: x, [])) == []


@pytest.mark.skipif(platform.system() != "Linux" or platform.libc_ver()[0] != "glibc", reason="glibc only")
def test_one_malloc_arena_is_set_on_glibc():
    assert threads._one_malloc_arena() is True


@pytest.mark.skipif(platform.system() != "Linux" or platform.libc_ver()[0] != "glibc", reason="glibc only")
def test_free_pages_are_returned_after_threaded_work(two_cores, monkeypatch):
    calls = []
    real = threads._glibc()

    class Recording:
        def malloc_trim(self, pad):
            calls.append(pad)
            return real.malloc_trim(pad)

        def mallopt(self, *a):
            return real.mallopt(*a)

    monkeypatch.setattr(threads, "_glibc", lambda: Recording())
    assert list(in_threads(lambda x: x + 1, range(3))) == [1, 2, 3]
    assert calls == [0]
    assert list(in_threads(lambda x: x, range(3), max_threads=1)) == [0, 1, 2]
    assert calls == [0]  # the plain loop leaves the heap as it is


def test_an_interrupted_wait_drops_the_items_not_started(two_cores, monkeypatch):
    """Ctrl-C while waiting: what has not started is cancelled, not run before the process may exit."""
    started = []

    def slow(x):
        started.append(x)
        time.sleep(0.2)
        return x

    def interrupted(futures):
        time.sleep(0.05)
        raise KeyboardInterrupt

    monkeypatch.setattr(threads, "wait", interrupted)
    with pytest.raises(KeyboardInterrupt):
        in_threads(slow, range(20))
    time.sleep(0.5)  # the items running when interrupted finish
    assert len(started) <= threads.MAX_THREADS
