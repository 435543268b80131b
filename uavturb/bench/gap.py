"""``uavturb bench gap``: seconds and peak memory of the gap finder per hour of 200 Hz flight.

The analysis (reading included) runs in a fresh Python process, so its peak resident memory is its
own (``ru_maxrss`` of the child) and not the benchmark's. Without recordings, two flights of
``minutes`` each are generated first (hexarotor, 200 Hz IMU, ground effect and rotor drag; not timed).
Figures per flight-hour scale the measured ones by the rows analysed: an hour at 200 Hz is 720,000
rows (time: linearly; memory: the part above the interpreter's own, linearly).
"""

from __future__ import annotations

import json
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Sequence

from uavturb.sim.flights.simulate import generate_flight

#: rows of one flight-hour at 200 Hz
HOUR_ROWS = 3600 * 200

_CHILD = """
import json, sys, time
t0 = time.perf_counter()
from uavturb.io.reader import load_recordings
from uavturb.gap.finder import analyse
t1 = time.perf_counter()
recs = load_recordings(sys.argv[1:])
t2 = time.perf_counter()
report, extras = analyse(recs, {})
t3 = time.perf_counter()
rows = sum(len(r.imu) if r.imu is not None else len(r.ground_truth) for r in recs)
seconds = sum((r.ground_truth.t_ns[-1] - r.ground_truth.t_ns[0]) * 1e-9 for r in recs)
print(json.dumps({"import_s": t1 - t0, "read_s": t2 - t1, "analyse_s": t3 - t2, "rows": rows, "flight_s": seconds,
                  "effects": [e["name"] for e in report["effects"]]}))
"""

_BASELINE = "import uavturb.gap.finder, uavturb.io.reader"


def _child(code: str, args: Sequence[str]) -> tuple[str, float]:
    """(stdout, peak resident memory in MB) of ``python -c code args`` in a fresh process."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
    out = subprocess.run([sys.executable, "-c", code, *args], check=True, capture_output=True, text=True)
    peak = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
    return out.stdout, max(peak, before) / 1024.0


def _generated(folder: Path, minutes: float) -> list[str]:
    """Two flights of ``minutes`` (hexarotor, ground effect and rotor drag) under ``folder``."""
    paths = []
    for k in range(2):
        path = folder / f"flight{k}"
        generate_flight(vehicle="hex", effects="ground_effect:mu=2,rotor_drag", duration=60.0 * minutes,
                        kind="mixed", seed=7 + k, out=path, overwrite=True)
        paths.append(str(path))
    return paths


def bench_gap(recordings: Sequence[str] = (), minutes: float = 5.0) -> dict[str, float]:
    """Time and peak memory of ``uavturb gap``'s analysis on ``recordings`` (or two generated flights
    of ``minutes`` each), and the same per flight-hour at 200 Hz. Prints one line per figure."""
    with tempfile.TemporaryDirectory(prefix="uavturb-bench-gap-") as tmp:
        paths = list(recordings) or _generated(Path(tmp), minutes)
        _, base_mb = _child(_BASELINE, [])
        t = time.perf_counter()
        out, peak_mb = _child(_CHILD, paths)
        wall = time.perf_counter() - t
    r = json.loads(out.strip().splitlines()[-1])
    work = r["read_s"] + r["analyse_s"]
    scale = HOUR_ROWS / r["rows"]
    figures = {
        "flights": len(paths), "flight time [s]": r["flight_s"], "rows (IMU or ground truth)": r["rows"],
        "read [s]": r["read_s"], "analyse [s]": r["analyse_s"], "wall, with start-up [s]": wall,
        "peak memory [MB]": peak_mb, "interpreter and imports [MB]": base_mb,
        "per flight-hour at 200 Hz: seconds": work * scale,
        "per flight-hour at 200 Hz: peak memory [MB]": base_mb + (peak_mb - base_mb) * scale,
    }
    for k, v in figures.items():
        print(f"{k:<48}{v:>12.4g}" if isinstance(v, float) else f"{k:<48}{v:>12}")
    print(f"{'effects named':<48}{', '.join(r['effects']) or 'none':>12}")
    return figures
