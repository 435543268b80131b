"""Multirotor description: geometry, known constants, the built-in vehicles, and ``vehicle.yaml``.

The rotor geometry and the rotor-force model are those of ``recordings.md`` (the
paper's eq. 1, after Furrer et al., RotorS): rotor ``i`` sits at angle ``a_i`` from body
``+x`` (counter-clockwise about ``+z``), at distance ``l`` (``arm_length``) from the
centre of mass, and spins in direction ``s_i`` (``+1`` = counter-clockwise seen from
above). With rotor speeds ``w`` [rad/s]::

    T     =  k_T       * sum(w_i^2)                  # N, along +z_B
    tau_x =  k_T * l   * sum(sin(a_i) * w_i^2)       # N m
    tau_y = -k_T * l   * sum(cos(a_i) * w_i^2)       # N m
    tau_z = -k_M       * sum(s_i * w_i^2)            # N m, a CCW rotor pushes the body CW
"""

from __future__ import annotations

import difflib
import math
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from uavturb.errors import InputError
from uavturb.physics.constants import GRAVITY

#: The most rotors a vehicle may have (a bound checked before anything is sized by ``rotor_count``).
MAX_ROTORS = 32


def is_finite_number(v: Any) -> bool:
    """A real number (not a bool) that a float holds finitely (an integer of 400 digits does not)."""
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        return False
    try:
        return math.isfinite(float(v))
    except OverflowError:
        return False


REQUIRED_KEYS = ("mass", "rotor_count", "arm_length", "rotor_angles_deg", "rotor_directions", "rotor_radius")
OPTIONAL_KEYS = ("name", "thrust_coefficient", "moment_coefficient", "inertia", "rotor_speed_scale", "max_rotor_speed",
                 "rotor_speed_source", "rotor_plane_z", "T_BS")

#: what ``rotors0`` holds (``recordings.md``): the flight controller's commands, or speeds the ESCs measured
ROTOR_SPEED_SOURCES = ("commanded", "measured")

#: ``T_BS`` rotation blocks whose ``R R^T`` differs from the identity by more than this are not
#: rotations (EuRoC prints them to 5 decimals: about 1e-5 off).
ROTATION_TOLERANCE = 1e-3


