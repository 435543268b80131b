"""Rotor commands (PWM, normalised throttle) as rotor speeds, through a declared thrust map.

Many flight logs hold no rotor speed, only what the controller sent to each motor. A thrust map
measured on a test stand (thrust per rotor as a polynomial in the command ``u`` and, since a
motor spins slower on a sagging battery, the battery voltage ``v``) turns a command into the
thrust ``f`` of that rotor [N]; the rotor speed of the nominal model (``recordings.md``:
``f = k_T w^2``) is then ``w = sqrt(f / k_T)`` [rad/s] with the vehicle's ``thrust_coefficient``
``k_T``. Such speeds are commands (``rotor_speed_source: commanded``).

The map (YAML, key ``thrust_map`` of a CSV map, or the file of ``uavturb import ulog --thrust-map``)::

    type: polynomial                # the only type
    unit: g                         # of the polynomial's value: N (default) or g (gram-force, 9.80665e-3 N)
    newtons_per_unit: 0.00981       # optional, instead of unit's factor (a source that used g = 9.81 m/s^2)
    command_range: [0, 1]           # raw command values that map to u = 0 and u = 1 (PWM: [1000, 2000])
    voltage_scale: 4.2              # v = battery voltage [V] / voltage_scale (default 1: v in volts)
    terms: [[0, 0, 11.09], [1, 0, -39.08], [0, 1, -9.53], [2, 0, 20.57], [1, 1, 38.43]]
                                    # [i, j, c]: thrust = sum of c u^i v^j

Sample-and-hold: where a logger repeats the last commands (every column bit-identical to the previous
row's), the voltage of the row that brought them is held too (:func:`held_voltage`), so the speeds repeat
bit for bit and the tools that find held streams see the commands' updates, not the battery's.

A command at or below the low end of ``command_range`` (``u <= 0``: motors off, a disarmed PWM) and a
negative thrust from the map are rotors at rest (0 rad/s): a polynomial's intercept is no thrust.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from uavturb.errors import InputError

#: N per gram-force (standard gravity)
GRAM_FORCE = 9.80665e-3
THRUST_UNITS = {"N": 1.0, "g": GRAM_FORCE}
KEYS = ("type", "unit", "newtons_per_unit", "command_range", "voltage_scale", "terms")
MAX_POWER = 6


def _finite(value: Any) -> bool:
    return not isinstance(value, bool) and isinstance(value, (int, float)) and math.isfinite(float(value))


@dataclass(frozen=True)
class ThrustMap:
    """Thrust per rotor ``sum c u^i v^j`` (in ``unit``), ``u`` the command scaled by ``command_range``,
    ``v`` the battery voltage over ``voltage_scale``."""

    terms: tuple[tuple[int, int, float], ...]
    unit: str = "N"
    command_range: tuple[float, float] = (0.0, 1.0)
    voltage_scale: float = 1.0
    newtons_per_unit: float | None = None  # N per unit of the polynomial; None: the unit's

    @property
    def needs_voltage(self) -> bool:
        return any(j > 0 for _, j, _ in self.terms)

    @classmethod
    def from_dict(cls, d: Any, where: str | Path, prefix: str = "thrust_map") -> "ThrustMap":
        """Validate a parsed ``thrust_map``; any problem raises :class:`InputError` naming ``where`` and the
        key (``prefix.key``)."""
        if not isinstance(d, dict):
            raise InputError(where, f"{prefix} must be a mapping with the keys " + ", ".join(KEYS))
        unknown = sorted(set(map(str, d)) - set(KEYS))
        if unknown:
            raise InputError(where, f"{prefix}: unknown key '{unknown[0]}' (known: {', '.join(KEYS)})")
        if d.get("type", "polynomial") != "polynomial":
            raise InputError(where, f"{prefix}.type: unknown type {str(d['type'])[:40]!r} (known: polynomial)")
        unit = d.get("unit", "N")
        if unit not in THRUST_UNITS:
            raise InputError(where, f"{prefix}.unit: unknown unit {str(unit)[:40]!r} (known: N, g)")
        lo_hi = d.get("command_range", [0.0, 1.0])
        if not isinstance(lo_hi, list) or len(lo_hi) != 2 or not all(map(_finite, lo_hi)) or lo_hi[1] == lo_hi[0]:
            raise InputError(where, f"{prefix}.command_range: expected two different numbers, got {lo_hi!r}"[:200])
        newtons = d.get("newtons_per_unit")
        if newtons is not None and (not _finite(newtons) or newtons <= 0):
            raise InputError(where, f"{prefix}.newtons_per_unit: expected a positive number, got {newtons!r}"[:200])
        scale = d.get("voltage_scale", 1.0)
        if not _finite(scale) or scale <= 0:
            raise InputError(where, f"{prefix}.voltage_scale: expected a positive number, got {scale!r}"[:200])
        return cls(terms=_terms(d.get("terms"), where, prefix), unit=unit,
                   command_range=(float(lo_hi[0]), float(lo_hi[1])),
                   voltage_scale=float(scale), newtons_per_unit=None if newtons is None else float(newtons))

    def thrust(self, command: np.ndarray, voltage: np.ndarray | None) -> np.ndarray:
        """Thrust per rotor [N], shape of ``command``; ``voltage`` [V] broadcasts against it (``(N, 1)``)."""
        lo, hi = self.command_range
        u = (np.asarray(command, dtype=np.float64) - lo) / (hi - lo)
        v = None if voltage is None else np.asarray(voltage, dtype=np.float64) / self.voltage_scale
        f = np.zeros_like(u)
        for i, j, c in self.terms:
            f = f + c * u**i * (v**j if j else 1.0)
        return f * (THRUST_UNITS[self.unit] if self.newtons_per_unit is None else self.newtons_per_unit)

    def rotor_speeds(self, command: np.ndarray, voltage: np.ndarray | None, k_T: float) -> tuple[np.ndarray, int]:
        """``(w [rad/s] = sqrt(f / k_T), number of values read as rotors at rest)``: 0 where the command is at
        or below the range's low end (motors off) or the thrust is negative."""
        lo, hi = self.command_range
        u = (np.asarray(command, dtype=np.float64) - lo) / (hi - lo)
        f = self.thrust(command, voltage)
        rest = (u <= 0) | (f < 0)
        return np.where(rest, 0.0, np.sqrt(np.where(rest, 0.0, f) / k_T)), int(np.count_nonzero(rest))


