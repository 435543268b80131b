"""numerics.processes: pieces of work in processes forked from this one, from its memory at the fork; an
optimisation only, so a piece a child cannot compute is left to the caller."""

import os
import signal
import subprocess
import sys
import textwrap
import time

import pytest

from uavturb.numerics import processes
from uavturb.numerics.processes import ForkedPool, forked_state

from processes_helpers import pid_written, process_gone

pytestmark = pytest.mark.skipif(not processes.forking_possible(), reason="forks only on Linux with two cores")


def _tenfold(key):
    """A piece: the pid that computed it and ten times the state's value for ``key``."""
    return os.getpid(), 10 * forked_state()[key]


def _fails_on_b(key):
    if key == "b":
        raise ValueError("b cannot be computed")
    return forked_state()[key]


def _dies_on_b(key):
    if key == "b":
        os._exit(3)  # a child killed (for memory, say): the pool is broken
    return forked_state()[key]


def _sigint_handler(key):
    return signal.getsignal(signal.SIGINT) is signal.SIG_IGN


def test_pieces_are_computed_in_children_from_the_state_as_it_was_at_the_fork():
    state = {"a": 1, "b": 2, "c": 3}
    with ForkedPool(state, max_processes=2) as pool:
        first = pool.map(_tenfold, ["a", "b", "c"])
        state["a"] = 100  # after the fork: the children (kept for the next map) do not see it
        again = pool.map(_tenfold, ["a", "b"])
    assert {k: v for k, (_, v) in first.items()} == {"a": 10, "b": 20, "c": 30}
    assert {k: v for k, (_, v) in again.items()} == {"a": 10, "b": 20}
    assert all(pid != os.getpid() for pid, _ in [*first.values(), *again.values()])


def test_a_piece_that_fails_in_a_child_is_left_to_the_caller_and_the_pool_goes_on():
    with ForkedPool({"a": 1, "b": 2, "c": 3}, max_processes=2) as pool:
        assert pool.map(_fails_on_b, ["a", "b", "c"]) == {"a": 1, "c": 3}
        assert pool.map(_fails_on_b, ["c", "a"]) == {"c": 3, "a": 1}


def test_a_child_that_dies_breaks_the_pool_and_the_caller_computes_the_rest():
    with ForkedPool({"a": 1, "b": 2, "c": 3}, max_processes=2) as pool:
        out = pool.map(_dies_on_b, ["a", "b", "c"])
        assert "b" not in out and set(out) <= {"a", "c"}
        assert pool.map(_fails_on_b, ["a", "c"]) == {}  # broken: nothing forked again


def test_one_piece_or_one_core_forks_nothing(monkeypatch):
    with ForkedPool({"a": 1, "b": 2}) as pool:
        assert pool.map(_fails_on_b, ["a"]) == {}
    monkeypatch.setattr(processes, "usable_cores", lambda: 1)
    with ForkedPool({"a": 1, "b": 2}) as pool:
        assert pool.workers == 0 and pool.map(_fails_on_b, ["a", "b"]) == {}


@pytest.mark.parametrize("error", [NotImplementedError("sem_open"), ImportError("sem_open"), OSError("/dev/shm")])
def test_a_machine_without_semaphores_computes_everything_in_the_caller(monkeypatch, error):
    """Where the pool cannot be made (no working ``sem_open``: some serverless hosts lack ``/dev/shm``), nothing is
    computed in children, and nothing is tried again."""
    made = []

    def no_pool(*args, **kwargs):
        made.append(1)
        raise error

    monkeypatch.setattr(processes, "ProcessPoolExecutor", no_pool)
    with ForkedPool({"a": 1, "b": 2}, max_processes=2) as pool:
        assert pool.map(_fails_on_b, ["a", "c"]) == {}
        assert pool.map(_fails_on_b, ["a", "c"]) == {} and made == [1]


def test_children_leave_ctrl_c_to_the_parent():
    with ForkedPool(None, max_processes=2) as pool:
        assert pool.map(_sigint_handler, [1, 2, 3]) == {1: True, 2: True, 3: True}


def test_a_child_runs_per_recording_work_on_threads_of_its_own():
    """The parent's thread pool, started before the fork, has no threads in a child: work queued there would wait
    forever. The child forgets it and starts its own (run in a separate process, so that a hang fails the test)."""
    code = textwrap.dedent("""
        from uavturb.numerics import processes, threads
        from uavturb.numerics.processes import ForkedPool
        threads.usable_cores = lambda: 2
        assert list(threads.in_threads(lambda x: x + 1, range(3))) == [1, 2, 3]  # the parent's pool is started

        def piece(key):
            return list(threads.in_threads(lambda x: x * key, range(3)))

        with ForkedPool(None, max_processes=2) as pool:
            out = pool.map(piece, [1, 2])
        assert out == {1: [0, 1, 2], 2: [0, 2, 4]}, out
        print("ok")
    """)
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0 and done.stdout.strip() == "ok", done.stderr


def _sleeps(key):
    """A piece that writes its pid to the file ``key`` and sleeps a minute."""
    with open(key, "w") as f:
        f.write(str(os.getpid()))
    time.sleep(60)


def _where_am_i(key):
    """Whether this piece runs in a forked child, whether it could fork a pool of its own, and its pid."""
    return processes.in_forked_child(), processes.forking_possible(), os.getpid()


def test_a_piece_started_aside_is_computed_in_a_child_while_the_caller_goes_on():
    state = {"a": 1}
    started = ForkedPool(state, max_processes=1).start(_tenfold, "a")
    state["a"] = 100  # the caller goes on; the child computes from the state at the fork
    pid, value = started.result(lambda: (os.getpid(), -1))
    assert value == 10 and pid != os.getpid()
    # the child knows it is one, and forks no pool of its own; the caller is none
    child, can_fork, pid = ForkedPool(None, max_processes=1).start(_where_am_i, 0).result(lambda: None)
    assert child and not can_fork and pid != os.getpid()
    assert not processes.in_forked_child() and processes.forking_possible()


def test_a_piece_started_aside_that_fails_or_cannot_start_is_computed_by_the_caller(monkeypatch):
    assert ForkedPool({"b": 2}, max_processes=1).start(_fails_on_b, "b").result(lambda: "here") == "here"
    assert ForkedPool({"b": 2}, max_processes=1).start(_dies_on_b, "b").result(lambda: "here") == "here"
    monkeypatch.setattr(processes, "usable_cores", lambda: 1)
    pool = ForkedPool({"a": 1}, max_processes=1)
    assert pool.workers == 0 and pool.start(_tenfold, "a").result(lambda: "here") == "here"


def test_a_piece_started_aside_and_cancelled_stops_at_once(tmp_path):
    where = tmp_path / "pid"
    started = ForkedPool(None, max_processes=1).start(_sleeps, str(where))
    pid = pid_written(where)
    assert pid != os.getpid() and not process_gone(pid, timeout_s=0.1)
    started.cancel()
    assert process_gone(pid)