@dataclass(frozen=True)
class Vehicle:
    """A multirotor: geometry, mass and (where known) rotor and inertia constants.

    Attributes
    ----------
    name : str
    mass : float
        kg.
    arm_length : float
        m, centre of mass to each rotor hub.
    rotor_angles_deg : tuple of float, length N
        deg, from body ``+x``, counter-clockwise about ``+z``.
    rotor_directions : tuple of int, length N
        ``+1`` counter-clockwise seen from above, ``-1`` clockwise.
    rotor_radius : float
        m, propeller radius ``r`` (ground and ceiling effect laws).
    thrust_coefficient : float or None
        ``k_T`` [N/(rad/s)^2]; ``None`` when it must be identified.
    moment_coefficient : float or None
        ``k_M`` [N m/(rad/s)^2].
    inertia : tuple of 3 floats or None
        kg m^2, diagonal of ``J`` in the body frame.
    rotor_speed_scale : float
        rad/s per unit of the ``rotors0`` values (raw EuRoC motor commands need one).
    max_rotor_speed : float or None
        rad/s, actuator bound used by controllers.
    rotor_speed_source : str
        ``"commanded"`` (default: the flight controller's commands) or ``"measured"`` (ESC
        telemetry). A measured speed already shows the battery's sag (``effects.md``).
    rotor_plane_z : float
        m, height of the rotor discs' plane above the body origin along ``z_B`` (negative: below
        it; ``recordings.md``, "Heights over surfaces"). Surface effects use the rotor plane's
        height, :meth:`rotor_plane_positions`.
    T_BS : 4x4 tuple of tuples of float, or None
        Pose of the sensor frame S (the ground truth's and the IMU's frame) in the rotor frame
        B: ``x_B = T_BS x_S`` (rotation ``R_BS``, translation ``t_BS`` [m] = the origin of S in
        B). ``None`` (key absent) means S = B. Kept as written so that files round-trip.
    """

    name: str
    mass: float
    arm_length: float
    rotor_angles_deg: tuple[float, ...]
    rotor_directions: tuple[int, ...]
    rotor_radius: float
    thrust_coefficient: float | None = None
    moment_coefficient: float | None = None
    inertia: tuple[float, float, float] | None = None
    rotor_speed_scale: float = 1.0
    max_rotor_speed: float | None = None
    rotor_speed_source: str = "commanded"
    rotor_plane_z: float = 0.0
    T_BS: tuple[tuple[float, ...], ...] | None = None
    extra: dict[str, Any] = field(default_factory=dict, compare=False, repr=False)

    @property
    def rotor_count(self) -> int:
        return len(self.rotor_angles_deg)

    @property
    def rotor_angles(self) -> np.ndarray:
        """Rotor angles [rad], shape ``(N,)``."""
        return np.deg2rad(np.asarray(self.rotor_angles_deg, dtype=float))

    def mixer(self) -> np.ndarray:
        """The paper's geometry matrix ``M`` (4 x N), so that
        ``[T, tau_x, tau_y, tau_z] = [k_T, l k_T, l k_T, k_M] ⊙ (M @ w**2)``."""
        a = self.rotor_angles
        s = np.asarray(self.rotor_directions, dtype=float)
        return np.stack([np.ones_like(a), np.sin(a), -np.cos(a), -s])

    def allocation(self, k_T: float | None = None, k_M: float | None = None) -> np.ndarray:
        """Allocation matrix ``A`` (4 x N): ``[T, tau] = A @ w**2`` [N, N m]."""
        k_T = self.thrust_coefficient if k_T is None else k_T
        k_M = self.moment_coefficient if k_M is None else k_M
        if k_T is None or k_M is None:
            raise InputError(self.name, "thrust_coefficient and moment_coefficient are unknown (identify them first)")
        return np.array([k_T, self.arm_length * k_T, self.arm_length * k_T, k_M])[:, None] * self.mixer()

    @property
    def T_BS_matrix(self) -> np.ndarray:
        """``T_BS`` (4, 4) with its rotation block made exactly orthonormal (nearest rotation, by
        SVD), so that transforming into B and back is exact to rounding; identity when absent."""
        T = np.eye(4)
        if not self.sensor_is_body:
            T[:3, :] = np.asarray(self.T_BS, dtype=float)[:3, :]
            U, _, Vt = np.linalg.svd(T[:3, :3])
            T[:3, :3] = U @ Vt
        return T

    @property
    def sensor_is_body(self) -> bool:
        """Whether S = B (no ``T_BS``, or an identity one)."""
        return self.T_BS is None or np.array_equal(np.asarray(self.T_BS, dtype=float), np.eye(4))

    def rotor_plane_positions(self, p: np.ndarray, R: np.ndarray) -> np.ndarray:
        """Centre of the rotor plane in W [m]: ``p + rotor_plane_z R e_z``.

        Parameters
        ----------
        p : (K, 3) or (3,) m, position of the body origin in W
        R : (K, 3, 3) or (3, 3), body-to-world rotations

        Returns
        -------
        Same shape as ``p``; ``p`` itself (not a copy) when ``rotor_plane_z`` is 0.
        """
        if self.rotor_plane_z == 0.0:
            return p
        R = np.asarray(R, dtype=float)
        return np.asarray(p, dtype=float) + self.rotor_plane_z * R[..., :, 2]

    def hover_speed(self) -> float:
        """Rotor speed [rad/s] at which all rotors together carry the weight."""
        if self.thrust_coefficient is None:
            raise InputError(self.name, "thrust_coefficient is unknown")
        return math.sqrt(self.mass * GRAVITY / (self.rotor_count * self.thrust_coefficient))

    @property
    def J(self) -> np.ndarray:
        """Inertia matrix [kg m^2], shape ``(3, 3)``."""
        if self.inertia is None:
            raise InputError(self.name, "inertia is unknown")
        return np.diag(np.asarray(self.inertia, dtype=float))

    def is_complete(self) -> bool:
        return None not in (self.thrust_coefficient, self.moment_coefficient, self.inertia)

    def with_params(self, **changes: Any) -> "Vehicle":
        return replace(self, **changes)

    # --- vehicle.yaml -------------------------------------------------------------
    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d.pop("extra")
        d["rotor_count"] = self.rotor_count
        d["rotor_angles_deg"] = [float(a) for a in self.rotor_angles_deg]
        d["rotor_directions"] = [int(s) for s in self.rotor_directions]
        if self.inertia is not None:
            d["inertia"] = [float(j) for j in self.inertia]
        if self.T_BS is not None:
            d["T_BS"] = [[float(x) for x in row] for row in self.T_BS]
        # keys at their defaults are left out, so files written before they existed stay the same
        if self.rotor_speed_source == "commanded":
            d.pop("rotor_speed_source")
        if self.rotor_plane_z == 0.0:
            d.pop("rotor_plane_z")
        order = ["name", "mass", "rotor_count", "arm_length", "rotor_angles_deg", "rotor_directions",
                 "rotor_radius", "thrust_coefficient", "moment_coefficient", "inertia",
                 "rotor_speed_scale", "max_rotor_speed", "rotor_speed_source", "rotor_plane_z", "T_BS"]
        return {k: d[k] for k in order if d.get(k) is not None}

    @classmethod
    def from_dict(cls, d: Any, where: str | Path = "vehicle.yaml") -> "Vehicle":
        """Validate a parsed ``vehicle.yaml``; any problem raises :class:`InputError` naming ``where``."""
        if not isinstance(d, dict):
            raise InputError(where, "expected a mapping of vehicle keys")
        missing = [k for k in REQUIRED_KEYS if k not in d or d[k] is None]
        if missing:
            raise InputError(where, f"missing required key(s): {', '.join(missing)}")

        def number(key: str, positive: bool = True) -> float:
            v = d[key]
            if not is_finite_number(v):
                raise InputError(where, f"key '{key}' must be a finite number, got {v!r}")
            if positive and float(v) <= 0:
                raise InputError(where, f"key '{key}' must be positive, got {v!r}")
            return float(v)

        def number_list(key: str, length: int) -> list[float]:
            v = d[key]
            if not isinstance(v, (list, tuple)):
                raise InputError(where, f"key '{key}' must be a list of {length} numbers, got {v!r}")
            if len(v) != length:
                raise InputError(where, f"key '{key}' has {len(v)} values, expected {length}")
            out = []
            for x in v:
                if not is_finite_number(x):
                    raise InputError(where, f"key '{key}' holds a non-numeric value {x!r}")
                out.append(float(x))
            return out

        rc = d["rotor_count"]
        if isinstance(rc, bool) or not isinstance(rc, int) or not 3 <= rc <= MAX_ROTORS:
            raise InputError(where, f"key 'rotor_count' must be an integer from 3 to {MAX_ROTORS}, got {rc!r}")
        angles = number_list("rotor_angles_deg", rc)
        dirs = number_list("rotor_directions", rc)
        if any(s not in (1.0, -1.0) for s in dirs):
            raise InputError(where, "key 'rotor_directions' must hold only +1 or -1")
        unknown = sorted(set(d) - set(REQUIRED_KEYS) - set(OPTIONAL_KEYS))
        for key in unknown:  # a typo of a key the tools read, that key absent, would drop its value without a word
            near = difflib.get_close_matches(str(key).lower(), [k for k in REQUIRED_KEYS + OPTIONAL_KEYS if k not in d],
                                             n=1, cutoff=KEY_TYPO_CUTOFF)
            if near:
                raise InputError(where, f"key '{key}' is not a vehicle.yaml key: did you mean '{near[0]}'? (its value "
                                        "would be ignored)")
        kwargs: dict[str, Any] = {}
        for key in ("thrust_coefficient", "moment_coefficient", "max_rotor_speed"):
            if d.get(key) is not None:
                kwargs[key] = number(key)
        if d.get("rotor_speed_scale") is not None:
            kwargs["rotor_speed_scale"] = number("rotor_speed_scale")
        if d.get("inertia") is not None:
            inertia = number_list("inertia", 3)
            if any(j <= 0 for j in inertia):
                raise InputError(where, "key 'inertia' must hold positive values")
            kwargs["inertia"] = tuple(inertia)
        if d.get("rotor_plane_z") is not None:
            kwargs["rotor_plane_z"] = number("rotor_plane_z", positive=False)
        if d.get("rotor_speed_source") is not None:
            source = d["rotor_speed_source"]
            if source not in ROTOR_SPEED_SOURCES:
                raise InputError(where, f"key 'rotor_speed_source' must be one of {', '.join(ROTOR_SPEED_SOURCES)}, "
                                        f"got {str(source)[:40]!r}")
            kwargs["rotor_speed_source"] = source
        if d.get("T_BS") is not None:
            kwargs["T_BS"] = checked_transform(d["T_BS"], where)
        name = d.get("name") or Path(str(where)).parent.name or "vehicle"
        mass, arm, radius = number("mass"), number("arm_length"), number("rotor_radius")
        if mass < MIN_MASS_KG:
            raise InputError(where, f"key 'mass' is {mass:g} kg, under {MIN_MASS_KG:g} kg: no multirotor is that light "
                                    "(vehicle.yaml is in kg)")
        for key, value, top, unit in (("mass", mass, MAX_MASS_KG, "kg"), ("arm_length", arm, MAX_SIZE_M, "m"),
                                      ("rotor_radius", radius, MAX_SIZE_M, "m"),
                                      ("rotor_plane_z", abs(kwargs.get("rotor_plane_z", 0.0)), MAX_SIZE_M, "m")):
            if value > top:
                raise InputError(where, f"key '{key}' is {value:g} {unit}, over {top:g} {unit}: vehicle.yaml is in SI "
                                        "units (kg, m), not grams or millimetres")
        plane, reach = abs(kwargs.get("rotor_plane_z", 0.0)), max(ROTOR_PLANE_MAX_M, 2.0 * arm)
        if plane > reach:
            raise InputError(where, f"key 'rotor_plane_z' is {kwargs['rotor_plane_z']:g} m: the rotor plane lies "
                                    f"within {reach:g} m of the body origin on any multirotor (arm_length {arm:g} m); "
                                    "it is the rotors' height above the origin along z_B, in metres")
        _check_rotors_apart(where, arm, radius, angles)
        return cls(
            name=str(name),
            mass=mass,
            arm_length=arm,
            rotor_angles_deg=tuple(angles),
            rotor_directions=tuple(int(s) for s in dirs),
            rotor_radius=radius,
            extra={k: d[k] for k in unknown},
            **kwargs,
        )

