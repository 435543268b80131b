"""Ground contact at both ends of a simulated flight: the vehicle on its landing gear, rotors spinning.

Real recordings start and end on the floor with the rotors running (``recordings.md``): the floor
carries part of the weight, a force no aerodynamic law explains. The simulator has no contact
model, so its flights "rest" hovering at their first and last set-points, a landing-gear height
over the floor (:func:`uavturb.sim.flights.simulate.low_heights`). :func:`with_ground_contact` splices
``seconds`` of contact before the flight's first record and after its last one, at the same
place (the flight's first and last true positions, level, at the flight's first and last
headings):

- position constant (plus the motion capture's noise), velocity and angular velocity zero,
  attitude level: the vehicle sits still;
- the *lift*, rotor thrust plus the effects' vertical force (a ground effect at the landed
  rotor-plane height, a ceiling effect), ramps from :data:`LIFT_FRACTION` ``[0]`` of the weight
  to ``[1]`` before take-off and back down after landing; every rotor at the same speed (no
  torque); the floor carries the rest of the weight and any horizontal push (friction);
- the IMU reads gravity, ``(0, 0, g)`` in B, plus its noise and the flight's biases (held);
- rotor speeds as the flight's, commands equal to speeds (the ramps are slow).

The :class:`~uavturb.sim.flights.simulate.Truth` is spliced alongside, so that the other conditions
(resampling, sensor frames, held streams) see the contact rows like any other. Effects that
depend on the time since the start (``battery_sag``) would move with the splice: they cannot be
combined with contact.
"""

from __future__ import annotations

from dataclasses import dataclass, fields, replace
from typing import Any

import numpy as np

from uavturb.errors import InputError
from uavturb.io.recording import GroundTruth, Imu, Recording, Rotors
from uavturb.physics import quaternion as quat
from uavturb.physics.dynamics import GRAVITY
from uavturb.physics.effects import EffectInputs, effect_force
from uavturb.physics.vehicle import Vehicle
from uavturb.sim.flights.sensors import sensor_readings, SensorNoise
from uavturb.sim.flights.simulate import Truth
from uavturb.sim.core.signals import Setpoint

#: fraction of the weight [-] the lift carries on the ground: at the recording's ends, and just
#: before take-off / just after landing (the floor carries the rest)
LIFT_FRACTION = (0.4, 0.7)
#: m, highest rotor-plane height over the floor at which a flight may be said to start or end landed
MAX_LANDED_HEIGHT = 0.3
#: m/s, fastest a flight may still move at its ends to touch down there
MAX_LANDING_SPEED = 0.1
#: m, most the rotor plane may end over the height it started resting at: the landing gear is the same at both
#: ends, so a flight cut short of its last set-point would "rest" in the air (1.7 cm up on a 60 s low_passes
#: flight). A flight settled at its last set-point ends within 1 cm of it (0.9 cm on a 12 s flight in ground effect)
MAX_LANDED_OFFSET = 0.012
#: effects whose law depends on the time since the recording's start
TIMED_EFFECTS = ("battery_sag",)


@dataclass
class Contact:
    """One contact segment: the :class:`Truth` rows and the sensor readings at ``n`` record times.

    Attributes
    ----------
    truth : Truth of the segment (its ``t`` from 0)
    rec : Recording of the segment (ground truth, IMU, rotors; timestamps from 0 ns)
    floor_force : (n, 3) N in W, what the floor pushes with (weight minus lift, minus horizontal effects)
    """

    truth: Truth
    rec: Recording
    floor_force: np.ndarray


def level(yaw: float) -> np.ndarray:
    """(4,) quaternion w, x, y, z, body to world, of a level attitude at ``yaw`` [rad]."""
    return np.array([np.cos(yaw / 2), 0.0, 0.0, np.sin(yaw / 2)])


