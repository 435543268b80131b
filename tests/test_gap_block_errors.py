"""The spread between time blocks of one recording (``uncertainty.error_budget``'s **between blocks**): each block
weighted by its share of the parameter's information (``fit.information_shares``, Hinkley's weighted jackknife
``numerics.blocks.weighted_jackknife_se``), so that a flight whose near-floor stretch is one block keeps its
evidence. Known answers."""

from __future__ import annotations

import os

import numpy as np
import pytest

from uavturb.gap.design import GapData
from uavturb.gap.fit import fit_model, information_shares
from uavturb.gap import uncertainty
from uavturb.gap.uncertainty import TIME_BLOCKS, error_budget
from uavturb.numerics import processes
from uavturb.numerics.blocks import contiguous_blocks, jackknife_se, weighted_jackknife_se
from uavturb.physics import quaternion as quat
from uavturb.physics.dynamics import GRAVITY

MASS, K_T, RADIUS, MU = 1.2, 8e-6, 0.1, 2.0


def _hover(d: np.ndarray, seed: int = 3) -> GapData:
    """A tilting hover at 200 Hz at heights ``d`` [m] of the rotor plane over the floor, ground effect mu = 2
    (Cheeseman-Bennett), force noise 0.02 N."""
    K = len(d)
    rng = np.random.default_rng(seed)
    t = np.arange(K) * 0.005
    hover = np.sqrt(MASS * GRAVITY / (4 * K_T))
    w = np.repeat(hover * (1 + 0.08 * rng.uniform(-1, 1, (K // 20, 4))), 20, axis=0)
    R = quat.to_rotation_matrix(quat.from_euler(0.1 * np.sin(t), 0.1 * np.cos(0.7 * t), 0.3 * t))
    S = np.sum(w ** 2, axis=1)
    rho = MU * (RADIUS / (4 * d)) ** 2
    y = K_T * S[:, None] * R[:, :, 2]
    y[:, 2] += K_T * S * rho / (1 - rho)
    y += rng.normal(0, 0.02, (K, 3))
    return GapData(np.zeros(K, int), t, np.zeros((K, 3)), y, R, w, np.zeros((K, 3)), d, np.full(K, np.inf),
                   MASS, RADIUS, ["hover"], "mocap", imu=np.zeros(K, bool), fits_bias=False)


def _low_first(K: int = 4000) -> np.ndarray:
    """Heights: 5-15 cm in the first fifth of the time, 1.0-1.6 m after it."""
    t = np.arange(K) / K
    return np.where(t < 0.2, 0.10 + 0.05 * np.sin(40 * t), 1.3 + 0.3 * np.sin(9 * t))


def _low_throughout(K: int = 4000) -> np.ndarray:
    t = np.arange(K) / K
    return 0.10 + 0.05 * np.sin(2 * np.pi * 11 * t)


def test_a_block_holding_the_near_floor_rows_holds_nearly_all_of_mu():
    data = _hover(_low_first())
    fit = fit_model(data, {"ground_effect"}, with_stderr=False)
    shares = information_shares(data, fit, "ground_effect", contiguous_blocks(data.t, TIME_BLOCKS))["mu"]
    assert shares.sum() == pytest.approx(1.0)
    assert shares[0] > 0.8 and np.all(shares[1:] < 0.05)


def test_near_floor_rows_through_the_flight_share_mu_alike():
    data = _hover(_low_throughout())
    fit = fit_model(data, {"ground_effect"}, with_stderr=False)
    shares = information_shares(data, fit, "ground_effect", contiguous_blocks(data.t, TIME_BLOCKS))["mu"]
    assert shares.sum() == pytest.approx(1.0)
    assert np.all(np.abs(shares - 1 / TIME_BLOCKS) < 0.05)


def test_weighted_jackknife_with_equal_shares_is_the_plain_one():
    # leave-one-out means of equal blocks average to the full mean, so the two formulas agree exactly
    x = np.random.default_rng(4).normal(size=10)
    loo = np.array([np.delete(x, i).mean() for i in range(10)])
    assert weighted_jackknife_se(loo, x.mean(), np.full(10, 0.1)) == pytest.approx(jackknife_se(loo))
    assert np.isnan(weighted_jackknife_se(loo[:1], x.mean(), np.ones(1)))


def test_weighted_jackknife_is_unbiased_where_one_block_holds_the_information():
    # y = b x + e over five blocks, x large in block 0 only: the slope's variance is sigma^2 / sum(x^2); the
    # weighted jackknife's mean variance matches it, the plain one's is several times too large
    rng = np.random.default_rng(5)
    x = np.concatenate([np.full(20, 5.0), np.full(80, 0.3)])
    block = np.repeat(np.arange(5), 20)
    info = np.array([np.sum(x[block == b] ** 2) for b in range(5)])
    shares, true_var = info / info.sum(), 1.0 / np.sum(x ** 2)
    weighted, plain = [], []
    for _ in range(2000):
        y = 2.0 * x + rng.normal(size=100)
        full = np.sum(x * y) / np.sum(x * x)
        loo = np.array([np.sum((x * y)[block != b]) / np.sum((x * x)[block != b]) for b in range(5)])
        weighted.append(weighted_jackknife_se(loo, full, shares) ** 2)
        plain.append(jackknife_se(loo) ** 2)
    assert np.mean(weighted) == pytest.approx(true_var, rel=0.1)
    assert np.mean(plain) > 3 * true_var


def test_a_lift_seen_in_one_stretch_keeps_its_evidence():
    # a slow flight whose near-floor hovers all fall in its first fifth: left out, the rest (1-1.6 m up) pins mu
    # hardly at all; weighted by what it holds, the spread stays well under mu, and the budget says which share
    data = _hover(_low_first())
    fit = fit_model(data, {"ground_effect"})
    budget = error_budget(data, fit, "ground_effect", height_reference_m=0.0)["mu"]
    assert fit.nonlinear["ground_effect"] == pytest.approx(MU, rel=0.05)
    assert budget["largest_block_share"] > 0.8
    assert budget["between_blocks"] < MU / 10  # the lift stays many errors from zero
    block = contiguous_blocks(data.t, TIME_BLOCKS)
    left_out = [fit_model(data.subset(block != b), {"ground_effect"}, with_stderr=False).nonlinear["ground_effect"]
                for b in range(TIME_BLOCKS)]
    assert jackknife_se(np.array(left_out)) > 2 * budget["between_blocks"]  # what the plain jackknife had said
    evenly = error_budget(_hover(_low_throughout()), fit_model(_hover(_low_throughout()), {"ground_effect"}),
                          "ground_effect", height_reference_m=0.0)["mu"]
    assert evenly["largest_block_share"] < 0.3


def test_refits_side_by_side_in_forked_processes_give_the_same_budget(monkeypatch):
    """Four recordings, each fitted alone side by side in forked processes (``Refits.prefetch``, where that is worth
    it): the same error budget to the bit as the plain loop's; the parent fits only the heights moved either way."""
    if not processes.forking_possible():
        pytest.skip("forks only on Linux with two cores")
    data = _hover(_low_throughout(12000))
    data.group = np.repeat(np.arange(4), len(data) // 4)
    data.names = [f"hover{g}" for g in range(4)]
    fit = fit_model(data, {"ground_effect"})
    fitted_here = []
    refit = uncertainty._fit_or_none
    monkeypatch.setattr(uncertainty, "_fit_or_none", lambda part, effects: (
        fitted_here.append(os.getpid()) or refit(part, effects)))
    forked = error_budget(data, fit, "ground_effect")["mu"]
    assert fitted_here.count(os.getpid()) == 2  # the recordings fitted in children (whose lists are their own)
    monkeypatch.setattr(uncertainty, "forking_worth", lambda rows, fits: False)
    plain = error_budget(data, fit, "ground_effect")["mu"]
    assert forked == plain and plain["fits"] == 4
    assert "between_recordings" in plain and plain["height_reference"] > 0  # both kinds of part were refitted
