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
