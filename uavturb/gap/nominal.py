"""The nominal model's own unknowns, anchored so that they cannot swallow an effect.

Two unknowns of the nominal model trade against the effects the gap finder looks for:

**Accelerometer bias.** Along the thrust axis a constant ``b_z`` is nearly the same regressor as the
thrust coefficient at hover (``m R e_z`` against ``S R e_z``, ``S`` the sum of squared rotor speeds):
a joint fit lets ``b_z`` take part of the thrust and of every law along it (the ground effect). On
real flights that joint fit put ``k_T`` 8-57 % below what ``uavturb identify`` finds, with ``b_z``
of 0.65-5.8 m/s^2. Where a recording has an IMU *and* motion capture, the bias is not a fit
parameter at all: it is what the accelerometer reads beyond the specific force the motion capture
shows, ``b = mean(a_imu - R^T (v_dot + g e_z))`` in B (:func:`anchored_bias`), measured without any
model of the thrust, so it cannot trade with one. ``identify`` anchors ``k_T`` the same way (its
motion-capture rows carry no bias), so the two agree.

**Thrust level.** Recordings of one vehicle made on different days, batteries or propellers differ
in thrust per rotor speed squared by a few percent (``recordings.md``). Pooled under one ``k_T``,
the difference leaks into whatever else differs between the recordings: on real Crazyflie
sessions 3-5 % apart it moved the ground effect's ``mu`` from about 4.6 to 6.45 and invented a
battery sag. :func:`thrust_levels` measures each recording's level far from any surface (where no
surface law acts) and, where the levels differ beyond their honest errors and by more than
:data:`LEVEL_PRACTICAL` (``gap-report.md``: "each gets its own thrust coefficient"), each
recording's rows carry their level.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from uavturb.physics.constants import GRAVITY

#: s, blocks whose means are taken as independent (errors of the bias and the thrust levels)
BLOCK_S = 1.0
#: relative difference of thrust levels under which recordings share one thrust coefficient
LEVEL_PRACTICAL = 0.005
#: chi^2 per degree of freedom of the levels' differences above which they differ (with honest errors)
LEVEL_CHI2 = 9.0


def block_labels(t: np.ndarray, block_s: float = BLOCK_S) -> np.ndarray:
    """(K,) int, consecutive ``block_s`` [s] blocks of times ``t`` [s]."""
    return np.floor((np.asarray(t, float) - float(np.min(t))) / block_s).astype(np.int64)


def block_mean_and_se(x: np.ndarray, labels: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Mean of ``x`` (K,) or (K, p) and its standard error from the spread of block means (blocks
    with samples weighted by their counts), so correlated samples do not count as independent."""
    x = np.asarray(x, float).reshape(len(labels), -1)
    _, inv = np.unique(labels, return_inverse=True)
    n = np.bincount(inv).astype(float)
    means = np.stack([np.bincount(inv, weights=x[:, j]) / n for j in range(x.shape[1])], axis=1)
    mean = np.average(means, axis=0, weights=n)
    B = len(n)
    if B < 2:
        return mean, np.full(x.shape[1], np.inf)
    var = np.average((means - mean) ** 2, axis=0, weights=n) * B / (B - 1)
    return mean, np.sqrt(var / B)


@dataclass(frozen=True)
class AnchoredBias:
    """Accelerometer bias of one recording, measured against motion capture.

    Attributes
    ----------
    b : (3,) m/s^2 in B, what the accelerometer reads beyond the motion capture's specific force
    stderr : (3,) m/s^2, from the spread of 1 s block means
    n : rows used
    """

    b: np.ndarray
    stderr: np.ndarray
    n: int


def mocap_specific_force(R: np.ndarray, dv: np.ndarray) -> np.ndarray:
    """(K, 3) m/s^2 in B, the specific force motion capture shows: ``R^T (v_dot + g e_z)``.

    Parameters
    ----------
    R : (K, 3, 3) body to world; dv : (K, 3) m/s^2, derivative of the world velocity
    """
    return np.einsum("kji,kj->ki", R, dv + np.array([0.0, 0.0, GRAVITY]))


def anchored_bias(t: np.ndarray, R: np.ndarray, acc: np.ndarray, dv: np.ndarray, use: np.ndarray) -> AnchoredBias:
    """The accelerometer bias as the mean of ``acc - R^T (dv + g e_z)`` over the rows ``use``.

    Parameters
    ----------
    t : (K,) s
    R : (K, 3, 3) body to world
    acc : (K, 3) m/s^2, specific force in B (state file's biases already removed)
    dv : (K, 3) m/s^2, smoothed derivative of the motion-capture velocity in W
    use : (K,) bool, rows in flight (no ground contact; the filter's edges out)
    """
    diff = (acc - mocap_specific_force(R, dv))[use]
    if len(diff) == 0:
        return AnchoredBias(np.zeros(3), np.full(3, np.inf), 0)
    mean, se = block_mean_and_se(diff, block_labels(t[use]))
    return AnchoredBias(mean, se, int(use.sum()))


