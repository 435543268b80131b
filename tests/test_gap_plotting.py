"""Thinning the gap report's plots (uavturb/gap/plotting.py): what is kept, and that the picture stays the same."""

from __future__ import annotations

import gc

import numpy as np
import pytest
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from uavturb.gap.plotting import COLUMNS_PER_PIXEL, column_envelope, gc_paused, scatter_rows, stride_sample
from uavturb.gap.plotting import grid_layout, hide_unused_cells, recording_grid, shade_spans  # the figures' layout


def test_envelope_keeps_each_columns_extremes_and_the_ends_in_time_order():
    # x 0..9 in 2 columns: rows 0-4 (x < 4.5) and rows 5-9
    y = np.array([3.0, 9.0, 1.0, 4.0, 5.0, 2.0, 8.0, 0.0, 6.0, 7.0])
    keep = column_envelope(np.arange(10.0), y, 2)
    # column 0: max row 1, min row 2; column 1: max row 6, min row 7; first and last rows 0 and 9
    assert keep.tolist() == [0, 1, 2, 6, 7, 9]


def test_envelope_at_most_two_per_column_besides_the_ends():
    rng = np.random.default_rng(3)
    n, columns = 20_000, 300
    x = np.sort(rng.uniform(0.0, 60.0, n))  # uneven sampling, s
    y = rng.normal(size=n)
    keep = column_envelope(x, y, columns)
    assert np.all(np.diff(keep) > 0)  # ascending: time order kept, no row twice
    col = np.minimum(((x - x.min()) / np.ptp(x) * columns).astype(int), columns - 1)
    inner = keep[(keep != 0) & (keep != n - 1)]
    assert np.bincount(col[inner], minlength=columns).max() <= 2
    assert len(keep) <= 2 * columns + 2
    for c in range(columns):  # every column's lowest and highest row is kept
        rows = np.flatnonzero(col == c)
        assert rows[np.argmin(y[rows])] in keep and rows[np.argmax(y[rows])] in keep
    assert {0, n - 1} <= set(keep.tolist())


def test_short_series_is_returned_whole():
    x = np.linspace(0.0, 1.0, 40)
    assert column_envelope(x, np.cos(x), 20).tolist() == list(range(40))
    assert column_envelope(x[:0], x[:0], 5).tolist() == []


def test_nan_rows_still_break_the_line():
    x = np.arange(12.0)
    y = np.array([1.0, 5.0, 2.0, 0.0, 3.0, np.nan, np.nan, 4.0, 9.0, 1.0, 2.0, 6.0])
    keep = column_envelope(x, y, 2)
    # run 0 (rows 0-4) all in column 0: min row 3, max row 1, ends 0 and 4; gap rows 5-6: row 5 kept;
    # run 1 (rows 7-11): column 1 (x >= 5.5): max row 8, min row 9, ends 7 and 11
    assert keep.tolist() == [0, 1, 3, 4, 5, 7, 8, 9, 11]
    assert np.isnan(y[keep]).sum() == 1
    # an infinite x breaks the line too; a series of only NaN keeps one NaN row
    x[2] = np.inf
    assert 2 in column_envelope(x, y, 2)
    assert column_envelope(np.arange(9.0), np.full(9, np.nan), 2).tolist() == [0]


def test_bad_arguments_are_refused():
    with pytest.raises(ValueError, match="shapes"):
        column_envelope(np.arange(5.0), np.arange(4.0), 2)
    with pytest.raises(ValueError, match="columns"):
        column_envelope(np.arange(5.0), np.arange(5.0), 0)
    with pytest.raises(ValueError, match="max_points"):
        stride_sample(5, 0)
    with pytest.raises(ValueError, match="shape of x"):
        scatter_rows(np.arange(10.0), (np.arange(9.0),), max_points=3)


def _line_pixels(x, y, width_px=600, lw=0.3):
    """Gray levels of a line drawn in an axes ``width_px`` pixels wide (no ticks, no frame), and its limits."""
    fig = Figure(figsize=(width_px / 100, 2), dpi=100)
    FigureCanvasAgg(fig)
    ax = fig.add_axes((0, 0, 1, 1))
    ax.plot(x, y, lw=lw, color="0.0")
    ax.set_axis_off()
    fig.canvas.draw()
    return np.asarray(fig.canvas.buffer_rgba())[..., 0].astype(int), ax.get_xlim(), ax.get_ylim()


