"""Synthetic flights: close the loop around the dynamics with the named effects of
``effects.md`` switched on, and record what the sensors of ``recordings.md`` would see.

The closed loop (controller, effects, RK4 physics, motor lag, held heights) is
:func:`uavturb.sim.core.closed_loop.track_reference`, the loop of every simulated flight: physics every
``physics_dt`` (1 ms), :class:`~uavturb.sim.core.controller.GeometricController` every ``control_dt``
(5 ms) on the true state, heights over the surface below and to the surface above from a
:class:`~uavturb.scene.heights.SurfaceIndex` on the scene cloud at the control rate.
``motor_lag``: ``rotors0`` records the commands (``effects.md``).

This module adds what the sensors of ``recordings.md`` see, every ``record_dt`` (5 ms, 200 Hz):
ground truth, IMU and rotor speeds, with the noise of :class:`~uavturb.sim.flights.sensors.SensorNoise`
(:mod:`uavturb.sim.flights.sensors`). The accelerometer
reads the specific force ``R^T (F_thrust + F_ext) / m`` of the same instant (from ``Dynamics.xdot``).

Timestamps are ``int64`` nanoseconds from a EuRoC-like epoch (:data:`EUROC_T0_NS`), so that
float-precision mistakes downstream show.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from functools import lru_cache
from pathlib import Path
from typing import Any

import numpy as np

from uavturb.errors import InputError
from uavturb.io.recording import GroundTruth, Imu, Recording, Rotors
from uavturb.io.vehicle_file import named_vehicle
from uavturb.io.writer import write_recording
from uavturb.physics import quaternion as quat
from uavturb.physics.dynamics import (
    GRAVITY,
    IDX_Q,
    IDX_V,
    dynamics_for,
    physical_params,
)
from uavturb.physics.effects import EFFECTS, EffectInputs, effect_force, parse_effects
from uavturb.physics.vehicle import Vehicle
from uavturb.scene.heights import SurfaceIndex, sample_mesh_points
from uavturb.scene.indoor import Scene
from uavturb.sim.core.closed_loop import track_reference, whole_ratio
from uavturb.sim.core.controller import ControllerGains
from uavturb.sim.core.signals import Reference, Setpoint
from uavturb.sim.flights import euroc_standin
from uavturb.sim.flights.plans import EUROC_ROOM, TABLE_ROOM, excitation, low_passes, mixed
from uavturb.sim.flights.sensors import SensorNoise, sensor_readings

#: First timestamp [ns] of synthetic flights: the epoch of EuRoC's MH_01_easy (2014-06-24).
EUROC_T0_NS = 1403636579758555392

KINDS = ("excitation", "low_passes", "mixed", "euroc_room")


def flight_room(kind: str) -> Scene:
    """The scene a flight kind is planned in: :data:`~uavturb.sim.flights.plans.EUROC_ROOM` for
    ``euroc_room`` (:mod:`uavturb.sim.flights.euroc_standin`), :data:`~uavturb.sim.flights.plans.TABLE_ROOM`
    otherwise."""
    return EUROC_ROOM if kind == "euroc_room" else TABLE_ROOM


@dataclass
class Truth:
    """What the simulator knows and the recording does not, at the ``K`` record times.

    Attributes
    ----------
    t : (K,) s since the recording's start
    x : (K, 13) true states ``p, q (w, x, y, z, body to world), v, w``
    effect_force : (K, 3) N in W, the whole unmodelled force: what
        ``m R a_imu - k_T sum(w_cmd^2) R e_z`` measures with noise-free sensors
        (``force + lag_force``)
    force : (K, 3) N in W, the effect force applied to the dynamics (all effects but ``motor_lag``)
    lag_force : (K, 3) N in W, ``R e_z k_T sum(w_act^2 - w_cmd^2)``: the thrust lost or gained by
        rotors lagging their commands (zero without ``motor_lag``)
    forces : dict name -> (K, 3) N in W, each effect on its own (``motor_lag``: ``lag_force``)
    rotor_speeds : (K, N) rad/s, actual rotor speeds
    rotor_commands : (K, N) rad/s, commanded rotor speeds (exact; ``rotors0`` holds them quantised)
    thrust : (K,) N, ``k_T sum(w_act^2)``
    specific_force : (K, 3) m/s^2 in B, noise- and bias-free accelerometer reading
    d_down, d_up : (K,) m, heights to the surfaces below and above used by the effects
    reference : Setpoint, the reference at the record times
    gyro_bias, acc_bias : (K, 3) true IMU biases in B (rad/s, m/s^2)
    saturated : (K,) bool, whether the controller's allocation hit rotor limits in that period
    """

    t: np.ndarray
    x: np.ndarray
    effect_force: np.ndarray
    force: np.ndarray
    lag_force: np.ndarray
    forces: dict[str, np.ndarray]
    rotor_speeds: np.ndarray
    rotor_commands: np.ndarray
    thrust: np.ndarray
    specific_force: np.ndarray
    d_down: np.ndarray
    d_up: np.ndarray
    reference: Setpoint
    gyro_bias: np.ndarray
    acc_bias: np.ndarray
    saturated: np.ndarray = field(default_factory=lambda: np.zeros(0, bool))

    def tracking_rms(self) -> float:
        """RMS [m] of the 3-D position tracking error."""
        e = self.x[:, 0:3] - self.reference.p
        return float(np.sqrt(np.mean(np.sum(e**2, axis=1))))


# --- the scene ----------------------------------------------------------------------


@lru_cache(maxsize=4)
def _room_cloud(room: Scene, spacing: float, seed: int) -> np.ndarray:
    pts = np.asarray(sample_mesh_points(room.mesh, spacing, seed), float)
    pts.setflags(write=False)
    return pts


def room_points(room: Scene = TABLE_ROOM, spacing: float = 0.03, seed: int = 0) -> np.ndarray:
    """The scene point cloud [m] in W, ``(P, 3)``: the room's mesh (:mod:`uavturb.scene.layouts`)
    sampled every ``spacing`` [m] (cached per scene; read-only)."""
    return _room_cloud(room, float(spacing), int(seed))


@lru_cache(maxsize=4)
def _room_index(room: Scene, spacing: float, seed: int) -> Any:
    return SurfaceIndex(_room_cloud(room, spacing, seed))


def surface_index(points: np.ndarray | None = None, room: Scene = TABLE_ROOM, spacing: float = 0.03) -> Any:
    """A :class:`~uavturb.scene.heights.SurfaceIndex` on ``points``, or on :func:`room_points` of
    ``room`` when ``points`` is ``None`` (cached)."""
    if points is None:
        return _room_index(room, float(spacing), 0)
    return SurfaceIndex(np.asarray(points, float))


# --- simulation ----------------------------------------------------------------------


def simulate_flight(vehicle: Vehicle, reference: Reference, *, duration: float | None = None,
                    effects: dict[str, dict[str, float]] | None = None, points: np.ndarray | None = None,
                    surfaces: Any = None, room: Scene = TABLE_ROOM, physics_dt: float = 0.001,
                    control_dt: float = 0.005,
                    record_dt: float = 0.005, noise: SensorNoise = SensorNoise(), seed: int = 0,
                    gains: ControllerGains = ControllerGains(), feedforward: bool = False, settle: bool = True,
                    t0_ns: int = EUROC_T0_NS, wind: np.ndarray | None = None) -> tuple[Recording, Truth]:
    """Fly ``vehicle`` along ``reference`` with ``effects`` switched on and record it.

    Parameters
    ----------
    vehicle : Vehicle with known ``thrust_coefficient``, ``moment_coefficient``, ``inertia``
    reference : Reference to track (it holds its last set-point after its end)
    duration : s, flight length (default: the reference's)
    effects : ``{name: {param: value}}`` as :func:`~uavturb.physics.effects.parse_effects` returns
    points : (P, 3) m, scene cloud in W (default: :func:`room_points` of ``room``); it is the
        recording's ``pointcloud0``
    surfaces : object with ``d_down(pos (K, 3)) -> (K,)`` and ``d_up(pos) -> (K,)`` [m]
        (default: a ``SurfaceIndex`` on ``points``)
    room : Scene, the default scene (a :func:`~uavturb.scene.layouts.table_room`)
    physics_dt, control_dt, record_dt : s; the last two are whole multiples of ``physics_dt``
    noise : SensorNoise (``SensorNoise.none()`` for perfect sensors)
    seed : seed of the sensor noise
    gains : ControllerGains
    feedforward : give the controller the effect force of the last physics step as a known
        external force (an ideal model-based controller); off by default
    settle : start as if the vehicle had been resting in the initial effect force (the
        controller's integral preloaded with it); otherwise the integral starts at zero
    t0_ns : int, timestamp [ns] of the first sample
    wind : (3,) m/s, wind velocity in W: the effects act on the airspeed ``v - wind`` (none: still air)

    Returns
    -------
    recording : Recording with ground truth, IMU, ``rotors0`` (commands) and the point cloud
    truth : Truth at the record times
    """
    effects = dict(effects or {})
    for name in effects:
        if name not in EFFECTS:
            raise InputError("effects", f"unknown effect '{name}'")
    for name in (n for n in effects if not EFFECTS[n].simulated):  # what logged commands mean, not a force
        raise InputError("effects", f"{name} is not a force the simulator applies but what logged commands mean on "
                                    f"a sagging battery: make it with 'uavturb generate flight --effects "
                                    f"{name}:k_V=... --battery-voltage V'")
    duration = float(reference.duration if duration is None else duration)
    if duration <= 0:
        raise InputError("simulate_flight", "duration must be positive")
    whole_ratio(control_dt, physics_dt, "control_dt")
    rec_every = whole_ratio(record_dt, physics_dt, "record_dt")
    lag = effects.pop("motor_lag", None)
    if surfaces is None:
        surfaces = surface_index(points, room)
    if points is None:
        points = room_points(room)
    loop = track_reference(vehicle, reference, surfaces, duration=duration, effects=effects, physics_dt=physics_dt,
                           control_dt=control_dt, record_dt=record_dt,
                           motor_tau=float(lag["tau"]) if lag is not None else 0.0, gains=gains,
                           feedforward=feedforward, settle=settle, wind=wind)
    K = len(loop.x)
    dt_rec = rec_every * physics_dt
    t_rec = np.arange(K) * dt_rec
    _check_tracked(loop.x[:, 0:3], reference(t_rec).p, t_rec, effects)
    f = _forces(vehicle, loop, effects, lag, t_rec, wind)
    s = sensor_readings(loop.x, f.specific_force, loop.rotor_commands, noise, seed, dt_rec)

    t_ns = np.int64(t0_ns) + np.arange(K, dtype=np.int64) * np.int64(round(dt_rec * 1e9))
    rec = Recording(
        vehicle=vehicle,
        ground_truth=GroundTruth(t_ns=t_ns, p=s.p, q=s.q, v=s.v, b_w=s.gyro_bias, b_a=s.acc_bias),
        imu=Imu(t_ns=t_ns.copy(), gyro=s.gyro, acc=s.acc, T_BS=np.eye(4), rate_hz=1.0 / dt_rec),
        rotors=Rotors(t_ns=t_ns.copy(), speeds=s.rotors),
        points=np.array(points, dtype=float),
    )
    truth = Truth(t=t_rec, x=loop.x, effect_force=loop.force + f.lag_force, force=loop.force, lag_force=f.lag_force,
                  forces=f.per_effect, rotor_speeds=loop.rotor_speeds, rotor_commands=loop.rotor_commands,
                  thrust=f.thrust, specific_force=f.specific_force, d_down=loop.d_down, d_up=loop.d_up,
                  reference=reference(t_rec), gyro_bias=s.gyro_bias, acc_bias=s.acc_bias, saturated=loop.saturated)
    return rec, truth


#: m, the farthest the simulated vehicle may stray from its reference: beyond, the controller lost it (a flight written
#: on regardless had its height run from -5.6 to 30.7 m under a ground effect of mu = 4 on 0.127 m rotors)
LOST_TRACK_M = 1.0


def _check_tracked(p: np.ndarray, reference: np.ndarray, t: np.ndarray, effects: dict[str, dict[str, float]]) -> None:
    """Refuse a flight whose vehicle (positions ``p`` (K, 3) [m]) strayed more than :data:`LOST_TRACK_M` from its
    reference (``reference`` (K, 3) [m], at ``t`` (K,) [s]): nothing is written of a flight the controller lost.

    Raises
    ------
    InputError
        ``generate flight: the simulated vehicle lost its reference at t = 3.2 s ...``
    """
    miss = np.linalg.norm(p - reference, axis=1)
    lost = ~np.isfinite(miss) | (miss > LOST_TRACK_M)
    if not lost.any():
        return
    k = int(np.argmax(lost))
    said = ", ".join(f"{n} ({', '.join(f'{a} = {v:g}' for a, v in ps.items())})" for n, ps in effects.items())
    raise InputError("generate flight", f"the simulated vehicle lost its reference at t = {t[k]:.2f} s (more than "
                                        f"{LOST_TRACK_M:g} m off; its height ran from {np.nanmin(p[:, 2]):.3g} to "
                                        f"{np.nanmax(p[:, 2]):.3g} m): the controller cannot hold these physics"
                                        f"{' (' + said + ')' if said else ''}; weaker effects, or a flight farther "
                                        "from the surfaces")


@dataclass
class _Forces:
    """Forces of a flown trajectory at the record times."""

    thrust: np.ndarray  # (K,) N, total rotor thrust of the actual rotor speeds
    specific_force: np.ndarray  # (K, 3) m/s^2 in B, what an ideal accelerometer reads
    lag_force: np.ndarray  # (K, 3) N in W, thrust of actual minus commanded rotor speeds (motor lag)
    per_effect: dict[str, np.ndarray]  # name -> (K, 3) N in W


def _forces(vehicle: Vehicle, loop: Any, effects: dict[str, dict[str, float]], lag: dict[str, float] | None,
            t_rec: np.ndarray, wind: np.ndarray | None) -> _Forces:
    """Thrust, specific force and each effect's force along ``loop`` (the effects on the airspeed ``v - wind``)."""
    X, W_act = loop.x, loop.rotor_speeds
    dyn = dynamics_for(vehicle)
    theta = physical_params(vehicle)
    k_T, r = float(vehicle.thrust_coefficient), float(vehicle.rotor_radius)
    thrust, _ = dyn.thrust_torque(W_act, theta)
    v_dot = dyn.xdot(X, W_act, theta, loop.force)[:, IDX_V]
    spec_force = quat.rotate_inverse(X[:, IDX_Q], v_dot + GRAVITY * np.array([0.0, 0.0, 1.0]))
    z_b = quat.to_rotation_matrix(X[:, IDX_Q])[:, :, 2]
    thrust_cmd, _ = dyn.thrust_torque(loop.rotor_commands, theta)
    lag_force = (thrust - thrust_cmd)[:, None] * z_b
    airspeed = X[:, IDX_V] - (0.0 if wind is None else np.asarray(wind, float))
    inp = EffectInputs(q=X[:, IDX_Q], v=airspeed, rotor_speeds=W_act, k_T=k_T, rotor_radius=r, d_down=loop.d_down,
                       d_up=loop.d_up, t=t_rec, arm_length=float(vehicle.arm_length))
    per_effect = {name: effect_force(name, params, inp) for name, params in effects.items()}
    if lag is not None:
        per_effect["motor_lag"] = lag_force
    return _Forces(thrust, spec_force, lag_force, per_effect)


# --- one call: a named flight ----------------------------------------------------------


def yaw_acc_limit(vehicle: Vehicle, share: float = 0.3) -> float:
    """Yaw acceleration [rad/s^2] the vehicle reaches at hover when each rotor's squared speed
    may move by ``share`` of its hover value."""
    A = vehicle.allocation()
    w2 = vehicle.hover_speed() ** 2
    return float(np.sum(np.abs(A[3])) * share * w2 / vehicle.inertia[2])


def roll_acc_limit(vehicle: Vehicle, share: float = 0.3) -> float:
    """Roll acceleration [rad/s^2] the vehicle reaches at hover when each rotor's squared speed
    may move by ``share`` of its hover value."""
    A = vehicle.allocation()
    w2 = vehicle.hover_speed() ** 2
    return float(np.sum(np.abs(A[1])) * share * w2 / vehicle.inertia[0])


#: m, lowest height of the body origin over a surface when landed (the landing gear's height)
MIN_BODY_HEIGHT = 0.02


def low_heights(vehicle: Vehicle) -> dict[str, Any]:
    """Rest height [m] and ranges of low hover heights [m] of the body origin for ``vehicle``.

    Planned for the rotor plane (``recordings.md``, "Heights over surfaces"): it rests 0.6 rotor
    radius over the floor (2 to 6 cm) and hovers from one rotor radius to 0.5 m; the body origin
    sits ``rotor_plane_z`` below it, never under :data:`MIN_BODY_HEIGHT` (rotors 15 cm above the
    origin rest 17 cm over the floor, as on their landing gear)."""
    r, z_r = vehicle.rotor_radius, vehicle.rotor_plane_z
    plane_rest = float(np.clip(0.6 * r, 0.02, 0.06))
    rest = plane_rest if z_r == 0.0 else max(plane_rest - z_r, MIN_BODY_HEIGHT)
    lo = max(r, 0.75 * plane_rest) - z_r
    if z_r != 0.0:
        lo = max(lo, 0.75 * rest, MIN_BODY_HEIGHT)
    hi = 0.5 - min(z_r, 0.0)
    return {"rest_height": rest, "floor_heights": (lo, hi), "table_heights": (lo, hi)}


def make_reference(kind: str = "excitation", duration: float = 60.0, seed: int = 0, vehicle: Vehicle | None = None,
                   room: Scene | None = None) -> Reference:
    """The reference of a named flight kind (``excitation``, ``low_passes``, ``mixed``, ``euroc_room``)
    for a vehicle: yaw acceleration within its authority (0.7 x :func:`yaw_acc_limit`, at most
    1 rad/s^2), faster and larger roll/pitch excitation for agile vehicles (:func:`roll_acc_limit`),
    low hovers from one rotor radius up to 0.5 m, rest height 0.6 rotor radius (2 to 6 cm), both
    of the rotor plane (:func:`low_heights`).
    ``euroc_room`` is :func:`uavturb.sim.flights.euroc_standin.reference` (its landed height).
    ``room``: default :func:`flight_room`."""
    room = flight_room(kind) if room is None else room
    yaw_acc = 0.5 if vehicle is None else float(np.clip(0.7 * yaw_acc_limit(vehicle), 0.1, 1.0))
    if kind == "euroc_room":
        return euroc_standin.reference(duration, seed, max_yaw_acc=yaw_acc, room=room)
    exc: dict[str, Any] = {}
    if vehicle is not None:  # agile vehicles are shaken faster (1 for the hexarotor, 2.5 for the quadrotor)
        agility = float(np.clip(np.sqrt(roll_acc_limit(vehicle) / 18.0), 1.0, 2.5))
        exc = {"fast_omega": (3.0 * agility, 7.0 * agility), "tilt_excitation": 0.08 * min(agility, 1.5),
               "max_yaw_rate": 0.8 * min(agility, 2.0)}
    if kind == "excitation":
        return excitation(duration, seed, max_yaw_acc=yaw_acc, **exc)
    low: dict[str, Any] = {}
    if vehicle is not None:
        low = low_heights(vehicle)
    if kind == "low_passes":
        return low_passes(duration, seed, room=room, max_yaw_acc=yaw_acc, **low)
    if kind == "mixed":
        return mixed(duration, seed, room=room, max_yaw_acc=yaw_acc, **low, **exc)
    raise InputError("flight kind", f"unknown kind '{kind}' (known: {', '.join(KINDS)})")


def generate_flight(vehicle: str | Vehicle = "hex", effects: str | dict[str, dict[str, float]] = "",
                    duration: float = 60.0, kind: str = "excitation", seed: int = 0, out: str | Path | None = None,
                    noise: SensorNoise | None = None, overwrite: bool = False, room: Scene | None = None,
                    **simulate_kw: Any) -> Recording:
    """Simulate a named flight and, when ``out`` is given, write it as a recording folder.

    Parameters
    ----------
    vehicle : built-in vehicle (``hex``, ``quad``), ``vehicle.yaml`` path, or Vehicle
    effects : ``"wind:f_x=0.5,ground_effect"`` (see ``parse_effects``) or the parsed dict
    duration : s
    kind : ``excitation``, ``low_passes``, ``mixed`` (see :mod:`uavturb.sim.flights.plans`) or
        ``euroc_room`` (:mod:`uavturb.sim.flights.euroc_standin`: EuRoC's VI-sensor and cam0 on the vehicle)
    seed : seeds the reference and the sensor noise
    out : recording folder to write (atomically, by ``write_recording``)
    noise : SensorNoise (default: realistic)
    overwrite : replace an existing ``out``
    room : the scene (default :func:`flight_room`)
    simulate_kw : passed on to :func:`simulate_flight`

    Returns
    -------
    Recording (with ``path`` set when written).
    """
    v = euroc_standin.flyable(named_vehicle(vehicle) if isinstance(vehicle, str) else vehicle)
    v = euroc_standin.with_vi_sensor(v) if kind == "euroc_room" else v
    room = flight_room(kind) if room is None else room
    eff = parse_effects(effects) if isinstance(effects, str) or effects is None else dict(effects)
    ref = make_reference(kind, duration, seed, v, room)
    rec, _ = simulate_flight(v, ref, duration=duration, effects=eff, room=room,
                             noise=SensorNoise() if noise is None else noise, seed=seed, **simulate_kw)
    rec = euroc_standin.with_cam0(rec) if kind == "euroc_room" else rec
    if out is not None:
        write_recording(rec, out, overwrite=overwrite)
        rec = replace(rec, path=Path(out))
    return rec
