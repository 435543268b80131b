"""uavturb.io.differentiate: derivatives at the samples' true times, known answers and degenerate windows."""

import numpy as np
import pytest

from uavturb.io.differentiate import local_quadratic


def test_local_quadratic_derivative_on_jittered_times_and_a_window_without_three_distinct_times():
    rng = np.random.default_rng(3)
    t = np.cumsum(0.01 + rng.uniform(-0.002, 0.002, 200))
    x = 2.0 + 3.0 * t - 0.5 * t**2  # a quadratic: exact whatever the sampling
    np.testing.assert_allclose(local_quadratic(t, x, 7, deriv=1), 3.0 - t, atol=1e-8)
    # the last time centuries off: its window holds two distinct times; the rows before keep their slope
    t = np.array([0.0, 0.01, 0.02, 0.03, 0.04, 7.8e9])
    d = local_quadratic(t, np.arange(6.0), 5)
    assert np.all(np.isfinite(d)) and d[:3] == pytest.approx([100.0] * 3)
