"""What the commands do, as library functions the command line and the tests both call."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Sequence

import numpy as np

from uavturb.errors import InputError
from uavturb.io.recording import Recording
from uavturb.physics.identification import Identification, identify
from uavturb.physics.residuals import Residuals, residual_forces, write_residuals
from uavturb.physics.vehicle import Vehicle, preset


def load_recordings(paths: Sequence[str | Path], vehicle: str | Vehicle | None = None) -> list[Recording]:
    """Read recording folders; ``vehicle`` (preset name, yaml path or Vehicle) serves folders without one."""
    from uavturb.io.reader import read_recording

    v = preset(vehicle) if isinstance(vehicle, str) else vehicle
    recs = [read_recording(p, vehicle=v, require_rotors=True) for p in paths]
    first = recs[0].vehicle
    for r in recs[1:]:
        if r.vehicle.rotor_count != first.rotor_count or r.vehicle.mass != first.mass:
            raise InputError(r.path / "vehicle.yaml", f"describes another vehicle than {recs[0].path}/vehicle.yaml")
    return recs


def identify_recordings(paths: Sequence[str | Path], *, model: str = "auto",
                        vehicle: str | Vehicle | None = None) -> Identification:
    """``uavturb identify``: the paper's least-squares identification over one or more flights."""
    recs = load_recordings(paths, vehicle)
    return identify(recs, recs[0].vehicle, model=model)


def format_identification(ident: Identification) -> str:
    """A human-readable table of identified constants with standard errors."""
    rows = [
        ("k_T", ident.thrust_coefficient, ident.thrust_coefficient_se, "N/(rad/s)^2"),
        ("k_M", ident.moment_coefficient, ident.moment_coefficient_se, "N m/(rad/s)^2"),
        ("J_x", ident.inertia[0], ident.inertia_se[0], "kg m^2"),
        ("J_y", ident.inertia[1], ident.inertia_se[1], "kg m^2"),
        ("J_z", ident.inertia[2], ident.inertia_se[2], "kg m^2"),
        ("theta_0 = k_T/m", ident.theta[0], ident.theta_se[0], "N/(kg (rad/s)^2)"),
        ("theta_1 = l k_T/J_x", ident.theta[1], ident.theta_se[1], "1/(rad/s)^2 s^-2 rad"),
        ("theta_2 = k_M/J_z", ident.theta[2], ident.theta_se[2], "s^-2/(rad/s)^2"),
        ("theta_3 = J_z/J_x", ident.theta[3], ident.theta_se[3], "-"),
    ]
    lines = [f"identified from {len(ident.recordings)} recording(s), {ident.n_samples} samples in free flight, "
             f"inertia model {ident.model}", f"{'parameter':<22}{'value':>14}{'std. error':>14}  unit"]
    lines += [f"{n:<22}{v:>14.6g}{s:>14.3g}  {u}" for n, v, s, u in rows]
    if np.all(np.isfinite(ident.accel_bias)):
        lines.append(f"{'accelerometer bias':<22}{np.array2string(ident.accel_bias, precision=4):>28}  m/s^2 (body)")
    return "\n".join(lines)


def residuals_to_file(path: str | Path, out: str | Path, *, source: str = "auto", derivative: str = "savgol",
                      params: str = "identified", vehicle: str | Vehicle | None = None) -> tuple[Residuals, Path]:
    """``uavturb residuals``: the residual force series of one flight, written to CSV or Parquet."""
    out = Path(out)
    if out.suffix not in (".csv", ".parquet"):
        raise InputError(out, "output must end in .csv or .parquet")
    if not out.parent.exists():
        raise InputError(out.parent, "output folder does not exist")
    (rec,) = load_recordings([path], vehicle)
    if params == "identified":
        v = identify([rec], rec.vehicle).apply(rec.vehicle)
    elif params == "nominal":
        v = rec.vehicle
        if not v.is_complete():
            raise InputError(Path(path) / "vehicle.yaml",
                             "--params nominal needs thrust_coefficient, moment_coefficient and inertia")
    else:
        raise InputError("--params", f"unknown value '{params}' (allowed: identified, nominal)")
    res = residual_forces(rec, v, source=source, derivative=derivative)
    return res, write_residuals(res, out)


