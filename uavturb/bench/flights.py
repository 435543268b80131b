"""``uavturb bench flights``: speed of closed-loop flights through generated scenes."""

from __future__ import annotations

from typing import Any

import numpy as np

from uavturb.scene.procedural import generate_scene
from uavturb.sim.dataset.flying import fly_trajectory


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
