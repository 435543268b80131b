"""Drawing the gap report's plots fast: only what a raster image can show, and without collector pauses.

A line over time drawn through many more rows than its axes have pixel columns costs Agg time
for nothing: within a narrow column only the extremes are visible (the line covers the column from
its lowest to its highest value). :func:`column_envelope` keeps those. :func:`scatter_rows` bounds
a scatter's points with a fixed stride (deterministic: the same report draws the same picture) and
keeps the extremes, so the axis limits stay those of every row. :func:`gc_paused` spares matplotlib's
many small objects Python's cyclic garbage collector while a figure is drawn. A figure with a cell per
recording wraps them at :data:`MAX_COLUMNS` to a row (:func:`recording_grid`), so a dozen recordings stay
readable on a screen.
"""

from __future__ import annotations

import functools
import gc

import numpy as np

#: most points a scatter of the gap report draws, its extremes aside (Agg: about 1 us a point; a 1100 x 400
#: px figure of two panels)
SCATTER_MAX_POINTS = 20_000
#: envelope columns per pixel column. One per pixel is enough for a line 1 px wide; a thinner one
#: (0.3 px) drawn through every row of a dense series covers each pixel column many times over and
#: reads darker than two strokes per pixel: at four per pixel the two pictures differ in under 2 % of
#: the inked pixels (tests/test_gap_plotting.py)
COLUMNS_PER_PIXEL = 4
#: recordings side by side in a figure with a cell per recording; more wrap to the rows below
MAX_COLUMNS = 4


def column_envelope(x: np.ndarray, y: np.ndarray, columns: int) -> np.ndarray:
    """Rows of a line to draw so that it looks as if every row were drawn: per pixel column, its extremes.

    The x range of the finite rows is cut into ``columns`` equal columns; in each column of each
    run of finite rows, the rows of the lowest and the highest ``y`` are kept (at most two per column),
    and each run's first and last rows, so the line starts and ends where it did and autoscaled axis
    limits stay the same. A row whose ``x`` or ``y`` is NaN or infinite breaks the line (as matplotlib
    draws it): the first row of each such gap is kept, so the line still breaks there. A series of at
    most ``2 * columns`` rows is returned whole.

    Parameters
    ----------
    x : ndarray, shape (n,)
        Abscissa, ascending within each run (time).
    y : ndarray, shape (n,)
        Values.
    columns : int
        Pixel columns the x range spans (at least 1).

    Returns
    -------
    ndarray of int, shape (m,)
        Indices of the rows to draw, ascending (time order kept), ``m <= n``.
    """
    x = np.asarray(x, dtype=float)
    y = np.asarray(y, dtype=float)
    if x.shape != y.shape or x.ndim != 1:
        raise ValueError(f"x and y must be 1-D of one length, got shapes {x.shape} and {y.shape}")
    if columns < 1:
        raise ValueError(f"columns must be at least 1, got {columns}")
    n = len(x)
    if n <= 2 * columns:
        return np.arange(n)
    ok = np.isfinite(x) & np.isfinite(y)
    rows = np.flatnonzero(ok)
    breaks = np.flatnonzero(~ok & np.concatenate(([True], ok[:-1])))  # first row of each gap
    if len(rows) == 0:
        return breaks
    run = np.cumsum(~ok)[rows]  # rows of one run share the count of gap rows before them
    lo, hi = x[rows].min(), x[rows].max()
    span = hi - lo if hi > lo else 1.0
    col = np.minimum(((x[rows] - lo) / span * columns).astype(np.int64), columns - 1)
    cell = run * columns + col  # one id per (run, column)
    order = np.lexsort((y[rows], cell))  # by cell, then by value
    first = np.flatnonzero(np.r_[True, cell[order][1:] != cell[order][:-1]])
    last = np.r_[first[1:] - 1, len(order) - 1]
    run_start = np.flatnonzero(np.r_[True, run[1:] != run[:-1]])
    run_end = np.r_[run_start[1:] - 1, len(rows) - 1]
    keep = np.concatenate((rows[order[first]], rows[order[last]], rows[run_start], rows[run_end], breaks))
    return np.unique(keep)


def stride_sample(n: int, max_points: int = SCATTER_MAX_POINTS) -> np.ndarray:
    """Every k-th of ``n`` rows, the smallest k that leaves at most ``max_points``.

    Parameters
    ----------
    n : int
        Rows.
    max_points : int
        Most rows to keep (at least 1).

    Returns
    -------
    ndarray of int, shape (m,)
        Ascending indices ``0, k, 2k, ...``, ``m <= max_points``; all of ``range(n)`` when ``n <= max_points``.
    """
    if max_points < 1:
        raise ValueError(f"max_points must be at least 1, got {max_points}")
    return np.arange(0, n, max(1, -(-n // max_points)))


def scatter_rows(x: np.ndarray, ys: tuple[np.ndarray, ...] | list[np.ndarray],
                 max_points: int = SCATTER_MAX_POINTS) -> np.ndarray:
    """Rows of a scatter to draw: :func:`stride_sample`, and the rows of the extremes of ``x`` and of each of ``ys``.

    The extremes keep the autoscaled axis limits those of every row (axes sharing ``y`` over the panels
    of ``ys``).

    Parameters
    ----------
    x : ndarray, shape (n,)
        Abscissa.
    ys : sequence of ndarray, each shape (n,)
        Ordinates of the panels drawn against ``x``.
    max_points : int
        Rows of the stride (the extremes come on top: at most ``max_points + 2 * (1 + len(ys))``).

    Returns
    -------
    ndarray of int, shape (m,)
        Ascending row indices, all of ``range(n)`` when ``n <= max_points``.
    """
    x = np.asarray(x, dtype=float)
    rows = [stride_sample(len(x), max_points)]
    if len(rows[0]) < len(x):
        for v in (x, *ys):
            v = np.asarray(v, dtype=float)
            if v.shape != x.shape:
                raise ValueError(f"each of ys must have the shape of x {x.shape}, got {v.shape}")
            finite = np.flatnonzero(np.isfinite(v))
            if len(finite):
                rows.append(finite[[np.argmin(v[finite]), np.argmax(v[finite])]])
    return np.unique(np.concatenate(rows))


def gc_paused(func):
    """Decorator: run ``func`` with Python's cyclic garbage collector paused, then restore its state.

    Drawing a figure makes tens of thousands of small linked objects (artists, transforms, ticks): the
    collector ran about 190 times over the four figures of a gap report, traversing the whole heap of
    the analysis each time it reached the oldest generation (10-15 % of the plot step's time). The
    figures' garbage is collected after the collector is resumed. A collector paused already (by the
    caller) stays paused.
    """

    @functools.wraps(func)
    def wrapper(*args, **kwargs):
        was_enabled = gc.isenabled()
        gc.disable()
        try:
            return func(*args, **kwargs)
        finally:
            if was_enabled:
                gc.enable()

    return wrapper


def recording_grid(n: int) -> tuple[int, int]:
    """``(columns, rows)`` of a figure with one cell per recording: at most :data:`MAX_COLUMNS` side by side,
    the rest wrapped below (a dozen recordings in one row made a figure 74 inches wide)."""
    cols = min(n, MAX_COLUMNS)
    return cols, -(-n // cols)


def hide_unused_cells(axes, n: int, cols: int, per_cell: int) -> None:
    """Switch off the axes of the grid's cells past the ``n``-th (each cell ``per_cell`` axes tall)."""
    for c in range(n, axes.shape[0] // per_cell * cols):
        for ax in axes[per_cell * (c // cols):per_cell * (c // cols + 1), c % cols]:
            ax.set_axis_off()
