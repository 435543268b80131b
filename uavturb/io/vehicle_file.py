"""``vehicle.yaml`` files (``recordings.md``) and vehicles by name (:func:`named_vehicle`): built-in
ones (``quad``, ``hex``), files shipped with the package (``uavturb/vehicles/<name>.yaml``, e.g. EuRoC's
``firefly``) or a path."""

from __future__ import annotations

from pathlib import Path

import yaml

from uavturb.errors import InputError
from uavturb.io.publish import write_text_atomic
from uavturb.io.yaml_mapping import read_yaml_mapping
from uavturb.physics.vehicle import BUILTIN_VEHICLES, Vehicle


def load_vehicle(path: str | Path) -> Vehicle:
    """Read and validate a ``vehicle.yaml``."""
    path = Path(path)
    return Vehicle.from_dict(read_yaml_mapping(path, expected="a mapping of vehicle keys"), where=path)


def save_vehicle(vehicle: Vehicle, path: str | Path) -> None:
    """Write ``vehicle.yaml`` atomically (temporary file, then rename)."""
    write_text_atomic(path, yaml.safe_dump(vehicle.to_dict(), sort_keys=False))


#: vehicle files shipped with the package (``uavturb/vehicles/<name>.yaml``), e.g. EuRoC's ``firefly``
SHIPPED_DIR = Path(__file__).resolve().parents[1] / "vehicles"


def named_vehicle(name: str) -> Vehicle:
    """A built-in vehicle by name (``quad``, ``hex``), a shipped vehicle file (``firefly``), or a
    ``vehicle.yaml`` path."""
    if name in BUILTIN_VEHICLES:
        return BUILTIN_VEHICLES[name]
    shipped = SHIPPED_DIR / f"{name}.yaml"
    if shipped.is_file():
        return load_vehicle(shipped)
    if Path(name).exists():
        return load_vehicle(name)
    known = [*BUILTIN_VEHICLES, *sorted(p.stem for p in SHIPPED_DIR.glob("*.yaml"))]
    raise InputError("vehicle", f"unknown vehicle '{name}' (built-in: {', '.join(known)}; or a vehicle.yaml path)")

