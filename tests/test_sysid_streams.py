"""What a logged stream holds: updates among repeats, their rate, their delay, and the noise."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.ndimage import uniform_filter1d

from uavturb.errors import InputError
from uavturb.gap.locate import noise_sigma
from uavturb.numerics.stream_updates import update_mask
from uavturb.sysid.streams import (estimate_lag, needed_rate_hz, noise_from_updates, slow_for, stream_updates,
                                   updates_only)

ROW_S = 0.02  # s, logger rows at 50 Hz


def held(t, sample_times, values):
    """Rows at ``t`` holding the last of ``values`` taken at ``sample_times`` (first row: the first value)."""
    i = np.searchsorted(sample_times, t, side="right") - 1
    return np.asarray(values)[np.maximum(i, 0)]


def thrust_needed(t):
    """N, a smooth thrust history around a 1.5 kg vehicle's weight."""
    return 14.7 * (1 + 0.15 * np.sin(2 * np.pi * 0.3 * t) + 0.1 * np.sin(2 * np.pi * 0.77 * t + 1)
                   + 0.05 * np.sin(2 * np.pi * 1.3 * t + 2))


def test_update_mask_marks_rows_whose_value_changed():
    x = np.array([1.0, 1.0, 2.0, 2.0, 2.0, 1.0, np.nan, np.nan, 3.0])
    assert update_mask(x).tolist() == [True, False, True, False, False, True, True, False, True]
    two = np.array([[1, 5], [1, 5], [1, 6], [2, 6], [2, 6]])
    assert update_mask(two).tolist() == [True, False, True, True, False]  # any column counts
    assert update_mask(np.zeros(0)).tolist() == [] and update_mask(np.ones(1)).tolist() == [True]
    assert update_mask(np.array([1.0, 1.0 + 1e-15])).tolist() == [True, True]  # exact equality only


def test_updates_only_keeps_the_first_row_of_each_run():
    t = np.arange(8) * 10
    x = np.array([[0, 0], [0, 0], [1, 0], [1, 0], [1, 0], [1, 2], [1, 2], [0, 0]])
    tu, xu = updates_only(t, x)
    assert tu.tolist() == [0, 20, 50, 70]
    assert xu.tolist() == [[0, 0], [1, 0], [1, 2], [0, 0]]


def test_stream_updates_counts_a_3_hz_stream_in_50_hz_rows():
    t = np.arange(0, 60, ROW_S)
    upd = np.arange(0, 60, 1 / 3)
    vals = held(t, upd, np.random.default_rng(0).normal(size=(len(upd), 4)))
    s = stream_updates("rotors0", (t * 1e9).astype(np.int64), vals)
    assert (s.rows, s.updates) == (3000, 180)
    assert s.row_rate_hz == pytest.approx(50.0) and s.update_rate_hz == pytest.approx(3.0, rel=0.02)
    assert s.held_share == pytest.approx(1 - 180 / 3000) and s.max_gap_s == pytest.approx(0.34, abs=0.011)
    assert s.describe().startswith("rotors0: 3000 rows at 50 Hz hold 180 updates at 3.0 Hz (94 % repeats")
    fresh = stream_updates("imu0", (t * 1e9).astype(np.int64), t)
    assert fresh.held_share == 0.0 and fresh.update_rate_hz == pytest.approx(50.0)
    with pytest.raises(InputError, match="imu0"):
        stream_updates("imu0", np.arange(3), np.zeros(4))


def test_slow_for_says_when_updates_are_too_slow():
    t = np.arange(0, 20, ROW_S)
    t_ns = (t * 1e9).astype(np.int64)
    rotors = stream_updates("rotors0", t_ns, held(t, np.arange(0, 20, 1 / 3), np.arange(60.0)))
    assert needed_rate_hz(0.02) == pytest.approx(100.0)
    msg = slow_for(rotors, needed_rate_hz(0.02), "a motor lag of 20 ms")
    assert msg.startswith("rotors0 updates at 3.0 Hz (94 % of its rows repeat the last value): too slow for "
                          "a motor lag of 20 ms, which needs updates at 100 Hz or faster")
    ground_effect = needed_rate_hz(0.1 / 0.5)  # 0.1 m of height crossed at 0.5 m/s
    position_9hz = stream_updates("groundtruth", t_ns, held(t, np.arange(0, 20, 1 / 9), np.arange(180.0)))
    assert ground_effect == pytest.approx(10.0) and "needs updates at 10 Hz" in slow_for(position_9hz, ground_effect)
    assert slow_for(stream_updates("groundtruth", t_ns, t), ground_effect) is None
    assert "never updates" in slow_for(stream_updates("rotors0", t_ns, np.ones(len(t))), 1.0)


def _late_held_signal(t, lag, rate_hz, seed, on_rows):
    """Thrust telemetry sampled every ~1/rate_hz s, arriving ``lag`` s later, written into the rows it reaches."""
    rng = np.random.default_rng(seed)
    arrive = np.cumsum(rng.uniform(0.85, 1.15, int(t[-1] * rate_hz) + 5) / rate_hz)
    arrive = arrive[arrive < t[-1] - ROW_S]
    row = np.round(arrive / ROW_S) if on_rows else np.ceil(arrive / ROW_S)  # first row showing it
    sampled = (row * ROW_S - lag) if on_rows else (arrive - lag)
    vals = 1.05 * thrust_needed(sampled) + rng.normal(0, 0.1, len(sampled))
    return held(t, row * ROW_S - 1e-9, vals)


@pytest.fixture(scope="module")
def reference():
    t = np.arange(0, 60, ROW_S)
    return t, thrust_needed(t) + np.random.default_rng(1).normal(0, 0.3, len(t))