#: how far the discs of two rotors at different angles may overlap, as their radii's sum over their centres'
#: distance, before vehicle.yaml's rotor_radius is refused: rotors in one plane cannot overlap (their blades would
#: strike), a frame with staggered heights overlaps them a little, and a diameter given as the radius reads 1.4-1.7
#: (a Crazyflie 1.42, a 2.5 kg hexarotor 1.69): a surface law's height in rotor radii, and mu with it, goes with it
ROTOR_OVERLAP_MAX = 1.25


def _check_rotors_apart(where: str | Path, arm: float, radius: float, angles: Sequence[float]) -> None:
    """Refuse a ``rotor_radius`` whose discs, at ``arm`` [m] from the centre at ``angles`` [deg], would overlap
    by more than :data:`ROTOR_OVERLAP_MAX` (coaxial rotors, at one angle, excepted)."""
    a = np.radians(np.asarray(angles, float))
    xy = arm * np.stack([np.cos(a), np.sin(a)], axis=1)
    dist = np.hypot(*(xy[:, None, :] - xy[None, :, :]).transpose(2, 0, 1))
    apart = np.abs((np.degrees(a[:, None] - a[None, :]) + 180.0) % 360.0 - 180.0) > 1.0
    if not apart.any():
        return
    i, j = np.unravel_index(np.argmin(np.where(apart, dist, np.inf)), dist.shape)
    ratio = 2.0 * radius / dist[i, j]
    if ratio > ROTOR_OVERLAP_MAX:
        raise InputError(where, f"key 'rotor_radius' is {radius:g} m, but rotors {min(i, j)} and {max(i, j)} sit "
                                f"{dist[i, j]:.3g} m apart (arm_length {arm:g} m): their discs would overlap "
                                f"{ratio:.2f} times over; rotor_radius is half the propeller's diameter")


