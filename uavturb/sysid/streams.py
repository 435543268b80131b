"""What a logged stream really holds: its updates, their rate, their delay, and its noise.

Loggers write rows at one rate but often repeat the last value until a new one arrives
(sample-and-hold): positions updated at 9 Hz in rows at 50-90 Hz, rotor telemetry updated
at 3 Hz and 40-80 ms late (``recordings.md``, "Streams that may be missing"). Repeats are
bit-identical, so an update is a row whose value differs from the previous row's. What a
stream can tell is set by its updates, not its rows: differences of held rows are mostly
zero (a noise level from them is far too small), a staircase is late by half its step, and an
effect faster than the updates cannot be seen. A stream can also stop for a while (a logger's or a
radio's dropout, motion capture losing the markers): its rows then leave a gap (:func:`dropouts`).

Times are seconds (``t``) or integer nanoseconds (``t_ns``) as named; values keep their units.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from uavturb.errors import InputError
from uavturb.numerics.stream_updates import column_update_masks, staggered, update_mask

MAD_TO_SIGMA = 1.4826  # sigma of a normal distribution per median absolute deviation


def updates_only(t_ns: np.ndarray, values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The update rows of a stream: the first row of each run of repeats.

    Parameters
    ----------
    t_ns : (N,) timestamps (any unit; returned as given)
    values : (N,) or (N, C)

    Returns
    -------
    t_u : (U,) timestamps of the updates
    values_u : (U,) or (U, C) the updated values
    """
    m = update_mask(values)
    return np.asarray(t_ns)[m], np.asarray(values)[m]


def _update_rate(t: np.ndarray, m: np.ndarray) -> tuple[float, float]:
    """(Hz, 1 / mean step between the update rows ``m`` of times ``t`` [s], steps over three times the
    median left out (dropouts); s, the longest step)."""
    gaps = np.diff(t[m])
    usual = gaps[gaps <= 3.0 * np.median(gaps)] if len(gaps) else gaps  # dropouts left out
    return (1.0 / float(np.mean(usual)) if len(usual) else float("nan"),
            float(gaps.max()) if len(gaps) else 0.0)


@dataclass
class StreamUpdates:
    """How often a stream's value really changes.

    Attributes
    ----------
    name : str, the stream (e.g. ``rotors0``)
    rows : int, rows written
    updates : int, rows whose value changed (the first row counts)
    row_rate_hz : Hz, 1 / median row step
    update_rate_hz : Hz, 1 / mean step between updates, steps over three times the median (dropouts)
        left out; ``nan`` with fewer than two updates. (A mean: update steps quantised to rows,
        0.32 and 0.34 s for 3 Hz in 50 Hz rows, would bias a median.)
    held_share : share of rows that repeat the previous row (0: every row is new)
    max_gap_s : s, the longest time between consecutive updates (0 with fewer than two)
    staggered : the columns update on their own (:func:`staggered`); ``update_rate_hz`` and ``max_gap_s`` are
        then the median column's, each value's own, and ``updates`` counts the rows where any column changed
    any_column_rate_hz : Hz, staggered streams: the rate of rows where any column changed (else equal to
        ``update_rate_hz``)
    rounded : the stream repeats because it is rounded (:func:`~uavturb.numerics.stream_updates.rounding_steps`):
        every row is a sample, ``update_rate_hz`` is its rows' rate, ``updates`` counts its changes of one step and
        ``max_gap_s`` its longest run (a steady hover), and it is read where it crossed a rounding boundary
    """

    name: str
    rows: int
    updates: int
    row_rate_hz: float
    update_rate_hz: float
    held_share: float
    max_gap_s: float
    staggered: bool = False
    any_column_rate_hz: float = float("nan")
    rounded: bool = False

    def describe(self) -> str:
        """One line for reports, e.g. ``rotors0: 1200 rows at 50 Hz hold 36 updates at 3.0 Hz (97 % repeats)``."""
        if self.rounded:
            return (f"{self.name}: {self.rows} rows at {self.row_rate_hz:.0f} Hz, rounded: {self.updates} changes of "
                    f"one step of its resolution ({100 * self.held_share:.0f} % of its rows repeat at it, longest run "
                    f"{self.max_gap_s:.2f} s); every row a sample, read where it crossed a rounding boundary")
        if self.staggered:
            return (f"{self.name}: {self.rows} rows at {self.row_rate_hz:.0f} Hz, each column updating on its own at "
                    f"{self.update_rate_hz:.1f} Hz, staggered ({self.updates} rows with a new value in some column, "
                    f"{self.any_column_rate_hz:.1f} Hz; longest gap of a column {self.max_gap_s:.2f} s)")
        return (f"{self.name}: {self.rows} rows at {self.row_rate_hz:.0f} Hz hold {self.updates} updates at "
                f"{self.update_rate_hz:.1f} Hz ({100 * self.held_share:.0f} % repeats, longest gap "
                f"{self.max_gap_s:.2f} s)")


