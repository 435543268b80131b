"""``uavturb bench gap``: seconds and peak memory of the gap finder per hour of 200 Hz flight.

The analysis (reading included) runs in a fresh Python process, which reports its own memory: the peak
of its imports, what is resident after them, and the peak of the reading and the analysis above that
(Linux: the kernel's ``VmHWM``, reset after the imports through ``/proc/self/clear_refs``; elsewhere
``ru_maxrss``, which counts the imports' peak too). Imports alone peak at 200-330 MB, more than the
analysis of ten minutes of flight adds, so a peak over the whole process would say nothing of how the
analysis grows. Without recordings, two flights of
``minutes`` each are generated first (hexarotor, 200 Hz IMU, ground effect and rotor drag; not timed).
Figures per flight-hour come from two measurements on the same recordings: whole, and cut to their
first half in time (every stream at the same instant, same held-out protocol). The line through the
two, in rows analysed, is carried to an hour at 200 Hz (720,000 rows): what does not grow with the
flight (start-up, the reader's blocks of at most 2 MB, fits over a few columns) stays out of the
slope, where scaling one measurement in proportion had counted it once per five minutes. The same line
is drawn through the child's CPU seconds (``time.process_time``): on a shared machine wall time varies
by a third between runs of the same code, CPU time far less. Per-recording work runs on up to
``threads`` threads (:mod:`uavturb.numerics.threads`, printed among the figures), so the CPU seconds exceed
the wall seconds on a machine with two cores or more.

Where :func:`~uavturb.gap.fit.forking_worth` says so (four recordings or more, 40,000 rows or fewer), the analysis
also fits effect sets and refits in processes forked from it (:mod:`uavturb.numerics.processes`). Their CPU
seconds are counted in (the children's, reaped when their pools shut down), and so is their memory: the peak is
the larger of the process's own ``VmHWM`` and its ``VmRSS`` plus the pages its children hold of their own
(``Private_Clean`` + ``Private_Dirty`` of ``/proc/<pid>/smaps_rollup``: what they wrote or allocated, not what
they share with it), read every 20 ms from the benchmark's own process.

The line holds for an hour in as many recordings as were given. An hour is also **measured** whole
(``measured_hour``): the recordings repeated (hard links where possible) until they make an hour of flight, each
copy one more recording (two 5-minute flights: twelve recordings), so that what grows with the number of
recordings (one held-out fold each) is in the figure too.
"""

from __future__ import annotations

import json
import math
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Sequence

from uavturb.bench.memory import children_private_kib, status_kib
from uavturb.numerics.processes import MAX_PROCESSES, forking_possible
from uavturb.numerics.threads import MAX_THREADS, usable_cores
from uavturb.sim.flights.simulate import generate_flight

#: rows of one flight-hour at 200 Hz
HOUR_ROWS = 3600 * 200

_CHILD = """
import json, resource, sys, time
from uavturb.bench.memory import status_kib

t0 = time.perf_counter()
from uavturb.io.reader import load_recordings
from uavturb.gap.finder import analyse
t1 = time.perf_counter()
import_peak = status_kib("VmHWM") or resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
try:  # reset the peak, so that what follows is the reading's and the analysis's own
    with open("/proc/self/clear_refs", "w") as f:
        f.write("5")
    start = status_kib("VmRSS")
    import_peak = max(import_peak, start or 0)  # pages the lines between touched count to the imports' peak
except OSError:
    start = None
c1, k1 = time.process_time(), resource.getrusage(resource.RUSAGE_CHILDREN)
recs = load_recordings(sys.argv[1:], repeats_allowed=True)  # the measured hour repeats flights on purpose
t2 = time.perf_counter()
report, extras = analyse(recs, {})
t3 = time.perf_counter()
k2 = resource.getrusage(resource.RUSAGE_CHILDREN)  # the forked children, reaped when their pools shut down
cpu = time.process_time() - c1 + (k2.ru_utime + k2.ru_stime) - (k1.ru_utime + k1.ru_stime)
rows = sum(len(r.imu) if r.imu is not None else len(r.ground_truth) for r in recs)
seconds = sum((r.ground_truth.t_ns[-1] - r.ground_truth.t_ns[0]) * 1e-9 for r in recs)
peak = status_kib("VmHWM") if start is not None else resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
print(json.dumps({"import_s": t1 - t0, "read_s": t2 - t1, "analyse_s": t3 - t2, "rows": rows, "flight_s": seconds,
                  "names": [r.name for r in recs],
                  "effects": [e["name"] for e in report["effects"]], "import_peak_kib": import_peak, "cpu_s": cpu,
                  "start_kib": start or 0, "peak_kib": max(peak, import_peak) if start is None else peak}))
"""