#: kg and m: no multirotor this project reads is heavier, or has arms, rotors or a rotor plane offset larger (a
#: vehicle.yaml in grams or millimetres is)
MAX_MASS_KG, MAX_SIZE_M = 1000.0, 5.0
#: m, the farthest a rotor plane may lie from the body origin along z_B, or twice the arm where that is more (a
#: motion-capture origin 10-20 cm from the rotors on real frames, recordings.md; 4-5 m had been read as the point
#: cloud's fault)
ROTOR_PLANE_MAX_M = 1.0
#: how alike a key must be to one vehicle.yaml's readers read (difflib's ratio) to be refused as its typo
KEY_TYPO_CUTOFF = 0.85
#: kg: the lightest multirotor read (the smallest nano quadrotors weigh about 10 g, a Crazyflie 27-32 g)
MIN_MASS_KG = 1e-3


def checked_transform(value: Any, where: str | Path, key: str = "T_BS") -> tuple[tuple[float, ...], ...]:
    """Validate a rigid transform given as 4 rows of 4 numbers; returns it as a tuple of tuples.

    Raises :class:`InputError` naming ``where`` and ``key`` unless it is 4x4, finite, with last
    row ``0 0 0 1`` and a rotation block (``R R^T = I`` to :data:`ROTATION_TOLERANCE`, ``det R > 0``).
    """
    shape_msg = f"key '{key}' must be 4 rows of 4 numbers (a rigid transform, last row 0 0 0 1)"
    if not isinstance(value, (list, tuple)) or len(value) != 4 or \
            any(not isinstance(r, (list, tuple)) or len(r) != 4 for r in value):
        raise InputError(where, f"{shape_msg}, got {value!r}")
    for r in value:
        for x in r:
            if not is_finite_number(x):
                raise InputError(where, f"key '{key}' holds a non-numeric or non-finite value {x!r}")
    T = np.asarray(value, dtype=float)
    R = T[:3, :3]
    if not np.array_equal(T[3], [0.0, 0.0, 0.0, 1.0]):
        raise InputError(where, f"key '{key}' must end with the row [0, 0, 0, 1], got {list(value[3])!r}")
    if not np.allclose(R @ R.T, np.eye(3), atol=ROTATION_TOLERANCE) or np.linalg.det(R) <= 0:
        raise InputError(where, f"key '{key}': the upper-left 3x3 block is not a rotation (R R^T != I or det R < 0)")
    return tuple(tuple(float(x) for x in r) for r in value)


