"""Which order of the recorded rotor columns the roll and pitch accelerations follow.

``vehicle.yaml`` gives each column of ``rotors0`` an angle (``rotor_angles_deg``, ``recordings.md``). A log whose
columns come in another order (the motors numbered from another rotor, or the other way round, or PX4's quad-X
numbering read as numbered round the frame) keeps the thrust right, a sum over the rotors, and makes the torques
wrong: ``identify`` then reads an inertia many times its physical bound, and a question about the order was all it
could say (a Neural-Swarm walk's commanded speeds, in vehicle.yaml's order, read 2.9 times the bound and were asked
about their order). Here the question is answered from the flight: the roll and pitch torques of each order of the
columns (the paper's eq. 1, ``tau = l k_T M w^2``: :meth:`~uavturb.physics.vehicle.Vehicle.mixer`) are correlated
with the measured angular acceleration about the same axis, and the order whose weaker axis follows best wins.

The correlations are computed from the columns' covariances once (each order is a permutation of them), so every
order of up to :data:`ALL_ORDERS_UP_TO` rotors is compared (720 for a hexarotor); with more rotors, the rotations
and reflections of the given order (numbering from another rotor, or the other way round).
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np

#: every permutation of the columns is compared for up to this many rotors; beyond, the given order's rotations and
#: reflections (an octorotor's 40,320 permutations would be as quick, but a log's mistakes are numbering ones)
ALL_ORDERS_UP_TO = 6
#: correlation by which one order's weaker axis must follow the angular acceleration better than another's for the
#: flight to tell them apart (a correlation's standard error is about 1/sqrt(n) on n independent samples: a
#: one-minute 100 Hz walk's accelerations, correlated over about 50 ms, hold about 1,200, so 0.03; the Neural-Swarm
#: flights' given orders lead the next by 0.2-0.5, a column shifted by one falls under 0.05)
ORDER_MARGIN = 0.1
#: rows a comparison needs
MIN_ROWS = 200

GIVEN, OTHER, UNDECIDED = "vehicle.yaml's", "another", "undecided"


@dataclass(frozen=True)
class RotorOrder:
    """How well the roll and pitch torques of the rotor columns' orders follow the angular acceleration.

    Attributes
    ----------
    given : (roll, pitch) correlations of vehicle.yaml's order (columns as recorded)
    best_other : the best of the other orders: the column read for each of vehicle.yaml's rotors, in its order
    best_other_correlations : (roll, pitch) correlations of ``best_other``
    orders : orders compared, the given one included
    verdict : :data:`GIVEN` (vehicle.yaml's order follows best, by :data:`ORDER_MARGIN` or more), :data:`OTHER`
        (``best_other`` does, by as much, and at least twice as well) or :data:`UNDECIDED`
    alike : other orders than ``best_other`` and the given one whose weaker axis follows within
        :data:`ORDER_MARGIN` of it: the flight does not tell them from ``best_other`` (rotors whose speeds the
        controller moves alike; a simulated hexarotor's weave had two pairs so)
    """

    given: tuple[float, float]
    best_other: tuple[int, ...]
    best_other_correlations: tuple[float, float]
    orders: int
    verdict: str
    alike: int = 0

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
                    f"{other})")
        if self.verdict == OTHER and self.alike:
            return (f"the rotor columns are in another order than vehicle.yaml's angles, which the flight does not "
                    f"tell: {self.alike + 1} orders' roll and pitch torques follow the angular acceleration within "
                    f"{ORDER_MARGIN:g} of the best (correlations {other}, read as {self.columns()}), as recorded at "
                    f"{given}")
        if self.verdict == OTHER:
            return (f"the rotor columns are in another order than vehicle.yaml's angles: read as {self.columns()} "
                    f"(vehicle.yaml's rotors in its order), their roll and pitch torques follow the angular "
                    f"acceleration at correlations {other}, as recorded at {given}")
        return (f"the flight does not tell the rotor columns' order: vehicle.yaml's torques follow the roll and pitch "
                f"accelerations at correlations {given}, the best of the {self.orders - 1} other orders at {other}")

    def to_dict(self) -> dict:
        return {"verdict": self.verdict, "given_correlations": list(self.given), "best_other": list(self.best_other),
                "best_other_correlations": list(self.best_other_correlations), "orders": self.orders,
                "alike": self.alike}


def candidate_orders(n: int) -> np.ndarray:
    """(P, n) the orders compared for ``n`` rotors, the given one (``0 .. n-1``) first: every permutation up to
    :data:`ALL_ORDERS_UP_TO` rotors, else the given order's rotations and reflections."""
    if n <= ALL_ORDERS_UP_TO:
        return np.array(list(itertools.permutations(range(n))), dtype=int)
    base = np.arange(n)
    rotations = [np.roll(base, -s) for s in range(n)]
    return np.array(rotations + [r[::-1] for r in rotations], dtype=int)


def rotor_order(w2: np.ndarray, dw: np.ndarray, mixer: np.ndarray) -> RotorOrder | None:
    """Which order of the rotor columns the roll and pitch accelerations follow (module docstring).

    Parameters
    ----------
    w2 : (K, N) (rad/s)^2, the recorded rotor speeds squared, filtered as ``dw`` is (the rows of one or more flights)
    dw : (K, 3) rad/s^2, the body's angular acceleration (body axes x, y, z)
    mixer : (4, N) the geometry matrix of vehicle.yaml's rotors (its rows 1 and 2: the roll and pitch torques per
        ``l k_T``)

    Returns
    -------
    :class:`RotorOrder`, or None with fewer than :data:`MIN_ROWS` finite rows or a single rotor.
    """
    w2, dw = np.asarray(w2, float), np.asarray(dw, float)
    ok = np.all(np.isfinite(w2), axis=1) & np.all(np.isfinite(dw[:, :2]), axis=1)
    n = w2.shape[1]
    if ok.sum() < MIN_ROWS or n < 2:
        return None
    x = w2[ok] - w2[ok].mean(axis=0)
    y = dw[ok][:, :2] - dw[ok][:, :2].mean(axis=0)
    cov_ww = x.T @ x  # (N, N)
    cov_wy = x.T @ y  # (N, 2): each column with the roll and the pitch acceleration
    var_y = np.sum(y * y, axis=0)
    orders = candidate_orders(n)
    m = np.asarray(mixer, float)[1:3]  # (2, N) roll and pitch rows
    # torque of order p about axis a: sum_j m[a, j] w2[:, p[j]]
    num = np.einsum("aj,pja->pa", m, cov_wy[orders])  # (P, 2)
    var_u = np.einsum("aj,pjk,ak->pa", m, cov_ww[orders[:, :, None], orders[:, None, :]], m)
    with np.errstate(divide="ignore", invalid="ignore"):
        corr = np.where(var_u > 0, num / np.sqrt(var_u * var_y), 0.0)
    corr = np.nan_to_num(corr)
    score = corr.min(axis=1)  # the weaker axis
    best = 1 + int(np.argmax(score[1:]))
    given, other = float(score[0]), float(score[best])
    if given - other >= ORDER_MARGIN:
        verdict = GIVEN
    elif other - given >= ORDER_MARGIN and other >= 2.0 * max(given, 0.0):
        verdict = OTHER
    else:
        verdict = UNDECIDED
    alike = int(np.sum(score[1:] > other - ORDER_MARGIN)) - 1  # the best other itself left out
    return RotorOrder(tuple(float(c) for c in corr[0]), tuple(int(c) for c in orders[best]),
                      tuple(float(c) for c in corr[best]), len(orders), verdict, alike)