@pytest.mark.parametrize("lw", [0.3, 1.0])  # the report's raw residual and its smoothed lines
def test_thinned_line_draws_the_same_picture(lw):
    rng = np.random.default_rng(7)
    t = np.linspace(0.0, 60.0, 12_000)  # 200 Hz for 60 s into 600 pixel columns
    y = np.cumsum(rng.normal(size=t.size)) * 0.01 + 0.05 * rng.normal(size=t.size)
    full, xlim, ylim = _line_pixels(t, y, lw=lw)
    keep = column_envelope(t, y, COLUMNS_PER_PIXEL * 600)
    assert len(keep) <= 2 * COLUMNS_PER_PIXEL * 600 + 2 and len(keep) < 0.45 * len(t)
    thin, xlim2, ylim2 = _line_pixels(t[keep], y[keep], lw=lw)
    assert (xlim2, ylim2) == (xlim, ylim)  # autoscaled limits unchanged
    inked, inked2 = full < 128, thin < 128  # the pixels a person sees as line
    assert (inked ^ inked2).sum() <= 0.02 * inked.sum()
    assert np.abs(full - thin).mean() < 0.5  # of 255 gray levels, over the whole picture


def test_stride_sample_bounds_points_deterministically():
    assert stride_sample(10, 3).tolist() == [0, 4, 8]
    assert stride_sample(10, 5).tolist() == [0, 2, 4, 6, 8]
    assert stride_sample(5, 10).tolist() == [0, 1, 2, 3, 4]
    for n in (1, 999, 20_000, 20_001, 123_457):
        idx = stride_sample(n)
        assert 0 < len(idx) <= 20_000 and idx[0] == 0 and len(np.unique(np.diff(idx))) <= 1  # one fixed stride
        assert len(idx) > 20_000 // 2 or n <= 20_000  # the smallest stride that fits: not needlessly sparse


def test_scatter_rows_keep_the_extremes_so_the_limits_stay():
    rng = np.random.default_rng(5)
    n = 50_001
    x = rng.uniform(0.0, 0.5, n)  # m
    before, after = rng.normal(0.0, 0.01, n), rng.normal(0.0, 0.005, n)  # N
    x[7], before[12_346], after[33_334], after[4] = 0.9, 0.2, -0.3, np.nan  # off the stride of 3
    rows = scatter_rows(x, (before, after))
    assert np.all(np.diff(rows) > 0) and len(rows) <= 20_000 + 6
    assert {7, 12_346, 33_334} <= set(rows.tolist()) and 4 not in rows  # the extremes, not the NaN
    assert set(stride_sample(n).tolist()) <= set(rows.tolist())
    limits = []
    for r in (np.arange(n), rows):
        fig = Figure(figsize=(11, 4), dpi=100)
        FigureCanvasAgg(fig)
        ax = fig.subplots(1, 2, sharey=True)
        ax[0].scatter(x[r], before[r], s=1)
        ax[1].scatter(x[r], after[r], s=1)
        limits.append((ax[0].get_xlim(), ax[1].get_xlim(), ax[0].get_ylim()))
    assert limits[0] == limits[1]
    short = np.arange(100.0)
    assert scatter_rows(short, (short,)).tolist() == list(range(100))


def test_gc_paused_restores_the_collectors_state_also_on_errors():
    @gc_paused
    def state(fail=False):
        if fail:
            raise RuntimeError("boom")
        return gc.isenabled()

    assert gc.isenabled()
    assert state() is False and gc.isenabled()
    with pytest.raises(RuntimeError, match="boom"):
        state(fail=True)
    assert gc.isenabled()
    gc.disable()
    try:
        assert state() is False
        assert not gc.isenabled()  # paused by the caller: left paused
    finally:
        gc.enable()


@pytest.mark.parametrize("n, grid", [(1, (1, 1)), (2, (2, 1)), (4, (4, 1)), (5, (4, 2)), (12, (4, 3))])
def test_per_recording_figures_wrap_at_four_columns(n, grid):
    # a dozen recordings side by side had made a residual figure 74 inches (7400 px) wide
    assert recording_grid(n) == grid


def test_cells_past_the_last_recording_are_switched_off():
    fig = Figure(figsize=(8, 6), dpi=100)
    axes = fig.subplots(3 * 2, 4, squeeze=False)  # five recordings, each three axes tall, four to a row
    hide_unused_cells(axes, 5, 4, 3)
    on = np.array([[ax.axison for ax in row] for row in axes])
    assert on[:3].all() and on[3:, 0].all() and not on[3:, 1:].any()


def _grid_figure(size=(13.0, 9.0), sharey=False):
    """A grid like the report's: titles, axis labels, wide and negative tick labels, an offset text ("1e-6"), a
    cell switched off and a figure title."""
    fig = Figure(figsize=size, dpi=100)
    FigureCanvasAgg(fig)
    axes = fig.subplots(3, 3, squeeze=False, sharey=sharey)
    t = np.linspace(0.0, 60.0, 200)
    scales = [1e-6, 2.5e4, -0.0125, 1.0, 3e-3, 120.0, -7.0, 0.5, 1e3]
    for k, (ax, scale) in enumerate(zip(axes.flat, scales)):
        ax.plot(t, scale * np.sin(t / 7.0) + (scale if k % 2 else 0.0))
        ax.set_title(f"recording {k}")
        ax.set_ylabel("|residual|, 0.25 s RMS [N]" if k % 3 == 0 else "F_z [N]")
        ax.set_xlabel("t [s]" if k % 2 else "")
    hide_unused_cells(axes, 8, 3, 1)
    return fig, axes, fig.suptitle("a figure title")