# --- built-in vehicles ------------------------------------------------------------------

#: The paper's simulated quadrotor: 50 g class, k_T = 5.45e-6 N/(rad/s)^2 and r = 0.01 m
#: (paper, Fig. "ground effect": hover at 150 rad/s per rotor). The paper gives neither arm
#: length, k_M nor inertia: we take Crazyflie-2-like values (arm 0.046 m, k_M/k_T = 0.006 m,
#: J from Förster 2015 scaled to 50 g).
QUADROTOR = Vehicle(
    name="quad-paper",
    mass=0.05,
    arm_length=0.046,
    rotor_angles_deg=(45.0, 135.0, -135.0, -45.0),
    rotor_directions=(1, -1, 1, -1),
    rotor_radius=0.01,
    thrust_coefficient=5.45e-6,
    moment_coefficient=0.006 * 5.45e-6,
    inertia=(2.3e-5, 2.3e-5, 4.0e-5),
    max_rotor_speed=300.0,
)

#: AscTec Firefly-like hexarotor (RotorS ``firefly.xacro``; the EuRoC-MAV vehicle).
HEXAROTOR = Vehicle(
    name="hex-firefly-like",
    mass=1.5,
    arm_length=0.215,
    rotor_angles_deg=(30.0, 90.0, 150.0, -150.0, -90.0, -30.0),
    rotor_directions=(1, -1, 1, -1, 1, -1),
    rotor_radius=0.1,
    thrust_coefficient=8.54858e-06,
    moment_coefficient=0.016 * 8.54858e-06,
    inertia=(0.0347563, 0.0458929, 0.0977),
    max_rotor_speed=838.0,
)

#: vehicles by name (``--vehicle quad``); the shipped vehicle files are ``uavturb/vehicles/*.yaml``
BUILTIN_VEHICLES: dict[str, Vehicle] = {"quad": QUADROTOR, "hex": HEXAROTOR}




