"""Statistics over time blocks (``uavturb.numerics.blocks``): known answers."""

from __future__ import annotations

import numpy as np
import pytest

from uavturb.numerics.blocks import block_labels, block_mean_and_se, contiguous_blocks, jackknife_se, unique_inverse


def test_block_labels_count_whole_blocks_from_the_first_time():
    assert block_labels(np.array([10.0, 10.4, 10.99, 11.0, 13.5]), 1.0).tolist() == [0, 0, 0, 1, 3]


def test_block_mean_and_se_from_the_spread_of_block_means():
    # three blocks of means 1, 2, 6 (counts 2, 2, 4): mean 3.75; the samples inside a block do not count as
    # independent, only the blocks' spread does
    x = np.array([1.0, 1.0, 2.0, 2.0, 5.0, 7.0, 5.0, 7.0])
    labels = np.array([0, 0, 1, 1, 2, 2, 2, 2])
    mean, se = block_mean_and_se(x, labels)
    n, means = np.array([2, 2, 4.0]), np.array([1, 2, 6.0])
    var = np.average((means - 3.75) ** 2, weights=n) * 3 / 2
    assert mean[0] == pytest.approx(3.75) and se[0] == pytest.approx(np.sqrt(var / 3))
    two = block_mean_and_se(np.stack([x, 2 * x], 1), labels)  # columns alike
    assert np.allclose(two[0], [3.75, 7.5]) and np.allclose(two[1], [se[0], 2 * se[0]])
    assert np.isinf(block_mean_and_se(x, np.zeros(8))[1][0])  # one block tells no spread


def test_contiguous_blocks_hold_as_many_samples_each_in_time_order():
    t = np.sort(np.random.default_rng(0).uniform(0, 60, 1000))
    b = contiguous_blocks(t, 5)
    assert np.all(np.diff(b) >= 0) and set(b.tolist()) == set(range(5))
    assert np.bincount(b).tolist() == [200] * 5


def test_jackknife_of_a_mean_is_its_standard_error():
    # leaving each of n values out in turn, the jackknife error of the mean is exactly s / sqrt(n)
    x = np.random.default_rng(1).normal(size=12)
    leave_one_out = np.array([np.delete(x, i).mean() for i in range(len(x))])
    assert jackknife_se(leave_one_out) == pytest.approx(np.std(x, ddof=1) / np.sqrt(len(x)))
    assert np.allclose(jackknife_se(np.stack([leave_one_out, 3 * leave_one_out], 1)),
                       np.array([1, 3]) * np.std(x, ddof=1) / np.sqrt(len(x)))
    assert np.isnan(jackknife_se(np.array([1.0])))


def test_unique_inverse_is_numpys_unique_with_its_inverse():
    """Hashing, not sorting: the same sorted labels and indices as ``np.unique`` (labels as the surface curve makes
    them: a recording times 10^7 plus a block), negative and repeated labels included."""
    rng = np.random.default_rng(7)
    for labels in (rng.integers(0, 12, 5000) * 10_000_000 + rng.integers(0, 300, 5000),
                   np.array([5, -3, 5, 0, -3, 2**40]), np.array([4]), np.zeros(0, np.int64)):
        u, inv = unique_inverse(labels)
        u0, inv0 = np.unique(labels, return_inverse=True)
        assert np.array_equal(u, u0) and np.array_equal(inv, inv0.reshape(-1))
        assert np.array_equal(u[inv], labels)