def contact_speeds(vehicle: Vehicle, effects: dict[str, dict[str, float]], lift: np.ndarray, q: np.ndarray,
                   airspeed: np.ndarray, d_down: float, d_up: float) -> np.ndarray:
    """Equal rotor speeds [rad/s] (n, N) whose thrust plus the effects' vertical force is ``lift`` [N] (n,).

    The vertical effect forces of a level vehicle standing still (ground and ceiling effects) are
    proportional to the thrust, so one trial speed gives their ratio ``k`` and ``T = lift / (1 + k)``."""
    n_rot, k_T = vehicle.rotor_count, float(vehicle.thrust_coefficient)
    w_trial = np.full((1, n_rot), vehicle.hover_speed())
    thrust_trial = k_T * n_rot * w_trial[0, 0] ** 2  # N
    inp = _inputs(vehicle, q[None], airspeed[None], w_trial, d_down, d_up)
    f_z = sum(float(effect_force(name, p, inp)[0, 2]) for name, p in effects.items())
    thrust = np.asarray(lift, float) / (1.0 + f_z / thrust_trial)
    return np.repeat(np.sqrt(thrust / (n_rot * k_T))[:, None], n_rot, axis=1)


def _inputs(vehicle: Vehicle, q: np.ndarray, airspeed: np.ndarray, w: np.ndarray, d_down: float,
            d_up: float) -> EffectInputs:
    K = len(q)
    return EffectInputs(q=q, v=airspeed, rotor_speeds=w, k_T=float(vehicle.thrust_coefficient),
                        rotor_radius=float(vehicle.rotor_radius), d_down=np.full(K, d_down), d_up=np.full(K, d_up),
                        t=np.zeros(K), arm_length=float(vehicle.arm_length))


def contact_segment(vehicle: Vehicle, effects: dict[str, dict[str, float]], *, p: np.ndarray, yaw: float,
                    lift_fraction: np.ndarray, d_down: float, d_up: float, biases: tuple[np.ndarray, np.ndarray],
                    effect_names: list[str], noise: SensorNoise, seed: int, dt: float,
                    wind: np.ndarray | None) -> Contact:
    """The vehicle still on the floor at ``p`` [m] (3,), level at ``yaw`` [rad], for ``len(lift_fraction)``
    records every ``dt`` [s], its lift that fraction of the weight at each (module docstring).

    ``biases``: the IMU's ``(gyro [rad/s], acc [m/s^2])`` biases in B, (3,) each, held;
    ``effect_names``: the keys of the flight's ``Truth.forces`` (each gets its force here, zero
    for ``motor_lag``); ``wind`` (3,) m/s in W or None."""
    n = len(lift_fraction)
    q = level(yaw)
    airspeed = -(np.zeros(3) if wind is None else np.asarray(wind, float))  # the vehicle stands still
    weight = vehicle.mass * GRAVITY  # N
    w = contact_speeds(vehicle, effects, weight * np.asarray(lift_fraction, float), q, airspeed, d_down, d_up)
    inp = _inputs(vehicle, np.repeat(q[None], n, 0), np.repeat(airspeed[None], n, 0), w, d_down, d_up)
    forces = {name: (effect_force(name, effects[name], inp) if name in effects else np.zeros((n, 3)))
              for name in effect_names}
    f_eff = sum(forces.values(), np.zeros((n, 3)))  # N in W
    thrust = float(vehicle.thrust_coefficient) * np.sum(w**2, axis=1)  # N, along e_z (level)
    floor = weight * np.array([0.0, 0.0, 1.0]) - thrust[:, None] * np.array([0.0, 0.0, 1.0]) - f_eff
    x = np.zeros((n, 13))
    x[:, 0:3], x[:, 3:7] = p, q  # state p, q (w, x, y, z), v = 0, omega = 0
    spec = np.tile([0.0, 0.0, GRAVITY], (n, 1))  # m/s^2 in B: the floor and the lift carry the weight
    quiet = replace(noise, gyro_bias=tuple(float(b) for b in biases[0]), acc_bias=tuple(float(b) for b in biases[1]),
                    gyro_random_walk=0.0, acc_random_walk=0.0)
    s = sensor_readings(x, spec, w, quiet, seed, dt)
    t = np.arange(n) * dt
    t_ns = np.round(t * 1e9).astype(np.int64)
    zeros3 = np.zeros((n, 3))
    ref = Setpoint(t=t, p=np.repeat(p[None], n, 0), v=zeros3, a=zeros3, j=zeros3, yaw=np.full(n, yaw),
                   yaw_rate=np.zeros(n), yaw_acc=np.zeros(n))
    truth = Truth(t=t, x=x, effect_force=f_eff, force=f_eff, lag_force=zeros3, forces=forces, rotor_speeds=w,
                  rotor_commands=w, thrust=thrust, specific_force=spec, d_down=np.full(n, d_down),
                  d_up=np.full(n, d_up), reference=ref, gyro_bias=s.gyro_bias, acc_bias=s.acc_bias,
                  saturated=np.zeros(n, bool))
    rec = Recording(vehicle=vehicle, ground_truth=GroundTruth(t_ns=t_ns, p=s.p, q=s.q, v=s.v, b_w=s.gyro_bias,
                                                              b_a=s.acc_bias),
                    imu=Imu(t_ns=t_ns.copy(), gyro=s.gyro, acc=s.acc, T_BS=np.eye(4), rate_hz=1.0 / dt),
                    rotors=Rotors(t_ns=t_ns.copy(), speeds=s.rotors))
    return Contact(truth, rec, floor)


