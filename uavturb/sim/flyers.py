"""Flyers: plan a reference in a scene, fly it in closed loop (:mod:`uavturb.sim.closed_loop`),
sample at the camera rate. ``mpc`` flies with the CasADi MPC through
:func:`uavturb.sim.scene_flight.fly_trajectory`, ``geometric`` with the geometric controller
through :func:`uavturb.sim.closed_loop.track_reference`; both plan with
:func:`uavturb.sim.planning.plan_trajectory`."""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np

from uavturb.errors import InputError
from uavturb.sim.presets import SimPreset


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
    """The :class:`~uavturb.sim.planning.PlanConfig` of a preset's trajectory with ``n_points`` points.

    A camera that hangs under the body origin (0.13 m for ``euroc_cam0``) would look from under
    the floor when landed at a few centimetres: the landed height and the lowest low hover become
    at least :func:`uavturb.scene.camera.least_body_height` (0.16 m for ``euroc_cam0``: the vehicle
    stands on legs that tall). ``forward`` changes nothing.
    """
    from dataclasses import replace

    from uavturb.scene.camera import least_body_height
    from uavturb.sim.planning import PlanConfig

    cfg = PlanConfig(**{**preset.plan, "n_points": int(n_points)})
    floor = least_body_height(preset.camera)
    if floor > 0:
        lo, hi = cfg.low_heights
        cfg = replace(cfg, rest_height=max(cfg.rest_for(rotor_radius), floor),
                      low_heights=(max(lo, floor), max(hi, floor)))
    return cfg


def _plan(scene, vehicle, task_seed: int, n_points: int, preset: SimPreset):
    from uavturb.sim.planning import plan_trajectory

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
    """Plan with :func:`uavturb.sim.planning.plan_trajectory`, fly with the geometric controller.

    Physics: :func:`uavturb.sim.closed_loop.track_reference` (RK4 and controller every
    ``geometric_dt`` with the preset's effects and the exact heights of the scene; the
    reference sampled once, vectorised), sampled at the camera rate. The controller's share
    of the time is what the closed loop reports for its controller calls.
    """
    from uavturb.scene.queries import scene_heights
    from uavturb.sim.closed_loop import track_reference

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


def _mpc_available() -> bool:
    try:
        from uavturb.sim import mpc, scene_flight  # noqa: F401
    except ImportError:
        return False
    return hasattr(scene_flight, "fly_trajectory") and hasattr(mpc, "MPCController")


def fly_mpc(scene, vehicle, task_seed: int, n_points: int, preset: SimPreset) -> Flight:
    """Plan and fly with :func:`uavturb.sim.scene_flight.fly_trajectory` and its CasADi MPC
    (physics at ``1 / physics_dt``, the MPC at its default rate; truncated at a collision)."""
    from uavturb.sim import scene_flight

    t0 = time.perf_counter()
    planned = _plan(scene, vehicle, task_seed, n_points, preset)
    t_plan = time.perf_counter() - t0
    states, rotor_speeds, t, info = scene_flight.fly_trajectory(
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
    """``auto`` -> ``mpc`` when :mod:`uavturb.sim.scene_flight` provides ``fly_trajectory``, else ``geometric``."""
    if name == "auto":
        return "mpc" if _mpc_available() else "geometric"
    if name == "mpc" and not _mpc_available():
        raise InputError("controller", "mpc needs uavturb.sim.scene_flight.fly_trajectory, which is not installed")
    if name not in FLYERS:
        raise InputError("controller", f"unknown controller {name!r} (known: auto, {', '.join(FLYERS)})")
    return name