#: s between two readings of the measured process's memory and its children's, from outside it
SAMPLE_S = 0.02


def _child(code: str, args: Sequence[str]) -> dict:
    """The last line ``python -c code args`` printed in a fresh process, read as JSON; its ``peak_kib`` raised to
    the largest ``VmRSS`` plus the pages its forked children held of their own, read every :data:`SAMPLE_S` from
    outside it (a thread inside it would have allocated from a heap of its own, and moved the peak it measures)."""
    with tempfile.TemporaryFile("w+") as out, tempfile.TemporaryFile("w+") as err:
        proc = subprocess.Popen([sys.executable, "-c", code, *args], stdout=out, stderr=err, text=True)
        together = 0
        while proc.poll() is None:
            together = max(together, (status_kib("VmRSS", proc.pid) or 0) + children_private_kib(proc.pid))
            time.sleep(SAMPLE_S)
        out.seek(0)
        err.seek(0)
        if proc.returncode:
            raise subprocess.CalledProcessError(proc.returncode, proc.args, out.read(), err.read())
        figures = json.loads(out.read().strip().splitlines()[-1])
    figures["peak_kib"] = max(figures["peak_kib"], together)
    return figures


def _generated(folder: Path, minutes: float) -> list[str]:
    """Two flights of ``minutes`` (hexarotor, ground effect and rotor drag) under ``folder``."""
    paths = []
    for k in range(2):
        path = folder / f"flight{k}"
        generate_flight(vehicle="hex", effects="ground_effect:mu=2,rotor_drag", duration=60.0 * minutes,
                        kind="mixed", seed=7 + k, out=path, overwrite=True)
        paths.append(str(path))
    return paths


def bench_gap(recordings: Sequence[str] = (), minutes: float = 5.0, measured_hour: bool = True,
              hour_s: float = 3600.0) -> dict[str, float]:
    """Time and peak memory of ``uavturb gap``'s analysis on ``recordings`` (or two generated flights
    of ``minutes`` each), and the same per flight-hour at 200 Hz (module docstring); with ``measured_hour``,
    also measured on the recordings repeated to ``hour_s`` [s] of flight. Prints one line per figure."""
    with tempfile.TemporaryDirectory(prefix="uavturb-bench-gap-") as tmp:
        paths = list(recordings) or _generated(Path(tmp), minutes)
        halves = [_first_half(Path(p), Path(tmp) / "half" / f"{k}_{Path(p).name}") for k, p in enumerate(paths)]
        h = _child(_CHILD, halves)
        t = time.perf_counter()
        r = _child(_CHILD, paths)
        wall = time.perf_counter() - t
        hour = _child(_CHILD, _repeated(paths, r["flight_s"], hour_s, Path(tmp) / "hour")) if measured_hour else None
    work, work_half = r["read_s"] + r["analyse_s"], h["read_s"] + h["analyse_s"]
    mb = {k: r[k] / 1024.0 for k in ("import_peak_kib", "start_kib", "peak_kib")}
    grow, grow_half = mb["peak_kib"] - mb["start_kib"], (h["peak_kib"] - h["start_kib"]) / 1024.0
    figures = {
        "flights": len(paths), "flight time [s]": r["flight_s"], "rows (IMU or ground truth)": r["rows"],
        "threads for per-recording work": min(MAX_THREADS, usable_cores()),
        "processes for fits side by side, at most": min(MAX_PROCESSES, usable_cores()) if forking_possible() else 1,
        "read [s]": r["read_s"], "analyse [s]": r["analyse_s"], "wall, with start-up [s]": wall,
        "interpreter and imports, peak [MB]": mb["import_peak_kib"],
        "resident after imports [MB]": mb["start_kib"],
        "read + analyse: peak above that [MB]": grow,
        "peak memory [MB]": max(mb["import_peak_kib"], mb["peak_kib"]),
        "first halves: rows": h["rows"], "first halves: read + analyse [s]": work_half,
        "first halves: peak above imports [MB]": grow_half,
        "per flight-hour at 200 Hz: seconds": _at_hour(h["rows"], work_half, r["rows"], work),
        "per flight-hour at 200 Hz: CPU seconds": _at_hour(h["rows"], h["cpu_s"], r["rows"], r["cpu_s"]),
        "per flight-hour at 200 Hz: peak memory [MB]": max(
            mb["import_peak_kib"], mb["start_kib"] + _at_hour(h["rows"], grow_half, r["rows"], grow)),
    }
    if hour is not None:
        figures.update({
            "hour measured: recordings (repeats)": len(hour["names"]),
            "hour measured: flight time [s]": hour["flight_s"],
            "hour measured: rows": hour["rows"],
            "hour measured: read + analyse [s]": hour["read_s"] + hour["analyse_s"],
            "hour measured: CPU seconds": hour["cpu_s"],
            "hour measured: peak memory [MB]": max(hour["import_peak_kib"], hour["peak_kib"]) / 1024.0})
    for k, v in figures.items():
        print(f"{k:<48}{v:>12.4g}" if isinstance(v, float) else f"{k:<48}{v:>12}")
    print(f"{'effects named':<48}{', '.join(r['effects']) or 'none':>12}")
    return figures


