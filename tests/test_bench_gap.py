"""``uavturb bench gap`` on two short flights: the figures it prints are measured in fresh processes, each
reporting its own peak memory (not the largest of every process the benchmark ever started), with the pages its
forked children hold of their own."""

from __future__ import annotations

import os

import numpy as np
import pytest

from uavturb.bench.gap import HOUR_ROWS, bench_gap
from uavturb.bench.memory import children_private_kib
from uavturb.numerics import processes
from uavturb.numerics import threads
from uavturb.sim.flights.simulate import generate_flight


def test_bench_gap_measures_the_analysis_and_its_own_memory(tmp_path, capsys):
    paths = []
    for k in range(2):
        path = tmp_path / f"flight{k}"
        generate_flight(vehicle="hex", effects="ground_effect:mu=2", duration=30.0, kind="mixed", seed=7 + k, out=path)
        paths.append(str(path))
    fig = bench_gap(paths, hour_s=120.0)  # 'an hour' of two minutes: the two flights twice
    assert fig["flights"] == 2 and fig["flight time [s]"] == pytest.approx(60.0, abs=0.1)
    assert fig["rows (IMU or ground truth)"] == pytest.approx(2 * 30 * 200, abs=4)  # 200 Hz IMU
    assert fig["first halves: rows"] == pytest.approx(fig["rows (IMU or ground truth)"] / 2, abs=4)
    assert fig["threads for per-recording work"] == min(threads.MAX_THREADS, threads.usable_cores()) >= 1
    assert fig["processes for fits side by side, at most"] == (min(processes.MAX_PROCESSES, threads.usable_cores())
                                                       if processes.forking_possible() else 1)
    # the reading and the analysis are measured above what the imports left resident: they hold the flights
    # (two 30 s flights: at least their 12,000 rows of 7 float64 columns), and nothing near a gigabyte
    assert 12_000 * 7 * 8 / 2**20 < fig["read + analyse: peak above that [MB]"] < 1024
    assert 100 < fig["resident after imports [MB]"] <= fig["interpreter and imports, peak [MB]"]
    assert fig["peak memory [MB]"] == max(fig["interpreter and imports, peak [MB]"],
                                          fig["resident after imports [MB]"]
                                          + fig["read + analyse: peak above that [MB]"])
    assert fig["per flight-hour at 200 Hz: peak memory [MB]"] >= fig["resident after imports [MB]"]
    # the per-hour line passes through both measurements: never below the whole run's figure
    assert fig["per flight-hour at 200 Hz: seconds"] >= fig["read [s]"] + fig["analyse [s]"]
    # CPU seconds come from a line of their own; beside other work its slope and the wall clock's part (a clean
    # clone's run with a second test run beside it read 7.4 CPU s for 0.5 s), so only its sign is checked here
    assert 0 < fig["per flight-hour at 200 Hz: CPU seconds"] < float("inf")
    assert HOUR_ROWS == 720_000
    # measured whole on repeats, each a recording of its own (the reader refuses one recording given twice)
    assert fig["hour measured: recordings (repeats)"] == 4
    assert fig["hour measured: flight time [s]"] == pytest.approx(120.0, abs=0.2)
    assert fig["hour measured: rows"] == 2 * fig["rows (IMU or ground truth)"]
    assert fig["hour measured: read + analyse [s]"] > 0
    assert fig["hour measured: peak memory [MB]"] >= fig["resident after imports [MB]"]
    printed = capsys.readouterr().out
    assert "per flight-hour at 200 Hz: peak memory [MB]" in printed and "effects named" in printed
    assert "hour measured: peak memory [MB]" in printed


@pytest.mark.skipif(not os.path.exists("/proc/self/smaps_rollup"), reason="reads Linux's /proc")
def test_a_childs_own_pages_are_counted_not_those_it_shares():
    """``children_private_kib``: a forked child that writes 64 MB of its own holds them (at least); before it,
    and after it ended, nothing. The parent's 64 MB array, shared with the child, is not counted."""
    shared = np.ones(8 * 2**20)  # 64 MB, written before the fork: shared with the child until it writes
    to_parent, to_child = os.pipe(), os.pipe()
    assert children_private_kib() == 0
    pid = os.fork()
    if pid == 0:  # the child: 64 MB of its own, then wait until the parent has read
        own = np.ones(8 * 2**20) + shared[0]
        os.write(to_parent[1], b"x")
        os.read(to_child[0], 1)
        os._exit(0 if own[0] == 2.0 else 1)
    try:
        os.read(to_parent[0], 1)
        held = children_private_kib()
    finally:
        os.write(to_child[1], b"x")
        _, status = os.waitpid(pid, 0)
        for fd in (*to_parent, *to_child):
            os.close(fd)
    assert os.waitstatus_to_exitcode(status) == 0
    assert 64 * 1024 <= held < 2 * 64 * 1024
    assert children_private_kib() == 0
