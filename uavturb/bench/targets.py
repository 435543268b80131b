"""``uavturb bench``: benchmarks that print figures (never timed tests).

cli.py builds ``uavturb bench``'s parser from :data:`TARGETS` beside all the others, so this
module is imported on each start of ``uavturb``: it imports only the standard library at the top
(not even numpy, ~0.15 s), and each target imports what it measures inside its branch (the stacks
of the others also stay out of the process it times).
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from uavturb.errors import InputError

#: ``uavturb bench`` targets: what each measures (the ``--help`` text comes from here)
TARGETS: dict[str, str] = {
    "physics": "RK4 step of one state and the mapped x_dot over 100k states (CasADi dynamics), us",
    "scene": "heights over the surface below/above from a 1M-point cloud, 100k queries, and depth projection",
    "flights": "MPC update times (mean, median, p95) and closed-loop tracking error on reference flights",
    "generate": "simulator throughput on the quick preset: samples/s and the control/physics/render split",
    "train": "training windows/s of the height model and the input overhead of the shard DataLoader",
    "gpu": "both training stages on a CUDA device at 128 px, fp32 and bf16-mixed: windows/s, epoch times, GPU\n"
           "            memory, DataLoader share, 500 pre-training epochs vs 2 CPU cores "
           "(--device cpu: small, on the CPU)",
    "infer": "exported streaming model on one CPU thread: per-frame latency (.pt2, ONNX) and batched throughput",
    "gap": "the gap finder's seconds and peak memory per hour of 200 Hz flight (RECORDINGS, or two generated flights)",
    "gap-proof": "the gap finder blind on concealed effects against PySINDy (writes gap_proof/)",
    "sweep": "the quick sweep one run after another and on a local Ray instance: wall times and their ratio",
    "readers": "a 1M-row ground-truth CSV read in a fresh process: seconds and peak memory against the file's size",
}

_READ_CHILD = """
import sys, time
from uavturb.io import euroc_csv
t = time.perf_counter()
if sys.argv[1] != "-":
    euroc_csv.read_csv(sys.argv[1], euroc_csv.GROUNDTRUTH_COLUMNS, "ground truth")
peak_kb = open("/proc/self/status").read().split("VmHWM:")[1].split()[0]  # this process's peak RSS
print(time.perf_counter() - t, peak_kb)
"""


def bench_readers(rows: int = 1_000_000) -> dict[str, float]:
    """Read a ground-truth CSV of ``rows`` rows (17 columns, written first, not timed) in a fresh
    process: wall time and the process's peak resident memory (the kernel's ``VmHWM``) above what
    its imports take, against the file's size and the arrays returned."""
    import numpy as np  # late, as every import here: numpy ~0.15 s on every start of uavturb (module docstring)

    from uavturb.io import euroc_csv  # late: pandas, ~1 s on every start of uavturb (module docstring)

    rng = np.random.default_rng(0)
    t_ns = 1403636579763555584 + np.arange(rows, dtype=np.int64) * 5_000_000
    values = rng.normal(size=(rows, euroc_csv.GROUNDTRUTH_COLUMNS - 1))
    with tempfile.TemporaryDirectory(prefix="uavturb-bench-readers-") as tmp:
        path = Path(tmp) / "data.csv"
        euroc_csv.write_csv(path, euroc_csv.GROUNDTRUTH_HEADER, t_ns, values, fmt="%.9g")
        del values
        peaks = []
        for arg in (str(path), "-"):  # the read, then the imports alone
            out = subprocess.run([sys.executable, "-c", _READ_CHILD, arg], capture_output=True, text=True, check=True,
                                 env={**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)}).stdout.split()
            peaks.append((float(out[1]) / 1024, float(out[0])))
        size = path.stat().st_size / 2**20
    return {"rows": float(rows), "file (MB)": size, "arrays returned (MB)": rows * 17 * 8 / 2**20,
            "read (s)": peaks[0][1], "peak memory above imports (MB)": peaks[0][0] - peaks[1][0],
            "peak memory / file size": (peaks[0][0] - peaks[1][0]) / size}


def bench_sweep(seeds: int = 1) -> dict[str, float]:
    """Wall time of the quick sweep (``sweeps/ablation.yaml --profile quick``) run one after another
    and on a local Ray instance (all this machine's CPUs), in one call so the ratio is like for like.

    Both sweeps use the same synthetic data (generated first, not timed) and a temporary MLflow
    store (created first, not timed); Ray's start-up is timed. Also prints the largest difference
    of a test metric between the two (same seeds: the same runs).
    """
    # late: torch, Lightning, MLflow and Ray, seconds on every start of uavturb (module docstring)
    from uavturb.runs import store
    from uavturb.runs.config import DEFAULT_SPEC, load_config
    from uavturb.runs.sweep import sweep
    from uavturb.runs.training_data import prepare_data

    out: dict[str, float] = {}
    old = os.environ.get("MLFLOW_TRACKING_URI")
    with tempfile.TemporaryDirectory(prefix="uavturb-bench-sweep-") as tmp:
        os.environ["MLFLOW_TRACKING_URI"] = f"sqlite:///{tmp}/mlflow.db"
        try:
            data = [f"data.root={tmp}/sim", f"data.pairs_root={tmp}/pairs"]
            for stage in ("pretrain", "height"):
                prepare_data(load_config(["data=synthetic", f"stage={stage}", *data]))
            metrics = {}
            for executor in ("sequential", "ray"):
                store.create_experiment(f"bench-{executor}", artifact_location=f"{tmp}/mlruns/{executor}")
                t = time.perf_counter()
                res = sweep(DEFAULT_SPEC, profile="quick", seeds=seeds, experiment=f"bench-{executor}",
                            overrides=[*data, f"trainer.default_root_dir={tmp}/runs-{executor}"], executor=executor)
                out[f"quick sweep, {executor} (s)"] = time.perf_counter() - t
                metrics[executor] = {(r["row"], r["seed"]): r["metrics"] for r in res["runs"]}
        finally:
            if old is None:
                os.environ.pop("MLFLOW_TRACKING_URI", None)
            else:
                os.environ["MLFLOW_TRACKING_URI"] = old
    out["speed-up (sequential / ray)"] = out["quick sweep, sequential (s)"] / out["quick sweep, ray (s)"]
    out["CPUs"] = float(os.cpu_count() or 1)
    out["max relative difference of test metrics"] = max(
        abs(m[k] - metrics["ray"][run][k]) / max(abs(m[k]), 1e-12)
        for run, m in metrics["sequential"].items() for k in store.TABLE1_METRICS)
    return out


