"""YAML files that hold one mapping (configs, ``vehicle.yaml``, ``sensor.yaml``): read, or fail in one line."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import yaml

from uavturb.errors import InputError


def parse_yaml_mapping(text: str, where: str | Path, *, expected: str = "a mapping") -> dict[str, Any]:
    """``text`` parsed as YAML; an empty document is ``{}``. Anything but a mapping raises
    :class:`InputError` naming ``where``: ``not valid YAML (ScannerError)``, ``expected <expected>``."""
    try:
        d = yaml.safe_load(text)
    except yaml.YAMLError as e:
        raise InputError(where, f"not valid YAML ({type(e).__name__})") from None
    if d is None:
        return {}
    if not isinstance(d, dict):
        raise InputError(where, f"expected {expected}")
    return d


def read_yaml_mapping(path: str | Path, *, expected: str = "a mapping",
                      not_found: str = "file not found") -> dict[str, Any]:
    """The mapping in the YAML file ``path`` (see :func:`parse_yaml_mapping`); a missing file raises
    :class:`InputError` ``<path>: <not_found>``. Bytes that are not UTF-8 read as U+FFFD."""
    path = Path(path)
    if not path.is_file():
        raise InputError(path, not_found)
    return parse_yaml_mapping(path.read_text(encoding="utf-8", errors="replace"), path, expected=expected)
