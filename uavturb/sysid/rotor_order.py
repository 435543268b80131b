"""Which order of the recorded rotor columns the roll and pitch accelerations follow.

``vehicle.yaml`` gives each column of ``rotors0`` an angle (``rotor_angles_deg``, ``recordings.md``). A log whose
columns come in another order (the motors numbered from another rotor, or the other way round, or PX4's quad-X
numbering read as numbered round the frame) keeps the thrust right, a sum over the rotors, and makes the torques
wrong: ``identify`` then reads an inertia many times its physical bound, and a question about the order was all it
could say (a Neural-Swarm take-off's commanded speeds, in vehicle.yaml's order, read 2.9 times the bound and were
asked about their order). Here the question is answered from the flight: the roll and pitch torques of each order of the
columns (the paper's eq. 1, ``tau = l k_T M w^2``: :meth:`~uavturb.physics.vehicle.Vehicle.mixer`) are correlated
with the measured angular acceleration about the same axis, and the order whose weaker axis follows best wins.

The correlations are computed from the columns' covariances once (each order is a permutation of them), so every
order of up to :data:`ALL_ORDERS_UP_TO` rotors is compared (720 for a hexarotor); with more rotors, the rotations
and reflections of the given order (numbering from another rotor, or the other way round).
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass
from typing import Sequence

import numpy as np

#: every permutation of the columns is compared for up to this many rotors; beyond, the given order's rotations and
#: reflections (an octorotor's 40,320 permutations would be as quick, but a log's mistakes are numbering ones)
ALL_ORDERS_UP_TO = 6
#: correlation by which one order's weaker axis must follow the angular acceleration better than another's for the
#: flight to tell them apart (a correlation's standard error is about 1/sqrt(n) on n independent samples: a
#: one-minute 100 Hz walk's accelerations, correlated over about 50 ms, hold about 1,200, so 0.03; the Neural-Swarm
#: flights' given orders lead the next by 0.2-0.8, a column shifted by one falls under 0.05)
ORDER_MARGIN = 0.1
#: correlation the order named (vehicle.yaml's or another) must reach on its weaker axis: the best of a hexarotor's
#: 720 orders at 31 shifts, where no torque is followed, reaches about four standard errors by chance (0.13 on the
#: walk above); the Neural-Swarm flights' orders read 0.27-0.82
MIN_FOLLOW = 0.2
#: rows a comparison needs
MIN_ROWS = 200
#: s, how far the recorded rotor speeds may lead (commands, ahead of the rotors by their lag) or trail (measured
#: speeds logged late) the angular acceleration: the orders are compared at the shift within this, in steps of
#: SHIFT_STEP_S, where some order follows best (a Crazyflie's commands follow best 0-30 ms ahead; ESC telemetry
#: arrives 40-80 ms late)
MAX_SHIFT_S, SHIFT_STEP_S = 0.15, 0.01

GIVEN, OTHER, UNDECIDED = "vehicle.yaml's", "another", "undecided"
#: what mends columns in another order (the constants' advice and the commands' warning say it alike)
REORDER = "give vehicle.yaml's rotor_angles_deg and rotor_directions in the order of rotors0's columns"


@dataclass(frozen=True)
class RotorOrder:
    """How well the roll and pitch torques of the rotor columns' orders follow the angular acceleration.

    Attributes
    ----------
    given : (roll, pitch) correlations of vehicle.yaml's order (columns as recorded)
    best_other : the best of the other orders: the column read for each of vehicle.yaml's rotors, in its order
    best_other_correlations : (roll, pitch) correlations of ``best_other``
    orders : orders compared, the given one included
    verdict : :data:`GIVEN` (vehicle.yaml's order follows best, by :data:`ORDER_MARGIN` or more, at
        :data:`MIN_FOLLOW` or more), :data:`OTHER` (``best_other`` does, by as much and as well) or :data:`UNDECIDED`
    alike : other orders than ``best_other`` and the given one whose weaker axis follows within
        :data:`ORDER_MARGIN` of it: the flight does not tell them from ``best_other`` (rotors whose speeds the
        controller moves alike; a simulated hexarotor's weave had two pairs so)
    lead_s : s, how far ahead of the angular acceleration the recorded speeds were taken (negative: behind it), one
        shift for all orders: where some order's torques follow best
    """

    given: tuple[float, float]
    best_other: tuple[int, ...]
    best_other_correlations: tuple[float, float]
    orders: int
    verdict: str
    alike: int = 0
    lead_s: float = 0.0

    def columns(self) -> str:
        """``best_other`` as the columns to read, in vehicle.yaml's order of its rotors (``w_1, w_0, ...``)."""
        return ", ".join(f"w_{c}" for c in self.best_other)

    def sentence(self) -> str:
        """What the flight says of the columns' order, as a phrase."""
        given = f"{self.given[0]:.2f} / {self.given[1]:.2f}"
        other = f"{self.best_other_correlations[0]:.2f} / {self.best_other_correlations[1]:.2f}"
        if self.verdict == GIVEN:
            return (f"the rotor columns are in vehicle.yaml's order (of {self.orders} orders, its roll and pitch "
                    f"torques follow the angular acceleration best: correlations {given}, the best other order "
                    f"{other}{_lead(self.lead_s)})")
        if self.verdict == OTHER and self.alike:
            return (f"the rotor columns are in another order than vehicle.yaml's angles, which the flight does not "
                    f"tell: {self.alike + 1} orders' roll and pitch torques follow the angular acceleration within "
                    f"{ORDER_MARGIN:g} of the best (correlations {other}, read as {self.columns()}), as recorded at "
                    f"{given}{_lead(self.lead_s)}")
        if self.verdict == OTHER:
            return (f"the rotor columns are in another order than vehicle.yaml's angles: read as {self.columns()} "
                    f"(vehicle.yaml's rotors in its order), their roll and pitch torques follow the angular "
                    f"acceleration at correlations {other}, as recorded at {given}{_lead(self.lead_s)}")
        return (f"the flight does not tell the rotor columns' order: vehicle.yaml's torques follow the roll and pitch "
                f"accelerations at correlations {given}, the best of the {self.orders - 1} other orders at {other}"
                f"{_lead(self.lead_s)}")

    def to_dict(self) -> dict:
        return {"verdict": self.verdict, "given_correlations": list(self.given), "best_other": list(self.best_other),
                "best_other_correlations": list(self.best_other_correlations), "orders": self.orders,
                "alike": self.alike, "lead_s": self.lead_s}


def _lead(lead_s: float) -> str:
    """How far ahead of the angular acceleration the recorded speeds were taken, as a clause ('' at none)."""
    if abs(lead_s) < SHIFT_STEP_S / 2:
        return ""
    return f", the recorded speeds taken {1e3 * abs(lead_s):.0f} ms {'ahead' if lead_s > 0 else 'behind'}"


def candidate_orders(n: int) -> np.ndarray:
    """(P, n) the orders compared for ``n`` rotors, the given one (``0 .. n-1``) first: every permutation up to
    :data:`ALL_ORDERS_UP_TO` rotors, else the given order's rotations and reflections."""
    if n <= ALL_ORDERS_UP_TO:
        return np.array(list(itertools.permutations(range(n))), dtype=int)
    base = np.arange(n)
    rotations = [np.roll(base, -s) for s in range(n)]
    return np.array(rotations + [r[::-1] for r in rotations], dtype=int)


def rotor_order(w2: Sequence[np.ndarray], dw: Sequence[np.ndarray], mixer: np.ndarray,
                dt: Sequence[float] | None = None, usable: Sequence[np.ndarray] | None = None) -> RotorOrder | None:
    """Which order of the rotor columns the roll and pitch accelerations follow (module docstring), over flights.

    The orders are compared at one time shift, the one within :data:`MAX_SHIFT_S` either way where some order's torques
    follow best (recorded commands lead the rotors by their lag; measured speeds reach a log late): a Crazyflie
    take-off's commanded torques follow the angular acceleration at 0.47 / 0.55 30 ms ahead and at -0.02 / 0.01 as
    stamped.

    Parameters
    ----------
    w2 : per flight (K, N) (rad/s)^2, the recorded rotor speeds squared, filtered as ``dw`` is
    dw : per flight (K, 3) rad/s^2, the body's angular acceleration (body axes x, y, z)
    mixer : (4, N) the geometry matrix of vehicle.yaml's rotors (its rows 1 and 2: the roll and pitch torques per
        ``l k_T``)
    dt : per flight s, its rows' step (None: the rows are compared as they are, no shift)
    usable : per flight (K,) bool, the rows whose acceleration counts (None: all)

    Returns
    -------
    :class:`RotorOrder`, or None with fewer than :data:`MIN_ROWS` finite rows or a single rotor.
    """
    w2 = [np.asarray(x, float) for x in w2]
    dw = [np.asarray(x, float)[:, :2] for x in dw]
    n = w2[0].shape[1]
    usable = [np.ones(len(x), bool) for x in w2] if usable is None else [np.asarray(u, bool) for u in usable]
    shifts = np.array([0.0]) if dt is None else np.arange(-MAX_SHIFT_S, MAX_SHIFT_S + SHIFT_STEP_S / 2, SHIFT_STEP_S)
    orders = candidate_orders(n)
    m = np.asarray(mixer, float)[1:3]  # (2, N) roll and pitch rows
    read = [(shift, _correlations(w2, dw, usable, [0] * len(w2) if dt is None else
                                  [int(round(shift / d)) if d > 0 else 0 for d in dt], orders, m)) for shift in shifts]
    read = [(shift, corr) for shift, corr in read if corr is not None]
    if not read or n < 2:
        return None
    # one shift for all orders, where some order follows best: the streams' timing is the data's, not an order's (each
    # order at its own best shift, a 67 g take-off's frame turned half round, its torques negated, read 0.57 / 0.58
    # where the oscillating acceleration had turned round too)
    lead, corr = max(read, key=lambda sc: float(sc[1].min(axis=1).max()))
    score = corr.min(axis=1)  # the weaker axis
    best = 1 + int(np.argmax(score[1:]))
    given, other = float(score[0]), float(score[best])
    if given - other >= ORDER_MARGIN and given >= MIN_FOLLOW:
        verdict = GIVEN
    elif other - given >= ORDER_MARGIN and other >= MIN_FOLLOW:
        verdict = OTHER
    else:
        verdict = UNDECIDED
    alike = int(np.sum(score[1:] > other - ORDER_MARGIN)) - 1  # the best other itself left out
    return RotorOrder(tuple(float(c) for c in corr[0]), tuple(int(c) for c in orders[best]),
                      tuple(float(c) for c in corr[best]), len(orders), verdict, alike, float(lead))


def _correlations(w2: list[np.ndarray], dw: list[np.ndarray], usable: list[np.ndarray], lead: list[int],
                  orders: np.ndarray, m: np.ndarray) -> np.ndarray | None:
    """(P, 2) each order's roll and pitch torque correlated with the angular acceleration, the rotor speeds taken
    ``lead[f]`` rows earlier than the acceleration in flight ``f``; None with under :data:`MIN_ROWS` rows."""
    xs, ys = [], []
    for x, y, u, k in zip(w2, dw, usable, lead):
        rows = np.flatnonzero(u)
        rows = rows[(rows - k >= 0) & (rows - k < len(x))]
        xk, yk = x[rows - k], y[rows]
        ok = np.all(np.isfinite(xk), axis=1) & np.all(np.isfinite(yk), axis=1)
        xs.append(xk[ok])
        ys.append(yk[ok])
    x, y = np.concatenate(xs), np.concatenate(ys)
    if len(x) < MIN_ROWS:
        return None
    x = x - x.mean(axis=0)
    y = y - y.mean(axis=0)
    cov_ww = x.T @ x  # (N, N)
    cov_wy = x.T @ y  # (N, 2): each column with the roll and the pitch acceleration
    var_y = np.sum(y * y, axis=0)
    # torque of order p about axis a: sum_j m[a, j] w2[:, p[j]]
    num = np.einsum("aj,pja->pa", m, cov_wy[orders])  # (P, 2)
    var_u = np.einsum("aj,pjk,ak->pa", m, cov_ww[orders[:, :, None], orders[:, None, :]], m)
    with np.errstate(divide="ignore", invalid="ignore"):
        corr = np.where((var_u > 0) & (var_y > 0), num / np.sqrt(var_u * var_y), 0.0)
    return np.nan_to_num(corr)
