"""Savitzky-Golay filters, the first-order lag filter and a moving-mean high-pass, without ``scipy.signal``.

Why not ``scipy.signal``: its ``__init__`` imports ``scipy.stats``, the window functions, the LTI
systems and ``scipy.interpolate``: 1.2 s of the 2.4 s that ``import uavturb.commands.gap`` took
(``python -X importtime``, the 2-core development machine, scipy 1.17; 1.55 s without it and
``scipy.stats``), paid by every command that smooths a stream, ``uavturb gap`` first. uavturb uses three of its
functions; they are written here with what the commands load anyway (numpy, ``scipy.ndimage.convolve1d``,
``scipy.linalg.lstsq``).

- :func:`savgol_coeffs` and :func:`savgol_filter` compute what ``scipy.signal``'s functions of the
  same names compute, the same way (least-squares coefficients, a convolution, a polynomial fitted to
  the first and the last window for the edges: scipy's ``mode="interp"``, the only mode here), so
  their results are scipy's (bitwise on the windows the package uses; ``tests/test_numerics_filters.py``).
- :func:`first_order_lag` is ``scipy.signal.lfilter([1 - a], [1, -a], x, zi=a * y_before)`` by
  recursive doubling: ``y[s:] += a^s y[:-s]`` for ``s = 1, 2, 4, ...``, at most ``log2(N)`` whole-array
  passes, fewer where ``a^s`` underflows to 0 first. Only powers ``a^s <= 1`` appear, so it is stable
  for ``0 <= a <= 1`` at any length; it agrees with ``lfilter`` to a few units in the last place (not
  bitwise: a different order of the same sums) and takes 1.5 to 3 times its time (15,000 x 4 rows:
  0.9 against 0.6 ms; 10^6 x 4: 0.09-0.12 against 0.04 s on the 2-core machine, quiet).
"""

from __future__ import annotations

import math

import numpy as np
from scipy.linalg import lstsq
from scipy.ndimage import convolve1d


def savgol_coeffs(window: int, polyorder: int, deriv: int = 0, delta: float = 1.0) -> np.ndarray:
    """Convolution coefficients of a Savitzky-Golay filter, evaluated at the window's centre.

    Parameters
    ----------
    window : odd number of samples, more than ``polyorder``
    polyorder : degree of the fitted polynomial
    deriv : order of the derivative (0: the smoothed value)
    delta : sample spacing (units of the axis, e.g. s); used for ``deriv > 0``

    Returns
    -------
    (window,) coefficients in convolution order (``scipy.signal.savgol_coeffs(window, polyorder,
    deriv, delta)``): a derivative comes out in units of the data per unit of ``delta`` to the ``deriv``.
    """
    _check_window(window, polyorder)
    if deriv > polyorder:
        return np.zeros(window)
    half = window // 2
    x = np.arange(-half, window - half, dtype=np.float64)[::-1]  # reversed: convolution order
    A = x ** np.arange(polyorder + 1, dtype=np.float64).reshape(-1, 1)  # (polyorder + 1, window)
    y = np.zeros(polyorder + 1)
    y[deriv] = math.factorial(deriv) / delta**deriv
    coeffs, *_ = lstsq(A, y, cond=np.finfo(np.float64).eps * max(A.shape))
    return coeffs


def savgol_filter(x: np.ndarray, window: int, polyorder: int, deriv: int = 0, delta: float = 1.0,
                  axis: int = -1) -> np.ndarray:
    """Savitzky-Golay smoothing or derivative of ``x`` along ``axis`` (scipy's ``mode="interp"``).

    Each output sample is the value (or ``deriv``-th derivative) at that sample of the polynomial of
    degree ``polyorder`` fitted by least squares to the ``window`` samples centred on it; the first
    and last ``window // 2`` samples take the polynomial fitted to the first / last ``window`` samples.

    Parameters
    ----------
    x : (..., N, ...) data, N samples along ``axis`` (``N >= window``); integers are read as float64
    window : odd number of samples, more than ``polyorder``
    polyorder : degree of the fitted polynomial
    deriv : order of the derivative (0: smoothed values)
    delta : sample spacing (e.g. s); a derivative is in units of ``x`` per unit of ``delta`` to the ``deriv``
    axis : axis of the samples

    Returns
    -------
    Same shape as ``x`` (float32 stays float32, anything else becomes float64).
    """
    x = np.asarray(x)
    if x.dtype not in (np.float64, np.float32):
        x = x.astype(np.float64)
    if window > x.shape[axis]:
        raise ValueError(f"savgol_filter: window {window} is longer than the data ({x.shape[axis]} samples)")
    y = convolve1d(x, savgol_coeffs(window, polyorder, deriv, delta), axis=axis, mode="constant")
    n, half = x.shape[axis], window // 2
    _fit_edge(x, y, axis, 0, (0, half), polyorder, deriv, delta)
    _fit_edge(x, y, axis, n - window, (n - half, n), polyorder, deriv, delta)
    return y


def _check_window(window: int, polyorder: int) -> None:
    if window % 2 != 1 or window <= polyorder:
        raise ValueError(f"Savitzky-Golay window must be odd and longer than the degree {polyorder}, got {window}")


