"""Reference signals for synthetic flights: position, velocity, acceleration, jerk and yaw (with
its rate and acceleration) as analytic functions of time.

A :class:`Reference` holds four scalar :class:`Signal` channels (``x``, ``y``, ``z`` in
the world frame W [m], ``yaw`` [rad], ZYX yaw of the body about world ``+z``). Every
signal returns its value and its first three time derivatives, so a reference gives
the controller velocity, acceleration and jerk feed-forward exactly. Signals are built
from sums of sines, products with a smooth envelope, and piecewise "minimum-snap"
septic segments between waypoints (continuous up to the jerk, so references can be
concatenated without jumps in the body-rate feed-forward).

Stop-and-go plans of waypoints: :mod:`uavturb.sim.core.waypoint_plan`; the flight plans of
``uavturb generate flight``: :mod:`uavturb.sim.flights.plans`; the plans through generated
scenes: :mod:`uavturb.sim.dataset.planning`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from uavturb.errors import InputError

# --- scalar signals with three derivatives ---------------------------------------------


def _as_t(t: np.ndarray | float) -> np.ndarray:
    return np.atleast_1d(np.asarray(t, dtype=float))


class Signal:
    """A scalar function of time [s] with its first three derivatives.

    Subclasses implement :meth:`derivs`; ``+`` and ``*`` build sums and products.
    """

    def derivs(self, t: np.ndarray) -> np.ndarray:
        """Value and derivatives at times ``t``.

        Parameters
        ----------
        t : (K,) s

        Returns
        -------
        (4, K): value, first, second and third time derivative.
        """
        raise NotImplementedError

    def __add__(self, other: "Signal") -> "Signal":
        return Sum((self, other))

    def __mul__(self, other: "Signal") -> "Signal":
        return Product(self, other)


@dataclass(frozen=True)
class Constant(Signal):
    """``f(t) = value``."""

    value: float

    def derivs(self, t: np.ndarray) -> np.ndarray:
        t = _as_t(t)
        out = np.zeros((4, len(t)))
        out[0] = self.value
        return out


@dataclass(frozen=True)
class Sines(Signal):
    """``f(t) = sum_k A_k sin(omega_k t + phi_k)``; amplitudes in the signal's unit, ``omega`` [rad/s]."""

    amplitude: tuple[float, ...]
    omega: tuple[float, ...]
    phase: tuple[float, ...]

    def derivs(self, t: np.ndarray) -> np.ndarray:
        t = _as_t(t)
        A, w, ph = (np.asarray(a, float)[:, None] for a in (self.amplitude, self.omega, self.phase))
        arg = w * t[None, :] + ph
        s, c = np.sin(arg), np.cos(arg)
        return np.stack([(A * s).sum(0), (A * w * c).sum(0), -(A * w**2 * s).sum(0), -(A * w**3 * c).sum(0)])

    def bounds(self) -> tuple[float, float, float]:
        """Upper bounds of ``|f|``, ``|f'|``, ``|f''|``."""
        A, w = np.abs(np.asarray(self.amplitude, float)), np.asarray(self.omega, float)
        return float(A.sum()), float((A * w).sum()), float((A * w**2).sum())


@dataclass(frozen=True)
class Sum(Signal):
    """Sum of signals."""

    terms: tuple[Signal, ...]

    def derivs(self, t: np.ndarray) -> np.ndarray:
        t = _as_t(t)
        out = np.zeros((4, len(t)))
        for s in self.terms:
            out += s.derivs(t)
        return out


@dataclass(frozen=True)
class Product(Signal):
    """Product ``f g`` (derivatives by Leibniz's rule)."""

    f: Signal
    g: Signal

    def derivs(self, t: np.ndarray) -> np.ndarray:
        t = _as_t(t)
        a, b = self.f.derivs(t), self.g.derivs(t)
        return np.stack([
            a[0] * b[0],
            a[1] * b[0] + a[0] * b[1],
            a[2] * b[0] + 2 * a[1] * b[1] + a[0] * b[2],
            a[3] * b[0] + 3 * a[2] * b[1] + 3 * a[1] * b[2] + a[0] * b[3],
        ])