def _terms(value: Any, where: str | Path, prefix: str) -> tuple[tuple[int, int, float], ...]:
    """``terms``: a non-empty list of ``[i, j, c]`` (powers of u and v, coefficient)."""
    if not isinstance(value, list) or not value:
        raise InputError(where, f"{prefix}.terms: expected a list of [i, j, c] (thrust = sum c u^i v^j)")
    out = []
    for k, term in enumerate(value):
        ok = isinstance(term, list) and len(term) == 3 and all(
            isinstance(p, int) and not isinstance(p, bool) and 0 <= p <= MAX_POWER for p in term[:2]) \
            and _finite(term[2])
        if not ok:
            raise InputError(where, f"{prefix}.terms[{k}]: expected [i, j, c] with powers 0..{MAX_POWER} "
                                    f"and a finite coefficient, got {term!r}"[:200])
        out.append((int(term[0]), int(term[1]), float(term[2])))
    return tuple(out)


def held_voltage(command: np.ndarray, voltage: np.ndarray) -> np.ndarray:
    """``voltage`` (N,) or (N, 1) [V] held over the rows whose commands ``(N, K)`` repeat the previous
    row's exactly: each row gets the voltage of the last row whose commands changed."""
    c = np.asarray(command)
    update = np.ones(len(c), bool)
    update[1:] = np.any(c[1:] != c[:-1], axis=1)
    last = np.maximum.accumulate(np.where(update, np.arange(len(c)), 0))
    return np.asarray(voltage)[last]


def rpm_to_rad_s(rpm: np.ndarray) -> np.ndarray:
    """Rotor speeds [rpm] in rad/s (``2 pi / 60``); the sign (spin direction, on some ESCs) is dropped."""
    return np.abs(np.asarray(rpm, dtype=np.float64)) * (2.0 * np.pi / 60.0)
