"""A logged stream's update rows: where its value really changes.

Loggers write rows at one rate but often repeat the last value until a new one arrives (sample-and-hold,
``recordings.md``, "Streams that may be missing"); repeats are bit-identical, so an update is a row whose
value differs from the previous row's. Here, beneath the readers' checks (:mod:`uavturb.io.consistency`) and
the stream analysis built on it (:mod:`uavturb.sysid.streams`: rates, delays, staggered columns, noise).
"""

from __future__ import annotations

import numpy as np


def update_mask(values: np.ndarray) -> np.ndarray:
    """Rows whose value differs from the previous row's (any column; exact equality).

    Parameters
    ----------
    values : (N,) or (N, C) array, a stream's rows in time order

    Returns
    -------
    (N,) bool, True where the row is an update; the first row is always one. NaN repeated
    after NaN counts as a repeat.
    """
    x = np.asarray(values)
    if x.ndim == 1:
        x = x[:, None]
    out = np.ones(len(x), bool)
    if len(x) > 1:
        a, b = x[1:], x[:-1]
        same = a == b
        if np.issubdtype(x.dtype, np.floating):
            same |= np.isnan(a) & np.isnan(b)
        out[1:] = ~np.all(same, axis=1)
    return out


def hold_period_s(t_ns: np.ndarray, values: np.ndarray) -> float:
    """s, how long a stream's columns hold a value: the median over columns of the median interval between a
    column's own updates (:func:`update_mask`); one row's period for a stream
    whose every row is fresh, a third of a second for ESC telemetry at 3 Hz; 0 with fewer than two updates."""
    x = np.asarray(values)
    x = x[:, None] if x.ndim == 1 else x
    t = (np.asarray(t_ns, np.int64) - int(t_ns[0])) * 1e-9
    periods = []
    for c in range(x.shape[1]):
        steps = np.diff(t[update_mask(x[:, c])])
        if len(steps):
            periods.append(float(np.median(steps)))
    return float(np.median(periods)) if periods else 0.0