def _repeated(paths: Sequence[str], flight_s: float, hour_s: float, folder: Path) -> list[str]:
    """Copies under ``folder`` of the recordings ``paths`` (``flight_s`` [s] of flight together), repeated until
    they hold ``hour_s`` [s]; each copy is a recording of its own (files hard-linked where the file system
    allows, camera images left out: the gap finder does not read them)."""
    copies = []
    for c in range(max(1, math.ceil(hour_s / flight_s))):
        for k, p in enumerate(paths):
            dst = folder / f"{c}_{k}_{Path(p).name}"
            shutil.copytree(Path(p).resolve(), dst, copy_function=_linked,
                            ignore=lambda d, names: ["data"] if Path(d).name == "cam0" else [])
            copies.append(str(dst))
    return copies


def _linked(src: str, dst: str) -> None:
    """``dst`` a hard link to ``src``, or a copy where the file system has none."""
    try:
        os.link(src, dst)
    except OSError:
        shutil.copy2(src, dst)


def _at_hour(rows_a: int, a: float, rows_b: int, b: float) -> float:
    """The line through ``(rows_a, a)`` and ``(rows_b, b)`` at :data:`HOUR_ROWS` (never below ``b`` scaled
    in proportion from the origin where the two points do not tell a slope)."""
    if rows_b <= rows_a:
        return b * HOUR_ROWS / rows_b
    slope = max((b - a) / (rows_b - rows_a), 0.0)
    return b + slope * (HOUR_ROWS - rows_b)


def _first_half(src: Path, dst: Path) -> str:
    """A copy of recording ``src`` at ``dst`` cut to the first half of its ground truth's time span: every
    stream's ``data.csv`` keeps its header and the rows up to that instant; other files are copied
    (camera images are left out: the gap finder does not read them)."""
    gt = src / "mav0" / "state_groundtruth_estimate0" / "data.csv"
    stamps = [int(line.split(",", 1)[0]) for line in gt.read_text().splitlines() if line and not line.startswith("#")]
    cut = stamps[0] + (stamps[-1] - stamps[0]) // 2
    for f in src.rglob("*"):
        rel = f.relative_to(src)
        if f.is_dir() or (len(rel.parts) > 2 and rel.parts[1] == "cam0" and rel.parts[2] == "data"):
            continue
        out = dst / rel
        out.parent.mkdir(parents=True, exist_ok=True)
        if f.name == "data.csv" and rel.parts[0] == "mav0":
            lines = f.read_text().splitlines()
            kept = [ln for ln in lines if not ln or ln.startswith("#") or int(ln.split(",", 1)[0]) <= cut]
            out.write_text("\n".join(kept) + "\n")
        else:
            shutil.copy2(f, out)
    return str(dst)
