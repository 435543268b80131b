"""The closed loop of every simulated flight: controller, effects and RK4 physics.

:func:`run_closed_loop` is the one loop behind ``uavturb generate flight``
(:func:`uavturb.sim.flights.simulate.simulate_flight`) and the training shards of ``uavturb generate sim``
(:mod:`uavturb.sim.dataset.generation`, through :func:`track_reference` and
:func:`uavturb.sim.dataset.flying.fly_trajectory`). Time stepping, all rates multiples of
``physics_dt``:

- physics, every ``physics_dt``: one RK4 step of :class:`~uavturb.physics.dynamics.Dynamics`
  (its ``rk4`` CasADi function through a preallocated buffer, :class:`Rk4Step`) with the
  rotor speeds and the effect force held over the step. The effect force is
  :func:`~uavturb.physics.effects.force_on_state` at the start of the step with the actual
  rotor speeds, the heights ``d_down``, ``d_up`` and ``t`` (:class:`EffectForce`).
- motor lag (``motor_tau > 0``, the ``motor_lag`` effect of ``effects.md``): the actual rotor
  speeds follow the held command with the exact first-order update
  ``w <- w_cmd + (w - w_cmd) exp(-dt / tau)`` every physics step.
- control, every ``control_every`` physics steps: the pilot (a callable
  ``pilot(x, t, force) -> rotor commands`` [rad/s]; ``force`` is the effect force of the last
  physics step [N, W]) on the true state; its commands are held until the next update.
  The heights are queried at this rate and, between queries, follow the vehicle's height
  change (:class:`HeldHeights`: exact over flat surfaces; an edge is resolved to one control
  period).
- recording, every ``record_every`` physics steps.
- optional stop check (:class:`CollisionWatch`): positions of every physics step, checked in
  batches; the loop stops at the first hit or at a non-finite state.

The loop times itself: :attr:`LoopRecord.control_s` (pilot calls) and
:attr:`LoopRecord.physics_s` (effects, recording and RK4), so that callers report the
split without patching the controller.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any, Callable, Protocol

import numpy as np

from uavturb.errors import InputError
from uavturb.physics import quaternion as quat
from uavturb.physics.dynamics import IDX_Q, IDX_V, N_STATE, dynamics_for, physical_params
from uavturb.physics.effects import force_on_state
from uavturb.physics.vehicle import Vehicle
from uavturb.sim.core.controller import ControllerGains, GeometricController, RotationOf
from uavturb.sim.core.signals import Reference, Setpoint

#: pilot(x (13,), t [s], force (3,) N in W of the last physics step) -> (N,) rad/s rotor commands
Pilot = Callable[[np.ndarray, float, np.ndarray], np.ndarray]


class HeightQuery(Protocol):
    """Heights [m] of positions ``(K, 3)`` [m] in W over the surface below and to the one above:
    :class:`~uavturb.scene.heights.SurfaceIndex` (point clouds) and the box heights of
    :mod:`uavturb.scene.queries` (generated scenes) answer it."""

    def d_down(self, positions: np.ndarray) -> np.ndarray: ...

    def d_up(self, positions: np.ndarray) -> np.ndarray: ...


@dataclass
class LoopRecord:
    """What :func:`run_closed_loop` recorded, ``K`` samples every ``record_every`` physics steps.

    Attributes
    ----------
    x : (K, 13) states ``p`` [m] W, ``q`` (w, x, y, z, body to world), ``v`` [m/s] W, ``w`` [rad/s] B
    rotor_speeds : (K, N) rad/s, actual rotor speeds
    rotor_commands : (K, N) rad/s, the pilot's held commands
    force : (K, 3) N in W, effect force applied to the dynamics
    d_down, d_up : (K,) m, heights used by the effects
    saturated : (K,) bool, the pilot's ``saturated`` attribute after its last update (False without)
    count : int, samples recorded before a stop (``K`` when the loop ran to its end)
    stop_time : s of the first hit or non-finite state, ``None`` when the loop ran to its end
    diverged : whether the stop was a non-finite state
    control_s, physics_s : s of wall time in the pilot and in effects, recording and RK4
    """

    x: np.ndarray
    rotor_speeds: np.ndarray
    rotor_commands: np.ndarray
    force: np.ndarray
    d_down: np.ndarray
    d_up: np.ndarray
    saturated: np.ndarray
    count: int = 0
    stop_time: float | None = None
    diverged: bool = False
    control_s: float = 0.0
    physics_s: float = 0.0

    @classmethod
    def empty(cls, K: int, n_rotors: int) -> "LoopRecord":
        return cls(np.empty((K, N_STATE)), np.empty((K, n_rotors)), np.empty((K, n_rotors)), np.empty((K, 3)),
                   np.empty(K), np.empty(K), np.zeros(K, bool))

    def first(self, k: int) -> "LoopRecord":
        """The first ``k`` samples."""
        return LoopRecord(self.x[:k], self.rotor_speeds[:k], self.rotor_commands[:k], self.force[:k],
                          self.d_down[:k], self.d_up[:k], self.saturated[:k], k, self.stop_time, self.diverged,
                          self.control_s, self.physics_s)


class Rk4Step:
    """One RK4 step [s] of the vehicle's :class:`~uavturb.physics.dynamics.Dynamics` through a
    preallocated CasADi buffer (about 1 us a call): ``step(x, w, f) -> x_next``."""

    def __init__(self, vehicle: Vehicle, dt: float):
        dyn = dynamics_for(vehicle)
        self._buf, self._run = dyn.rk4.buffer()
        self._x, self._w = np.zeros(N_STATE), np.zeros(vehicle.rotor_count)
        self._theta = physical_params(vehicle).astype(float).copy()
        self._f, self._tau, self._dt, self._out = np.zeros(3), np.zeros(3), np.array([float(dt)]), np.zeros(N_STATE)
        for i, a in enumerate((self._x, self._w, self._theta, self._f, self._tau, self._dt)):
            self._buf.set_arg(i, memoryview(a))
        self._buf.set_res(0, memoryview(self._out))

    def __call__(self, x: np.ndarray, w: np.ndarray, f: np.ndarray) -> np.ndarray:
        """State after one step from ``x`` (13,) with rotor speeds ``w`` (N,) rad/s and world force ``f`` (3,) N."""
        self._x[:], self._w[:], self._f[:] = x, w, f
        self._run()
        return self._out.copy()


class EffectForce:
    """The effect force [N, W] on one state: :func:`~uavturb.physics.effects.force_on_state` of
    ``effects`` (``{name: params}``; ``motor_lag`` excluded) for this vehicle. With a ``wind``
    velocity [m/s, W] the laws see the airspeed ``v - wind`` (drag acts on the airspeed)."""

    def __init__(self, vehicle: Vehicle, effects: dict[str, dict[str, float]], wind: np.ndarray | None = None):
        self.effects = effects
        self.wind = np.zeros(3) if wind is None else np.asarray(wind, float)
        self.k_T, self.r = float(vehicle.thrust_coefficient), float(vehicle.rotor_radius)
        self.arm = float(vehicle.arm_length)  # m, for laws that use the rotor spacing
        self._rotation = RotationOf()

    def __call__(self, x: np.ndarray, w: np.ndarray, t: float, d_down: float, d_up: float) -> np.ndarray:
        q = x[IDX_Q]
        return force_on_state(self.effects, q, x[IDX_V] - self.wind, w, t, d_down, d_up, self.k_T, self.r,
                              self._rotation(q) if self.effects else None, self.arm)


class HeldHeights:
    """``d_down``, ``d_up`` [m] queried at :meth:`refresh` and, until the next refresh, following
    the vehicle's height change (:meth:`at`)."""

    def __init__(self, query: HeightQuery):
        self.query = query
        self.d_down = self.d_up = self.z = 0.0

    def now(self, p: np.ndarray) -> tuple[float, float]:
        """``(d_down, d_up)`` [m] of one position ``p`` (3,) m."""
        pos = np.asarray(p, float)[None, :]
        return (float(np.asarray(self.query.d_down(pos)).ravel()[0]),
                float(np.asarray(self.query.d_up(pos)).ravel()[0]))

    def refresh(self, p: np.ndarray) -> None:
        self.d_down, self.d_up = self.now(p)
        self.z = p[2]

    def at(self, z: float) -> tuple[float, float]:
        """Held heights moved by the height change ``z - z_refresh`` [m]."""
        dz = z - self.z
        return self.d_down + dz, self.d_up - dz