def bench(what: str) -> None:
    """``uavturb bench``: print the figures of one of :data:`TARGETS`.

    Each target imports what it measures here, not at the top of the module (as cli.py does):
    ``uavturb bench --help`` reads :data:`TARGETS`, and a target must not load the stacks of the
    others (torch and Lightning, Ray, CasADi, PySINDy) into the process it times."""
    if what == "readers":  # bounded CSV reader (uavturb.io.euroc_csv)
        for k, v in bench_readers().items():
            print(f"{k:<48}{v:>12.4g}")
        return
    if what == "sweep":  # the quick sweep, sequential and on Ray (uavturb.runs.executors)
        for k, v in bench_sweep().items():
            print(f"{k:<48}{v:>12.4g}")
        return
    if what in ("train", "infer"):  # learning pipeline (uavturb.bench.learning)
        from uavturb.bench import learning

        (learning.bench_train if what == "train" else learning.bench_infer)()
        return
    if what == "generate":
        from uavturb.bench import generate as dataset_benchmark

        for k, v in dataset_benchmark.benchmark().items():
            print(f"{k:<48}{v:>12.4g}" if isinstance(v, float) else f"{k:<48}{v:>12}")
        return
    if what == "flights":  # MPC solve times and closed-loop flight speed (uavturb.bench.flights)
        from uavturb.bench import flights as flight_benchmark
        from uavturb.sim.dataset.flying import CONTROLLERS

        for k, v in flight_benchmark.mpc_update_times().items():
            print(f"{'mpc ' + k:<40}{v:>12.4g}")
        for ctrl in CONTROLLERS:
            flight_benchmark.benchmark(3, ctrl)
        return
    if what == "scene":
        from uavturb.bench import scene

        for k, v in scene.benchmark().items():
            print(f"{k:<40}{v:>12.4g}")
    elif what == "gap-proof":
        from uavturb.proof.gap_proof import gap_proof

        gap_proof(Path("gap_proof"))
    elif what == "physics":
        # late: CasADi, ~0.1 s on every start of uavturb (module docstring)
        import numpy as np

        from uavturb.physics.dynamics import dynamics_for, physical_params
        from uavturb.physics.vehicle import HEXAROTOR

        d, th = dynamics_for(HEXAROTOR), physical_params(HEXAROTOR)
        x = np.r_[0, 0, 1.0, 1, 0, 0, 0, 0, 0, 0, 0, 0, 0]
        w = np.full(6, HEXAROTOR.hover_speed())
        t = time.perf_counter()
        for _ in range(5000):
            x = d.step(x, w, th, 1e-3)
        single = (time.perf_counter() - t) / 5000
        X, W = np.tile(x, (100000, 1)), np.tile(w, (100000, 1))
        t = time.perf_counter()
        d.xdot(X, W, th)
        mapped = (time.perf_counter() - t) / 100000
        print(f"{'RK4 step, one state (us)':<40}{single * 1e6:>12.2f}")
        print(f"{'x_dot over 100k states (us/state)':<40}{mapped * 1e6:>12.3f}")


#: options of ``uavturb bench gpu`` (keyword arguments of :func:`uavturb.bench.gpu.bench_gpu`)
BENCH_OPTIONS = ("recordings", "minutes", "measured_hour", "device", "size", "batch_size", "workers", "steps", "epochs",
                 "precisions", "cpu_threads")


def bench_target(what: str, options: dict | None = None) -> None:
    """``uavturb bench TARGET [options]``: :func:`bench`, or for ``gpu`` its measurement with ``options``
    (keyword arguments of :func:`uavturb.bench.gpu.bench_gpu`, None = default).

    Raises
    ------
    InputError : an option given to a target other than ``gpu``, or a bad option of ``gpu``.
    """
    options = {k: v for k, v in (options or {}).items() if v is not None and v != []}
    if what == "gap":  # speed and memory of the gap finder (uavturb.bench.gap)
        from uavturb.bench.gap import bench_gap

        bench_gap(options.pop("recordings", ()), **options)
        return
    options.pop("recordings", None)
    options.pop("minutes", None)
    options.pop("measured_hour", None)
    if what == "gpu":  # both training stages on a CUDA device (uavturb.bench.gpu)
        from uavturb.bench.gpu import bench_gpu

        bench_gpu(**options)
        return
    if options:
        raise InputError("--" + next(iter(options)).replace("_", "-"), "only with TARGET gpu")
    bench(what)
