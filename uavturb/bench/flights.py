"""``uavturb bench flights``: MPC update times on a plain hover-and-step flight, and the speed of
closed-loop flights through generated scenes."""

from __future__ import annotations

from typing import Any

import numpy as np

from uavturb.io.vehicle_file import named_vehicle
from uavturb.physics.vehicle import Vehicle
from uavturb.scene.procedural import generate_scene
from uavturb.sim.core.mpc import track
from uavturb.sim.core.signals import Constant, Reference, Waypoints
from uavturb.sim.dataset.flying import fly_trajectory


def mpc_update_times(vehicle: Vehicle | str = "quad", seconds: float = 10.0, **options: Any) -> dict[str, float]:
    """Time MPC updates on a hover-and-step flight in closed loop (no effects).

    Returns ``{"mean_ms", "median_ms", "p95_ms", "max_ms", "updates", "rms_error_m"}``.
    """
    v = named_vehicle(vehicle) if isinstance(vehicle, str) else vehicle
    ref = Reference(Waypoints((0.0, 1.0, 3.0, 5.0), (0.0, 0.0, 1.0, 1.0)), Constant(0.0),
                    Waypoints((0.0, 1.0, 3.0), (1.0, 1.0, 1.3)), Constant(0.0), seconds, "bench")
    out = track(v, ref, seconds, **options)
    st = np.asarray(out["solve_ms"])
    return {"mean_ms": float(st.mean()), "median_ms": float(np.median(st)), "p95_ms": float(np.percentile(st, 95)),
            "max_ms": float(st.max()),
            "updates": float(len(st)), "rms_error_m": float(np.sqrt(np.mean(out["error"] ** 2)))}


def benchmark(n_trajectories: int = 3, controller: str = "mpc", seed: int = 0, print_fn: Any = print,
              **fly_kw: Any) -> dict[str, float]:
    """Fly ``n_trajectories`` (one per generated scene ``seed + i``) and report the speed.

    Returns and prints samples/s (camera frames per wall second, one process), the share of
    time in the controller and the physics, MPC update times (mean, p95) [ms], tracking error
    (mean, max) [m] and the collision count.
    """

    frames = wall = ctrl_s = phys_s = 0.0
    solve, err = [], []
    coll = 0
    vehicle = fly_kw.pop("vehicle", "quad")
    for i in range(n_trajectories):
        sc = generate_scene(seed + i)
        X, _, _, info = fly_trajectory(sc, vehicle, seed + i, controller, **fly_kw)
        frames += len(X)
        wall += info["wall_s"]
        ctrl_s += info["control_s"]
        phys_s += info["physics_s"]
        solve.append(info["solve_ms"])
        err.append(info["tracking_error"])
        coll += info["collisions"]
        print_fn(f"[{i + 1}/{n_trajectories}] scene {seed + i}: {len(X)} frames, "
                 f"{len(X) / info['wall_s']:.0f} samples/s")
    s, e = np.concatenate(solve), np.concatenate(err)
    out = {"samples_per_s": frames / wall, "frames": frames, "wall_s": wall, "control_share": ctrl_s / wall,
           "physics_share": phys_s / wall, "solve_mean_ms": float(s.mean()),
           "solve_p95_ms": float(np.percentile(s, 95)), "solve_median_ms": float(np.median(s)),
           "error_mean_m": float(e.mean()), "error_max_m": float(e.max()), "collisions": coll}
    print_fn(f"{controller}: {out['samples_per_s']:.0f} samples/s (one process), "
             f"control {100 * out['control_share']:.0f}%, physics {100 * out['physics_share']:.0f}%, "
             f"update {out['solve_mean_ms']:.2f} ms mean / "
             f"{out['solve_p95_ms']:.2f} ms p95, tracking error {1000 * out['error_mean_m']:.1f} mm mean / "
             f"{1000 * out['error_max_m']:.1f} mm max, collisions {coll}")
    return out
