"""Time derivatives of sampled streams, at any rate and with jittered timestamps.

Real streams run at 50 Hz and up and their timestamps jitter (``recordings.md``). A
Savitzky-Golay filter assumes uniform sampling: on a jittered stream it differentiates as if
every sample were at its nominal time, an error of ``x_dot * jitter / dt``. Here every sample's
derivative is the slope of a quadratic fitted by least squares to the samples of a window
around it **at their true times** -- the Savitzky-Golay derivative when sampling is uniform
(``mode="interp"`` at the edges: the window is shifted inside and the fit evaluated at the
sample), and exact for quadratic signals whatever the sampling.

The window is given in seconds, so a derivative has the same bandwidth at every rate; it
holds at least :data:`MIN_WINDOW_SAMPLES` samples (a quadratic through 3 points does not smooth).
"""

from __future__ import annotations

import numpy as np

from uavturb.numerics.filters import savgol_coeffs, savgol_filter

#: fewest samples in a window (at 50 Hz a 0.05 s window would hold 3)
MIN_WINDOW_SAMPLES = 5


def window_samples(t: np.ndarray, window_s: float) -> int:
    """Odd number of samples of a ``window_s`` [s] window at the median step of ``t`` [s]
    (at least :data:`MIN_WINDOW_SAMPLES`, at most ``len(t)`` rounded down to odd)."""
    dt = float(np.median(np.diff(t))) if len(t) > 1 else 0.0
    n = max(MIN_WINDOW_SAMPLES, int(round(window_s / dt)) | 1) if dt > 0 else MIN_WINDOW_SAMPLES
    return min(n, len(t) if len(t) % 2 else len(t) - 1)


def local_quadratic(t: np.ndarray, x: np.ndarray, window: int, deriv: int = 1) -> np.ndarray:
    """Value (``deriv=0``) or first derivative (``deriv=1``) of a moving quadratic fit.

    Parameters
    ----------
    t : (N,) increasing times [s] (any spacing)
    x : (N,) or (N, D) samples
    window : odd number of samples per fit (>= 3)
    deriv : 0 (smoothed value) or 1 (derivative, units of ``x`` per second)

    Returns
    -------
    Same shape as ``x``.
    """
    t = np.asarray(t, dtype=np.float64)
    x = np.asarray(x, dtype=np.float64)
    flat = x.reshape(len(x), -1)
    N = len(t)
    if N < 3:
        return np.zeros_like(x) if deriv else x.copy()
    n = min(window, N if N % 2 else N - 1)
    if _uniform(t):
        # uniform sampling: the same fits by Savitzky-Golay's convolution (equal to 1e-10), ~50x faster
        return savgol_filter(x, n, 2, deriv=deriv, delta=float(np.median(np.diff(t))), axis=0)
    out = np.empty_like(flat)
    for a in range(0, N, CHUNK_ROWS):  # in chunks: the (rows, n, 3) fits of an hour at 200 Hz would take GBs
        rows = np.arange(a, min(a + CHUNK_ROWS, N))
        out[rows] = _fits(t, flat, rows, n, deriv)
    return out.reshape(x.shape)


#: relative spread of the time steps under which sampling counts as uniform (:func:`local_quadratic`)
UNIFORM_TOLERANCE = 1e-6


def _uniform(t: np.ndarray) -> bool:
    """Whether the times ``t`` [s] (N >= 2,) are evenly spaced within :data:`UNIFORM_TOLERANCE` of their median step."""
    step = np.diff(t)
    dt = float(np.median(step))
    return dt > 0 and float(np.max(np.abs(step - dt))) <= UNIFORM_TOLERANCE * dt


#: rows fitted at once by :func:`local_quadratic` (bounds its memory to ~100 MB whatever the length)
CHUNK_ROWS = 65536


