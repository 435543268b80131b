"""Real recordings' troubles, reproduced on simulated flights with a known truth.

``uavturb generate flight`` simulates a flight (:func:`uavturb.sim.flights.simulate.simulate_flight`:
true states, rotor speeds, accelerations, and the clean 200 Hz recording of ``recordings.md``
in B). The :class:`~uavturb.sim.flights.condition_schema.Conditions` (their schema: ranges, help
texts, the command's options) make it look like a real recording, each trouble written
down in ``truth.yaml`` (:func:`truth_document`) so that tests and the gap proof can score
against it:

``no_imu``
    no ``imu0`` folder (motion capture only).
``rate_hz``, ``jitter_ms``
    ground truth and rotors resampled at ``rate_hz`` (the IMU keeps the simulator's rate), each
    row taken at ``k / rate_hz + U(-jitter, jitter)`` from the stream's first time, two streams
    with independent jitter: every row is the (noisy) state *at its own timestamp* (states
    interpolated linearly, attitudes by slerp, from the 200 Hz record; rotor commands held, as
    a flight controller holds them). Timestamps are exact; the sampling is irregular.
``fixed_heading``, ``heading_deg``
    the reference's yaw is held at its initial value, or at ``heading_deg`` [deg] when given (a
    flight that never turns; two flights at one heading).
``motor_commands``
    ``rotors0`` holds normalised motor commands ``u`` in [0, 1] instead of speeds; the vehicle's
    true speed is the affine thrust curve ``w = a + b u`` [rad/s] (:class:`MotorCurve`: ``a`` an
    idle speed of a quarter of the hover speed, ``a + b`` the controller's top speed).
    ``vehicle.yaml``'s ``rotor_speed_scale`` is ``w_hover / u_hover``, so the nominal model,
    which sees ``scale * u``, is exact at hover and off by ``a (w - w_h) / (w_h - a)`` elsewhere:
    the mismatch is known.
``wind_speed``
    a steady horizontal wind ``v_w = (v_x, v_y, 0)`` [m/s, W], acting as drag on the airspeed
    ``v_a = v - v_w`` (``effects.md``): every effect law sees ``v_a`` instead of ``v``, with the
    vehicle's drag coefficients (``rotor_drag:k_d`` and ``body_drag:c_d`` as given in
    ``--effects``, else their ``effects.md`` magnitudes, switched on)::

        F = -k_d Wsum R [v_a,B,x, v_a,B,y, 0] - c_d |v_a| v_a

    At hover (``v = 0``, level, ``Wsum_h = n sqrt(m g / (n k_T))``) that is the steady push
    ``(f_x, f_y) = k_d Wsum_h (v_x, v_y) + c_d |v_w| (v_x, v_y)`` (:func:`wind_push_at_hover`):
    the ``wind`` the gap finder should find, recorded under ``equivalent_effects``.
``accel_bias_walk``
    the accelerometer bias performs a random walk of density ``sigma`` [m/s^3/sqrt(Hz)] (from
    the sensor's initial bias); the state file's ``b_a`` columns stay at that initial bias, as
    a motion-capture ground truth would not know the walk. The true path is
    ``truth/accel_bias.csv`` (in the IMU's frame).
``sensor_frame = "euroc"``
    ground truth and IMU written in a sensor frame S like EuRoC's VI-sensor IMU
    (:data:`EUROC_T_BS`): x_S 20 deg from B's up axis, z_S forward and 20 deg down, the origin
    10 cm from B's (8 cm forward, 6 cm down), ``T_BS`` in ``vehicle.yaml`` (``recordings.md``:
    ``x_B = T_BS x_S``, ``q_RS`` the attitude of S, ``p``/``v`` of S's origin, IMU in S). The
    IMU at S feels the lever-arm accelerations, computed from the true angular velocity and
    acceleration (:mod:`uavturb.physics.frames`).
``mass_error``
    ``vehicle.yaml``'s mass is the simulated mass times ``1 + mass_error``.
``ground_contact_s``
    the recording starts and ends with ``ground_contact_s`` seconds on the landing gear, rotors
    spinning (:mod:`uavturb.sim.flights.ground_contact`): still, level, at the flight's landed height
    (the first and last set-points of ``low_passes``, ``mixed`` and ``euroc_room`` flights, over the
    floor), the IMU reading gravity, the lift (thrust plus the effects' vertical force) ramping
    from 40 % of the weight to 70 % before take-off and back after landing, the floor carrying
    the rest. ``truth.yaml``: the contact intervals ``[t_start, t_end]`` [s since the first
    ground-truth row] and the floor's force.
``position_hold_hz``, ``rotor_hold_hz``
    sample-and-hold: the ground-truth rows (pose and velocity: a motion-capture pose at
    ``position_hold_hz``) or the ``rotors0`` rows keep their rate (``rate_hz`` or 200 Hz), but the
    value only updates at the hold rate: each update, at ``t0 + k / hold_hz``, appears in the first
    row at or after it with that row's own value, and is repeated bit for bit until the next
    (:func:`~uavturb.sim.flights.stream_troubles.held_rows`). ``truth.yaml``: the update rates and counts.
``rotor_hold_staggered``
    with ``rotor_hold_hz``: each rotor's column is held on its own, rotor ``c`` of ``n`` updating at
    ``t0 + (k + c / n) / rotor_hold_hz`` (round-robin ESC telemetry, as PX4's DShot telemetry asks one
    ESC at a time): the rows change ``n`` times as often as any one rotor's speed.
``rotor_delay_s``
    the ``rotors0`` timestamps are late: the row at ``t`` holds the rotor value in force at
    ``t - delay`` (the 200 Hz stream shifted before any resampling or holding; the first value
    repeated before the start).
``thrust_level``
    the true thrust coefficient is ``vehicle.yaml``'s times ``thrust_level`` (the flight is
    simulated with ``k_T * thrust_level``, ``vehicle.yaml`` keeps ``k_T``): recordings of one vehicle
    on other days, batteries or propellers. ``truth.yaml``: both coefficients.
``thrust_tilt_deg``, ``thrust_tilt_azimuth_deg``
    the rotors' thrust axis is tilted by ``tilt`` from the airframe's z axis, towards the azimuth
    ``az`` in the airframe's x-y plane (a bent arm, tilted motor mounts). The physics runs in the
    rotor frame B; the recording's attitude and IMU are the *airframe's* (the motion-capture
    markers and the flight controller's IMU sit on it), ``R_WS = R_WB R_SB^T`` with ``R_SB`` the
    tilt (:func:`~uavturb.sim.flights.stream_troubles.tilt_rotation`), the IMU's gyro and accelerometer
    rotated alike, and ``vehicle.yaml`` does not know it (no ``T_BS``). A model thrusting along the
    airframe's z then sees a push fixed in the airframe, ``m g sin(tilt)`` at hover towards
    ``az``: at a fixed heading it looks like ``wind``, which it is not (``effects.md``'s
    look-alikes). ``truth.yaml``: tilt, azimuth and that push (``push_at_hover``, in W at the
    flight's first heading, and in the airframe).
``rotor_plane_z``
    the rotor discs' plane sits ``rotor_plane_z`` [m] above the body origin along z_B (negative:
    below), written in ``vehicle.yaml``; surface effects act at the rotor plane's height (the
    simulator's closed loop), and low flights are planned for the rotor plane
    (:func:`uavturb.sim.flights.simulate.low_heights`).
``measured_rotors``
    ``rotors0`` holds the rotor speeds the ESCs measure: the actual speeds (lagging the commands
    by the motor time constant of a ``motor_lag`` in the physics), slowed by a ``battery_sag`` as a
    sagging voltage would (:func:`~uavturb.sim.flights.stream_troubles.measured_speeds`, the nominal
    model's thrust is then the true one), quantised like commands; ``vehicle.yaml``'s
    ``rotor_speed_source`` is ``measured``. A ``battery_sag`` or ``motor_lag`` in the physics is then
    invisible: ``truth.yaml`` lists them under ``invisible_effects`` and leaves them out of
    ``equivalent_effects`` (naming them is wrong).
``battery_voltage``
    a ``battery0`` stream (10 Hz, voltage only) from this voltage [V] (16.8 for a full 4S pack),
    sagging as ``V0 sqrt(1 - s t)``: ``s`` the ``battery_sag`` of the physics (thrust per speed
    squared goes as the voltage squared), else a drain of 7e-4 1/s that speed-regulated motors
    do not feel.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from uavturb.errors import InputError
from uavturb.io import align
from uavturb.io.recording import GroundTruth, Recording, Rotors
from uavturb.io.vehicle_file import named_vehicle
from uavturb.io.writer import write_recording
from uavturb.io.yaml_mapping import read_yaml_mapping
from uavturb.physics import frames
from uavturb.physics.dynamics import GRAVITY, IDX_W, dynamics_for, physical_params
from uavturb.physics.effects import EFFECTS, parse_effects
from uavturb.physics.vehicle import Vehicle
from uavturb.sim.flights import euroc_standin
from uavturb.sim.flights.condition_schema import Conditions
from uavturb.sim.core.signals import Constant, Reference
from uavturb.sim.flights.ground_contact import not_settled, with_ground_contact
from uavturb.sim.flights.sensors import SensorNoise
from uavturb.sim.flights.simulate import flight_room, make_reference, simulate_flight
from uavturb.sim.flights.stream_troubles import (
    DRAIN_SAG,
    battery_samples,
    battery_stream,
    delayed_rows,
    held_rows,
    loaded_voltage,
    measured_speeds,
    tilt_push_at_hover,
    tilt_rotation,
    voltage_commands,
)

#: EuRoC-like pose of the sensor frame S in B (``x_B = T_BS x_S``): columns of the rotation are S's
#: axes in B, x_S = (sin 20, 0, cos 20) (20 deg from up), y_S = (0, -1, 0), z_S = (cos 20, 0, -sin 20)
#: (forward, 20 deg down); origin (0.08, 0, -0.06) m: 10 cm forward and below the rotor centre.
#: At hover the IMU reads R_BS^T (0, 0, g) = (9.22, 0, -3.36) m/s^2, as EuRoC's does (recordings.md).
_C, _S = np.cos(np.radians(20.0)), np.sin(np.radians(20.0))
EUROC_T_BS = np.array([[_S, 0.0, _C, 0.08],
                       [0.0, -1.0, 0.0, 0.0],
                       [_C, 0.0, -_S, -0.06],
                       [0.0, 0.0, 0.0, 1.0]])
#: file of the truth, at the recording's root
TRUTH_FILE = "truth.yaml"
#: s, flown past a plan that outlasts the duration asked for, or past the duration where the flight's last descent
#: has not settled on its landing gear by then (``ground_contact.not_settled``: gap-proof's conditions, seed 101
#: at 30 s, 131, 137 and 139 at 45 s, ended 1.7-2.2 cm over their landed height), so that a flight with ground
#: contact ends landed
LANDING_SETTLE_S = 3.0
BIAS_FILE = "truth/accel_bias.csv"
ROTOR_TRUTH_FILE = "truth/rotor_speeds.csv"


# --- before the simulation: the reference and the physics ------------------------------------------


def hold_heading(reference: Reference, yaw: float | None = None) -> Reference:
    """``reference`` with its yaw held at ``yaw`` [rad], default its initial value (yaw rate and
    acceleration zero)."""
    yaw0 = float(reference.yaw.derivs(np.zeros(1))[0, 0]) if yaw is None else float(yaw)
    return replace(reference, yaw=Constant(yaw0), name=f"{reference.name}, fixed heading")


def drag_coefficients(effects: dict[str, dict[str, float]]) -> tuple[float, float]:
    """``(k_d [N s^2/m], c_d [kg/m])``: the ``--effects`` values, else ``effects.md``'s magnitudes."""
    k_d = effects.get("rotor_drag", {}).get("k_d", EFFECTS["rotor_drag"].typical[0])
    c_d = effects.get("body_drag", {}).get("c_d", EFFECTS["body_drag"].typical[0])
    return float(k_d), float(c_d)


