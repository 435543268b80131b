"""Closed-loop flights through a generated scene along a planned reference, and the dataset's
two flyers (:data:`FLYERS`) built on them.

``fly_trajectory(scene, vehicle, seed, controller="mpc", camera_rate=20.0, ...)`` plans a
reference as above and flies it in closed loop
(:func:`uavturb.sim.core.closed_loop.run_closed_loop`):

- physics every ``1 / physics_rate`` s (default 200 Hz): one RK4 step of the one model of
  :mod:`uavturb.physics.dynamics` with the effects of ``effects.md`` (default: the
  simulator's ground effect, ``mu = 2``) evaluated with the actual rotor speeds and the
  heights ``d_down``/``d_up`` over the scene (exact box queries of :mod:`~uavturb.scene.queries`,
  refreshed at the control rate and followed by the height change in between);
- control every ``1 / control_rate`` s: ``controller="mpc"`` (:class:`~uavturb.sim.core.mpc.MPCController`,
  default 25 Hz, a real-time-iteration MPC on the full quaternion model with rotor-speed
  bounds) or ``"geometric"`` (:class:`~uavturb.sim.core.controller.GeometricController`, default
  200 Hz);
- samples every ``1 / camera_rate`` s (the camera frames);
- collision check of the position at every physics step (:func:`~uavturb.scene.queries.collides`: boxes grown by
  the vehicle's radius ``arm_length + rotor_radius`` horizontally and half the landed
  height vertically), in batches of one second of flight: a flight that hits something is
  truncated one frame before the hit (``info["collided"]``, ``info["collisions"]``).

Returns ``(states (T, 13), rotor_speeds (T, N), t (T,), info)``: states are ``p`` [m] in W,
``q`` (w, x, y, z, body to world), ``v`` [m/s] in W, ``w`` [rad/s] in B; ``rotor_speeds``
[rad/s] the actual speeds applied over the frame's instant; ``t`` [s] from the flight's
start; ``info`` holds ``d_down`` (T,) [m] height of the body over the surface below,
``effect_force`` (T, 3) [N] in W, ``reference`` (a :class:`Setpoint` of K=T samples),
``phases``, the plan, timing figures and the collision report.

The flyers of ``uavturb generate sim`` (:data:`FLYERS`) plan a reference in a scene with
:func:`uavturb.sim.dataset.planning.plan_trajectory`, fly it in closed loop and sample it at the
camera rate: ``mpc`` with the CasADi MPC through :func:`fly_trajectory`, ``geometric`` with the
geometric controller through :func:`uavturb.sim.core.closed_loop.track_reference`.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field, replace
from typing import Any, Callable

import numpy as np

from uavturb.errors import InputError
from uavturb.io.vehicle_file import named_vehicle
from uavturb.physics.effects import DEFAULT_EFFECTS
from uavturb.scene.indoor import Scene
from uavturb.scene.queries import collides, scene_heights
from uavturb.scene.camera import least_body_height
from uavturb.sim.core.closed_loop import (
    CollisionWatch,
    GeometricTracker,
    initial_state,
    run_closed_loop,
    track_reference,
)
from uavturb.sim.core.mpc import MPCController
from uavturb.sim.core.signals import Reference
from uavturb.sim.dataset.planning import PlanConfig, PlannedTrajectory, plan_trajectory
from uavturb.sim.dataset.presets import SimPreset

CONTROLLERS = ("mpc", "geometric")


def _ratio(rate_hi: float, rate_lo: float, what: str) -> int:
    n = int(round(rate_hi / rate_lo))
    if n < 1 or abs(n * rate_lo - rate_hi) > 1e-6 * rate_hi:
        raise InputError(what, f"physics_rate ({rate_hi} Hz) must be a whole multiple of it ({rate_lo} Hz)")
    return n



def make_controller(kind: str, vehicle: Any, reference: Reference, control_rate: float | None = None,
                    **options: Any) -> tuple[Any, float]:
    """A controller for :func:`fly_trajectory` and its rate [Hz] (defaults: MPC 25 Hz,
    geometric 200 Hz)."""
    if kind == "mpc":
        rate = 25.0 if control_rate is None else float(control_rate)
        return MPCController(vehicle, reference, dt=1.0 / rate, **options), rate
    if kind == "geometric":
        rate = 200.0 if control_rate is None else float(control_rate)
        dt = 1.0 / rate
        return GeometricTracker(vehicle, reference, dt, int(np.ceil(reference.duration / dt)) + 2), rate
    raise InputError("controller", f"unknown controller '{kind}' (known: {', '.join(CONTROLLERS)})")


def fly_trajectory(scene: Scene, vehicle: Any = "quad", seed: int = 0, controller: str = "mpc", *,
                   camera_rate: float = 20.0, physics_rate: float = 200.0, control_rate: float | None = None,
                   effects: dict[str, dict[str, float]] | None = None,
                   plan: PlanConfig | PlannedTrajectory = PlanConfig(), duration: float | None = None,
                   controller_options: dict | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray, dict[str, Any]]:
    """Plan a reference trajectory through ``scene`` and fly it in closed loop.

    Parameters
    ----------
    scene : Scene
    vehicle : Vehicle or built-in vehicle (``quad``: the paper's 50 g drone; ``hex``)
    seed : fixes the plan (the flight itself is deterministic)
    controller : ``"mpc"`` or ``"geometric"``
    camera_rate : Hz, sample rate of the output (camera frames)
    physics_rate : Hz, integration rate; a whole multiple of ``camera_rate`` and ``control_rate``
    control_rate : Hz (default 25 for the MPC, 200 for the geometric controller)
    effects : ``{name: {param: value}}`` of ``effects.md`` (default: the simulator's
        :data:`~uavturb.physics.sim_config.DEFAULT_EFFECTS`, ground effect ``mu = 2``);
        ``{}`` for none. ``motor_lag`` is not supported here.
    plan : PlanConfig, or an already planned trajectory
    duration : s, flight length (default: the reference's)
    controller_options : passed on to the controller (e.g. ``horizon`` for the MPC)

    Returns
    -------
    states : (T, 13) ``p`` [m] W, ``q`` w, x, y, z (body to world), ``v`` [m/s] W, ``w`` [rad/s] B
    rotor_speeds : (T, N) rad/s, actual rotor speeds at the sample times
    t : (T,) s from the start, ``k / camera_rate``
    info : dict with ``d_down`` (T,) m, ``d_up`` (T,) m, ``effect_force`` (T, 3) N in W,
        ``reference`` (Setpoint of T samples), ``phases`` (dict of ``(t0, t1)`` lists),
        ``plan`` (PlannedTrajectory), ``collided`` (bool), ``collisions`` (0 or 1: the flight is
        truncated at its first hit), ``collision_time`` (s or None), ``tracking_error`` (T,) m,
        ``solve_ms`` (controller update times), ``wall_s``, ``samples_per_s``, ``controller``.
    """

    wall0 = time.perf_counter()
    veh = named_vehicle(vehicle) if isinstance(vehicle, str) else vehicle
    if controller not in CONTROLLERS:
        raise InputError("controller", f"unknown controller '{controller}' (known: {', '.join(CONTROLLERS)})")
    effects = dict(DEFAULT_EFFECTS if effects is None else effects)
    if "motor_lag" in effects:
        raise InputError("effects", "motor_lag is not supported by fly_trajectory")
    planned = plan if isinstance(plan, PlannedTrajectory) else plan_trajectory(
        scene, seed, plan, rotor_radius=veh.rotor_radius, vehicle_radius=veh.arm_length + veh.rotor_radius)
    ref = planned.reference
    duration = float(ref.duration if duration is None else duration)
    ctrl, rate = make_controller(controller, veh, ref, control_rate, **(controller_options or {}))
    loop = _fly_until_collision(scene, veh, planned, ctrl, effects, duration, physics_rate=physics_rate,
                                control_rate=rate, camera_rate=camera_rate)
    k, collided, t_hit = _frames_before_collision(loop, camera_rate)
    X, W, F_rec, DD, DU = loop.x[:k], loop.rotor_speeds[:k], loop.force[:k], loop.d_down[:k], loop.d_up[:k]
    t_ctrl, t_phys = loop.control_s, loop.physics_s
    t_out = np.arange(k) / camera_rate
    sp = ref(t_out)
    wall = time.perf_counter() - wall0
    solve = np.asarray(getattr(ctrl, "solve_times", []), float) * 1e3
    info: dict[str, Any] = {
        "d_down": DD, "d_up": DU, "effect_force": F_rec, "reference": sp, "phases": dict(ref.notes),
        "plan": planned, "collided": collided, "collisions": int(collided), "collision_time": t_hit,
        "tracking_error": np.linalg.norm(X[:, 0:3] - sp.p, axis=1) if k else np.zeros(0),
        "solve_ms": solve, "controller": controller, "control_rate": rate, "physics_rate": physics_rate,
        "camera_rate": camera_rate, "wall_s": wall, "control_s": t_ctrl, "physics_s": t_phys,
        "samples_per_s": k / wall if wall > 0 else float("inf"), "effects": effects,
    }
    return X, W, t_out, info


def _fly_until_collision(scene: Scene, veh: Any, planned: PlannedTrajectory, ctrl: Any,
                         effects: dict[str, dict[str, float]], duration: float, *, physics_rate: float,
                         control_rate: float, camera_rate: float) -> Any:
    """The closed loop of ``ctrl`` flying ``planned``'s reference [Hz rates], stopped at the first hit of the
    scene (:func:`uavturb.sim.core.closed_loop.run_closed_loop`'s result, recorded at ``camera_rate``)."""

    ref = planned.reference
    cam_every = _ratio(physics_rate, camera_rate, "camera_rate")
    ctrl_every = _ratio(physics_rate, control_rate, "control_rate")
    dt = 1.0 / physics_rate
    radius = veh.arm_length + veh.rotor_radius
    rest = float(ref(0.0).p[2] - planned.points[0, 2])  # m, landed height of the start
    half_h = float(np.clip(0.5 * rest, 0.005, 0.02))  # m, vertical half-extent in the collision check

    x = initial_state(ref(0.0))
    ctrl.reset(x)
    # collision check in batches of the positions of every physics step (about 1 s of flight)
    watch = CollisionWatch(lambda p: collides(scene, p, radius, half_h), int(round(physics_rate)), dt)
    return run_closed_loop(veh, x, lambda x, t, force: ctrl.update(x, t), scene_heights(scene), effects=effects,
                           n_steps=int(round(duration * physics_rate)), physics_dt=dt, control_every=ctrl_every,
                           record_every=cam_every, watch=watch)


def _frames_before_collision(loop: Any, camera_rate: float) -> tuple[int, bool, float | None]:
    """(frames kept, collided, time of the hit [s] or None): a flight that hits the scene keeps the frames
    strictly before the hit, less the last (the vehicle was about to touch)."""
    k = loop.count
    collided, t_hit = loop.stop_time is not None, loop.stop_time
    if collided and not loop.diverged:
        k = min(k, int(np.ceil(t_hit * camera_rate - 1e-9)))  # frames strictly before the hit
    if collided:
        k = max(k - 1, 0)  # drop the last frame before the hit too: the vehicle was about to touch
    return k, collided, t_hit


# --- the flyers of the dataset --------------------------------------------------------


@dataclass
class Flight:
    """What a flyer returns, sampled at the camera rate.

    Attributes
    ----------
    t : (T,) s from the start
    state : (T, 13) ``p`` (m, W), ``q`` (w, x, y, z, body to world), ``v`` (m/s, W), ``omega`` (rad/s, B)
    rotor_speeds : (T, N) rad/s, actual rotor speeds
    timing : seconds spent in ``control`` and ``physics``
    info : free-form (controller, tracking error...)
    """

    t: np.ndarray
    state: np.ndarray
    rotor_speeds: np.ndarray
    timing: dict[str, float] = field(default_factory=dict)
    info: dict[str, Any] = field(default_factory=dict)


def plan_config(preset: SimPreset, n_points: int, rotor_radius: float):
    """The :class:`~uavturb.sim.dataset.planning.PlanConfig` of a preset's trajectory with ``n_points`` points.

    A camera that hangs under the body origin (0.13 m for ``euroc_cam0``) would look from under
    the floor when landed at a few centimetres: the landed height and the lowest low hover become
    at least :func:`uavturb.scene.camera.least_body_height` (0.16 m for ``euroc_cam0``: the vehicle
    stands on legs that tall). ``forward`` changes nothing.
    """
    cfg = PlanConfig(**{**preset.plan, "n_points": int(n_points)})
    floor = least_body_height(preset.camera)
    if floor > 0:
        lo, hi = cfg.low_heights
        cfg = replace(cfg, rest_height=max(cfg.rest_for(rotor_radius), floor),
                      low_heights=(max(lo, floor), max(hi, floor)))
    return cfg


def _plan(scene, vehicle, task_seed: int, n_points: int, preset: SimPreset):
    cfg = plan_config(preset, n_points, vehicle.rotor_radius)
    return plan_trajectory(scene, task_seed, cfg, rotor_radius=vehicle.rotor_radius,
                           vehicle_radius=vehicle.arm_length + vehicle.rotor_radius)


def _duration(planned, preset: SimPreset) -> float:
    """Flight length [s]: the plan's, cut at ``max_seconds``, on the camera grid."""
    dur = float(planned.reference.duration)
    if preset.max_seconds > 0:
        dur = min(dur, preset.max_seconds)
    return math.floor(dur * preset.camera_hz + 1e-9) / preset.camera_hz


def fly_geometric(scene, vehicle, task_seed: int, n_points: int, preset: SimPreset) -> Flight:
    """Plan with :func:`uavturb.sim.dataset.planning.plan_trajectory`, fly with the geometric controller.

    Physics: :func:`uavturb.sim.core.closed_loop.track_reference` (RK4 and controller every
    ``geometric_dt`` with the preset's effects and the exact heights of the scene; the
    reference sampled once, vectorised), sampled at the camera rate. The controller's share
    of the time is what the closed loop reports for its controller calls.
    """
    t0 = time.perf_counter()
    planned = _plan(scene, vehicle, task_seed, n_points, preset)
    t_plan = time.perf_counter() - t0
    t0 = time.perf_counter()
    record_dt = 1.0 / preset.camera_hz
    effects = {k: dict(v) for k, v in preset.effects.items()}
    lag = effects.pop("motor_lag", None)
    loop = track_reference(vehicle, planned.reference, scene_heights(scene), duration=_duration(planned, preset),
                           effects=effects, physics_dt=preset.geometric_dt, control_dt=preset.geometric_dt,
                           record_dt=record_dt, motor_tau=float(lag["tau"]) if lag is not None else 0.0)
    total = time.perf_counter() - t0
    rec_every = int(round(record_dt / preset.geometric_dt))
    t = np.arange(len(loop.x)) * (rec_every * preset.geometric_dt)
    error = loop.x[:, 0:3] - planned.reference(t).p
    return Flight(t=t, state=loop.x, rotor_speeds=loop.rotor_speeds,
                  timing={"control": t_plan + loop.control_s, "physics": total - loop.control_s},
                  info={"controller": "geometric", "plan_s": t_plan, "plan_points": int(n_points),
                        "tracking_rms_m": float(np.sqrt(np.mean(np.sum(error**2, axis=1))))})


def fly_mpc(scene, vehicle, task_seed: int, n_points: int, preset: SimPreset) -> Flight:
    """Plan and fly with :func:`fly_trajectory` and its CasADi MPC
    (physics at ``1 / physics_dt``, the MPC at its default rate; truncated at a collision)."""
    t0 = time.perf_counter()
    planned = _plan(scene, vehicle, task_seed, n_points, preset)
    t_plan = time.perf_counter() - t0
    states, rotor_speeds, t, info = fly_trajectory(
        scene, vehicle, task_seed, controller="mpc", camera_rate=preset.camera_hz,
        physics_rate=1.0 / preset.physics_dt, effects={k: dict(v) for k, v in preset.effects.items()},
        plan=planned, duration=_duration(planned, preset))
    return Flight(t=np.asarray(t), state=np.asarray(states), rotor_speeds=np.asarray(rotor_speeds),
                  timing={"control": t_plan + float(info.get("control_s", float("nan"))),
                          "physics": float(info.get("physics_s", float("nan")))},
                  info={"controller": "mpc", "plan_s": t_plan, "plan_points": int(n_points),
                        "collided": bool(info.get("collided", False)),
                        "tracking_rms_m": float(np.sqrt(np.mean(np.asarray(info.get("tracking_error", [0.0])) ** 2)))})


#: name -> flyer(scene, vehicle, task_seed, n_points, preset) -> Flight
FLYERS: dict[str, Callable[..., Flight]] = {"geometric": fly_geometric, "mpc": fly_mpc}


def resolve_controller(name: str) -> str:
    """``auto`` -> ``mpc`` (the CasADi MPC of :func:`fly_trajectory`); ``mpc`` and ``geometric`` as they are."""
    if name == "auto":
        return "mpc"
    if name not in FLYERS:
        raise InputError("controller", f"unknown controller {name!r} (known: auto, {', '.join(FLYERS)})")
    return name
