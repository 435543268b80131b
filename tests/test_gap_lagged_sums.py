"""The gap finder's lagged rotor-speed sums (``GapData.S_lag``) and what makes them fast: the same numbers,
to the bit, as the plain computation (each recording's lag filter on its own rows, ``np.sum(w**2, axis=1)``,
block means of the contiguous samples)."""

from __future__ import annotations

import numpy as np
import pytest

from uavturb.gap.design import GapData, block_means, lag_key, sum_of_squares
from uavturb.physics.effects import lag_rotor_speeds, lag_stretches


def _flights(K: int = 4000, seed: int = 0, groups=(0, 1)) -> GapData:
    """Two recordings of ``K`` samples each at 200 Hz, the second with a dropout and a jittered stretch."""
    rng = np.random.default_rng(seed)
    parts = []
    for g in groups:
        t = np.arange(K) * 0.005
        if g == 1:  # steps jittered by far more than LAG_JITTER (the exact loop), then a dropout, then even steps
            t = np.r_[0.0, np.cumsum(np.where(np.arange(K - 1) < K // 2, rng.uniform(0.001, 0.009, K - 1), 0.005))]
            t[K // 2:] += 0.5
        w = 1800 + np.cumsum(rng.normal(0, 5, (K, 6)), axis=0)
        parts.append((np.full(K, g), t, w))
    group, t, w = (np.concatenate([p[i] for p in parts]) for i in range(3))
    n = len(t)
    R = np.broadcast_to(np.eye(3), (n, 3, 3)).copy()
    return GapData(group, t, np.zeros((n, 3)), rng.normal(0, 1, (n, 3)), R, w, np.zeros((n, 3)),
                   np.full(n, np.inf), np.full(n, np.inf), 1.5, 0.1, ["a", "b"], "mocap", imu=np.zeros(n, bool),
                   fits_bias=False)


def _plain(data: GapData, tau: float) -> np.ndarray:
    """The lagged sums as first written: each recording's rows by a mask, numpy's own sum of squares."""
    out = np.empty(len(data))
    for g in np.unique(data.group):
        m = data.group == g
        out[m] = np.sum(lag_rotor_speeds(data.t[m], data.rotor_speeds[m], lag_key(tau)) ** 2, axis=1)
    return out


@pytest.mark.parametrize("columns", [1, 2, 3, 4, 6, 7, 8, 12])
def test_sum_of_squares_is_numpys_to_the_bit(columns):
    w = np.random.default_rng(columns).normal(1500, 400, (5000, columns))
    assert np.array_equal(sum_of_squares(w), np.sum(w**2, axis=1))
    assert sum_of_squares(np.zeros((0, 4))).shape == (0,)


def test_lag_stretches_known_answer_and_reuse():
    t = np.r_[np.arange(100) * 0.01, 2.0 + np.arange(50) * 0.01]  # a dropout of 1 s after sample 99
    t[120:130] += 0.003 * (-1.0) ** np.arange(10)  # jitter in the second stretch
    st = lag_stretches(t)
    assert [(a, b) for a, b, _ in st] == [(0, 100), (100, 150)]
    assert st[0][2] == pytest.approx(0.01)
    w = np.random.default_rng(1).normal(1000, 50, (150, 4))
    for tau in (0.003, 0.04):
        assert np.array_equal(lag_rotor_speeds(t, w, tau, st), lag_rotor_speeds(t, w, tau))
    assert lag_stretches(np.array([0.0])) == [(0, 1, None)]


def test_lagged_sums_are_the_plain_ones_on_flights_and_subsets():
    data = _flights()
    assert [(a, b, m is None) for a, b, m in lag_stretches(data.t[data.group == 1])] == [(0, 2000, True),
                                                                                        (2000, 4000, False)]
    for tau in (0.002, 0.0153, 0.08, 0.3):
        assert np.array_equal(data.S_lag(tau), _plain(data, tau))
    # a subset (one recording held out) and block means of 8 samples read the contiguous flights' sums
    keep = np.ones(len(data), bool)
    keep[:50] = keep[4100:4180] = False
    sub = data.subset(keep & (data.group == 1))
    blocks = block_means(data, keep, 8)
    for tau in (0.0153, 0.04):
        full = _plain(data, tau)
        assert np.array_equal(sub.S_lag(tau), full[keep & (data.group == 1)])
        expect = np.bincount(blocks.block_of, weights=full[blocks.rows]) / np.bincount(blocks.block_of)
        assert np.array_equal(blocks.S_lag(tau), expect)
        assert np.array_equal(blocks.S_lag(tau * (1 + 1e-4)), expect)  # the same cached value of tau
    # a subset's recordings are filtered first, the others when asked for
    fresh = _flights()
    one = fresh.subset(fresh.group == 0)
    assert np.array_equal(one.S_lag(0.05), _plain(fresh, 0.05)[fresh.group == 0])
    assert fresh._lag_done[lag_key(0.05)] == {0}
    assert np.array_equal(fresh.S_lag(0.05), _plain(fresh, 0.05))
    assert fresh._lag_done[lag_key(0.05)] == {0, 1}
    # the samples of a recording need not be consecutive
    mixed = _flights(K=1000)
    order = np.argsort(np.r_[np.arange(1000) * 2, np.arange(1000) * 2 + 1], kind="stable")
    shuffled = GapData(mixed.group[order], mixed.t[order], mixed.p, mixed.y, mixed.R, mixed.rotor_speeds[order],
                       mixed.v, mixed.d_down, mixed.d_up, 1.5, 0.1, ["a", "b"], "mocap")
    assert np.array_equal(shuffled.S_lag(0.03)[np.argsort(order)], _plain(mixed, 0.03))


def test_lagged_sums_stay_right_when_the_cache_drops_old_values(monkeypatch):
    from uavturb.gap import design

    data = _flights(K=2000)
    monkeypatch.setattr(design, "LAG_CACHE_BYTES", 2 * len(data) * 8)  # two values of tau
    monkeypatch.setattr(design, "ROWS_LAG_CACHE_BYTES", (len(data) // 2) * 8)  # one, of the subset
    sub = data.subset(data.group == 1)
    taus = (0.01, 0.02, 0.04, 0.01, 0.08, 0.02)
    for tau in taus:
        assert np.array_equal(sub.S_lag(tau), _plain(data, tau)[data.group == 1])
        assert np.array_equal(data.S_lag(tau), _plain(data, tau))
        assert len(data._lag_cache) <= 3 and set(data._lag_done) == set(data._lag_cache)  # the limit, and one more
        assert len(sub._lag_cache) <= 2


def test_the_cache_keeps_as_many_values_of_tau_whatever_the_flights_length():
    """A short flight keeps no more values of tau than a flight-hour's byte cap allows (the benchmark's line
    through a 5- and a 10-minute flight had carried a cache growing with the flight to an hour)."""
    from uavturb.gap import design

    data = _flights(K=500)
    sub = data.subset(data.group == 0)
    for tau in np.geomspace(0.005, 0.2, 60):
        assert np.array_equal(sub.S_lag(tau), _plain(data, tau)[data.group == 0])
        assert np.array_equal(data.S_lag(tau), _plain(data, tau))
    assert 0 < len(data._lag_cache) <= design.LAG_CACHE_TAUS and set(data._lag_done) == set(data._lag_cache)
    assert 0 < len(sub._lag_cache) <= design.ROWS_LAG_CACHE_TAUS