def concatenate_truths(parts: list[Truth], dt: float) -> Truth:
    """One :class:`Truth` of ``parts`` in time order, its ``t`` every ``dt`` [s] from 0."""
    out: dict[str, Any] = {}
    for f in fields(Truth):
        vals = [getattr(p, f.name) for p in parts]
        if f.name == "forces":
            out[f.name] = {k: np.concatenate([v[k] for v in vals]) for k in vals[0]}
        elif f.name == "reference":
            out[f.name] = Setpoint(*(np.concatenate([getattr(v, g) for v in vals])
                                     for g in ("t", "p", "v", "a", "j", "yaw", "yaw_rate", "yaw_acc")))
        else:
            out[f.name] = np.concatenate(vals)
    n = len(out["t"])
    out["t"] = np.arange(n) * dt
    out["reference"] = replace(out["reference"], t=out["t"].copy())
    return Truth(**out)


def concatenate_recordings(base: Recording, parts: list[Recording], dt_ns: int) -> Recording:
    """``base`` with the ground truth, IMU and rotors of ``parts`` one after the other, rows every
    ``dt_ns`` [ns] from ``base``'s first timestamp (every part at that one rate, all streams together)."""
    n = sum(len(p.ground_truth) for p in parts)
    t_ns = base.t0_ns + np.arange(n, dtype=np.int64) * np.int64(dt_ns)
    gt = GroundTruth(t_ns=t_ns, **{k: np.concatenate([getattr(p.ground_truth, k) for p in parts])
                                   for k in ("p", "q", "v", "b_w", "b_a")})
    imu = replace(base.imu, t_ns=t_ns.copy(), gyro=np.concatenate([p.imu.gyro for p in parts]),
                  acc=np.concatenate([p.imu.acc for p in parts]))
    rotors = Rotors(t_ns=t_ns.copy(), speeds=np.concatenate([p.rotors.speeds for p in parts]))
    return replace(base, ground_truth=gt, imu=imu, rotors=rotors)


def not_settled(truth: Truth) -> str | None:
    """Why the simulated flight ``truth`` has not come to rest on its landing gear at its end, at the speed
    (:data:`MAX_LANDING_SPEED`) and rotor-plane height (:data:`MAX_LANDED_OFFSET`) it started from, or None where
    it has: a flight whose last descent has not settled would "rest" in the air or still moving."""
    speed = np.linalg.norm(truth.x[[0, -1], 7:10], axis=1)  # m/s
    if speed.max() > MAX_LANDING_SPEED:
        return f"needs a flight that ends landed; this one still moves at {speed[1]:.2f} m/s at its end"
    offset = float(truth.d_down[-1] - truth.d_down[0])  # m
    if abs(offset) > MAX_LANDED_OFFSET:
        return (f"needs a flight that ends on its landing gear, at the rotor-plane height it started from "
                f"({truth.d_down[0]:.3f} m over the surface below); this one ends {100 * offset:+.1f} cm from it")
    return None


