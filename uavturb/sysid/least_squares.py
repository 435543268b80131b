"""Linear least squares with honest standard errors.

Samples of a flight are strongly correlated in time (oversampling, smoothed derivatives),
so the textbook ``sigma^2 (A^T A)^-1`` covariance understates the uncertainty. We use the
Newey-West (1987) heteroscedasticity- and autocorrelation-consistent covariance with a
Bartlett kernel, whose lag is given in samples.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class LstsqResult:
    """Coefficients, covariance and fit quality.

    Attributes
    ----------
    coef : (P,) estimates
    cov : (P, P) Newey-West covariance of ``coef``
    residual : (K,) ``y - A coef``
    rms : float, root mean square of the residual
    cond : float, condition number of the column-normalised (weighted) regressors: how nearly
        collinear the columns are (1: orthogonal)
    """

    coef: np.ndarray
    cov: np.ndarray
    residual: np.ndarray
    rms: float
    cond: float = 1.0

    @property
    def stderr(self) -> np.ndarray:
        return np.sqrt(np.maximum(np.diag(self.cov), 0.0))


def newey_west_meat(Aw: np.ndarray, lag: int, groups: np.ndarray | None = None) -> np.ndarray:
    """``sum_k w_k (Gamma_k + Gamma_k^T)`` of the score ``Aw = A * residual[:, None]`` (K, P).

    ``groups`` (K,) labels independent segments (recordings): no cross products between them.
    """
    S = Aw.T @ Aw
    K = len(Aw)
    for k in range(1, min(lag, K - 1) + 1):
        w = 1.0 - k / (lag + 1.0)
        prod = Aw[k:].T @ Aw[:-k]
        if groups is not None:  # take out the few pairs across segments (their boundaries) afterwards
            cross = np.flatnonzero(groups[k:] != groups[:-k])
            if len(cross):
                prod -= Aw[k:][cross].T @ Aw[:-k][cross]
        S += w * (prod + prod.T)
    return S


def lstsq(A: np.ndarray, y: np.ndarray, *, lag: int = 20, weights: np.ndarray | None = None,
          groups: np.ndarray | None = None) -> LstsqResult:
    """Solve ``min ||W^(1/2) (y - A c)||^2`` with a Newey-West covariance.

    Parameters
    ----------
    A : (K, P) regressors
    y : (K,) targets
    lag : Bartlett kernel lag [samples]; about the correlation length of the residual
    weights : (K,) optional positive row weights
    groups : (K,) optional segment labels (independent recordings)
    """
    A = np.asarray(A, float)
    y = np.asarray(y, float)
    sw = np.ones(len(y)) if weights is None else np.sqrt(np.asarray(weights, float))
    Aw, yw = A * sw[:, None], y * sw
    scale = np.linalg.norm(Aw, axis=0)
    scale[scale == 0] = 1.0
    As = Aw / scale
    coef_s, *_ = np.linalg.lstsq(As, yw, rcond=None)
    res_w = yw - As @ coef_s
    bread = np.linalg.pinv(As.T @ As)
    meat = newey_west_meat(As * res_w[:, None], lag, groups)
    cov_s = bread @ meat @ bread
    coef = coef_s / scale
    cov = cov_s / np.outer(scale, scale)
    residual = y - A @ coef
    sv = np.linalg.svd(As, compute_uv=False)
    cond = float(sv[0] / sv[-1]) if sv[-1] > 0 else float("inf")
    return LstsqResult(coef=coef, cov=cov, residual=residual, rms=float(np.sqrt(np.mean(residual**2))), cond=cond)
