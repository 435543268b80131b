"""The map of ``uavturb import csv``: which columns of a logger's CSV hold what, in which units and frames.

A YAML file, every key checked: an unknown key, a unit or frame that does not exist, or a value of
the wrong kind fails in one line naming the key (README, "Importing a CSV log", holds the full table).
A column is named by its header text (``"x[m]"``) or by its 0-based index (``3``)::

    time: {column: "time[ms]", unit: us}          # s | ms | us | ns
    world: enu                                    # enu | ned | neu  (log_frames.py)
    body: flu                                     # flu | frd
    position: {columns: [x, y, z], unit: m}       # m | cm | mm
    velocity: {columns: [vx, vy, vz], unit: m/s}  # optional: m/s | cm/s | mm/s; else differentiated
    quaternion: {columns: [qx, qy, qz, qw], order: xyzw, direction: body_to_world}
    # or  euler: {columns: [roll, pitch, yaw], unit: deg, sequence: zyx}
    rotors: {columns: [m1, m2, m3, m4], unit: command, motor_order: [0, 1, 2, 3], thrust_map: {...}}
    battery: {voltage: "Vbat[V]", voltage_unit: V, current: null, current_unit: A}
    imu: {gyro: [wx, wy, wz], gyro_unit: rad/s, acc: [ax, ay, az], acc_unit: m/s^2, acc_frame: body}
    delimiter: ","                                # , | ; | tab | space
    header: auto                                  # auto | true | false
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

from uavturb.errors import InputError
from uavturb.io.log_frames import BODIES, EULER_SEQUENCES, WORLDS
from uavturb.io.thrust_map import ThrustMap
from uavturb.io.yaml_mapping import read_yaml_mapping

#: a column: its header text or its 0-based index
Column = str | int

TIME_UNITS = {"s": 1e9, "ms": 1e6, "us": 1e3, "ns": 1.0}  # ns per unit
LENGTH_UNITS = {"m": 1.0, "cm": 1e-2, "mm": 1e-3}
SPEED_UNITS = {"m/s": 1.0, "cm/s": 1e-2, "mm/s": 1e-3}
ANGLE_UNITS = {"rad": 1.0, "deg": 0.017453292519943295}
RATE_UNITS = {"rad/s": 1.0, "deg/s": 0.017453292519943295}
ACC_UNITS = {"m/s^2": 1.0, "g": 9.80665}
ACC_FRAMES = ("body", "world")
ROTOR_UNITS = ("rpm", "rad/s", "command")
ROTOR_SOURCES = ("commanded", "measured")
VOLTAGE_UNITS = {"V": 1.0, "mV": 1e-3}
CURRENT_UNITS = {"A": 1.0, "mA": 1e-3}
DELIMITERS = {",": ",", ";": ";", "tab": "\t", "space": None}
QUATERNION_ORDERS = ("wxyz", "xyzw")
DIRECTIONS = ("body_to_world", "world_to_body")
TOP_KEYS = ("time", "world", "body", "position", "velocity", "quaternion", "euler", "rotors", "battery", "imu",
            "delimiter", "header")


@dataclass(frozen=True)
class CsvMap:
    """A parsed, checked map (the module docstring); units as factors to SI (or ns for time)."""

    path: Path
    time: Column
    time_ns_per_unit: float
    world: str
    body: str
    position: tuple[Column, Column, Column]
    position_scale: float
    attitude: tuple[Column, ...]  # 4 quaternion columns in ``quaternion_order``, or roll, pitch, yaw
    attitude_kind: str  # "quaternion" or "euler"
    quaternion_order: str = "wxyz"
    quaternion_direction: str = "body_to_world"
    euler_scale: float = 1.0
    euler_sequence: str = "zyx"
    velocity: tuple[Column, Column, Column] | None = None
    velocity_scale: float = 1.0
    rotors: tuple[Column, ...] | None = None
    rotor_unit: str = "rad/s"
    rotor_source: str = "commanded"
    motor_order: tuple[int, ...] | None = None
    thrust_map: ThrustMap | None = None
    voltage: Column | None = None
    voltage_scale: float = 1.0
    current: Column | None = None
    current_scale: float = 1.0
    gyro: tuple[Column, Column, Column] | None = None
    gyro_scale: float = 1.0
    acc: tuple[Column, Column, Column] | None = None
    acc_scale: float = 1.0
    acc_frame: str = "body"
    delimiter: str | None = ","
    header: str = "auto"

    def columns(self) -> dict[str, Column]:
        """Every column the map reads, by the map key that names it (``rotors.columns[2]``)."""
        out: dict[str, Column] = {"time.column": self.time}
        groups = {"position.columns": self.position, f"{self.attitude_kind}.columns": self.attitude,
                  "velocity.columns": self.velocity, "rotors.columns": self.rotors, "imu.gyro": self.gyro,
                  "imu.acc": self.acc}
        for key, cols in groups.items():
            for i, c in enumerate(cols or ()):
                out[f"{key}[{i}]"] = c
        if self.voltage is not None:
            out["battery.voltage"] = self.voltage
        if self.current is not None:
            out["battery.current"] = self.current
        return out


class _Keys:
    """Reads one mapping of the map, naming ``prefix.key`` in every error."""

    def __init__(self, d: Any, prefix: str, known: tuple[str, ...], where: Path):
        if not isinstance(d, dict):
            raise InputError(where, f"{prefix}: expected a mapping with the keys {', '.join(known)}")
        unknown = [str(k) for k in d if k not in known]
        if unknown:
            raise InputError(where, f"{self._name(prefix, unknown[0])}: unknown key (known: {', '.join(known)})")
        self.d, self.prefix, self.where = d, prefix, where

    @staticmethod
    def _name(prefix: str, key: str) -> str:
        return f"{prefix}.{key}" if prefix else key

    def fail(self, key: str, problem: str) -> InputError:
        return InputError(self.where, f"{self._name(self.prefix, key)}: {problem}"[:300])

    def choice(self, key: str, choices: Any, default: Any = None) -> Any:
        value = self.d.get(key, default)
        if value is None and default is None:
            raise self.fail(key, f"required (one of {', '.join(choices)})")
        if not isinstance(value, str) or value not in choices:
            raise self.fail(key, f"unknown value {str(value)[:40]!r} (known: {', '.join(choices)})")
        return value

    def column(self, key: str, required: bool = True) -> Column | None:
        value = self.d.get(key)
        if value is None:
            if required:
                raise self.fail(key, "required: a column's header text or its 0-based index")
            return None
        return _column(value, lambda p: self.fail(key, p))

    def columns(self, key: str, n: int, required: bool = True) -> tuple[Column, ...] | None:
        value = self.d.get(key)
        if value is None and not required:
            return None
        if not isinstance(value, list) or (n and len(value) != n) or not value:
            raise self.fail(key, f"expected a list of {n or 'one or more'} columns (header texts or 0-based "
                                 f"indices), got {value!r}")
        return tuple(_column(v, lambda p, i=i: self.fail(f"{key}[{i}]", p)) for i, v in enumerate(value))


def _column(value: Any, fail) -> Column:
    if isinstance(value, bool) or not isinstance(value, (str, int)):
        raise fail(f"expected a header text or a 0-based index, got {value!r}")
    if isinstance(value, int) and value < 0:
        raise fail(f"a column index must be >= 0, got {value}")
    return value.strip() if isinstance(value, str) else value


def load_csv_map(path: str | Path) -> CsvMap:
    """Read and check a CSV map file (module docstring); :class:`InputError` names the key at fault."""
    path = Path(path)
    top = _Keys(read_yaml_mapping(path, expected="a mapping of CSV map keys"), "", TOP_KEYS, path)
    d = top.d
    for key in ("time", "world", "body", "position"):
        if key not in d:
            raise top.fail(key, "required")
    if ("quaternion" in d) == ("euler" in d):
        raise top.fail("quaternion", "give exactly one of quaternion and euler (the attitude)")
    t = _Keys(d["time"], "time", ("column", "unit"), path)
    pos = _Keys(d["position"], "position", ("columns", "unit"), path)
    kw: dict[str, Any] = dict(
        path=path, time=t.column("column"), time_ns_per_unit=TIME_UNITS[t.choice("unit", TIME_UNITS)],
        world=top.choice("world", WORLDS), body=top.choice("body", BODIES), position=pos.columns("columns", 3),
        position_scale=LENGTH_UNITS[pos.choice("unit", LENGTH_UNITS, "m")],
        delimiter=DELIMITERS[top.choice("delimiter", DELIMITERS, ",")],
        header=top.choice("header", ("auto", "true", "false"), "auto") if not isinstance(d.get("header"), bool)
        else str(d["header"]).lower())
    kw.update(_attitude(d, path))
    if "velocity" in d:
        vel = _Keys(d["velocity"], "velocity", ("columns", "unit"), path)
        kw.update(velocity=vel.columns("columns", 3), velocity_scale=SPEED_UNITS[vel.choice("unit", SPEED_UNITS,
                                                                                           "m/s")])
    if "rotors" in d:
        kw.update(_rotors(d["rotors"], path))
    if "battery" in d:
        b = _Keys(d["battery"], "battery", ("voltage", "voltage_unit", "current", "current_unit"), path)
        kw.update(voltage=b.column("voltage"), voltage_scale=VOLTAGE_UNITS[b.choice("voltage_unit", VOLTAGE_UNITS,
                                                                                    "V")],
                  current=b.column("current", required=False),
                  current_scale=CURRENT_UNITS[b.choice("current_unit", CURRENT_UNITS, "A")])
    if "imu" in d:
        m = _Keys(d["imu"], "imu", ("gyro", "gyro_unit", "acc", "acc_unit", "acc_frame"), path)
        kw.update(gyro=m.columns("gyro", 3), gyro_scale=RATE_UNITS[m.choice("gyro_unit", RATE_UNITS, "rad/s")],
                  acc=m.columns("acc", 3), acc_scale=ACC_UNITS[m.choice("acc_unit", ACC_UNITS, "m/s^2")],
                  acc_frame=m.choice("acc_frame", ACC_FRAMES, "body"))
    if kw.get("thrust_map") is not None and kw["thrust_map"].needs_voltage and kw.get("voltage") is None:
        raise top.fail("rotors", "thrust_map uses the battery voltage (terms with j > 0): map battery.voltage")
    return CsvMap(**kw)


def _attitude(d: dict, path: Path) -> dict[str, Any]:
    if "quaternion" in d:
        q = _Keys(d["quaternion"], "quaternion", ("columns", "order", "direction"), path)
        return dict(attitude=q.columns("columns", 4), attitude_kind="quaternion",
                    quaternion_order=q.choice("order", QUATERNION_ORDERS, "wxyz"),
                    quaternion_direction=q.choice("direction", DIRECTIONS, "body_to_world"))
    e = _Keys(d["euler"], "euler", ("columns", "unit", "sequence"), path)
    return dict(attitude=e.columns("columns", 3), attitude_kind="euler",
                euler_scale=ANGLE_UNITS[e.choice("unit", ANGLE_UNITS)],
                euler_sequence=e.choice("sequence", EULER_SEQUENCES, "zyx"))


def _rotors(d: Any, path: Path) -> dict[str, Any]:
    r = _Keys(d, "rotors", ("columns", "unit", "source", "motor_order", "thrust_map"), path)
    cols = r.columns("columns", 0)
    unit = r.choice("unit", ROTOR_UNITS)
    source = r.choice("source", ROTOR_SOURCES, "commanded")
    order = r.d.get("motor_order")
    if order is not None:
        if not isinstance(order, list) or sorted(order) != list(range(len(cols))) or \
                any(isinstance(i, bool) for i in order):
            raise r.fail("motor_order", f"expected a permutation of 0..{len(cols) - 1} (vehicle rotor i is "
                                        f"rotors.columns[motor_order[i]]), got {order!r}")
        order = tuple(int(i) for i in order)
    tmap = None
    if unit == "command":
        if "thrust_map" not in r.d:
            raise r.fail("thrust_map", "required when rotors.unit is command (commands become speeds through it)")
        if source != "commanded":
            raise r.fail("source", "commands through a thrust map are commanded speeds, not measured ones")
        tmap = ThrustMap.from_dict(r.d["thrust_map"], path, "rotors.thrust_map")
    elif "thrust_map" in r.d:
        raise r.fail("thrust_map", f"only used with rotors.unit: command (the unit is {unit})")
    return dict(rotors=cols, rotor_unit=unit, rotor_source=source, motor_order=order, thrust_map=tmap)