def import_euroc(bag: str | Path, out: str | Path, *, vehicle: str = "firefly", asl: str | Path | None = None,
                 rotor_speed_scale: float | None = None, overwrite: bool = False) -> Recording:
    """``uavturb import-euroc``: a raw EuRoC sequence as a recording folder of ``recordings.md``.

    The bag gives the rotor speeds (``/fcu/motor_speed``), and, without ``asl``, the IMU and the
    Vicon ground truth. With ``asl`` (the sequence's ASL folder, ``mav0/`` inside), its
    ground-truth state, IMU, point cloud and camera description are used and only the rotor
    speeds come from the bag. Camera frames are not copied (depth comes from the point cloud).
    """
    from dataclasses import replace

    from uavturb.io.align import overlap
    from uavturb.io.reader import read_recording
    from uavturb.io.rosbag import read_rosbag
    from uavturb.io.writer import write_recording

    v = preset(vehicle) if isinstance(vehicle, str) else vehicle
    from_bag = read_rosbag(bag, v, rotor_speed_scale=rotor_speed_scale)
    if from_bag.rotors is None:
        raise InputError(bag, "no rotor speeds (/fcu/motor_speed) in the bag")
    if asl is None:
        rec = from_bag
    else:
        rec = read_recording(asl, vehicle=from_bag.vehicle)
        rec.rotors = from_bag.rotors
        rec.vehicle = from_bag.vehicle
        if rec.cam0 is not None:
            rec.cam0 = replace(rec.cam0, t_ns=rec.cam0.t_ns[:0], files=[])
    start, end = overlap(rec.ground_truth.t_ns, rec.rotors.t_ns)
    if end <= start:
        raise InputError(bag, f"its rotor speeds do not overlap the ground truth of {asl} in time")
    write_recording(rec, out, overwrite=overwrite)
    rec.path = Path(out)
    return rec


def generate_flight(*, vehicle: str = "hex", effects: str = "none", duration: float = 60.0, kind: str = "mixed",
                    seed: int = 0, noise: str = "realistic", out: str | Path | None = None) -> Recording:
    """``uavturb generate flight``: a simulated flight in the EuRoC layout."""
    from uavturb.sim import flight

    if noise not in ("realistic", "none"):
        raise InputError("--noise", f"unknown value '{noise}' (allowed: realistic, none)")
    sensor_noise = flight.SensorNoise() if noise == "realistic" else flight.SensorNoise.none()
    return flight.generate_flight(vehicle=vehicle, effects=effects, duration=duration, kind=kind, seed=seed,
                                  noise=sensor_noise, out=out)


def preset_overrides(items: Sequence[str]) -> dict:
    """``--set KEY=VALUE`` options as a dict; values are read as YAML scalars (``64``, ``0.5``, ``true``)."""
    import yaml

    out = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep or not key.strip():
            raise InputError("--set", f"expected KEY=VALUE, got {item!r}")
        try:
            out[key.strip()] = yaml.safe_load(value)
        except yaml.YAMLError:
            raise InputError(f"--set {key.strip()}", f"cannot read value {value!r}") from None
    return out


def generate_sim(preset: str, out: str | Path, *, workers: int = 1, seed: int = 0, shard: str | None = None,
                 **overrides) -> str:
    """``uavturb generate sim``: training shards; ``overrides`` change preset fields. Returns the summary line."""
    from uavturb.sim import dataset

    m = dataset.generate_sim(preset, out, workers=workers, seed=seed, shard=shard, **overrides)
    return dataset.describe(m.root)