class CollisionWatch:
    """Stops the loop where ``collides(positions (B, 3)) -> (B,) bool`` first holds or the state
    is not finite; positions of every physics step, checked every ``batch`` steps."""

    def __init__(self, collides: Callable[[np.ndarray], np.ndarray], batch: int, dt: float):
        self.collides, self.dt = collides, dt
        self.positions = np.empty((max(1, int(batch)), 3))
        self.n = 0

    def check(self, i: int, x: np.ndarray, last: bool) -> tuple[float | None, bool]:
        """``(stop time [s] or None, diverged)`` after physics step ``i`` at state ``x``."""
        if not np.all(np.isfinite(x)):
            return i * self.dt, True
        self.positions[self.n] = x[0:3]
        self.n += 1
        if self.n == len(self.positions) or last:
            hit = self.collides(self.positions[:self.n])
            if hit.any():
                return (i - self.n + 1 + int(np.argmax(hit))) * self.dt, False
            self.n = 0
        return None, False


def rotor_plane(vehicle: Vehicle, x: np.ndarray) -> np.ndarray:
    """(3,) m, centre of the rotor plane in W of state ``x`` (13,): where surface heights are measured
    (``recordings.md``, "Heights over surfaces"); the body origin when ``rotor_plane_z`` is 0."""
    if vehicle.rotor_plane_z == 0.0:
        return x[0:3]
    return vehicle.rotor_plane_positions(x[0:3], quat.to_rotation_matrix(x[IDX_Q]))


