"""Drawing the gap report's plots fast: only what a raster image can show, and without collector pauses.

A line over time drawn through many more rows than its axes have pixel columns costs Agg time
for nothing: within a narrow column only the extremes are visible (the line covers the column from
its lowest to its highest value). :func:`column_envelope` keeps those. :func:`scatter_rows` bounds
a scatter's points with a fixed stride (deterministic: the same report draws the same picture) and
keeps the extremes, so the axis limits stay those of every row. :func:`gc_paused` spares matplotlib's
many small objects Python's cyclic garbage collector while a figure is drawn. A figure with a cell per
recording wraps them at :data:`MAX_COLUMNS` to a row (:func:`recording_grid`), so a dozen recordings stay
readable on a screen; :func:`grid_layout` leaves its axes' labels room as ``tight_layout`` does, measuring the
label texts alone (``tight_layout`` lays every tick out to measure it: half of a dozen recordings' figure time).
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


#: room [inch] kept between two axes' decorations and around the grid: ``tight_layout``'s default pad, 1.08 font
#: sizes of 10 points
LAYOUT_PAD_IN = 1.08 * 10 / 72


def grid_layout(fig, axes: np.ndarray, title=None) -> None:
    """Subplot parameters for the grid ``axes`` (rows, columns) of ``fig`` so that no axis's tick labels, axis
    labels, title or offset text overlap another's, the figure's ``title`` (the text ``fig.suptitle`` returned) or
    the figure's edge: ``tight_layout``'s result, measured from the label texts alone.

    ``tight_layout`` lays every tick of every axis out to measure it, and the figure's draw does it again: a
    dozen recordings' residual figure (36 axes) took 2.50 s with it and 2.16 s with this. Here each axis's tick
    labels are formatted (its locator and formatter, as the draw will) and only the texts are measured, at the figure's
    font sizes (``rcParams``: the report's figures keep matplotlib's defaults). Switched-off axes (cells past the
    last recording) take no room; where the decorations would leave the axes none, ``tight_layout`` decides.
    """
    renderer = fig.canvas.get_renderer()
    rows, cols = axes.shape
    reach = np.zeros((rows, cols, 4))  # inches each axis's decorations reach beyond it: left, right, bottom, top
    for (i, j), ax in np.ndenumerate(axes):
        if ax.axison:
            reach[i, j] = _decorations_reach(ax, renderer)
    width, height = fig.get_size_inches()
    pad = LAYOUT_PAD_IN
    top_in = 0.0  # what the figure's title takes from the top: its place under the edge, its height and a pad
    if title is not None and title.get_text():
        top_in = (1.0 - title.get_position()[1]) * height + title.get_window_extent(renderer).height / fig.dpi + pad
    left, right = reach[:, 0, 0].max() + pad, reach[:, -1, 1].max() + pad
    bottom, top = reach[-1, :, 2].max() + pad, reach[0, :, 3].max() + pad + top_in
    gap_w = max([(reach[:, j, 1] + reach[:, j + 1, 0]).max() + pad for j in range(cols - 1)], default=0.0)
    gap_h = max([(reach[i, :, 2] + reach[i + 1, :, 3]).max() + pad for i in range(rows - 1)], default=0.0)
    axis_w = (width - left - right - (cols - 1) * gap_w) / cols
    axis_h = (height - bottom - top - (rows - 1) * gap_h) / rows
    if axis_w <= 0 or axis_h <= 0:
        fig.tight_layout()  # its best effort, with its warning
        return
    fig.subplots_adjust(left=left / width, right=1 - right / width, bottom=bottom / height, top=1 - top / height,
                        wspace=gap_w / axis_w, hspace=gap_h / axis_h)


def _decorations_reach(ax, renderer) -> tuple[float, float, float, float]:
    """How far [inch] ``ax``'s tick labels, ticks, axis labels, title and offset texts reach beyond its left,
    right, bottom and top edges (:func:`grid_layout`)."""
    # matplotlib only where a figure is drawn (the gap command imports it for its plots alone)
    from matplotlib import rcParams
    from matplotlib.font_manager import FontProperties

    dpi = ax.figure.dpi

    def size(text: str, prop) -> tuple[float, float]:
        """(width, height) [inch] of one line of ``text``, at least a line's height ("lp", as matplotlib lays
        out a text)."""
        if not text:
            return 0.0, 0.0
        w, h, _ = renderer.get_text_width_height_descent(text, prop, ismath=False)
        line = renderer.get_text_width_height_descent("lp", prop, ismath=False)[1]
        return w / dpi, max(h, line) / dpi

    reach = []
    for axis, name in ((ax.yaxis, "y"), (ax.xaxis, "x")):
        shown = axis.get_tick_params(which="major").get("labelleft" if name == "y" else "labelbottom", True)
        labels, offset = _tick_labels(axis) if shown else ([], "")
        prop = FontProperties(size=rcParams[f"{name}tick.labelsize"])
        sizes = [size(s, prop) for s in labels] or [(0.0, 0.0)]
        ticks = (rcParams[f"{name}tick.major.pad"]
                 + (rcParams[f"{name}tick.major.size"] if rcParams[f"{name}tick.direction"] != "in" else 0.0)) / 72
        label = size(axis.label.get_text(), axis.label.get_fontproperties())[1]
        label = label + axis.labelpad / 72 if label else 0.0
        reach.append((max(w for w, _ in sizes), max(h for _, h in sizes), ticks, label,
                      size(offset, prop)[1] if shown and offset else 0.0))
    (y_w, y_h, y_ticks, y_label, y_offset), (x_w, x_h, x_ticks, x_label, x_offset) = reach
    title = size(ax.title.get_text(), ax.title.get_fontproperties())[1]
    title = title + rcParams["axes.titlepad"] / 72 if title else 0.0
    left = (y_w + y_ticks if y_w else 0.0) + y_label
    right = x_w / 2  # the last x tick label, centred on the axis's right end
    bottom = max((x_h + x_ticks if x_h else 0.0) + x_offset + x_label, y_h / 2)
    top = max(title, y_offset + y_ticks / 2, y_h / 2)
    return left, right, bottom, top


def _tick_labels(axis) -> tuple[list[str], str]:
    """The major tick labels ``axis`` will draw (its locator's ticks within the view, its formatter's texts) and
    its offset text ("1e-5", "+1.5": empty where none)."""
    lo, hi = sorted(axis.get_view_interval())
    slack = 1e-9 * (hi - lo)
    locs = [v for v in axis.get_major_locator()() if lo - slack <= v <= hi + slack]
    formatter = axis.get_major_formatter()
    return formatter.format_ticks(locs), formatter.get_offset()


def shade_spans(ax, spans: list[tuple[float, float]], **kwargs) -> None:
    """Shade the x intervals ``spans`` (data units) over the axes' full height: what ``ax.axvspan`` draws for
    each, as one collection (``kwargs``: its colour, alpha...). A patch per span cost 1 ms each to add and
    draw: a dozen recordings' residual figure shades about 450. The spans do not move the autoscaled limits (the
    shaded stretches lie inside the lines drawn)."""
    from matplotlib.collections import PolyCollection  # matplotlib only where a figure is drawn

    if spans:
        boxes = [[(a, 0.0), (b, 0.0), (b, 1.0), (a, 1.0)] for a, b in spans]
        ax.add_collection(PolyCollection(boxes, transform=ax.get_xaxis_transform(), **kwargs), autolim=False)
