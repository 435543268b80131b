"""The "in flight" rows of the readers' checks (:func:`uavturb.io.consistency.in_flight`) on rotor streams held
at a slow update rate: known answers on rotor speeds made here."""

from types import SimpleNamespace

import numpy as np
import pytest

from uavturb.io.consistency import (POSITION_WINDOW_S, _column_correlations, _masked_correlation, _window_edges,
                                    clock_offset, in_flight)
from uavturb.io.recording import Rotors
from uavturb.numerics.stream_updates import hold_period_s

HOVER, IDLE = 2000.0, 600.0  # rad/s
TAKE_OFF, TOUCH_DOWN = 2.0, 8.0  # s
ROW_S = 0.01  # s, logger rows at 100 Hz


def _rotors(hold_hz: float | None, delay_s: float = 0.0, *, one_at_a_time: bool = False
            ) -> tuple[np.ndarray, SimpleNamespace]:
    """Rows at 100 Hz over 10 s, the rotors at hover (varying by 1 %) between take-off and touchdown, idling on
    the ground; with ``hold_hz``, written as a logger repeats ESC telemetry updated at that rate, ``delay_s``
    late, all motors together or ``one_at_a_time`` (round robin, each motor at ``hold_hz``)."""
    rng = np.random.default_rng(0)
    t = np.arange(1000) * ROW_S
    true = np.where((t >= TAKE_OFF) & (t < TOUCH_DOWN), HOVER, IDLE)[:, None] * (1 + 0.01 * rng.random((len(t), 4)))
    if hold_hz is None:
        w = true
    else:
        w = np.empty_like(true)
        for c in range(4):
            phase = c / (4 * hold_hz) if one_at_a_time else 0.0
            update = np.floor((t - phase) * hold_hz) / hold_hz + phase  # each column's last update at or before a row
            source = np.clip(np.round((update - delay_s) / ROW_S).astype(int), 0, len(t) - 1)
            w[:, c] = true[source, c]
    return t, SimpleNamespace(rotors=Rotors(t_ns=np.round(t * 1e9).astype(np.int64), speeds=w))


def test_a_fresh_stream_flies_between_take_off_and_touchdown():
    t, rec = _rotors(None)
    assert hold_period_s(rec.rotors.t_ns, rec.rotors.speeds) == pytest.approx(ROW_S)
    flying = in_flight(rec, rec.rotors.t_ns)
    assert np.array_equal(flying, (t >= TAKE_OFF - 1e-9) & (t < TOUCH_DOWN - ROW_S - 1e-9))  # one row less at the end


@pytest.mark.parametrize("one_at_a_time", [False, True], ids=["together", "round-robin"])
def test_a_held_stream_stops_flying_an_update_period_before_its_held_values_do(one_at_a_time):
    """ESC telemetry at 3 Hz and 60 ms late keeps its hover values up to 0.39 s into the touchdown: those rows (a
    real take-off's landing impacts) are not flight. Each interval in flight ends one update period earlier."""
    t, rec = _rotors(3.0, 0.06, one_at_a_time=one_at_a_time)
    assert hold_period_s(rec.rotors.t_ns, rec.rotors.speeds) == pytest.approx(1 / 3, abs=ROW_S)
    flying = in_flight(rec, rec.rotors.t_ns)
    lingers = rec.rotors.speeds.max(axis=1) > 0.9 * HOVER
    assert lingers[(t > TOUCH_DOWN + 0.1) & (t < TOUCH_DOWN + 0.4)].any()  # the held values linger past touchdown
    assert not flying[t >= TOUCH_DOWN + 0.06].any() and not flying[t < TAKE_OFF].any()
    assert np.all(np.diff(np.flatnonzero(flying)) == 1)  # one interval, most of the flight
    assert flying.sum() * ROW_S > TOUCH_DOWN - TAKE_OFF - 1.0


def test_position_windows_are_bounded_by_the_samples_not_the_span():
    t = np.concatenate([np.arange(0.0, 10.0, 0.01), 1e7 + np.arange(0.0, 4.0, 0.01), 2e7 + np.arange(0.0, 1.0, 2.0)])
    starts, ends = _window_edges(t, POSITION_WINDOW_S)
    assert len(starts) <= len(t) // 10
    assert np.all(ends - starts == pytest.approx(POSITION_WINDOW_S))
    # no window spans a gap: each lies inside one stretch of the stream
    assert np.all((ends <= 10.0) | ((starts >= 1e7) & (ends <= 1e7 + 4.0)))


def test_masked_correlation_is_pearsons_r_on_each_rows_samples():
    rng = np.random.default_rng(2)
    x, y = rng.normal(size=(4, 500)), rng.normal(size=(4, 500))
    y[1] = 2.0 * x[1] + 0.1 * y[1]
    ok = rng.uniform(size=(4, 500)) < 0.8
    ok[3, 10:] = False  # under MIN_FLIGHT_ROWS samples: nan
    r = _masked_correlation(x, y, ok)
    for j in range(3):
        assert r[j] == pytest.approx(np.corrcoef(x[j, ok[j]], y[j, ok[j]])[0, 1], abs=1e-12)
    assert r[1] > 0.99 and np.isnan(r[3])
    assert np.isnan(_masked_correlation(np.ones((1, 100)), y[:1, :100], np.ones((1, 100), bool))[0])


def test_column_correlations_are_corrcoefs_of_each_column():
    """Every column's Pearson's r with one series at once: np.corrcoef's, column by column; nan for a constant
    column; a column equal to the series, or to its negative times two, at exactly +-1."""
    rng = np.random.default_rng(3)
    y = rng.normal(size=800)
    X = rng.normal(size=(800, 6)) + np.linspace(-1.0, 1.0, 6) * y[:, None]
    X[:, 2] = 4.0
    X[:, 3] = y
    X[:, 4] = -2.0 * y + 7.0
    r = _column_correlations(y, X)
    for j in (0, 1, 5):
        assert r[j] == pytest.approx(np.corrcoef(y, X[:, j])[0, 1], abs=1e-14)
    assert r[0] < -0.5 < 0.5 < r[5] and np.isnan(r[2])
    assert r[3] == pytest.approx(1.0, abs=1e-15) and r[4] == pytest.approx(-1.0, abs=1e-15)
    assert np.all(np.abs(r[[3, 4]]) <= 1.0)  # clipped


@pytest.mark.parametrize("late_s", [0.0, 0.15, -0.4, 2.5])
def test_clock_offset_finds_a_known_offset_near_and_far(late_s):
    """A signal stamped ``late_s`` late is found there, near (the fine grid: 5 ms) and beyond the near search."""
    rng = np.random.default_rng(5)
    t = np.arange(0.0, 60.0, 0.005)
    base = np.convolve(rng.normal(size=len(t)), np.ones(40) / 40, "same")  # swings of a fifth of a second
    t_sig = t[::2]
    signal = np.interp(t_sig - late_s, t, base) + 0.05 * rng.normal(size=len(t_sig))
    lag, best, at_zero = clock_offset(t, base, t_sig, signal)
    assert lag == pytest.approx(late_s, abs=0.006) and best > 0.9
    assert (at_zero > 0.9) == (late_s == 0.0)
