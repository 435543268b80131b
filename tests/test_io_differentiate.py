"""uavturb.io.differentiate: derivatives at the samples' true times, known answers and degenerate windows."""

import numpy as np
import pytest

from uavturb.io.differentiate import derivative_matched, local_quadratic


def test_local_quadratic_derivative_on_jittered_times_and_a_window_without_three_distinct_times():
    rng = np.random.default_rng(3)
    t = np.cumsum(0.01 + rng.uniform(-0.002, 0.002, 200))
    x = 2.0 + 3.0 * t - 0.5 * t**2  # a quadratic: exact whatever the sampling
    np.testing.assert_allclose(local_quadratic(t, x, 7, deriv=1), 3.0 - t, atol=1e-8)
    # the last time centuries off: its window holds two distinct times; the rows before keep their slope
    t = np.array([0.0, 0.01, 0.02, 0.03, 0.04, 7.8e9])
    d = local_quadratic(t, np.arange(6.0), 5)
    assert np.all(np.isfinite(d)) and d[:3] == pytest.approx([100.0] * 3)


@pytest.mark.parametrize("jitter", [0.0, 0.002])
def test_derivative_matched_is_the_derivative_filter_inside_and_the_smoother_at_the_ends(jitter):
    """Inside: the filter ``local_quadratic``'s derivative puts on a rate (``y`` the trapezoid integral of ``x``,
    exact on even steps); the ``window // 2`` rows at each end: the value smoother's own fits, on even and
    jittered times alike."""
    rng = np.random.default_rng(5)
    n, window = 400, 9
    h = window // 2
    t = np.cumsum(0.01 + rng.uniform(-jitter, jitter, n))
    x = np.stack([np.sin(7.0 * t), np.cos(3.0 * t) + 0.1 * rng.normal(size=n)], axis=1)  # (N, 2)
    matched = derivative_matched(t, x, window)
    smoothed = local_quadratic(t, x, window, deriv=0)
    np.testing.assert_array_equal(matched[:h], smoothed[:h])
    np.testing.assert_array_equal(matched[n - h:], smoothed[n - h:])
    if jitter == 0.0:
        y = np.concatenate([np.zeros((1, 2)), np.cumsum(0.5 * np.diff(t)[:, None] * (x[1:] + x[:-1]), axis=0)])
        np.testing.assert_allclose(matched[h:n - h], local_quadratic(t, y, window, deriv=1)[h:n - h], atol=1e-9)
    # a flight shorter than the window: the window shrinks to it, and the rows outside its middle one are the ends
    short = derivative_matched(t[:7], x[:7], window)
    np.testing.assert_array_equal(np.delete(short, 3, axis=0), np.delete(local_quadratic(t[:7], x[:7], 7, deriv=0), 3,
                                                                         axis=0))
