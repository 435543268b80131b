"""``uavturb bench generate``: time the generation of a preset from scratch."""

from __future__ import annotations

import shutil
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from uavturb.io import shards
from uavturb.sim.dataset.generation import generate_sim, time_split
from uavturb.sim.dataset.presets import get_preset


def benchmark(preset: str = "quick", workers: int = 2, seed: int = 0, out: str | Path | None = None,
              **overrides: Any) -> dict[str, float]:
    """``uavturb bench generate``: generate a preset from scratch and time it.

    The wall-clock rate depends on what else runs on the machine; the CPU time of the
    workers (all threads, rendering included) gives the rate the same work reaches on free
    cores. The split between control (MPC, planning included), physics, rendering and the
    rest is the workers' wall time per stage.

    Returns
    -------
    dict of printable figures (names carry units).
    """
    with tempfile.TemporaryDirectory(prefix="uavturb-bench-") as tmp:
        root = Path(out) if out is not None else Path(tmp) / "sim"
        if root.exists():
            shutil.rmtree(root)
        t0 = time.perf_counter()
        generate_sim(preset, root, workers=workers, seed=seed, progress=True, **overrides)
        wall = time.perf_counter() - t0

        m = shards.read_manifest(root)
        metas = [shards.read_meta(f) for s in shards.SPLITS for f in m.folders(s)]
    n = sum(mt["stats"]["samples"] for mt in metas)
    secs = time_split(metas)
    busy = sum(v for v in secs.values() if np.isfinite(v))
    cpu = sum(mt["stats"].get("cpu_s", float("nan")) for mt in metas)
    p = get_preset(preset, **overrides)
    res = {"preset": p.name, "controller": metas[0]["controller"], "image": f"{p.width}x{p.height}",
           "workers": int(workers), "samples": int(n), "wall_s": wall, "samples_per_s (wall)": n / wall,
           "cpu_ms_per_sample (all threads)": 1e3 * cpu / n,
           "samples_per_s per free core (from CPU time)": n / cpu,
           f"samples_per_s on {workers} free cores (projected)": workers * n / cpu,
           "cores used on average": cpu / wall}
    for k, v in secs.items():
        res[f"share of worker time: {k}"] = v / busy if busy > 0 else float("nan")
    return res
