"""Stop-and-go waypoint plans (:class:`WaypointPlan`): each move starts and ends at rest, its time
the least that keeps speed, acceleration, yaw rate and yaw acceleration within bounds; the plan
becomes a :class:`~uavturb.sim.core.signals.Reference` of :class:`~uavturb.sim.core.signals.Waypoints`.

The one plan builder of every planned flight: the flight plans of ``uavturb generate flight``
(:mod:`uavturb.sim.flights.plans`, :mod:`uavturb.sim.flights.euroc_standin`) and the plans through
generated scenes (:mod:`uavturb.sim.dataset.planning`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from uavturb.sim.core.signals import SMOOTHSTEP_MAX_ACC, SMOOTHSTEP_MAX_RATE, Reference, Waypoints


def wrap_near(yaw: float, near: float) -> float:
    """``yaw`` [rad] shifted by a multiple of 2 pi to lie within pi of ``near`` [rad] (the heading a
    plan turns to: the short way round)."""
    return near + (yaw - near + math.pi) % (2 * math.pi) - math.pi

@dataclass
class WaypointPlan:
    """Builds stop-and-go waypoint plans (each move starts and ends at rest)."""

    p: np.ndarray
    yaw: float
    speed: float = 0.8  # m/s, peak speed of a move
    acc: float = 1.0  # m/s^2, peak acceleration of a move
    yaw_rate: float = 0.8  # rad/s
    yaw_acc: float = 0.5  # rad/s^2
    times: list = field(default_factory=list)
    points: list = field(default_factory=list)
    phases: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.p = np.asarray(self.p, float)
        self.times.append(0.0)
        self.points.append((*self.p, self.yaw))

    @property
    def t(self) -> float:
        return self.times[-1]

    def move_time(self, p: np.ndarray, yaw: float | None = None, speed: float | None = None) -> float:
        dist = float(np.linalg.norm(np.asarray(p, float) - self.p))
        dyaw = abs((self.yaw if yaw is None else yaw) - self.yaw)
        v = self.speed if speed is None else speed
        return max(0.5, SMOOTHSTEP_MAX_RATE * dist / v, math.sqrt(SMOOTHSTEP_MAX_ACC * dist / self.acc),
                   SMOOTHSTEP_MAX_RATE * dyaw / self.yaw_rate, math.sqrt(SMOOTHSTEP_MAX_ACC * dyaw / self.yaw_acc))

    def move(self, p: np.ndarray, yaw: float | None = None, speed: float | None = None,
             phase: str | None = None) -> "WaypointPlan":
        T = self.move_time(p, yaw, speed)
        t0 = self.t
        self.p = np.asarray(p, float)
        self.yaw = self.yaw if yaw is None else float(yaw)
        self.times.append(t0 + T)
        self.points.append((*self.p, self.yaw))
        if phase:
            self.phases.setdefault(phase, []).append((t0, t0 + T))
        return self

    def hold(self, seconds: float, phase: str | None = None) -> "WaypointPlan":
        t0 = self.t
        self.times.append(t0 + float(seconds))
        self.points.append((*self.p, self.yaw))
        if phase:
            self.phases.setdefault(phase, []).append((t0, t0 + float(seconds)))
        return self

    def reference(self, name: str, duration: float | None = None) -> Reference:
        if duration is not None and duration > self.t + 1e-9:
            self.hold(duration - self.t)
        P = np.asarray(self.points)
        T = tuple(float(t) for t in self.times)
        ch = [Waypoints(T, tuple(float(v) for v in P[:, k])) for k in range(4)]
        return Reference(*ch, duration=float(self.t), name=name, notes=dict(self.phases))