def _fit_edge(x: np.ndarray, y: np.ndarray, axis: int, start: int, rows: tuple[int, int], polyorder: int,
              deriv: int, delta: float) -> None:
    """Write into ``y[rows]`` (along ``axis``) the polynomial fitted to ``x[start:start + window]``
    (``window = 2 * (rows[1] - rows[0]) + 1``), as scipy's ``_fit_edge`` does (same scaling, same solver)."""
    window = 2 * (rows[1] - rows[0]) + 1
    xs = np.moveaxis(x, axis, 0)[start:start + window]
    ys = np.moveaxis(y, axis, 0)  # a view: writing into it writes into y
    s = np.arange(window, dtype=x.dtype)
    lhs = s[:, None] ** np.arange(polyorder, -1, -1, dtype=x.dtype)[None, :]  # highest power first
    scale = np.sqrt(np.sum(lhs * lhs, axis=0))
    lhs /= scale
    c, *_ = lstsq(lhs, xs.reshape(window, -1), cond=window * np.finfo(x.dtype).eps)
    c = (c.T / scale).T  # (polyorder + 1, columns)
    for k in range(deriv):  # differentiate: drop the constant, multiply by the powers
        c = c[:-1] * np.arange(len(c) - 1, 0, -1, dtype=c.dtype)[:, None] if len(c) > 1 else np.zeros_like(c[:1])
    at = np.arange(rows[0] - start, rows[1] - start, dtype=c.dtype).reshape(-1, 1)
    values = np.zeros_like(at)
    for coeff in c:  # Horner
        values = values * at + coeff
    ys[rows[0]:rows[1]] = (values / delta**deriv).reshape((rows[1] - rows[0], *ys.shape[1:]))


#: a^s under which the recursive doubling of :func:`first_order_lag` stops (its terms are then below float64's
#: resolution, 2.2e-16, of the largest output)
_NEGLIGIBLE = 1e-17


def first_order_lag(x: np.ndarray, a: float, y_before: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
    """``y[n] = a y[n-1] + (1 - a) x[n]`` along axis 0, started from ``y[-1] = y_before``.

    The discrete first-order lag (exponential smoothing): ``a = exp(-dt / tau)`` for a lag of time
    constant ``tau`` sampled every ``dt``. Equal to ``scipy.signal.lfilter([1 - a], [1, -a], x, axis=0,
    zi=a * y_before[None])[0]`` to rounding.

    Parameters
    ----------
    x : (N, ...) input samples (units of the output)
    a : pole, ``0 <= a <= 1``
    y_before : (...) the output before the first sample
    out : (N, ...) float64, where to write the output (a slice of a larger array saves a copy; not ``x``'s memory)

    Returns
    -------
    (N, ...) float64 output (``out`` where given).
    """
    if not 0.0 <= a <= 1.0:
        raise ValueError(f"first_order_lag: the pole a = {a} is not in [0, 1]")
    x = np.asarray(x, dtype=np.float64)
    if len(x) == 0:
        return x.copy() if out is None else out
    before = np.asarray(y_before, dtype=np.float64)
    # in deviations from the start (which makes the start 0): smaller numbers, and an input that
    # stays at the start gives exactly the start
    y = np.subtract(x, before, out=out)
    y *= 1.0 - a
    s, power = 1, a  # power = a^s
    # after the pass for s, y[n] holds sum_{k = 0 .. 2s-1} a^k u[n - k]; once a^s is under _NEGLIGIBLE, what
    # the next passes would add is below float64's resolution of the largest |y| (a = 0.9: 9 passes, not 13)
    while s < len(y) and power >= _NEGLIGIBLE:
        y[s:] += power * y[:-s]
        s, power = 2 * s, power * power
    y += before
    return y


def moving_mean_bounds(t: np.ndarray, window_s: float) -> tuple[np.ndarray, np.ndarray]:
    """(N,) each row's first and (N,) one past its last row within ``window_s / 2`` [s] of it (``t``: (N,) s,
    increasing): the rows :func:`high_passed` averages, which depend on the times only (a search that high-passes
    many signals on one set of times computes them once)."""
    t = np.asarray(t, float)
    return np.searchsorted(t, t - window_s / 2), np.searchsorted(t, t + window_s / 2, side="right")


def high_passed(t: np.ndarray, x: np.ndarray, window_s: float,
                bounds: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray:
    """``x`` less its centred moving mean over ``window_s`` [s]: what changes faster than the window.

    Parameters
    ----------
    t : (N,) s, increasing row times (any spacing)
    x : (N,) or (N, C) values at ``t``
    window_s : s, the moving mean's width (rows within ``window_s / 2`` of each row, the row included)
    bounds : :func:`moving_mean_bounds` of ``t`` and ``window_s`` where already computed

    Returns
    -------
    array shaped like ``x``.
    """
    x = np.asarray(x, float)
    c = np.concatenate([np.zeros((1,) + x.shape[1:]), np.cumsum(x, axis=0)])
    lo, hi = moving_mean_bounds(t, window_s) if bounds is None else bounds
    n = np.maximum(hi - lo, 1).reshape((-1,) + (1,) * (x.ndim - 1))
    return x - (c[hi] - c[lo]) / n