def smoothstep(tau: np.ndarray) -> np.ndarray:
    """Septic "minimum-snap" step ``s(tau) = 35 tau^4 - 84 tau^5 + 70 tau^6 - 20 tau^7`` on [0, 1],
    0 before and 1 after; its first three derivatives vanish at both ends.

    Returns
    -------
    (4, K): ``s``, ``ds/dtau``, ``d2s/dtau2``, ``d3s/dtau3``.
    """
    tau = np.clip(np.asarray(tau, float), 0.0, 1.0)
    t2, t3 = tau * tau, tau**3
    s = t2 * t2 * (35 - 84 * tau + 70 * t2 - 20 * t3)
    s1 = t3 * (140 - 420 * tau + 420 * t2 - 140 * t3)
    s2 = t2 * (420 - 1680 * tau + 2100 * t2 - 840 * t3)
    s3 = tau * (840 - 5040 * tau + 8400 * t2 - 4200 * t3)
    return np.stack([s, s1, s2, s3])


_tau = np.linspace(0.0, 1.0, 2001)
SMOOTHSTEP_MAX_RATE = float(np.max(np.abs(smoothstep(_tau)[1])))  # 2.1875 = 35/16
SMOOTHSTEP_MAX_ACC = float(np.max(np.abs(smoothstep(_tau)[2])))  # about 7.51
del _tau


@dataclass(frozen=True)
class Envelope(Signal):
    """1 on ``[ramp, duration - ramp]``, rising smoothly from 0 at ``t = 0`` and falling back to
    0 at ``t = duration`` (septic steps of length ``ramp`` [s]); 0 outside ``[0, duration]``."""

    duration: float
    ramp: float

    def derivs(self, t: np.ndarray) -> np.ndarray:
        t = _as_t(t)
        r = self.ramp
        up = smoothstep(t / r) * (1.0 / r) ** np.arange(4)[:, None]
        down = smoothstep((self.duration - t) / r) * (-1.0 / r) ** np.arange(4)[:, None]
        return Product(_Array(up), _Array(down)).derivs(t)


@dataclass(frozen=True, eq=False)
class _Array(Signal):
    """Precomputed derivatives (internal: lets :class:`Envelope` reuse Leibniz's rule)."""

    values: np.ndarray

    def derivs(self, t: np.ndarray) -> np.ndarray:
        return self.values


@dataclass(frozen=True)
class Waypoints(Signal):
    """Piecewise septic steps between waypoint values ``values[i]`` at ``times[i]`` [s]:
    at rest (zero derivatives) at every waypoint, constant before the first and after the last.
    Equal consecutive values make a hold."""

    times: tuple[float, ...]
    values: tuple[float, ...]

    def __post_init__(self) -> None:
        if len(self.times) != len(self.values) or len(self.times) == 0:
            raise InputError("reference", "waypoint times and values must have the same non-zero length")
        if np.any(np.diff(self.times) <= 0):
            raise InputError("reference", "waypoint times must increase strictly")

    def derivs(self, t: np.ndarray) -> np.ndarray:
        t = _as_t(t)
        T, V = np.asarray(self.times, float), np.asarray(self.values, float)
        out = np.zeros((4, len(t)))
        out[0] = V[0]
        if len(T) == 1:
            return out
        i = np.clip(np.searchsorted(T, t, side="right") - 1, 0, len(T) - 2)
        h = T[i + 1] - T[i]
        s = smoothstep((t - T[i]) / h)
        dv = V[i + 1] - V[i]
        out[0] = V[i] + dv * s[0]
        out[1] = dv * s[1] / h
        out[2] = dv * s[2] / h**2
        out[3] = dv * s[3] / h**3
        return out


@dataclass(frozen=True)
class Piecewise(Signal):
    """Signals one after another: piece ``k`` runs on ``[starts[k], starts[k+1])`` in its own time
    ``t - starts[k]``; the last piece runs on for ever."""

    pieces: tuple[Signal, ...]
    starts: tuple[float, ...]

    def derivs(self, t: np.ndarray) -> np.ndarray:
        t = _as_t(t)
        out = np.zeros((4, len(t)))
        k = np.clip(np.searchsorted(np.asarray(self.starts, float), t, side="right") - 1, 0, len(self.pieces) - 1)
        for j, piece in enumerate(self.pieces):
            m = k == j
            if m.any():
                out[:, m] = piece.derivs(t[m] - self.starts[j])
        return out


