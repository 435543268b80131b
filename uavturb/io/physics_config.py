"""Simulator physics configuration: which effects of ``effects.md`` are on, with which parameters.

File form (``conf/physics/*.yaml``, and what ``uavturb gap --apply`` writes)::

    effects:
      ground_effect: {mu: 2.0}
      rotor_drag: {k_d: 8.06e-05}
    vehicle:                       # optional overrides of vehicle constants
      thrust_coefficient: 8.5e-06
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import yaml

from uavturb.errors import InputError
from uavturb.io.publish import write_text_atomic
from uavturb.io.yaml_mapping import read_yaml_mapping
from uavturb.physics.effects import EFFECTS, check_params, defaults
from uavturb.schema import check_keys


#: the keys of a physics config
KEYS = ("effects", "vehicle", "source")


def load_physics_config(path: str | Path) -> dict[str, Any]:
    """Read and validate a physics config; returns ``{"effects": {...}, "vehicle": {...}}``.

    The schema of ``effects`` is the effect registry (:data:`uavturb.physics.effects.EFFECTS`: names,
    their parameters); keys are checked as every settings schema is (:func:`uavturb.schema.check_keys`):
    an unknown one fails naming the file, the key and the closest allowed one.
    """
    path = Path(path)
    d = read_yaml_mapping(path, expected="a mapping with 'effects'")
    check_keys(d, KEYS, lambda k: f"{path}: {k}")
    effects = d.get("effects") or {}
    if not isinstance(effects, dict):
        raise InputError(f"{path}: effects", "expected a mapping of effect names to parameters")
    check_keys(effects, list(EFFECTS), lambda k: f"{path}: effects.{k}", noun="effect")
    out = {}
    for name, params in effects.items():
        if not isinstance(params or {}, dict):
            raise InputError(f"{path}: effects.{name}", "expected a mapping of parameter names to numbers")
        check_keys(params or {}, EFFECTS[name].params, lambda k, n=name: f"{path}: effects.{n}.{k}", noun="parameter")
        full = {**defaults(name), **(params or {})}
        for key, value in full.items():
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
                raise InputError(f"{path}: effects.{name}.{key}", f"{value!r} is not allowed; allowed: a finite number")
        try:
            check_params(name, full)
        except InputError as e:
            raise InputError(path, str(e)) from None
        out[name] = {k: float(v) for k, v in full.items()}
    return {"effects": out, "vehicle": d.get("vehicle") or {}}


def write_physics_config(path: str | Path, effects: dict[str, dict[str, float]],
                         vehicle: dict[str, Any] | None = None, source: str | None = None,
                         overwrite: bool = False) -> Path:
    """Write a physics config atomically; an existing ``path`` is replaced only with ``overwrite``."""
    path = Path(path)
    body: dict[str, Any] = {}
    if source:
        body["source"] = source
    body["effects"] = {n: {k: float(v) for k, v in p.items()} for n, p in effects.items()}
    if vehicle:
        body["vehicle"] = vehicle
    return write_text_atomic(path, yaml.safe_dump(body, sort_keys=False), overwrite=overwrite)