def _overlapping(fig, axes, title):
    """Pairs of visible axes whose drawn decorations overlap, and those reaching outside the figure or into the
    figure ``title``, as matplotlib itself measures them after a draw."""
    fig.canvas.draw()
    r = fig.canvas.get_renderer()
    boxes = [ax.get_tightbbox(r) for ax in axes.flat if ax.axison]
    title = title.get_window_extent(r)
    width, height = fig.canvas.get_width_height()
    bad = [i for i, b in enumerate(boxes) if b.x0 < 0 or b.y0 < 0 or b.x1 > width or b.y1 > height or b.overlaps(title)]
    bad += [(i, j) for i, a in enumerate(boxes) for j, b in enumerate(boxes[i + 1:], i + 1) if a.overlaps(b)]
    return bad


@pytest.mark.parametrize("sharey", [False, True])
def test_grid_layout_leaves_every_label_room_as_tight_layout_does(sharey):
    fig, axes, title = _grid_figure(sharey=sharey)
    grid_layout(fig, axes, title)
    ours = fig.subplotpars
    ours = np.array([ours.left, ours.right, ours.bottom, ours.top, ours.wspace, ours.hspace])
    assert _overlapping(fig, axes, title) == []
    fig.tight_layout()  # which keeps room for the figure title too
    tight = fig.subplotpars
    tight = np.array([tight.left, tight.right, tight.bottom, tight.top, tight.wspace, tight.hspace])
    # the same room within a tenth of an inch at the edges (of 13 x 9 in), and the gaps between axes within 30 %;
    # at the top, tight_layout's plus the figure title's place under the edge (2 % of the height), which
    # tight_layout leaves out (on a 21-inch figure the title had met the top row's titles)
    tight[3] -= 0.02
    assert np.all(np.abs(ours[:4] - tight[:4]) * np.array([13, 13, 9, 9]) < 0.1), (ours, tight)
    assert np.all(np.abs(ours[4:] - tight[4:]) <= 0.3 * tight[4:] + 0.02), (ours, tight)
    if sharey:  # inner columns show no y tick labels: narrower gaps between columns
        assert ours[4] < 0.5 * _unshared_wspace()


def _unshared_wspace():
    """The gap between columns that :func:`grid_layout` gives the grid when every column shows its y labels."""
    fig, axes, title = _grid_figure()
    grid_layout(fig, axes, title)
    return fig.subplotpars.wspace


def test_grid_layout_gives_way_to_tight_layout_where_labels_leave_no_room():
    fig, axes, title = _grid_figure(size=(2.0, 1.5))  # 27 labelled axes' worth of text in 2 x 1.5 inches
    with pytest.warns(UserWarning, match="[Tt]ight layout"):  # no negative sizes, no error: tight_layout's try
        grid_layout(fig, axes, title)
    ours = fig.subplotpars
    ours = (ours.left, ours.right, ours.bottom, ours.top, ours.wspace, ours.hspace)
    with pytest.warns(UserWarning):  # what tight_layout says of such a figure
        fig.tight_layout()
    tight = fig.subplotpars
    assert ours == (tight.left, tight.right, tight.bottom, tight.top, tight.wspace, tight.hspace)


def _shaded_pixels(shade):
    fig = Figure(figsize=(6, 2), dpi=100)
    FigureCanvasAgg(fig)
    ax = fig.add_axes((0, 0, 1, 1))
    ax.plot([0.0, 60.0], [-1.0, 1.0], color="k", lw=0.5)
    shade(ax, [(3.2, 7.9), (10.0, 10.4), (41.55, 59.0)])
    ax.set_axis_off()
    fig.canvas.draw()
    return np.asarray(fig.canvas.buffer_rgba())[..., :3].astype(int), ax.get_xlim(), ax.get_ylim()


def test_shaded_spans_draw_what_axvspan_draws():
    def one_patch_each(ax, spans):
        for a, b in spans:
            ax.axvspan(a, b, color="tab:red", alpha=0.15, lw=0)

    patches, xlim, ylim = _shaded_pixels(one_patch_each)
    collection, xlim2, ylim2 = _shaded_pixels(lambda ax, spans: shade_spans(ax, spans, color="tab:red", alpha=0.15,
                                                                             lw=0))
    assert (xlim2, ylim2) == (xlim, ylim)
    shaded = (patches != 255).any(axis=2)
    assert shaded.sum() > 0.3 * shaded.size  # the spans cover 37 % of the width
    assert np.abs(patches - collection).max() <= 1  # the same colours, at most a rounding apart
    empty, _, _ = _shaded_pixels(lambda ax, spans: shade_spans(ax, [], color="tab:red"))
    assert (empty != 255).any(axis=2).sum() < 0.05 * shaded.sum()  # nothing shaded: the line alone