def stream_updates(name: str, t_ns: np.ndarray, values: np.ndarray, rounded: bool = False) -> StreamUpdates:
    """Count a stream's updates and measure their rate.

    Parameters
    ----------
    name : str, the stream's name (for messages)
    t_ns : (N,) int ns, increasing
    values : (N,) or (N, C), the stream's values (raw, as logged: repeats must be bit-identical)
    rounded : its repeats are its resolution's (rotor speeds, :func:`uavturb.sysid.flight_data.rotor_repeats`):
        every row is a sample, and it updates at its rows' rate (a 50 g quadrotor's speeds rounded to 1 rad/s,
        changing every 7 rows on median at 200 Hz, had been called too slow for a motor lag at 25 Hz)

    Raises
    ------
    InputError : no rows, or ``t_ns`` and ``values`` differ in length
    """
    t_ns = np.asarray(t_ns)
    if len(t_ns) == 0 or len(t_ns) != len(values):
        raise InputError(name, f"{len(t_ns)} timestamps for {len(values)} rows of values (need as many, at least one)")
    m = update_mask(values)
    t = (t_ns - t_ns[0]) * 1e-9
    row_rate = 1.0 / float(np.median(np.diff(t))) if len(t) > 1 else float("nan")
    rate, max_gap = _update_rate(t, m)
    out = StreamUpdates(name=name, rows=len(t), updates=int(m.sum()), row_rate_hz=row_rate, update_rate_hz=rate,
                        held_share=1.0 - m.sum() / len(t), max_gap_s=max_gap, any_column_rate_hz=rate)
    if staggered(values):
        own = column_update_masks(values)
        own[:, 0] &= own.sum(axis=1) <= 2  # a column's first row is the log's start, not one of its updates
        per_column = np.array([_update_rate(t, mc) for mc in own])
        c = int(np.argsort(per_column[:, 0])[len(per_column) // 2])  # the median column
        out.staggered, out.update_rate_hz, out.max_gap_s = True, float(per_column[c, 0]), float(per_column[c, 1])
    elif rounded:
        out.rounded, out.update_rate_hz = True, row_rate
    return out


#: a stream with no row for longer than this many of its median steps, and at least
#: :data:`MIN_DROPOUT_S`, has a dropout (jittered loggers space a few rows by two or three steps)
DROPOUT_STEPS = 5
#: s, shortest dropout (a 200 Hz stream missing a few rows is jitter, not a dropout)
MIN_DROPOUT_S = 0.05


def dropouts(t_ns: np.ndarray) -> list[tuple[int, int]]:
    """``(last row before, first row after)`` [ns] of each stretch longer than :data:`DROPOUT_STEPS`
    median steps (and :data:`MIN_DROPOUT_S`) with no row in a stream's increasing timestamps ``t_ns``."""
    if len(t_ns) < 3:
        return []
    d = np.diff(t_ns)
    limit = max(DROPOUT_STEPS * float(np.median(d)), MIN_DROPOUT_S * 1e9)
    i = np.flatnonzero(d > limit)
    return [(int(t_ns[k]), int(t_ns[k + 1])) for k in i]


def needed_rate_hz(timescale_s: float, samples: float = 2.0) -> float:
    """Update rate [Hz] that puts ``samples`` updates within ``timescale_s`` [s].

    E.g. a motor lag of 0.02 s needs 100 Hz; a ground effect over 0.1 m of height crossed at
    0.5 m/s (0.2 s) needs 10 Hz.
    """
    return samples / float(timescale_s)


def slow_for(stream: StreamUpdates, needed_hz: float, what: str | None = None) -> str | None:
    """A sentence when ``stream`` updates too slowly for what is asked, else ``None``.

    Parameters
    ----------
    stream : StreamUpdates
    needed_hz : Hz, the update rate the question needs (see :func:`needed_rate_hz`)
    what : str, what is asked (e.g. ``"a motor lag of 20 ms"``), for the sentence
    """
    rate = stream.update_rate_hz
    if np.isfinite(rate) and rate >= needed_hz:
        return None
    asked = what or "this"
    have = (f"updates at {rate:.1f} Hz" if np.isfinite(rate) else "never updates")
    return (f"{stream.name} {have} ({100 * stream.held_share:.0f} % of its rows repeat the last value): "
            f"too slow for {asked}, which needs updates at {needed_hz:.0f} Hz or faster")


@dataclass
class Lag:
    """A stream's delay against a reference, ``reference(t) ≈ offset + gain * signal(t + lag_s)``.

    Attributes
    ----------
    lag_s : s, >= 0: the signal's timestamps are late, its value recorded at ``t`` happened at
        ``t - lag_s`` (counted from the row where an update first appears)
    stderr_s : s, standard error of ``lag_s`` (moving-block bootstrap over the reference's rows)
    gain, offset : reference units per signal unit, reference units (least squares at ``lag_s``)
    r2 : share of the reference's variance the shifted signal explains at ``lag_s``
    resolvable : whether the data pin the lag down
    why : str, why not (``""`` where resolvable)
    updates : int, the signal's updates over the rows used
    """

    lag_s: float
    stderr_s: float
    gain: float
    offset: float
    r2: float
    resolvable: bool
    why: str
    updates: int

    def describe(self, name: str = "the signal") -> str:
        """One line for reports, e.g. ``rotor speeds late by 60 ± 3 ms (r2 0.94, 179 updates)``."""
        if not self.resolvable:
            return f"{name}: delay not resolvable: {self.why}"
        return (f"{name} late by {1e3 * self.lag_s:.0f} ± {1e3 * self.stderr_s:.0f} ms "
                f"(r2 {self.r2:.2f}, {self.updates} updates)")


def _line_sse(W: np.ndarray, X: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Weighted least-squares SSE of ``y ≈ a + b x`` for each row of ``X`` and each weight row.

    ``W`` (B, M) weights, ``X`` (L, M) candidate regressors, ``y`` (M,): returns (B, L).
    """
    n = W.sum(1)[:, None]
    sy, syy = W @ y, W @ (y * y)
    # (L, M) @ (M, B): the fast BLAS path (W @ X.T is many times slower with OpenBLAS here)
    sx, sxx, sxy = (X @ W.T).T, ((X * X) @ W.T).T, ((X * y) @ W.T).T
    vx = sxx - sx * sx / n
    cxy = sxy - sx * sy[:, None] / n
    vy = (syy - sy * sy / n.ravel())[:, None]
    return np.where(vx > 1e-12 * np.maximum(sxx, 1e-300), vy - cxy**2 / np.where(vx > 0, vx, 1.0), vy)


def _vertex(lags: np.ndarray, sse: np.ndarray) -> np.ndarray:
    """The minimum of each row of ``sse`` (B, L) over ``lags`` (L,), refined by a parabola."""
    j = np.argmin(sse, axis=1)
    out = lags[j].astype(float)
    inner = (j > 0) & (j < len(lags) - 1)
    b = np.flatnonzero(inner)
    s0, s1, s2 = sse[b, j[b] - 1], sse[b, j[b]], sse[b, j[b] + 1]
    curv = s0 - 2 * s1 + s2
    shift = np.where(curv > 0, 0.5 * (s0 - s2) / np.where(curv > 0, curv, 1.0), 0.0)
    out[b] += np.clip(shift, -0.5, 0.5) * (lags[1] - lags[0])
    return out


def _block_weights(m: int, block: int, n_boot: int, rng: np.random.Generator) -> np.ndarray:
    """Moving-block bootstrap counts (n_boot, m): blocks of ``block`` rows drawn with replacement."""
    block = int(min(max(block, 1), m))
    k = int(np.ceil(m / block))
    starts = rng.integers(0, m - block + 1, size=(n_boot, k))
    idx = (starts[:, :, None] + np.arange(block)).reshape(n_boot, -1)[:, :m]
    return np.stack([np.bincount(i, minlength=m) for i in idx]).astype(float)


def estimate_lag(t: np.ndarray, reference: np.ndarray, t_sig: np.ndarray, signal: np.ndarray, *,
                 max_lag_s: float = 0.2, step_s: float | None = None, min_r2: float = 0.3,
                 n_boot: int = 200, seed: int = 0) -> Lag:
    """The delay ``d >= 0`` that best explains ``reference(t) ≈ a + b signal(t + d)``.

    The signal is reduced to its updates (sample-and-hold repeats removed: a held staircase
    is late by half its step) and interpolated linearly at the shifted times; each lag of a grid
    from 0 to ``max_lag_s`` is fitted by least squares on the same reference rows, and the best
    refined by a parabola. Its error comes from a moving-block bootstrap (blocks of three
    update steps or 0.5 s, whichever is longer), as the residual of a slowly updated signal is
    far from white.

    Parameters
    ----------
    t : (M,) s, reference times, increasing
    reference : (M,) e.g. the thrust [N] motion capture or the IMU say was needed
    t_sig : (N,) s, the signal's row times, increasing (same clock as ``t``)
    signal : (N,) e.g. ``k_T sum(w^2)`` [N] from logged rotor speeds, as logged (repeats included)
    max_lag_s : s, the longest lag searched
    step_s : s, grid step; default the reference's median step, at most 5 ms (at least
        ``max_lag_s / 100``)
    min_r2 : least share of the reference's variance the signal must explain to time it
    n_boot, seed : bootstrap draws and their random seed

    Returns
    -------
    Lag, with ``resolvable`` False and ``why`` saying why where the data cannot time the signal.
    """
    t, y = np.asarray(t, float), np.asarray(reference, float)
    if len(t) != len(y) or len(t_sig) != len(signal) or len(t_sig) == 0:
        raise InputError("estimate_lag", f"{len(t)} reference times for {len(y)} values, {len(t_sig)} signal "
                         f"times for {len(signal)} values (need as many, at least one)")
    if n_boot < 2:
        raise InputError("estimate_lag", f"n_boot = {n_boot}: the bootstrap needs at least 2 draws")
    tu, su = updates_only(np.asarray(t_sig, float), np.asarray(signal, float))
    ok = np.isfinite(y) & (t >= tu[0]) & (t + max_lag_s <= tu[-1])
    t, y = t[ok], y[ok]
    n_upd = int(np.sum((tu >= t[0]) & (tu <= t[-1] + max_lag_s))) if len(t) else 0
    if len(t) < 10 or n_upd < 8:
        return Lag(np.nan, np.nan, np.nan, np.nan, 0.0, False,
                   f"only {len(t)} reference rows and {n_upd} signal updates overlap: too few to time the signal",
                   n_upd)
    dt = float(np.median(np.diff(t)))
    step = float(step_s) if step_s else max(min(dt, 0.005), max_lag_s / 100)
    lags = np.arange(0.0, max_lag_s + 0.5 * step, step)
    X = np.stack([np.interp(t + d, tu, su) for d in lags])  # (L, M)
    sse = _line_sse(np.ones((1, len(t))), X, y)[0]
    lag = float(_vertex(lags, sse[None])[0])
    x = np.interp(t + lag, tu, su)
    b, a = np.polyfit(x, y, 1) if np.ptp(x) > 0 else (0.0, float(np.mean(y)))
    r2 = 1.0 - float(np.sum((y - a - b * x) ** 2)) / max(float(np.sum((y - y.mean()) ** 2)), 1e-300)
    block = int(round(max(3.0 * float(np.median(np.diff(tu))), 0.5) / dt))
    rng = np.random.default_rng(seed)
    boot = np.concatenate([_vertex(lags, _line_sse(_block_weights(len(t), block, n, rng), X, y))
                           for n in np.diff(np.r_[0:n_boot:20, n_boot])])
    stderr = float(np.std(boot, ddof=1))
    why = _lag_why(lag, stderr, float(b), r2, lags, max_lag_s, min_r2)
    return Lag(lag, stderr, float(b), float(a), r2, why == "", why, n_upd)


def _lag_why(lag: float, stderr: float, gain: float, r2: float, lags: np.ndarray, max_lag_s: float,
             min_r2: float) -> str:
    """Why a fitted lag cannot be trusted (``""`` when it can)."""
    if r2 < min_r2:
        return (f"the signal explains only {100 * r2:.0f} % of the reference's variance at its best lag: it varies "
                f"too little, or too unlike the reference, to be timed")
    if gain <= 0:
        return f"the signal moves against the reference (gain {gain:.3g}): it cannot be the same quantity"
    if lag >= lags[-1] - 1e-12:
        return f"the best lag is the longest searched ({max_lag_s:.3f} s): the delay may be longer"
    if stderr > max_lag_s / 4:
        return (f"the lag is spread over the searched range (standard error {1e3 * stderr:.0f} ms of "
                f"{1e3 * max_lag_s:.0f} ms): the signal varies too little between its updates")
    return ""


def noise_from_updates(t: np.ndarray, r: np.ndarray, group: np.ndarray | None = None,
                       update: np.ndarray | None = None, *, min_step_s: float = 0.0) -> np.ndarray:
    """Per-axis white-noise level of a residual from differences between consecutive updates.

    First differences of all rows of a sample-and-held residual are mostly exact zeros, so their
    median absolute deviation says the noise is nil. Here differences are taken only between
    consecutive update rows of one recording (rows where the inputs changed), where two
    independent draws of the noise differ: ``sigma = 1.4826 MAD(diff) / sqrt(2)``. Differences
    over more than three times the median update step (gaps, dropped updates) are left out, so
    that slow changes of the residual do not pass for noise.

    A residual that went through a filter (derivatives smoothed over a window) is correlated
    over that window, and differences of its neighbouring rows are too small in the same way:
    ``min_step_s`` (the filter's window) thins the updates so that the differences span at least
    that long.

    The result is the noise of one update. A mean over ``n`` rows that hold ``n_u`` updates has a
    noise of ``sigma / sqrt(n_u)``, not ``sigma / sqrt(n)``.

    Parameters
    ----------
    t : (K,) s, row times (increasing within a recording)
    r : (K, C) residual, e.g. a force [N] (C = 3) or (K,)
    group : (K,) int recording index, or None for one recording
    update : (K,) bool, rows where the inputs changed; default: rows where ``r`` changed
        (:func:`update_mask`, per recording)
    min_step_s : s, the shortest time between the updates differenced (0: consecutive updates)

    Returns
    -------
    (C,) noise level, in ``r``'s units

    Raises
    ------
    InputError : fewer than two differences between updates
    """
    t = np.asarray(t, float)
    r = np.asarray(r, float)
    r2 = r[:, None] if r.ndim == 1 else r
    group = np.zeros(len(t), int) if group is None else np.asarray(group)
    diffs, steps = [], []
    for g in np.unique(group):
        rows = np.flatnonzero(group == g)
        upd = update_mask(r2[rows]) if update is None else np.asarray(update, bool)[rows]
        upd[0] = True
        u = rows[upd]
        u = u[_spaced(t[u], min_step_s)] if min_step_s > 0 else u
        diffs.append(np.diff(r2[u], axis=0))
        steps.append(np.diff(t[u]))
    d, dt = np.concatenate(diffs), np.concatenate(steps)
    if len(d):
        d = d[dt <= 3.0 * np.median(dt)]
    if len(d) < 2:
        raise InputError("residual", f"{len(d)} differences between updates: too few for a noise level")
    mad = np.median(np.abs(d - np.median(d, axis=0)), axis=0)
    sigma = MAD_TO_SIGMA * mad / np.sqrt(2.0)
    return sigma if r.ndim > 1 else sigma[:1]


def _spaced(t: np.ndarray, min_step_s: float) -> np.ndarray:
    """Indices into increasing ``t`` [s], from the first, each at least ``min_step_s`` after the last picked."""
    picks = [0]
    while True:
        j = int(np.searchsorted(t, t[picks[-1]] + min_step_s - 1e-12))
        if j >= len(t):
            return np.asarray(picks, int)
        picks.append(j)
