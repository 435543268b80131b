"""uavturb.numerics.filters against scipy.signal (which the package no longer imports) and known answers:
Savitzky-Golay values and derivatives in every window / derivative / layout the package uses, edges and
short inputs; the first-order lag against lfilter with its initial state and the closed-form step response."""

import numpy as np
import pytest
from scipy import signal

from uavturb.numerics.filters import first_order_lag, high_passed, moving_mean_bounds, savgol_coeffs, savgol_filter


def close(a, b, tol=1e-12):
    """Equal to ``tol`` relative to the data's scale (coefficients near 0 compare absolutely)."""
    a, b = np.asarray(a), np.asarray(b)
    assert a.shape == b.shape and a.dtype == b.dtype
    np.testing.assert_allclose(a, b, rtol=tol, atol=tol * max(1.0, float(np.max(np.abs(b)))))


@pytest.mark.parametrize("window", [5, 7, 11, 21, 51, 101])
@pytest.mark.parametrize("deriv", [0, 1, 2, 3])
def test_savgol_coeffs_are_scipys(window, deriv):
    for delta in (1.0, 0.005):
        close(savgol_coeffs(window, 2, deriv, delta), signal.savgol_coeffs(window, 2, deriv, delta))
    close(savgol_coeffs(window, 3, deriv), signal.savgol_coeffs(window, 3, deriv))


def test_savgol_coeffs_known_answer():
    # scipy's documented example and the classic 5-point quadratic smoother (-3, 12, 17, 12, -3) / 35
    close(savgol_coeffs(5, 2), np.array([-3.0, 12.0, 17.0, 12.0, -3.0]) / 35)
    close(savgol_coeffs(5, 2, deriv=1), np.array([0.2, 0.1, 0.0, -0.1, -0.2]), tol=1e-15)
    with pytest.raises(ValueError, match="odd"):
        savgol_coeffs(6, 2)
    with pytest.raises(ValueError, match="odd"):
        savgol_coeffs(3, 3)


@pytest.mark.parametrize("window,deriv,delta", [(5, 0, 1.0), (11, 0, 1.0), (21, 0, 1.0), (51, 0, 1.0),  # design.py
                                                (11, 1, 0.01), (11, 1, 0.0333),  # locate.py
                                                (5, 1, 0.005), (31, 1, 0.002), (7, 0, 0.005)])  # io, sysid
def test_savgol_filter_1d_is_scipys(window, deriv, delta):
    rng = np.random.default_rng(window + deriv)
    for n in (window, window + 1, 2 * window, 1000):  # the edges' windows overlap when n < 2 window
        x = np.cumsum(rng.normal(size=n)) + 0.3 * rng.normal(size=n)
        close(savgol_filter(x, window, 2, deriv=deriv, delta=delta),
              signal.savgol_filter(x, window, 2, deriv=deriv, delta=delta, mode="interp"))


@pytest.mark.parametrize("window,deriv", [(5, 0), (5, 1), (11, 1), (21, 0), (41, 1)])
def test_savgol_filter_2d_axis0_is_scipys(window, deriv):
    rng = np.random.default_rng(7)
    x = rng.normal(size=(500, 3)).cumsum(axis=0) * [1.0, 10.0, 0.01]  # columns of different scales
    close(savgol_filter(x, window, 2, deriv=deriv, delta=0.005, axis=0),
          signal.savgol_filter(x, window, 2, deriv=deriv, delta=0.005, axis=0, mode="interp"))
    close(savgol_filter(x.T, window, 2, deriv=deriv, delta=0.005),  # samples along the last axis
          signal.savgol_filter(x.T, window, 2, deriv=deriv, delta=0.005))
    x3 = rng.normal(size=(200, 2, 3))
    close(savgol_filter(x3, window, 2, deriv=deriv, axis=0), signal.savgol_filter(x3, window, 2, deriv=deriv, axis=0))


def test_savgol_filter_is_exact_on_a_quadratic_edges_included():
    t = np.arange(40) * 0.01  # s
    x = np.stack([3.0 - 2.0 * t + 5.0 * t**2, 0.5 * t**2], axis=1)
    close(savgol_filter(x, 11, 2, axis=0), x, tol=1e-11)
    close(savgol_filter(x, 11, 2, deriv=1, delta=0.01, axis=0), np.stack([-2.0 + 10.0 * t, t], axis=1), tol=1e-10)
    close(savgol_filter(x, 11, 2, deriv=2, delta=0.01, axis=0), np.tile([10.0, 1.0], (40, 1)), tol=1e-8)