def with_drag(effects: dict[str, dict[str, float]]) -> dict[str, dict[str, float]]:
    """``effects`` with rotor and body drag switched on (the wind acts through them)."""
    k_d, c_d = drag_coefficients(effects)
    return {**effects, "rotor_drag": {"k_d": k_d}, "body_drag": {"c_d": c_d}}


def hover_rotor_sum(vehicle: Vehicle) -> float:
    """``Wsum_h = n sqrt(m g / (n k_T))`` [rad/s]: the rotor speeds' sum at hover."""
    n = vehicle.rotor_count
    return n * float(np.sqrt(vehicle.mass * GRAVITY / (n * float(vehicle.thrust_coefficient))))


def wind_push_at_hover(vehicle: Vehicle, k_d: float, c_d: float, wind_speed: tuple[float, float]) -> np.ndarray:
    """The steady push [N] (2,) of a wind ``(v_x, v_y)`` [m/s] on the vehicle hovering level:
    ``k_d Wsum_h v_w + c_d |v_w| v_w`` (rotor drag and body drag on the airspeed ``-v_w``)."""
    vw = np.asarray(wind_speed, float)
    return k_d * hover_rotor_sum(vehicle) * vw + c_d * float(np.linalg.norm(vw)) * vw


@dataclass(frozen=True)
class MotorCurve:
    """Affine thrust curve of the motors: true speed ``w = a + b u`` [rad/s] for a command ``u`` in [0, 1].

    Attributes
    ----------
    a : rad/s, speed at zero command (idle)
    b : rad/s, speed gained from zero to full command
    """

    a: float
    b: float

    @classmethod
    def for_vehicle(cls, vehicle: Vehicle, w_max: float) -> "MotorCurve":
        """Idle at a quarter of the hover speed, full command at ``w_max`` [rad/s]."""
        a = round(0.25 * vehicle.hover_speed(), 1)
        return cls(a=a, b=round(w_max - a, 1))

    def speed(self, u: np.ndarray) -> np.ndarray:
        """rad/s, ``a + b u``."""
        return self.a + self.b * np.asarray(u, float)

    def command(self, w: np.ndarray) -> np.ndarray:
        """``u = (w - a) / b``, clipped to [0, 1]."""
        return np.clip((np.asarray(w, float) - self.a) / self.b, 0.0, 1.0)

    def scale_at_hover(self, w_hover: float) -> float:
        """rad/s per unit command that makes ``scale * u`` exact at hover: ``w_h / u_h``."""
        return float(w_hover / ((w_hover - self.a) / self.b))


