"""``uavturb identify`` and ``uavturb residuals``: identification and residual series of recordings."""

from __future__ import annotations

from pathlib import Path
from typing import Sequence

import numpy as np

from uavturb.errors import InputError
from uavturb.io.reader import load_recordings
from uavturb.physics.vehicle import Vehicle
from uavturb.sysid.identification import Identification, identify
from uavturb.sysid.residuals import Residuals, residual_forces, write_residuals


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
    if ident.accel_bias is not None:
        lines.append(f"{'accelerometer bias':<22}{np.array2string(ident.accel_bias, precision=4):>28}  m/s^2 (body)")
    else:
        lines.append(f"{'accelerometer bias':<22}{'absent':>28}  (no imu0: motion capture only, nothing to estimate)")
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