def test_savgol_filter_types_and_short_inputs():
    x = np.arange(9) ** 2  # integers are read as float64
    close(savgol_filter(x, 9, 2), x.astype(np.float64), tol=1e-12)
    x32 = np.random.default_rng(1).normal(size=50).astype(np.float32)
    y32 = savgol_filter(x32, 7, 2)
    assert y32.dtype == np.float32
    np.testing.assert_allclose(y32, signal.savgol_filter(x32, 7, 2), rtol=1e-5, atol=1e-6)
    with pytest.raises(ValueError, match="window 7 is longer than the data"):
        savgol_filter(np.ones(6), 7, 2)


def lfilter_lag(x, a, y_before):
    return signal.lfilter([1 - a], [1, -a], x, axis=0, zi=a * np.atleast_2d(y_before))[0]


@pytest.mark.parametrize("a", [0.0, 0.2, np.exp(-0.005 / 0.03), 0.999, 0.99999, 1.0])
def test_first_order_lag_is_lfilter_with_its_initial_state(a):
    rng = np.random.default_rng(3)
    for n in (1, 2, 3, 4, 5, 1023, 1024, 1025, 5000):  # around the doubling's powers of 2
        x = 1000.0 + 100.0 * rng.normal(size=(n, 4))  # rad/s, rotor speeds
        y0 = x[0] - 50.0
        close(first_order_lag(x, a, y0), lfilter_lag(x, a, y0), tol=1e-12)


def test_first_order_lag_step_response_and_layouts():
    a = 0.9
    y = first_order_lag(np.ones(100), a, 0.0)  # 1-D, a scalar start
    close(y, 1.0 - a ** np.arange(1, 101), tol=1e-14)
    x = np.random.default_rng(4).normal(size=(300, 2, 3))
    y3 = first_order_lag(x, 0.7, np.zeros((2, 3)))
    assert y3.shape == x.shape
    close(y3.reshape(300, 6), lfilter_lag(x.reshape(300, 6), 0.7, np.zeros(6)))
    assert first_order_lag(np.empty((0, 4)), 0.5, np.zeros(4)).shape == (0, 4)
    with pytest.raises(ValueError, match="not in"):
        first_order_lag(np.ones(3), 1.5, 0.0)


def test_first_order_lag_into_a_slice_of_a_larger_array():
    """``out``: the output written in place (rows of a larger array), the same numbers to the bit."""
    x = 1000.0 + 100.0 * np.random.default_rng(5).normal(size=(700, 4))
    big = np.full((702, 4), -1.0)
    y = first_order_lag(x, 0.95, x[0], out=big[1:701])
    assert np.shares_memory(y, big)
    assert np.array_equal(big[1:701], first_order_lag(x, 0.95, x[0]))
    assert np.all(big[[0, 701]] == -1.0)  # nothing written outside



def test_high_passed_keeps_what_changes_faster_than_its_window():
    """A constant and a ramp's interior are taken off; a 2 Hz swing over a 2 s window stays (its mean over four
    whole periods is nil); columns are filtered alike."""
    t = np.arange(0.0, 20.0, 0.01)
    assert np.allclose(high_passed(t, np.full(len(t), 3.0), 2.0), 0.0)
    inner = (t > 1.5) & (t < 18.5)
    assert np.allclose(high_passed(t, 0.5 * t, 2.0)[inner], 0.0, atol=3e-3)  # one row more on a side: half a step
    swing = np.sin(2 * np.pi * 2.0 * t)
    out = high_passed(t, np.column_stack([swing + 5.0, 2 * swing]), 2.0)
    assert (np.allclose(out[inner, 0], swing[inner], atol=0.01)
            and np.allclose(out[inner, 1], 2 * swing[inner], atol=0.02))


def test_high_passed_with_its_bounds_given_is_the_same_to_the_bit():
    """A search that high-passes many signals on one set of times computes the moving mean's rows once."""
    rng = np.random.default_rng(11)
    t = np.cumsum(rng.uniform(0.004, 0.006, 3000))  # s, jittered rows
    x = rng.normal(size=(3000, 3))
    bounds = moving_mean_bounds(t, 2.0)
    lo, hi = bounds
    assert np.all(t[hi - 1] <= t + 1.0) and np.all(t[lo] >= t - 1.0) and np.all(lo <= np.arange(3000))
    assert np.array_equal(high_passed(t, x, 2.0, bounds), high_passed(t, x, 2.0))
    assert np.array_equal(high_passed(t, x, 2.0, bounds)[:, 1], high_passed(t, x[:, 1], 2.0))