def _fits(t: np.ndarray, flat: np.ndarray, rows: np.ndarray, n: int, deriv: int) -> np.ndarray:
    """(len(rows), D): :func:`local_quadratic` at ``rows`` with windows of ``n`` samples."""
    N = len(t)
    start = np.clip(rows - n // 2, 0, N - n)
    idx = start[:, None] + np.arange(n)[None, :]  # (R, n) the samples of each fit
    tau = t[idx] - t[rows, None]  # (R, n) s, times relative to the sample evaluated
    scale = np.maximum(np.abs(tau).max(axis=1, keepdims=True), 1e-12)
    u = tau / scale  # dimensionless, in [-1, 1]: a well-conditioned normal matrix
    powers = np.stack([np.ones_like(u), u, u * u], axis=2)  # (R, n, 3)
    A = np.einsum("kni,knj->kij", powers, powers)  # (R, 3, 3)
    b = np.einsum("kni,knd->kid", powers, flat[idx])  # (R, 3, D)
    try:
        coef = np.linalg.solve(A, b)  # (R, 3, D): x ~ c0 + c1 u + c2 u^2
    except np.linalg.LinAlgError:  # a window with under 3 distinct times (a timestamp centuries off): least norm
        coef = np.linalg.pinv(A) @ b
    return coef[:, 0, :] if deriv == 0 else coef[:, 1, :] / scale


def derivative(t: np.ndarray, x: np.ndarray, window_s: float) -> np.ndarray:
    """``dx/dt`` of samples ``x`` (N,) or (N, D) at times ``t`` [s], by :func:`local_quadratic`
    over ``window_s`` seconds (:func:`window_samples`)."""
    return local_quadratic(t, x, window_samples(np.asarray(t, float), window_s), deriv=1)


def derivative_matched(t: np.ndarray, x: np.ndarray, window: int) -> np.ndarray:
    """``x`` (N,) or (N, D) at times ``t`` [s] through the filter that :func:`local_quadratic`'s derivative puts on
    a rate: where ``dy/dt = x`` exactly, ``local_quadratic(t, y, window, deriv=1)`` equals this (the trapezoid rule
    aside). A regression of a derivative on its causes wants them filtered alike: against the value smoother
    (``deriv=0``), which lowers a swing less than the slope of a local fit does (by about ``1 - (w h)^2 / 10``), a
    rotor torque's slope came out low and the inertia 0.2-10 % high for windows of 0.02-0.2 s, without noise.

    The derivative's coefficients ``c_k`` (``k = -h .. h``) weigh the increments ``y_{i+m+1} - y_i+m`` by
    ``g_m = sum_{k > m} c_k`` (``m >= 0``; mirrored below), each increment ``dt (x_{i+m} + x_{i+m+1}) / 2``; the
    weights sum to 1. The kernel is built on the median step; rows within ``window // 2`` of an end keep their
    value smoothed (:func:`local_quadratic`, ``deriv=0``), as the fits there are one-sided.
    """
    t = np.asarray(t, dtype=np.float64)
    x = np.asarray(x, dtype=np.float64)
    N = len(t)
    if N < 3:
        return x.copy()
    n = min(window, N if N % 2 else N - 1)
    h = n // 2
    dt = float(np.median(np.diff(t)))
    c = savgol_coeffs(n, 2, deriv=1, delta=dt)[::-1]  # c[h + k] weighs y_{i+k}
    g = np.array([c[h + m + 1:].sum() if m >= 0 else -c[:h + m + 1].sum() for m in range(-h, h)])  # m = -h..h-1
    weights = np.zeros(n)  # on x_{i+j}, j = -h..h
    weights[:-1] += 0.5 * dt * g  # x_{i+m}
    weights[1:] += 0.5 * dt * g  # x_{i+m+1}
    flat = x.reshape(N, -1)
    out = np.empty_like(flat)  # n <= N, so at least one row lies inside
    out[h:N - h] = np.stack([np.convolve(flat[:, d], weights[::-1], mode="valid") for d in range(flat.shape[1])],
                            axis=1)
    if _uniform(t):  # the smoother's convolution is cheap on every row; its end rows as local_quadratic gives them
        ends = local_quadratic(t, flat, n, deriv=0)
        out[:h], out[N - h:] = ends[:h], ends[N - h:]
    else:  # the end rows' fits only (a fit on every row had taken 2/3 of the rotor timing's reading, jittered logs)
        out[:h] = _fits(t, flat, np.arange(h), n, 0)
        out[N - h:] = _fits(t, flat, np.arange(N - h, N), n, 0)
    return out.reshape(x.shape)