def generate_normals(preset: str, out: str | Path, *, workers: int = 1, seed: int = 0, irs: str | None = None,
                     size: int = 128, **overrides) -> str:
    """``uavturb generate normals``: pre-training pairs (rendered, or converted from IRS)."""
    from uavturb.sim import pretraining

    if irs is not None:
        meta = pretraining.import_irs(irs, out, size=size)
    else:
        meta = pretraining.generate_normals(preset, out, workers=workers, seed=seed, **overrides)
    return f"wrote {Path(out) / 'pairs'}: {meta['count']} pairs of {meta['image_size'][0]}x{meta['image_size'][1]} px"


def generate_merge(dirs: Sequence[str | Path], out: str | Path) -> str:
    """``uavturb generate merge``: join shard folders."""
    from uavturb.sim import dataset

    m = dataset.merge_datasets(dirs, out)
    return dataset.describe(m.root)


def bench(what: str) -> None:
    """``uavturb bench``: print figures."""
    if what in ("train", "infer"):  # learning pipeline (uavturb.bench_learning)
        from uavturb import bench_learning

        (bench_learning.bench_train if what == "train" else bench_learning.bench_infer)()
        return
    if what == "generate":
        from uavturb.sim import dataset

        for k, v in dataset.benchmark().items():
            print(f"{k:<48}{v:>12.4g}" if isinstance(v, float) else f"{k:<48}{v:>12}")
        return
    if what == "flights":  # MPC solve times and closed-loop flight speed (uavturb.sim.trajectories)
        from uavturb.sim import mpc, trajectories

        for k, v in mpc.benchmark().items():
            print(f"{'mpc ' + k:<40}{v:>12.4g}")
        for ctrl in trajectories.CONTROLLERS:
            trajectories.benchmark(3, ctrl)
        return
    if what == "scene":
        from uavturb.scene import heights

        for k, v in heights.benchmark().items():
            print(f"{k:<40}{v:>12.4g}")
    elif what == "gap":
        gap_proof(Path("gap_proof"))
    elif what == "physics":
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


def gap_proof(out: Path, *, duration: float = 90.0, seed: int = 0, singles: list[str] | None = None,
              pairs: bool = True) -> dict:
    """``uavturb gap-proof``: the finder blind on concealed effects; writes ``out/proof.md`` and ``proof.json``."""
    import json

    from uavturb.gap.proof import confusion_table, run_proof
    from uavturb.physics.effects import EFFECTS

    for s in singles or []:
        if s not in EFFECTS:
            raise InputError("--effects", f"unknown effect '{s}' (known: {', '.join(EFFECTS)})")
    result = run_proof(out, duration=duration, seed=seed, singles=singles, pairs=pairs)
    table = confusion_table(result["rows"])
    s = result["summary"]
    text = (f"{table}\n\n{s['exact']}/{s['cases']} cases named exactly (PySINDy: {s['sindy_exact']}/{s['cases']}); "
            f"{s['params_within_15pct']}/{s['cases']} named exactly with every parameter within 15 % "
            f"(PySINDy: {s['sindy_params_within_15pct']}/{s['cases']}); "
            f"{s['heldout_improved']}/{s['cases']} with every held-out fit improved; "
            f"{s['false_discoveries_on_clean']} false discoveries on clean flights "
            f"(PySINDy: {s['sindy_false_discoveries_on_clean']}); analysis of two {duration:.0f} s flights at 200 Hz "
            f"(reading included): median {s['median_analysis_seconds']:.1f} s, slowest {s['max_analysis_seconds']:.1f} s\n")
    print(text)
    (out / "proof.md").write_text(text)
    (out / "proof.json").write_text(json.dumps(result, indent=2, default=float))
    return result


def demo(out: Path, seed: int = 0) -> dict:
    """``make demo``: what the project does end to end (grows with the project)."""
    from uavturb import demo as demo_mod

    return demo_mod.run(out, seed=seed)