# --- after the simulation: what the recording shows ---------------------------------------------------


def angular_motion(truth: Any, vehicle: Vehicle) -> tuple[np.ndarray, np.ndarray]:
    """True ``(omega_B [rad/s], alpha_B [rad/s^2])`` (K, 3) of a simulated flight (``Truth``):
    the states' rates and the dynamics' angular acceleration (no external torque is simulated)."""
    dyn, theta = dynamics_for(vehicle), physical_params(vehicle)
    xdot = dyn.xdot(truth.x, truth.rotor_speeds, theta, truth.force)
    return truth.x[:, IDX_W], np.asarray(xdot)[:, IDX_W]


def to_sensor_frame(rec: Recording, truth: Any, T_BS: np.ndarray) -> Recording:
    """``rec`` (in B, S = B) as recorded by a sensor at ``T_BS`` (pose of S in B): ground truth of
    S's origin and attitude, IMU in S with the lever-arm accelerations of the true motion."""
    omega, alpha = angular_motion(truth, rec.vehicle)
    gt = rec.ground_truth
    gt_s = GroundTruth(t_ns=gt.t_ns, p=frames.position_to_sensor(gt.p, gt.q, T_BS),
                       q=frames.attitude_to_sensor(gt.q, T_BS), v=frames.velocity_to_sensor(gt.v, gt.q, omega, T_BS),
                       b_w=frames.vector_to_sensor(gt.b_w, T_BS), b_a=frames.vector_to_sensor(gt.b_a, T_BS))
    imu = rec.imu
    if imu is not None:
        imu = replace(imu, gyro=frames.vector_to_sensor(imu.gyro, T_BS),
                      acc=frames.specific_force_to_sensor(imu.acc, omega, alpha, T_BS), T_BS=np.eye(4))
    T = tuple(tuple(float(x) for x in row) for row in T_BS)
    return replace(rec, vehicle=rec.vehicle.with_params(T_BS=T), ground_truth=gt_s, imu=imu, frame="S")


