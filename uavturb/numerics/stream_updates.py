"""A logged stream's update rows: where its value really changes.

Loggers write rows at one rate but often repeat the last value until a new one arrives (sample-and-hold,
``recordings.md``, "Streams that may be missing"); repeats are bit-identical, so an update is a row whose
value differs from the previous row's. Here, beneath the readers' checks (:mod:`uavturb.io.consistency`) and
the stream analysis built on it (:mod:`uavturb.sysid.streams`: rates, delays, noise); here too, whether a
stream's columns update one after another (round-robin telemetry) and a held stream read between its updates;
and whether a stream repeats because it is rounded, read then where it crossed its rounding boundaries.
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


#: a staggered stream (round-robin ESC telemetry reports one motor at a time): its median column changes on
#: fewer than ``STAGGER_SHARE`` of the rows where any column changes, at least ``STAGGER_ONE_SHARE`` of those rows
#: change one column only, and a column's updates come at regular intervals (median absolute deviation of its
#: intervals under ``STAGGER_REGULARITY`` of their median, in rows). Columns of a quantised stream also change
#: one at a time where the values barely move (a position at rest in millimetres), but at random intervals,
#: often flickering for a single row.
STAGGER_SHARE, STAGGER_ONE_SHARE, STAGGER_REGULARITY = 0.6, 0.8, 0.25


def column_update_masks(values: np.ndarray) -> np.ndarray:
    """(C, N) bool, each column's own update rows (:func:`update_mask` of that column alone) of a stream's
    rows ``values`` (N, C)."""
    x = np.asarray(values)
    x = x[:, None] if x.ndim == 1 else x
    return np.stack([update_mask(x[:, c]) for c in range(x.shape[1])])


def staggered(values: np.ndarray) -> bool:
    """Whether a multi-column stream ``values`` (N, C) updates its columns on their own, one after another
    (held rotor speeds reported one ESC at a time; the thresholds: :data:`STAGGER_SHARE`). A stream whose
    columns change together is not, nor a quantised one whose columns change at random, nor one column."""
    x = np.asarray(values)
    if x.ndim == 1 or x.shape[1] < 2 or len(x) < 3:
        return False
    own = column_update_masks(x)[:, 1:]
    changed = own.sum(axis=0)  # columns changing at each row
    union = int((changed > 0).sum())
    if union == 0 or not np.median(own.sum(axis=1)) < STAGGER_SHARE * union:
        return False
    if not (changed == 1).sum() >= STAGGER_ONE_SHARE * union:
        return False
    spread = []
    for rows in own:
        steps = np.diff(np.flatnonzero(rows))
        if len(steps) >= 3:
            med = float(np.median(steps))
            # a held column's value stays two rows or more (a quantised value flickering for one row does not)
            spread.append(float(np.median(np.abs(steps - med))) / med if med >= 2 else np.inf)
    return bool(spread) and float(np.median(spread)) <= STAGGER_REGULARITY


def read_between_updates(t: np.ndarray, values: np.ndarray) -> np.ndarray:
    """(N, C) a held stream read between its updates: each column's value at every row ``t`` (N,) interpolated
    linearly between that column's own update rows (:func:`update_mask` of the column), where a staircase read as
    held lags by half its step. For a staggered stream (round-robin ESC telemetry, :func:`staggered`) the rows
    where any column changes are nearly all rows, and reading them as updates kept each rotor's half step of lag
    (50 ms at 10 Hz): 40 ms late telemetry then read 90 ms late, over what commanded speeds may trail the force.

    Parameters
    ----------
    t : (N,) times (any unit, increasing)
    values : (N,) or (N, C) the stream's rows
    """
    x = np.asarray(values, float)
    x = x[:, None] if x.ndim == 1 else x
    out = np.empty_like(x)
    for c in range(x.shape[1]):
        m = update_mask(x[:, c])
        out[:, c] = np.interp(t, np.asarray(t)[m], x[m, c])
    return out


def rotor_quantum(speeds: np.ndarray) -> float:
    """Resolution [rad/s] of recorded rotor speeds ``(K, N)``: the step all values are whole
    multiples of, counted from the most frequent value (EuRoC's integer motor speeds times their scale; 1 rad/s for
    the project's synthetic flights; commands whose map to speed has an offset, ``w = a + b u`` rounded to 1 rad/s
    and written as ``u`` times a scale, sit on a lattice of steps that does not pass through zero), or 0 when they
    are not quantised. Zeros (rotors stopped before take-off, after landing) say nothing of the resolution and are
    left out: on an offset lattice they lie off it."""
    w = np.asarray(speeds, float).ravel()
    w = w[np.isfinite(w) & (w != 0)]
    u, counts = np.unique(w, return_counts=True)
    if len(u) < 3:
        return 0.0
    d = np.diff(u)
    d = d[d > 1e-9 * max(float(np.abs(u).max()), 1.0)]
    if not len(d):
        return 0.0
    q = float(np.min(d))
    steps = (w - u[int(np.argmax(counts))]) / q
    frac = np.abs(steps - np.round(steps))
    return q if np.mean(frac < 1e-3) > 0.99 else 0.0


def rounding_share(speeds: np.ndarray, quantum: float) -> float:
    """The relative error [-] of ``sum(w_i^2)`` that rotor speeds ``speeds`` (K, N) [rad/s] rounded to ``quantum``
    [rad/s] leave at their median row: ``w_i`` off by ``e_i`` uniform in ``+-quantum/2`` puts the sum off by
    ``2 sum(w_i e_i)``, one standard deviation ``quantum / sqrt(3) / sqrt(sum(w_i^2))`` of it. In a steady hover
    the rounding stays the same for seconds, so a thrust coefficient read on such speeds carries it whole: a
    probe's 1.2 kg quadrotor, its speeds rounded to 1 rad/s, read k_T 0.08 % high at 11 stated errors (this
    share: 0.06 %). 0 where the speeds are not quantised."""
    if not quantum > 0:
        return 0.0
    S = np.sum(np.asarray(speeds, float) ** 2, axis=1)
    S = S[np.isfinite(S) & (S > 0)]
    return float(quantum / np.sqrt(3.0) / np.sqrt(np.median(S))) if len(S) else 0.0


#: spread of a stream's runs between changes (median absolute deviation over the median, in rows) over which they
#: are a rounded value's (how long a speed takes to move a step varies with how fast it moves), not a logger's hold
#: (its period, or a multiple where an update repeats the value: measured rotor speeds held at 3 Hz in 50 Hz rows
#: read 17 rows, spread 0, even where a steady hover changed them one step at a time)
ROUNDED_RUN_SPREAD = 0.25


def rounding_steps(values: np.ndarray) -> bool:
    """Whether a stream ``values`` (N,) or (N, C) repeats because it is rounded, not because a logger holds it: its
    changes mostly move by one step of its resolution (the median change at most 1.5 times the smallest; rotor
    speeds rounded to 1 rad/s change by 1, a held stream by whatever the value moved between its updates), and
    its runs between changes are irregular (:data:`ROUNDED_RUN_SPREAD`)."""
    x = np.asarray(values, float)
    x = x[:, None] if x.ndim == 1 else x
    changes = np.flatnonzero(update_mask(x))
    if len(changes) < 4:
        return False
    steps = np.max(np.abs(np.diff(x[changes], axis=0)), axis=1)
    steps = steps[steps > 0]
    if len(steps) < 3 or not np.median(steps) <= 1.5 * np.min(steps):
        return False
    runs = np.diff(changes)
    middle = float(np.median(runs))
    return bool(np.median(np.abs(runs - middle)) > ROUNDED_RUN_SPREAD * middle)


#: a run of a rounded value lasting this many times the column's median run is a value that held (a steady hover)
ROUNDED_LONG_RUN = 3.0


def read_at_crossings(t_ns: np.ndarray, values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A rounded stream (:func:`rounding_steps`) read where its value crossed a rounding boundary.

    A value rounded to a resolution ``q`` and sampled every row changes from ``a`` to ``b`` in the row after the
    true value crossed ``(a + b) / 2``: that crossing, placed halfway between the two rows, is known exactly, and
    a line between crossings of a value moving one way follows it. Read on its changes instead, the stream runs
    half a step ahead of the value in the way it moves, a lead that reads as a lag of half the time between
    changes (a simulated 50 g quadrotor's speeds rounded to 1 rad/s named a motor lag of 11 ms that was not
    there). Read row by row, the rounding's error is the same size but random. Where the value is only known to
    lie within ``q/2`` of the rounded one (a run that the value enters and leaves by the same boundary, a run
    lasting over :data:`ROUNDED_LONG_RUN` times the column's median run, the first and last), the rounded value
    holds on the run's first and last rows. Each column is read on its own crossings.

    Parameters
    ----------
    t_ns : (N,) int64 ns, increasing
    values : (N,) or (N, C), the stream's rows

    Returns
    -------
    (M,) int64 ns and (M, C) float64: the points of every column, each column interpolated at the others' points.
    """
    t = np.asarray(t_ns, np.int64)
    x = np.asarray(values, float)
    x = x[:, None] if x.ndim == 1 else x
    if len(t) < 2:
        return t.copy(), x.copy()
    times = [_column_points(t, x[:, c]) for c in range(x.shape[1])]
    out_t = np.unique(np.concatenate([p[0] for p in times]))
    rel = (out_t - t[0]).astype(float)
    out = np.column_stack([np.interp(rel, (pt - t[0]).astype(float), pv) for pt, pv in times])
    return out_t, out