def test_the_lag_of_rotor_telemetry_at_3_hz_comes_out_60_ms(reference):
    t, ref = reference
    sig = _late_held_signal(t, 0.06, 3.0, seed=2, on_rows=True)
    assert np.mean(update_mask(sig)) < 0.07
    lag = estimate_lag(t, ref, t, sig)
    assert lag.resolvable and lag.why == ""
    assert abs(lag.lag_s - 0.06) < 0.015 and 0 < lag.stderr_s < 0.015
    assert lag.r2 > 0.8 and lag.gain > 0 and 150 < lag.updates < 200
    assert lag.describe("rotors0") == (f"rotors0 late by {1e3 * lag.lag_s:.0f} ± {1e3 * lag.stderr_s:.0f} ms "
                                       f"(r2 {lag.r2:.2f}, {lag.updates} updates)")


def test_a_lag_counts_the_wait_for_the_next_row(reference):
    """Updates arriving between rows show at the next one: on average half a row (10 ms) later."""
    t, ref = reference
    lag = estimate_lag(t, ref, t, _late_held_signal(t, 0.06, 3.0, seed=3, on_rows=False))
    assert lag.resolvable and abs(lag.lag_s - 0.07) < 0.015


def test_a_fresh_signal_gives_its_lag_gain_and_offset(reference):
    t, _ = reference
    sig = 2.0 * thrust_needed(t) + 3.0  # every row new, 45 ms late
    lag = estimate_lag(t, thrust_needed(t), t + 0.045, sig, max_lag_s=0.1)
    assert lag.lag_s == pytest.approx(0.045, abs=2e-3) and lag.stderr_s < 2e-3
    assert lag.gain == pytest.approx(0.5, rel=1e-3) and lag.offset == pytest.approx(-1.5, abs=0.02)
    assert lag.r2 > 0.999


def test_a_lag_is_not_resolvable_where_the_signal_does_not_vary_or_is_later_than_searched(reference):
    t, ref = reference
    rng = np.random.default_rng(4)
    flat = held(t, np.arange(0, 60, 1 / 3), 14.7 + rng.normal(0, 0.01, 180))  # stuck telemetry
    lag = estimate_lag(t, ref, t, flat)
    assert not lag.resolvable and "explains only" in lag.why
    assert lag.describe("rotors0").startswith("rotors0: delay not resolvable: the signal explains only")
    late = estimate_lag(t, ref, t, _late_held_signal(t, 0.35, 3.0, seed=5, on_rows=True))
    assert not late.resolvable and "longest searched (0.200 s)" in late.why
    few = estimate_lag(t[:40], ref[:40], t[:40], flat[:40])
    assert not few.resolvable and "too few" in few.why and np.isnan(few.lag_s)
    with pytest.raises(InputError, match="estimate_lag"):
        estimate_lag(t, ref[:-1], t, flat)


def _held_noise(sigma, n_rows, hold, seed):
    draws = np.random.default_rng(seed).normal(0, 1, (n_rows // hold + 1, len(sigma))) * sigma
    return np.repeat(draws, hold, axis=0)[:n_rows]


def test_noise_from_updates_finds_held_white_noise_that_row_differences_call_nil():
    t = np.arange(0, 120, ROW_S)
    r = _held_noise(np.array([0.2, 0.2, 0.2]), len(t), 5, seed=6)
    assert np.all(noise_sigma(r) < 0.01)  # MAD of mostly zeros
    assert noise_from_updates(t, r) == pytest.approx([0.2] * 3, rel=0.1)
    drift = 0.5 * np.sin(2 * np.pi * t[::5] / 20)  # a slow change, held like the noise
    axes = _held_noise(np.array([0.1, 0.2, 0.4]), len(t), 5, seed=7) + np.repeat(drift, 5)[:, None]
    assert noise_from_updates(t, axes) == pytest.approx([0.1, 0.2, 0.4], rel=0.1)


def test_noise_from_updates_takes_the_inputs_updates_and_keeps_recordings_apart():
    t = np.arange(0, 60, ROW_S)
    r = _held_noise(np.array([0.2, 0.2, 0.2]), len(t), 5, seed=8)
    r = r + np.random.default_rng(9).normal(0, 0.01, r.shape)  # every row changes a little
    inputs = np.arange(len(t)) % 5 == 0
    assert noise_from_updates(t, r, update=inputs) == pytest.approx([0.2] * 3, rel=0.1)
    assert np.all(noise_from_updates(t, r) < 0.05)  # every row an update: the small noise only
    group = np.r_[np.zeros(len(t) // 2, int), np.ones(len(t) - len(t) // 2, int)]
    shifted = r + 100.0 * group[:, None]  # recordings at other levels: no jump counted as noise
    assert noise_from_updates(t, shifted, group, inputs) == pytest.approx([0.2] * 3, rel=0.1)
    with pytest.raises(InputError, match="residual"):
        noise_from_updates(t[:2], r[:2])


def test_noise_from_updates_spans_the_window_of_a_filter():
    """White noise of sigma 1 averaged over 10 rows: sigma 1/sqrt(10), correlated over 10 rows."""
    t = np.arange(0, 120, ROW_S)
    r = uniform_filter1d(np.random.default_rng(10).normal(0, 1, (len(t), 3)), 10, axis=0)
    # neighbours share 9 of their 10 draws: their difference is that of two draws over 10, so 0.1
    assert noise_from_updates(t, r) == pytest.approx([0.1] * 3, rel=0.1)
    spanned = noise_from_updates(t, r, min_step_s=10 * ROW_S)
    assert spanned == pytest.approx([1 / np.sqrt(10)] * 3, rel=0.1)