def jittered_times(t0_ns: int, t1_ns: int, rate_hz: float, jitter_ms: float, rng: np.random.Generator) -> np.ndarray:
    """int64 ns, ``t0 + k / rate + U(-jitter, jitter)`` within ``[t0, t1]``, strictly increasing."""
    period = 1e9 / rate_hz
    n = int((t1_ns - t0_ns) // period) + 1
    t = t0_ns + np.round(np.arange(n) * period).astype(np.int64)
    if jitter_ms > 0:
        t = t + np.round(rng.uniform(-jitter_ms, jitter_ms, n) * 1e6).astype(np.int64)
    return np.clip(t, t0_ns, t1_ns)


def resample_streams(rec: Recording, rate_hz: float, jitter_ms: float, rng: np.random.Generator) -> Recording:
    """Ground truth and rotors at ``rate_hz`` with jittered sampling times (module docstring)."""
    gt, rot = rec.ground_truth, rec.rotors
    t = jittered_times(int(gt.t_ns[0]), int(gt.t_ns[-1]), rate_hz, jitter_ms, rng)
    lin = {k: align.interpolate(gt.t_ns, getattr(gt, k), t) for k in ("p", "v", "b_w", "b_a")}
    gt_new = GroundTruth(t_ns=t, q=align.interpolate_quaternions(gt.t_ns, gt.q, t), **lin)
    rotors = rot
    if rot is not None:
        tr = jittered_times(int(rot.t_ns[0]), int(rot.t_ns[-1]), rate_hz, jitter_ms, rng)
        held = np.searchsorted(rot.t_ns, tr, side="right") - 1  # the command in force at each time
        rotors = Rotors(t_ns=tr, speeds=rot.speeds[held])
    return replace(rec, ground_truth=gt_new, rotors=rotors)


def motor_command_stream(rec: Recording, curve: MotorCurve, w_hover: float) -> tuple[Recording, dict[str, Any]]:
    """``rotors0`` as normalised commands ``u = (w - a) / b``; ``vehicle.yaml``'s
    ``rotor_speed_scale`` = ``w_h / u_h`` (in memory the rotor stream is ``scale * u``, which the
    writer divides by the scale: ``u`` on disk)."""
    u = curve.command(rec.rotors.speeds)
    clipped = int(np.sum((rec.rotors.speeds < curve.a) | (rec.rotors.speeds > curve.a + curve.b)))
    scale = curve.scale_at_hover(w_hover)
    vehicle = rec.vehicle.with_params(rotor_speed_scale=scale)
    truth = {"law": "w = a + b u (true rotor speed [rad/s] from the normalised command u in rotors0)",
             "a": curve.a, "b": curve.b, "rotor_speed_scale": scale, "u_hover": float((w_hover - curve.a) / curve.b),
             "nominal_model_error": "scale u - w = a (w - w_hover) / (w_hover - a) [rad/s]: exact at hover",
             "clipped_samples": clipped}
    return replace(rec, vehicle=vehicle, rotors=Rotors(rec.rotors.t_ns, scale * u)), truth


@dataclass
class Conditioned:
    """A conditioned recording and its truth.

    Attributes
    ----------
    recording : the Recording to write (``frame`` ``"S"`` with a sensor frame)
    truth : the ``truth.yaml`` document (dict)
    extras : ``{relative path: text}`` files of the truth (``truth.yaml``, the bias path)
    """

    recording: Recording
    truth: dict[str, Any]
    extras: dict[str, str] = field(default_factory=dict)


def condition(rec: Recording, truth: Any, cond: Conditions, *, true_vehicle: Vehicle,
              effects: dict[str, dict[str, float]], seed: int = 0, w_max: float | None = None,
              noise: SensorNoise | None = None) -> Conditioned:
    """Make the simulator's recording ``rec`` (in B, with its ``Truth``) show the troubles of ``cond``.

    Parameters
    ----------
    rec, truth : :func:`~uavturb.sim.flights.simulate.simulate_flight`'s outputs
    cond : Conditions
    true_vehicle : the simulated vehicle (with ``thrust_level`` already in its ``k_T``)
    effects : the simulated effects (``{name: params}``)
    seed : seeds the sampling jitter, the contact segments' and the battery's noise
    w_max : rad/s, the controller's top speed (the motor curve's full command)
    noise : the flight's SensorNoise (default realistic): the contact segments' noise and the
        measured rotor speeds' resolution
    """
    rng = np.random.default_rng([int(seed), 11])
    noise = SensorNoise() if noise is None else noise
    doc: dict[str, Any] = {}
    extras: dict[str, str] = {}
    if cond.ground_contact_s > 0:
        wind = None if cond.wind_speed is None else np.array([*cond.wind_speed, 0.0])
        rec, truth, doc["ground_contact"] = with_ground_contact(rec, truth, cond.ground_contact_s,
                                                                vehicle=true_vehicle, effects=physics_effects(effects),
                                                                noise=noise, seed=seed, wind=wind)
    volts = _loaded_voltage(rec, truth, cond, effects, true_vehicle)
    volts_t_ns = rec.rotors.t_ns  # the simulator's rows (the streams may be resampled below)
    if volts is not None and "battery_voltage" in effects and not cond.measured_rotors:
        k_V = float(effects["battery_voltage"]["k_V"])
        # the law's reference: the mean voltage in flight (the finder's, to first order), so that k_V is the law's
        # slope at the flight's own level: the level itself is the recording's thrust level
        flying = np.sum(np.asarray(truth.rotor_speeds, float) ** 2, axis=1) * float(true_vehicle.thrust_coefficient) \
            > 0.3 * true_vehicle.mass * GRAVITY
        v_ref = float(np.mean(volts[flying])) if flying.any() else float(np.mean(volts))
        rec = replace(rec, rotors=Rotors(rec.rotors.t_ns, voltage_commands(rec.rotors.speeds, volts, v_ref, k_V)))
        doc["battery_voltage"] = {"law": "thrust per commanded speed squared k_T (1 + k_V (V - V_ref)): rotors0 "
                                         "holds w / sqrt(1 + k_V (V - V_ref)) for the true speeds w",
                                  "k_V": k_V, "V_ref": float(v_ref)}
    rec = _rotor_telemetry(rec, truth, cond, effects, noise, doc, extras)
    rec = _frames(rec, truth, cond, doc, extras)
    if cond.motor_commands:
        curve = MotorCurve.for_vehicle(true_vehicle, w_max or 2.5 * true_vehicle.hover_speed())
        rec, doc["motor_commands"] = motor_command_stream(rec, curve, true_vehicle.hover_speed())
    if cond.resampled:
        rate = cond.rate_hz or 200.0
        rec = resample_streams(rec, rate, cond.jitter_ms, rng)
        doc["streams"] = {"rate_hz": rate, "jitter_ms": cond.jitter_ms,
                          "applies_to": ["state_groundtruth_estimate0", "rotors0"],
                          "law": "row k taken at k / rate_hz + U(-jitter, jitter) (exact timestamps); rotor commands "
                                 "held"}
    rec = _held_streams(rec, cond, doc)
    if cond.no_imu:
        rec = replace(rec, imu=None)
        doc["no_imu"] = True
    rec = _vehicle_file(rec, cond, true_vehicle, truth, doc)
    if cond.fixed_heading:
        doc["fixed_heading"] = {"yaw_rad": float(truth.reference.yaw[0])}
    if cond.wind_speed is not None:
        k_d, c_d = drag_coefficients(effects)
        push = wind_push_at_hover(true_vehicle, k_d, c_d, cond.wind_speed)
        doc["wind_speed"] = {"v_x": float(cond.wind_speed[0]), "v_y": float(cond.wind_speed[1]), "unit": "m/s",
                             "law": "F = -k_d Wsum R [v_a,B,x, v_a,B,y, 0] - c_d |v_a| v_a, v_a = v - v_wind",
                             "k_d": k_d, "c_d": c_d, "wsum_hover": hover_rotor_sum(true_vehicle),
                             "push_at_hover": {"f_x": float(push[0]), "f_y": float(push[1])}}
    if volts is not None:
        rec = replace(rec, battery=battery_samples(volts_t_ns, volts, np.random.default_rng([int(seed), 13])))
        doc["battery"] = {"stream": "battery0", "law": "V = V0 sqrt(1 - s t) - V0 load_sag (T / (m g))^1.5",
                          "V0": cond.battery_voltage, "s": DRAIN_SAG, "load_sag": cond.battery_load_sag,
                          "rate_hz": 10.0}
    elif cond.battery_voltage is not None:
        sag = float(effects.get("battery_sag", {}).get("s", DRAIN_SAG))
        gt = rec.ground_truth
        rec = replace(rec, battery=battery_stream(int(gt.t_ns[0]), int(gt.t_ns[-1]), cond.battery_voltage, sag,
                                                  np.random.default_rng([int(seed), 13])))
        doc["battery"] = {"stream": "battery0", "law": "V = V0 sqrt(1 - s t)", "V0": cond.battery_voltage, "s": sag,
                          "s_from": "battery_sag" if "battery_sag" in effects else "drain (thrust unaffected)",
                          "rate_hz": 10.0}
    return Conditioned(rec, doc, extras)


def physics_effects(effects: dict[str, dict[str, float]]) -> dict[str, dict[str, float]]:
    """The effects the simulator's physics applies: all but those that are not forces (``EffectSpec.simulated``:
    ``battery_voltage``, what the logged commands mean, which :func:`condition` writes into ``rotors0``)."""
    return {name: p for name, p in effects.items() if EFFECTS[name].simulated}


def _loaded_voltage(rec: Recording, truth: Any, cond: Conditions, effects: dict[str, dict[str, float]],
                    true_vehicle: Vehicle) -> np.ndarray | None:
    """(K,) V on the rotor stream's rows, a battery sagging under load (:func:`~uavturb.sim.flights.stream_troubles.
    loaded_voltage`), where ``--battery-load-sag`` or a ``battery_voltage`` in the effects asks for it; else None."""
    if cond.battery_voltage is None or (cond.battery_load_sag <= 0 and "battery_voltage" not in effects):
        return None
    thrust = float(true_vehicle.thrust_coefficient) * np.sum(np.asarray(truth.rotor_speeds, float) ** 2, axis=1)
    t = (rec.rotors.t_ns - rec.t0_ns) * 1e-9
    return loaded_voltage(t, thrust, cond.battery_voltage, DRAIN_SAG, cond.battery_load_sag,
                          true_vehicle.mass * GRAVITY)


def _rotor_telemetry(rec: Recording, truth: Any, cond: Conditions, effects: dict[str, dict[str, float]],
                     noise: SensorNoise, doc: dict[str, Any], extras: dict[str, str]) -> Recording:
    """``rotors0`` as measured speeds and/or late (on the simulator's single-rate stream); the true
    speeds as ``truth/rotor_speeds.csv`` when rotor telemetry is troubled."""
    rot = rec.rotors
    if cond.measured_rotors:
        sag = float(effects.get("battery_sag", {}).get("s", 0.0))
        t = (rot.t_ns - rec.t0_ns) * 1e-9
        rot = Rotors(rot.t_ns, measured_speeds(truth.rotor_speeds, t, sag, noise.rotor_quantum))
        invisible = sorted(set(effects) & {"battery_sag", "battery_voltage", "motor_lag"})
        doc["measured_rotors"] = {"rotor_speed_source": "measured",
                                  "law": "w_meas = w_actual sqrt(1 - s t) (s: battery_sag, else 0), quantised",
                                  "quantum": noise.rotor_quantum, "invisible": invisible}
    if cond.rotor_delay_s > 0:
        rot = Rotors(rot.t_ns, rot.speeds[delayed_rows(rot.t_ns, cond.rotor_delay_s)])
        doc["rotor_delay"] = {"seconds": cond.rotor_delay_s, "stream": "rotors0",
                              "law": "the row at t holds the value in force at t - delay (before resampling)"}
    if cond.measured_rotors or cond.rotor_delay_s > 0 or cond.rotor_hold_hz is not None:
        n = truth.rotor_speeds.shape[1]
        lines = ["#timestamp [ns]," + ",".join(f"w_{i} [rad s^-1]" for i in range(n))]
        lines += [f"{t}," + ",".join(f"{w:.6f}" for w in row) for t, row in zip(rec.rotors.t_ns, truth.rotor_speeds)]
        extras[ROTOR_TRUTH_FILE] = "\n".join(lines) + "\n"
        doc["true_rotor_speeds"] = {"file": ROTOR_TRUTH_FILE, "what": "actual rotor speeds at the simulator's "
                                                                      "record times (on time)"}
    return replace(rec, rotors=rot)


def _frames(rec: Recording, truth: Any, cond: Conditions, doc: dict[str, Any], extras: dict[str, str]) -> Recording:
    """The attitude and IMU in the airframe of a tilted thrust axis, or in EuRoC's sensor frame; the
    accelerometer bias walk's truth."""
    if cond.accel_bias_walk > 0 and rec.imu is not None:
        b0 = truth.acc_bias[:1]  # the initial bias: all a motion-capture state file would know
        rec = replace(rec, ground_truth=replace(rec.ground_truth, b_a=np.repeat(b0, len(rec.ground_truth), 0)))
    T_BS = EUROC_T_BS if cond.sensor_frame == "euroc" else np.eye(4)
    if cond.sensor_frame == "euroc":
        rec = to_sensor_frame(rec, truth, T_BS)
        doc["sensor_frame"] = {"name": "euroc", "T_BS": T_BS.tolist(),
                               "lever_arm_m": float(np.linalg.norm(T_BS[:3, 3])), "x_S_from_up_deg": 20.0,
                               "imu_at_hover_m_s2": (T_BS[:3, :3].T @ [0, 0, GRAVITY]).tolist()}
    if cond.thrust_tilt_deg > 0:
        R_SB = tilt_rotation(cond.thrust_tilt_deg, cond.thrust_tilt_azimuth_deg)
        T_BS = np.eye(4)
        T_BS[:3, :3] = R_SB.T
        vehicle, frame = rec.vehicle, rec.frame
        rec = replace(to_sensor_frame(rec, truth, T_BS), vehicle=vehicle, frame=frame)  # vehicle.yaml does not know
        push = tilt_push_at_hover(vehicle.mass, cond.thrust_tilt_deg, cond.thrust_tilt_azimuth_deg,
                                  float(truth.reference.yaw[0]))
        doc["thrust_tilt"] = {"tilt_deg": cond.thrust_tilt_deg, "azimuth_deg": cond.thrust_tilt_azimuth_deg,
                              "thrust_axis_in_airframe": (R_SB @ [0.0, 0.0, 1.0]).tolist(),
                              "law": "attitude and IMU of the airframe S, R_WS = R_WB R_SB^T; thrust along z_B",
                              "push_at_hover": push,
                              "looks_like": "wind at a fixed heading (the push turns with the airframe)"}
    if cond.accel_bias_walk > 0 and rec.imu is not None:
        bias = frames.vector_to_sensor(truth.acc_bias, T_BS)  # the true bias, in the IMU's frame
        lines = ["#timestamp [ns],b_a_x [m s^-2],b_a_y [m s^-2],b_a_z [m s^-2]"]
        lines += [f"{t},{b[0]:.9g},{b[1]:.9g},{b[2]:.9g}" for t, b in zip(rec.imu.t_ns, bias)]
        extras[BIAS_FILE] = "\n".join(lines) + "\n"
        doc["accel_bias_walk"] = {"sigma": cond.accel_bias_walk, "unit": "m/s^3/sqrt(Hz)", "file": BIAS_FILE,
                                  "frame": "S" if cond.sensor_frame == "euroc" else "B",
                                  "state_file_b_a": "held at the initial bias", "initial": bias[0].tolist(),
                                  "final": bias[-1].tolist(), "max_abs": float(np.abs(bias).max())}
    return rec


def _held_streams(rec: Recording, cond: Conditions, doc: dict[str, Any]) -> Recording:
    """Ground truth and/or rotors updating at their hold rates in rows at their own rates."""
    held: dict[str, Any] = {}
    row_hz = cond.rate_hz or 200.0
    if cond.position_hold_hz is not None:
        gt = rec.ground_truth
        k = held_rows(gt.t_ns, cond.position_hold_hz)
        rec = replace(rec, ground_truth=GroundTruth(t_ns=gt.t_ns, **{f: getattr(gt, f)[k]
                                                                    for f in ("p", "q", "v", "b_w", "b_a")}))
        held["state_groundtruth_estimate0"] = {"update_hz": cond.position_hold_hz, "row_hz": row_hz,
                                               "updates": int(len(np.unique(k)))}
    if cond.rotor_hold_hz is not None:
        rot = rec.rotors
        n = rot.speeds.shape[1]
        phases = [c / n if cond.rotor_hold_staggered else 0.0 for c in range(n)]
        ks = [held_rows(rot.t_ns, cond.rotor_hold_hz, phase) for phase in phases]
        rec = replace(rec, rotors=Rotors(rot.t_ns, np.column_stack([rot.speeds[k, c] for c, k in enumerate(ks)])))
        held["rotors0"] = {"update_hz": cond.rotor_hold_hz, "row_hz": row_hz, "updates": int(len(np.unique(ks[0])))}
        if cond.rotor_hold_staggered:
            held["rotors0"]["staggered"] = "rotor c of n updates at t0 + (k + c / n) / update_hz"
    if held:
        doc["held_streams"] = {**held, "law": "update k at t0 + k / update_hz appears in the first row at or after "
                                              "it and repeats bit for bit until the next"}
    return rec


def _vehicle_file(rec: Recording, cond: Conditions, true_vehicle: Vehicle, truth: Any,
                  doc: dict[str, Any]) -> Recording:
    """What ``vehicle.yaml`` says: a mass off, the nominal thrust coefficient, the rotor speeds' source (``measured``
    with measured rotors, ``commanded`` with motor commands, whatever the vehicle file given said), the rotor
    plane's height (already the simulated vehicle's)."""
    v = rec.vehicle
    if cond.mass_error:
        m = true_vehicle.mass
        v = v.with_params(mass=m * (1.0 + cond.mass_error))
        doc["mass_error"] = {"fraction": cond.mass_error, "true_mass": m, "recorded_mass": m * (1.0 + cond.mass_error)}
    if cond.thrust_level != 1.0:
        k_true = float(true_vehicle.thrust_coefficient)
        v = v.with_params(thrust_coefficient=k_true / cond.thrust_level)
        doc["thrust_level"] = {"factor": cond.thrust_level, "true_thrust_coefficient": k_true,
                               "recorded_thrust_coefficient": k_true / cond.thrust_level,
                               "law": "true k_T = vehicle.yaml's k_T * factor (a per-recording thrust level)"}
    if cond.measured_rotors:
        v = v.with_params(rotor_speed_source="measured")
    elif cond.motor_commands:  # commands, whatever the vehicle file given said: one that said measured had been
        v = v.with_params(rotor_speed_source="commanded")  # kept, and the finder read the commands' map as speeds
    if cond.rotor_plane_z != 0.0:
        z_body = truth.x[:, 2]
        doc["rotor_plane_z"] = {"m": cond.rotor_plane_z, "in": "vehicle.yaml",
                                "rotor_plane_height_min_m": float(np.min(truth.d_down)),
                                "body_origin_height_min_m": float(np.min(z_body))}
    return replace(rec, vehicle=v)


def truth_document(true_vehicle: Vehicle, effects: dict[str, dict[str, float]], conditions: dict[str, Any], *,
                   seed: int, kind: str, duration: float) -> dict[str, Any]:
    """The ``truth.yaml`` document: the simulated vehicle, the simulated effects, the effects the
    gap finder should find (``equivalent_effects``), those of the physics the recording cannot
    show (``invisible_effects``: with measured rotor speeds) and the conditions' truths."""
    invisible = conditions.get("measured_rotors", {}).get("invisible", [])
    equivalent = {name: dict(p) for name, p in effects.items() if name not in invisible}
    if "wind_speed" in conditions:
        equivalent["wind"] = dict(conditions["wind_speed"]["push_at_hover"])
    return {
        "simulator": "uavturb generate flight",
        "seed": int(seed), "kind": kind, "duration_s": float(duration),
        "vehicle": {"mass": true_vehicle.mass, "thrust_coefficient": true_vehicle.thrust_coefficient,
                    "moment_coefficient": true_vehicle.moment_coefficient,
                    "inertia": [float(j) for j in true_vehicle.inertia],
                    "rotor_plane_z": float(true_vehicle.rotor_plane_z)},
        "effects": {name: {k: float(v) for k, v in p.items()} for name, p in effects.items()},
        "equivalent_effects": {name: {k: float(v) for k, v in p.items()} for name, p in equivalent.items()},
        "invisible_effects": list(invisible),
        "conditions": conditions,
    }


def _check_voltage_law(effects: dict[str, dict[str, float]], conditions: Conditions) -> None:
    """A ``battery_voltage`` needs a battery to follow and cannot sit beside ``battery_sag`` (both say what the
    battery does to the thrust per command)."""
    if "battery_voltage" not in effects:
        return
    if conditions.battery_voltage is None:
        raise InputError("--effects", "battery_voltage needs --battery-voltage (the voltage the thrust follows)")
    if "battery_sag" in effects:
        raise InputError("--effects", "battery_voltage and battery_sag both set the thrust per command: give one")


def read_truth(path: str | Path) -> dict[str, Any]:
    """``truth.yaml`` of a generated recording folder."""
    return read_yaml_mapping(Path(path) / TRUTH_FILE,
                             not_found="file not found (only recordings made by 'uavturb generate flight' carry one)")


def generate_conditioned_flight(vehicle: str | Vehicle = "hex", effects: str | dict[str, dict[str, float]] = "",
                                duration: float = 60.0, kind: str = "mixed", seed: int = 0,
                                conditions: Conditions = Conditions(), noise: Any = None,
                                out: str | Path | None = None, overwrite: bool = False) -> Conditioned:
    """Simulate a named flight under ``conditions`` and, when ``out`` is given, write it with its
    ``truth.yaml`` (one atomic publication).

    Parameters
    ----------
    vehicle : built-in vehicle (``hex``, ``quad``), ``vehicle.yaml`` path or Vehicle (the simulated, true vehicle; the
        shipped ``firefly`` flies with RotorS's constants, :func:`uavturb.sim.flights.euroc_standin.flyable`)
    effects : ``"wind:f_x=0.5,rotor_drag"`` or the parsed dict (``effects.md``)
    duration : s (with ground contact, longer where the plan's take-off and landing need it); kind : flight kind
        (:data:`uavturb.sim.flights.simulate.KINDS`; ``euroc_room`` adds EuRoC's VI-sensor frame and cam0,
        :mod:`uavturb.sim.flights.euroc_standin`); seed : reference and noise
    conditions : Conditions
    noise : SensorNoise (default realistic); ``accel_bias_walk`` sets its ``acc_random_walk``
    out : recording folder to write; overwrite : replace it

    Returns
    -------
    Conditioned (``recording.path`` set when written).
    """
    stand_in = kind == euroc_standin.KIND
    v = euroc_standin.flyable(named_vehicle(vehicle) if isinstance(vehicle, str) else vehicle)
    v = euroc_standin.with_vi_sensor(v) if stand_in else v
    v = v.with_params(rotor_plane_z=conditions.rotor_plane_z or v.rotor_plane_z,
                      thrust_coefficient=float(v.thrust_coefficient) * conditions.thrust_level)
    room = flight_room(kind)
    eff = parse_effects(effects) if isinstance(effects, str) or effects is None else dict(effects)
    noise = SensorNoise() if noise is None else noise
    if conditions.accel_bias_walk > 0:
        noise = replace(noise, acc_random_walk=float(conditions.accel_bias_walk))
    ref = make_reference(kind, duration, seed, v, room)
    if conditions.ground_contact_s > 0 and ref.duration > duration:  # take-off and landing needed longer:
        duration = ref.duration + LANDING_SETTLE_S  # it must land before its rest on the gear is spliced on
    if conditions.fixed_heading:
        ref = hold_heading(ref, None if conditions.heading_deg is None else np.radians(conditions.heading_deg))
    wind = None
    if conditions.wind_speed is not None:
        eff = with_drag(eff)
        wind = np.array([conditions.wind_speed[0], conditions.wind_speed[1], 0.0])
    _check_voltage_law(eff, conditions)
    rec, truth = simulate_flight(v, ref, duration=duration, effects=physics_effects(eff), noise=noise, seed=seed,
                                 wind=wind, room=room)
    if conditions.ground_contact_s > 0 and not_settled(truth) is not None:  # its last descent still under way:
        duration += LANDING_SETTLE_S  # flown longer, the reference holding its rest set-point
        rec, truth = simulate_flight(v, ref, duration=duration, effects=physics_effects(eff), noise=noise, seed=seed,
                                     wind=wind, room=room)
    w_max = v.max_rotor_speed or 2.5 * v.hover_speed()  # the controller's bound (sim.core.controller)
    out_c = condition(rec, truth, conditions, true_vehicle=v, effects=eff, seed=seed, w_max=w_max, noise=noise)
    out_c.truth = truth_document(v, eff, out_c.truth, seed=seed, kind=kind, duration=duration)
    if stand_in:  # EuRoC's cam0, its T_BS relative to the recording's S
        out_c.recording = euroc_standin.with_cam0(out_c.recording)
        out_c.truth["stand_in"] = euroc_standin.truth_entry()
    out_c.extras[TRUTH_FILE] = ("# what the simulator knows and the recording does not "
                                "(uavturb.sim.flights.conditions)\n"
                                + yaml.safe_dump(out_c.truth, sort_keys=False))
    if out is not None:
        write_recording(out_c.recording, out, overwrite=overwrite, extras=out_c.extras)
        out_c.recording = replace(out_c.recording, path=Path(out))
    return out_c