def with_ground_contact(rec: Recording, truth: Truth, seconds: float, *, vehicle: Vehicle,
                        effects: dict[str, dict[str, float]], noise: SensorNoise, seed: int,
                        wind: np.ndarray | None = None) -> tuple[Recording, Truth, dict[str, Any]]:
    """``rec`` and ``truth`` (a simulated flight at the simulator's single rate) with ``seconds`` [s]
    of ground contact before and after (module docstring), and the ``truth.yaml`` entry.

    Raises
    ------
    InputError
        The flight does not start and end low over the floor (its kind never lands), or its
        effects depend on the time since the start.
    """
    timed = sorted(set(effects) & set(TIMED_EFFECTS))
    if timed:
        raise InputError("--ground-contact-s", f"cannot be combined with {', '.join(timed)} (its law runs on the "
                                               "time since the start, which the contact would shift)")
    if max(truth.d_down[0], truth.d_down[-1]) > MAX_LANDED_HEIGHT:
        raise InputError("--ground-contact-s", f"needs a flight that takes off from and lands on the floor (kinds "
                                               f"low_passes, mixed, euroc_room); this one starts "
                                               f"{truth.d_down[0]:.2f} m and ends {truth.d_down[-1]:.2f} m over it")
    unsettled = not_settled(truth)
    if unsettled is not None:
        raise InputError("--ground-contact-s", f"{unsettled} (give a longer --duration)")
    dt = float(truth.t[1] - truth.t[0])
    n = max(1, int(round(seconds / dt)))
    ramp = np.linspace(LIFT_FRACTION[0], LIFT_FRACTION[1], n)
    ends = {"before": (0, ramp, 100_003), "after": (-1, ramp[::-1], 200_003)}
    segs = {}
    for where, (k, lift, salt) in ends.items():
        segs[where] = contact_segment(
            vehicle, {n_: p for n_, p in effects.items() if n_ != "motor_lag"}, p=truth.x[k, 0:3],
            yaw=float(quat.yaw_of(truth.x[k, 3:7])), lift_fraction=lift, d_down=float(truth.d_down[k]),
            d_up=float(truth.d_up[k]), biases=(truth.gyro_bias[k], truth.acc_bias[k]), effect_names=list(truth.forces),
            noise=noise, seed=int(seed) + salt, dt=dt, wind=wind)
    dt_ns = int(rec.ground_truth.t_ns[1] - rec.ground_truth.t_ns[0])
    rec_out = concatenate_recordings(rec, [segs["before"].rec, rec, segs["after"].rec], dt_ns)
    truth_out = concatenate_truths([segs["before"].truth, truth, segs["after"].truth], dt)
    t_end = float(truth_out.t[-1])
    floor = np.concatenate([segs["before"].floor_force, segs["after"].floor_force])
    doc = {"intervals_s": [[0.0, float(truth_out.t[n - 1])], [float(truth_out.t[-n]), t_end]],
           "seconds_each": n * dt, "landed_position_m": [truth.x[0, 0:3].tolist(), truth.x[-1, 0:3].tolist()],
           "rotor_plane_height_m": [float(truth.d_down[0]), float(truth.d_down[-1])],
           "lift_fraction": list(LIFT_FRACTION),
           "law": "on the landing gear: still, level, IMU reads gravity; lift (thrust plus the effects' vertical "
                  "force) ramps 0.4 -> 0.7 of the weight before take-off and 0.7 -> 0.4 after landing; the floor "
                  "carries the rest",
           "floor_force_z_N": [float(floor[:, 2].min()), float(floor[:, 2].max())],
           "thrust_over_weight": [float(np.min(segs["before"].truth.thrust) / (vehicle.mass * GRAVITY)),
                                  float(np.max(segs["before"].truth.thrust) / (vehicle.mass * GRAVITY))]}
    return rec_out, truth_out, doc