# --- references ----------------------------------------------------------------------


@dataclass
class Setpoint:
    """A reference sampled at one time (shapes as below) or at ``K`` times (a leading ``K`` axis).

    Attributes
    ----------
    t : float or (K,) s
    p, v, a, j : (3,) or (K, 3): position [m], velocity [m/s], acceleration [m/s^2], jerk [m/s^3] in W
    yaw, yaw_rate, yaw_acc : float or (K,): rad, rad/s, rad/s^2 (ZYX yaw about world +z)
    """

    t: np.ndarray
    p: np.ndarray
    v: np.ndarray
    a: np.ndarray
    j: np.ndarray
    yaw: np.ndarray
    yaw_rate: np.ndarray
    yaw_acc: np.ndarray

    def __getitem__(self, k: int) -> "Setpoint":
        """The ``k``-th sample of a sampled reference."""
        return Setpoint(*(getattr(self, f)[k] for f in ("t", "p", "v", "a", "j", "yaw", "yaw_rate", "yaw_acc")))

    def __len__(self) -> int:
        return len(np.atleast_1d(self.t))


@dataclass(frozen=True)
class Reference:
    """A flight plan: four channels of time.

    Attributes
    ----------
    x, y, z : Signal, m, world position of the body origin
    yaw : Signal, rad
    duration : float, s, the plan's length (it holds its last set-point afterwards)
    name : str
    notes : dict, free-form description of the plan (phases and their times)
    """

    x: Signal
    y: Signal
    z: Signal
    yaw: Signal
    duration: float
    name: str = "reference"
    notes: dict = field(default_factory=dict, compare=False)

    def __call__(self, t: np.ndarray | float) -> Setpoint:
        """Sample the reference at time(s) ``t`` [s]: a scalar ``t`` gives a one-sample
        :class:`Setpoint` (shapes ``(3,)`` and scalars), an array ``(K,)`` a ``K``-sample one."""
        scalar = np.ndim(t) == 0
        tt = _as_t(t)
        d = np.stack([c.derivs(tt) for c in (self.x, self.y, self.z)], axis=-1)  # (4, K, 3)
        yw = self.yaw.derivs(tt)
        sp = Setpoint(tt, d[0], d[1], d[2], d[3], yw[0], yw[1], yw[2])
        return sp[0] if scalar else sp

    def then(self, other: "Reference", tol: float = 1e-6) -> "Reference":
        """This plan followed by ``other`` (which must start where this one ends, at rest)."""
        end, start = self(self.duration), other(0.0)
        jump = max(np.max(np.abs(end.p - start.p)), abs(float(end.yaw - start.yaw)),
                   np.max(np.abs(start.v)), np.max(np.abs(end.v)))
        if jump > tol:
            raise InputError("reference", f"cannot join '{self.name}' and '{other.name}': they do not meet at rest "
                                          f"(mismatch {jump:.3g})")
        chans = []
        for c in ("x", "y", "z", "yaw"):
            a, b = getattr(self, c), getattr(other, c)
            pa = a.pieces if isinstance(a, Piecewise) else (a,)
            sa = a.starts if isinstance(a, Piecewise) else (0.0,)
            chans.append(Piecewise(pa + (b,), sa + (self.duration,)))
        notes = dict(self.notes)
        for k, v in other.notes.items():
            notes[k] = [(t0 + self.duration, t1 + self.duration) for t0, t1 in v] if isinstance(v, list) else v
        return Reference(*chans, duration=self.duration + other.duration, name=f"{self.name}+{other.name}",
                         notes=notes)


def hover(p: tuple[float, float, float], yaw: float = 0.0, duration: float = 10.0) -> Reference:
    """Hold position ``p`` [m] and ``yaw`` [rad] for ``duration`` [s]."""
    return Reference(Constant(p[0]), Constant(p[1]), Constant(p[2]), Constant(yaw), float(duration), "hover")