def _column_points(t: np.ndarray, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """One column's points for :func:`read_at_crossings`: its crossings, and the first and last rows of the runs
    whose value holds (times ``t`` (N,) int64 ns, values ``x`` (N,))."""
    k = np.flatnonzero(update_mask(x)[1:]) + 1  # rows whose value changed
    if not len(k):
        return t[[0, -1]], x[[0, -1]]
    crossing_t = t[k - 1] + (t[k] - t[k - 1]) // 2
    crossing_v = 0.5 * (x[k - 1] + x[k])
    first, last = np.r_[0, k], np.r_[k, len(x)] - 1  # each run's rows (the value of x[first])
    up = np.sign(x[k] - x[k - 1])
    turns = np.r_[True, up[1:] != up[:-1], True]  # entered and left by the same boundary (the ends: unknown)
    length = t[last] - t[first]
    inner = length[1:-1]
    long = length > ROUNDED_LONG_RUN * (np.median(inner) if len(inner) else np.inf)
    held = turns | long
    held[[0, -1]] = True
    pt = np.concatenate([crossing_t, t[first[held]], t[last[held]]])
    pv = np.concatenate([crossing_v, x[first[held]], x[last[held]]])
    order = np.argsort(pt, kind="stable")
    pt, pv = pt[order], pv[order]
    keep = np.r_[True, np.diff(pt) > 0]  # a one-row run held: its first and last row are one point
    return pt[keep], pv[keep]