def initial_state(sp0: Setpoint) -> np.ndarray:
    """(13,) state at rest on the first set-point, level, with its heading."""
    x = np.zeros(N_STATE)
    x[0:3], x[IDX_V] = sp0.p, sp0.v
    x[IDX_Q] = quat.from_euler(0.0, 0.0, float(sp0.yaw))
    return x


def run_closed_loop(vehicle: Vehicle, x0: np.ndarray, pilot: Pilot, heights: HeightQuery, *,
                    effects: dict[str, dict[str, float]], n_steps: int, physics_dt: float, control_every: int,
                    record_every: int, motor_tau: float = 0.0, force0: np.ndarray | None = None,
                    watch: CollisionWatch | None = None, wind: np.ndarray | None = None) -> LoopRecord:
    """Fly ``n_steps`` physics steps of ``physics_dt`` [s] from ``x0`` (13,) with ``pilot``.

    Parameters
    ----------
    vehicle : Vehicle
    x0 : (13,) initial state
    pilot : ``pilot(x, t, force) -> (N,)`` rad/s, called every ``control_every`` steps; an
        attribute ``saturated`` (bool), when it has one, is recorded
    heights : HeightQuery of the scene
    effects : ``{name: params}`` of ``effects.md`` (without ``motor_lag``: see ``motor_tau``)
    n_steps : physics steps (``n_steps + 1`` states, the last one recorded when on the grid)
    physics_dt : s
    control_every, record_every : physics steps between pilot updates and between samples
    motor_tau : s, first-order rotor lag (0: none)
    force0 : (3,) N, the "last" effect force the pilot sees at ``t = 0`` (default zero)
    watch : CollisionWatch stopping the loop (none: run to the end)
    wind : (3,) m/s, wind velocity in W: the effects see the airspeed (none: still air)

    Returns
    -------
    LoopRecord of ``n_steps // record_every + 1`` samples (``count`` of them filled).
    """
    step, force_of, held = Rk4Step(vehicle, physics_dt), EffectForce(vehicle, effects, wind), HeldHeights(heights)
    rec = LoopRecord.empty(n_steps // record_every + 1, vehicle.rotor_count)
    a_lag = float(np.exp(-physics_dt / motor_tau)) if motor_tau > 0 else 0.0
    x = np.asarray(x0, float).copy()
    F = np.zeros(3) if force0 is None else np.asarray(force0, float)
    w_act = w_cmd = np.zeros(vehicle.rotor_count)
    saturated, k, t_ctrl, t_phys = False, 0, 0.0, 0.0
    clock = time.perf_counter
    for i in range(n_steps + 1):
        t = i * physics_dt
        if watch is not None:
            rec.stop_time, rec.diverged = watch.check(i, x, i == n_steps)
            if rec.stop_time is not None:
                break
        if i % control_every == 0:
            held.refresh(rotor_plane(vehicle, x))
            t1 = clock()
            w_cmd = pilot(x, t, F)
            t_ctrl += clock() - t1
            saturated = bool(getattr(pilot, "saturated", False))
            if i == 0 or motor_tau <= 0:
                w_act = w_cmd.copy()
        t1 = clock()
        dd, du = held.at(rotor_plane(vehicle, x)[2])
        F = force_of(x, w_act, t, dd, du)
        if i % record_every == 0:
            rec.x[k], rec.rotor_speeds[k], rec.rotor_commands[k] = x, w_act, w_cmd
            rec.force[k], rec.d_down[k], rec.d_up[k], rec.saturated[k] = F, dd, du, saturated
            k += 1
        if i == n_steps:
            break
        x = step(x, w_act, F)
        if motor_tau > 0:
            w_act = w_cmd + (w_act - w_cmd) * a_lag
        t_phys += clock() - t1
    rec.count, rec.control_s, rec.physics_s = k, t_ctrl, t_phys
    return rec


class GeometricTracker:
    """A :class:`~uavturb.sim.core.controller.GeometricController` following a reference, as a pilot
    of :func:`run_closed_loop`: the reference is sampled once at the ``n_updates`` control times
    ``k dt`` (one vectorised call; later times are evaluated one by one).

    Parameters
    ----------
    vehicle : Vehicle
    reference : Reference
    dt : s, control period
    n_updates : control times sampled in advance
    gains : ControllerGains
    feedforward : give the controller the effect force of the last physics step as a known
        external force (an ideal model-based controller)
    """

    def __init__(self, vehicle: Vehicle, reference: Reference, dt: float, n_updates: int,
                 gains: ControllerGains = ControllerGains(), feedforward: bool = False):
        self.ctrl = GeometricController(vehicle, gains)
        self.reference, self.dt, self.feedforward = reference, float(dt), bool(feedforward)
        self.setpoints = reference(np.arange(int(n_updates)) * self.dt)
        self.saturated = False
        self.solve_times: list[float] = []

    def settle(self, x: np.ndarray, force_of_command: Callable[[np.ndarray], np.ndarray]) -> np.ndarray:
        """Preload the integral with the effect force [N, W] the vehicle rests in at ``x`` (a
        fixed point: the force depends on the thrust that answers it); returns that force."""
        F = np.zeros(3)
        for _ in range(4):
            self.ctrl.reset(F)
            F = force_of_command(self.ctrl.update(x, self.setpoints[0], 0.0))
        self.ctrl.reset(F)
        return F

    def reset(self, x: Any = None) -> None:
        """Clear the integral (``x``: unused, for the pilot interface of the MPC)."""
        self.ctrl.reset()

    def update(self, x: np.ndarray, t: float) -> np.ndarray:
        """Rotor commands [rad/s] at state ``x`` and time ``t`` [s] (no feed-forward force)."""
        return self(x, t, np.zeros(3))

    def __call__(self, x: np.ndarray, t: float, force: np.ndarray) -> np.ndarray:
        t0 = time.perf_counter()
        k = int(round(t / self.dt))
        sp = self.setpoints[k] if k < len(self.setpoints) else self.reference(t)
        w = self.ctrl.update(x, sp, self.dt, force if self.feedforward else None)
        self.saturated = self.ctrl.last.saturated
        self.solve_times.append(time.perf_counter() - t0)
        return w


def whole_ratio(a: float, b: float, what: str, where: str = "simulate_flight") -> int:
    """``a / b`` as a whole number >= 1; raises InputError naming ``where`` and ``what`` otherwise."""
    n = int(round(a / b))
    if n < 1 or abs(n * b - a) > 1e-9 * max(a, 1.0):
        raise InputError(where, f"{what} must be a whole multiple of physics_dt")
    return n


def track_reference(vehicle: Vehicle, reference: Reference, heights: HeightQuery, *, duration: float,
                    effects: dict[str, dict[str, float]], physics_dt: float, control_dt: float, record_dt: float,
                    motor_tau: float = 0.0, gains: ControllerGains = ControllerGains(), feedforward: bool = False,
                    settle: bool = True, wind: np.ndarray | None = None) -> LoopRecord:
    """Fly ``reference`` for ``duration`` [s] with the geometric controller (:class:`GeometricTracker`).

    The vehicle starts at rest on the reference (:func:`initial_state`). With ``settle`` (and
    effects, and no feed-forward) it starts as if it had been resting in the initial effect force, at
    the rotor plane's heights as in flight: the controller's integral preloaded with it
    (:meth:`GeometricTracker.settle`). (Preloaded at the body origin's heights, a hexarotor whose rotors sit
    15 cm above it started with the lift of an exponential ground law 15 cm lower, 17.7 % of the weight for
    7.3 %, and sank 2.6 cm through the floor it rested on.)
    ``control_dt`` and ``record_dt`` are whole multiples of ``physics_dt``; ``wind`` [m/s, W]: see
    :class:`EffectForce`.
    """
    ctrl_every = whole_ratio(control_dt, physics_dt, "control_dt")
    rec_every = whole_ratio(record_dt, physics_dt, "record_dt")
    n_steps = int(round(duration / physics_dt))
    tracker = GeometricTracker(vehicle, reference, control_dt, n_steps // ctrl_every + 1, gains, feedforward)
    x = initial_state(tracker.setpoints[0])
    F = np.zeros(3)
    if settle and effects and not feedforward:
        dd, du = HeldHeights(heights).now(rotor_plane(vehicle, x))  # where the flight's surface laws act
        force_of = EffectForce(vehicle, effects, wind)
        F = tracker.settle(x, lambda w: force_of(x, w, 0.0, dd, du))
    else:
        tracker.ctrl.reset(F if (settle and not feedforward) else None)
    return run_closed_loop(vehicle, x, tracker, heights, effects=effects, n_steps=n_steps, physics_dt=physics_dt,
                           control_every=ctrl_every, record_every=rec_every, motor_tau=motor_tau, force0=F, wind=wind)


__all__ = ["Pilot", "HeightQuery", "LoopRecord", "Rk4Step", "EffectForce", "HeldHeights", "CollisionWatch",
           "initial_state", "run_closed_loop", "GeometricTracker", "whole_ratio", "track_reference"]