@dataclass(frozen=True)
class ThrustLevels:
    """Each recording's thrust per rotor speed squared, relative to their pooled value.

    Attributes
    ----------
    k_T : (G,) N/(rad/s)^2, each recording's thrust coefficient far from surfaces (nan: not measurable)
    stderr : (G,) N/(rad/s)^2, from 1 s block ratios
    level : (G,) -, the level applied to each recording's thrust (all 1 where they do not differ)
    differ : whether the recordings differ in thrust level (and each got its own)
    why : one sentence with the numbers
    """

    k_T: np.ndarray
    stderr: np.ndarray
    level: np.ndarray
    differ: bool
    why: str

    @property
    def spread_percent(self) -> float:
        """%, range of the measured levels (max - min over their mean); 0 for one recording."""
        k = self.k_T[np.isfinite(self.k_T)]
        return float(100.0 * np.ptp(k) / np.mean(k)) if len(k) > 1 else 0.0


def _level_of(y_thrust: np.ndarray, S: np.ndarray, t: np.ndarray) -> tuple[float, float]:
    """(k [N/(rad/s)^2], stderr): ratio estimator ``sum(y) / sum(S)`` and its error from block sums."""
    labels = block_labels(t)
    _, inv = np.unique(labels, return_inverse=True)
    ys, ss = np.bincount(inv, weights=y_thrust), np.bincount(inv, weights=S)
    k = float(ys.sum() / ss.sum())
    B = len(ys)
    if B < 4:
        return k, float("inf")
    # linearised ratio estimator over blocks: var(k) = sum((y_b - k S_b)^2) / S^2 * B / (B - 1)
    return k, float(np.sqrt(np.sum((ys - k * ss) ** 2) * B / (B - 1)) / ss.sum())


def thrust_levels(group: np.ndarray, t: np.ndarray, y_thrust: np.ndarray, S: np.ndarray, far: np.ndarray,
                  names: list[str]) -> ThrustLevels:
    """Each recording's thrust coefficient on its rows far from surfaces (``far``), and whether they
    differ: chi^2 of their differences over :data:`LEVEL_CHI2` per degree of freedom *and* a spread
    over :data:`LEVEL_PRACTICAL`.

    Parameters
    ----------
    group : (K,) int, recording index; t : (K,) s
    y_thrust : (K,) N, the measured force along the body z axis (what the rotors must make)
    S : (K,) (rad/s)^2, sum of squared rotor speeds
    far : (K,) bool, rows in flight farther from every surface than a surface law reaches
    names : recording names, for the sentence
    """
    G = int(group.max()) + 1 if len(group) else 0
    k = np.full(G, np.nan)
    se = np.full(G, np.nan)
    for g in range(G):
        m = far & (group == g)
        if m.sum() >= 50:
            k[g], se[g] = _level_of(y_thrust[m], S[m], t[m])
    ok = np.isfinite(k) & np.isfinite(se)
    level = np.ones(G)
    if ok.sum() < 2:
        why = ("one recording: its thrust coefficient is fitted with the rest" if G == 1 else
               "fewer than two recordings fly far enough from surfaces to measure their thrust levels; "
               "they share one thrust coefficient")
        return ThrustLevels(k, se, level, False, why)
    w = 1.0 / np.maximum(se[ok], 1e-300) ** 2
    mean = float(np.sum(w * k[ok]) / np.sum(w))
    chi2_dof = float(np.sum(w * (k[ok] - mean) ** 2) / (ok.sum() - 1))
    spread = float(np.ptp(k[ok]) / mean)
    listing = ", ".join(f"{n} {100 * (kg / mean - 1):+.1f} %" for n, kg, o in zip(names, k, ok) if o)
    differ = chi2_dof > LEVEL_CHI2 and spread > LEVEL_PRACTICAL
    if differ:
        level[ok] = k[ok] / mean
        why = (f"the recordings differ in thrust per rotor speed squared far from surfaces ({listing}; "
               f"chi^2/dof = {chi2_dof:.1f}): each gets its own thrust coefficient")
    else:
        why = (f"the recordings' thrust levels far from surfaces agree ({listing}; chi^2/dof = {chi2_dof:.1f}, "
               f"spread {100 * spread:.1f} %): one thrust coefficient")
    return ThrustLevels(k, se, level, differ, why)
