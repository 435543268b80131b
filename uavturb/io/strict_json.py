"""Strict JSON: what the project prints or writes as JSON is valid JSON (RFC 8259), which has no NaN or
infinity. Python's ``json`` writes them as bare ``NaN`` / ``Infinity`` unless told not to; here a number that is
not finite becomes ``null`` and numpy scalars and arrays become plain numbers and lists."""

from __future__ import annotations

import json
from typing import Any

import numpy as np


def finite_or_none(o: Any) -> Any:
    """``o`` with every float that is not finite replaced by None, recursively (dicts, lists, tuples, arrays)."""
    if isinstance(o, dict):
        return {k: finite_or_none(v) for k, v in o.items()}
    if isinstance(o, (list, tuple)):
        return [finite_or_none(v) for v in o]
    if isinstance(o, np.ndarray):
        return finite_or_none(o.tolist())
    if isinstance(o, (float, np.floating)):
        return float(o) if np.isfinite(o) else None
    if isinstance(o, np.integer):
        return int(o)
    return o


def _numpy_scalars(o: Any) -> Any:
    if isinstance(o, (np.floating, np.integer)):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    raise TypeError(f"{type(o).__name__} is not JSON serialisable")


def dumps_strict(o: Any, **kwargs: Any) -> str:
    """``json.dumps`` of :func:`finite_or_none` ``(o)``, refusing anything JSON cannot hold (``allow_nan=False``)."""
    return json.dumps(finite_or_none(o), default=_numpy_scalars, allow_nan=False, **kwargs)
