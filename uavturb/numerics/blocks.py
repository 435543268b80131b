"""Statistics over time blocks: samples of a flight are correlated over a fraction of a second to seconds, so
errors are taken from the spread of blocks of them, not from the samples as if independent.

- :func:`block_labels` and :func:`block_mean_and_se`: blocks of a fixed duration and the standard error of a mean
  from the spread of their means (the accelerometer's bias, a recording's thrust level);
- :func:`contiguous_blocks` and :func:`jackknife_se`: a few contiguous blocks of equal counts, each left out in
  turn, and the jackknife standard error of what the fits without each give (``identify``'s ``theta_0``, the gap
  finder's parameters on a single recording).
"""

from __future__ import annotations

import numpy as np
import pandas as pd


def unique_inverse(labels: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``np.unique(labels, return_inverse=True)`` for integer labels (K,), by hashing rather than sorting (five
    times faster on half a million rows: a flight-hour's blocks are labelled many times over): (U,) the sorted
    distinct labels and (K,) each label's index among them."""
    codes, uniques = pd.factorize(np.asarray(labels), sort=True)
    return np.asarray(uniques), codes.astype(np.intp)


def block_labels(t: np.ndarray, block_s: float) -> np.ndarray:
    """(K,) int, consecutive ``block_s`` [s] blocks of times ``t`` (K,) [s], from the first."""
    return np.floor((np.asarray(t, float) - float(np.min(t))) / block_s).astype(np.int64)


def block_mean_and_se(x: np.ndarray, labels: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Mean of ``x`` (K,) or (K, p) and its standard error from the spread of block means (blocks ``labels`` (K,)
    weighted by their counts), so that correlated samples do not count as independent; ``inf`` with one block.

    Returns
    -------
    (mean, stderr), each (p,)
    """
    x = np.asarray(x, float).reshape(len(labels), -1)
    _, inv = unique_inverse(labels)
    n = np.bincount(inv).astype(float)
    means = np.stack([np.bincount(inv, weights=x[:, j]) / n for j in range(x.shape[1])], axis=1)
    mean = np.average(means, axis=0, weights=n)
    B = len(n)
    if B < 2:
        return mean, np.full(x.shape[1], np.inf)
    var = np.average((means - mean) ** 2, axis=0, weights=n) * B / (B - 1)
    return mean, np.sqrt(var / B)


def contiguous_blocks(t: np.ndarray, count: int) -> np.ndarray:
    """(K,) int in ``0 .. count - 1``: ``count`` contiguous blocks of times ``t`` (K,) [s] holding about as many
    samples each (edges at the quantiles of ``t``)."""
    t = np.asarray(t, float)
    edges = np.quantile(t, np.linspace(0, 1, count + 1))
    return np.clip(np.searchsorted(edges, t, side="right") - 1, 0, count - 1)


def jackknife_se(values: np.ndarray) -> np.ndarray:
    """The delete-one jackknife standard error of an estimate from its values ``values`` (B,) or (B, p) with each
    of ``B`` blocks left out in turn: ``sqrt((B - 1) / B sum((v - mean)^2))``; nan with fewer than two."""
    v = np.asarray(values, float)
    if len(v) < 2:
        return np.full(v.shape[1:], np.nan)
    B = len(v)
    return np.sqrt((B - 1) / B * np.sum((v - v.mean(axis=0)) ** 2, axis=0))


def weighted_jackknife_se(values: np.ndarray, full: float, shares: np.ndarray) -> float:
    """Hinkley's (1977) weighted delete-one jackknife standard error of an estimate ``full`` from its values
    ``values`` (B,) with each of ``B`` blocks left out in turn, each block's deviation weighted by ``1 - h``, ``h``
    (B,) the block's share of the estimate's information (shares summing to 1 over all blocks):
    ``sqrt(sum((1 - h) (v - full)^2))``. For a linear estimate it is unbiased however the information falls:
    leaving out a block holding nearly all of it leaves a fit of almost none, whose wide deviation the plain
    jackknife (:func:`jackknife_se`) counts in full; with equal shares the two agree. nan with fewer than two."""
    v, h = np.asarray(values, float), np.clip(np.asarray(shares, float), 0.0, 1.0)
    if len(v) < 2:
        return float("nan")
    return float(np.sqrt(np.sum((1.0 - h) * (v - full) ** 2)))
