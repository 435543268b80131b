"""Where the residual stands out of the noise, and what drives it.

Noise level: from the data, never assumed. Sensor noise is white at the sample rate while
unmodelled physics is slow, so the first differences of the residual carry the noise:
``sigma = 1.4826 MAD(diff r) / sqrt(2)`` per axis (robust to the slow part and to spikes).

Segments: the residual smoothed over ``window_s`` (noise then ``sigma / sqrt(n)``) beyond
``k`` times that level for at least ``min_s`` seconds, per axis; gaps shorter than ``min_s``
are merged.

Drivers: each candidate feature's share of the smoothed residual's variance explained by a
nonparametric fit (mean per quantile bin of the feature; captures ``1/d^2``-like laws as
well as linear ones), the best over the three axes.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.ndimage import uniform_filter1d

from uavturb.gap.design import GapData
from uavturb.numerics.filters import savgol_filter
from uavturb.sysid.streams import noise_from_updates

AXES = "xyz"
FAR = 10.0  # m, stands for "no surface" (inf) in feature binning


def noise_sigma(r: np.ndarray, group: np.ndarray | None = None) -> np.ndarray:
    """Per-axis white-noise level [N] of a residual ``(K, 3)`` from its first differences."""
    d = np.diff(r, axis=0)
    if group is not None:
        d = d[group[1:] == group[:-1]]
    mad = np.median(np.abs(d - np.median(d, axis=0)), axis=0)
    return 1.4826 * mad / np.sqrt(2.0)


def smooth(r: np.ndarray, n: int, group: np.ndarray) -> np.ndarray:
    """Moving average over ``n`` samples within each recording."""
    out = np.empty_like(r)
    for g in np.unique(group):
        m = group == g
        out[m] = uniform_filter1d(r[m], size=max(1, n), axis=0, mode="nearest")
    return out


@dataclass
class Segment:
    """A located segment: ``t_start``/``t_end`` [s] since the recording's first ground-truth row,
    ``rms_N`` [N] of the smoothed residual on ``axis`` (W); ``group`` indexes the recording."""

    recording: str
    t_start: float
    t_end: float
    axis: str
    rms_N: float
    group: int = 0


def window_rows(data: GapData, window_s: float, update_step_s: float = 0.0) -> tuple[int, int]:
    """(rows in a ``window_s`` [s] window, independent noise draws in it): the rows, or the updates of the
    slowest stream where it updates every ``update_step_s`` [s], more slowly than the rows come."""
    dt = float(np.median(np.diff(data.t)))
    n = max(3, int(round(window_s / dt)))
    return n, (n if update_step_s <= dt else max(1, int(round(window_s / update_step_s))))


def residual_noise(data: GapData, r: np.ndarray, update_step_s: float = 0.0) -> np.ndarray:
    """Per-axis noise [N] of one independent draw of the residual ``r`` (K, 3): from first differences
    (:func:`noise_sigma`), or, where a stream updates more slowly than the rows come (every
    ``update_step_s`` [s]), from differences between rows that far apart
    (:func:`uavturb.sysid.streams.noise_from_updates`): neighbouring rows then share an update and
    their differences say the noise is nil."""
    dt = float(np.median(np.diff(data.t)))
    if update_step_s <= dt:
        return noise_sigma(r, data.group)
    return noise_from_updates(data.t, r, data.group, update=np.ones(len(r), bool), min_step_s=update_step_s)


def segments(data: GapData, r: np.ndarray, *, window_s: float = 0.5, k: float = 5.0,
             min_s: float = 0.3, update_step_s: float = 0.0) -> tuple[list[Segment], np.ndarray, np.ndarray]:
    """Located segments, the smoothed residual ``(K, 3)`` and the per-axis noise ``sigma`` [N] of one
    independent draw (``update_step_s`` [s]: the slowest stream's update step, :func:`residual_noise`)."""
    n, draws = window_rows(data, window_s, update_step_s)
    sigma = residual_noise(data, r, update_step_s)
    rs = smooth(r, n, data.group)
    level = k * np.maximum(sigma, 1e-9) / np.sqrt(draws)
    out: list[Segment] = []
    for g in np.unique(data.group):
        m = np.flatnonzero(data.group == g)
        t = data.t[m]
        for j, ax in enumerate(AXES):
            over = np.abs(rs[m, j]) > level[j]
            # close gaps shorter than min_s, then keep runs longer than min_s
            runs = _runs(over)
            merged: list[list[int]] = []
            for a, b in runs:
                if merged and t[a] - t[merged[-1][1] - 1] < min_s:
                    merged[-1][1] = b
                else:
                    merged.append([a, b])
            for a, b in merged:
                if t[b - 1] - t[a] >= min_s:
                    out.append(Segment(data.names[g], float(t[a]), float(t[b - 1]), ax,
                                       float(np.sqrt(np.mean(rs[m[a:b], j] ** 2))), int(g)))
    out.sort(key=lambda s: -s.rms_N * (s.t_end - s.t_start))
    return out, rs, sigma


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    d = np.diff(np.r_[0, mask.astype(np.int8), 0])
    return list(zip(np.flatnonzero(d == 1), np.flatnonzero(d == -1)))


def features(data: GapData) -> dict[str, np.ndarray]:
    """Candidate drivers, per sample: heights, velocities (world and body), speed, rotor speeds
    and their rates, thrust share, time."""
    vB = np.einsum("kji,kj->ki", data.R, data.v)
    wsum = np.sum(data.rotor_speeds, axis=1)
    rate = np.empty_like(wsum)
    for g in np.unique(data.group):
        m = data.group == g
        dt = float(np.median(np.diff(data.t[m])))
        rate[m] = savgol_filter(wsum[m], 11, 2, deriv=1, delta=dt) if m.sum() > 11 else 0.0
    f = {
        "d_down": np.minimum(data.d_down, FAR),
        "d_up": np.minimum(data.d_up, FAR),
        "v_x": data.v[:, 0], "v_y": data.v[:, 1], "v_z": data.v[:, 2],
        "v_Bx": vB[:, 0], "v_By": vB[:, 1], "v_Bz": vB[:, 2],
        "speed": np.linalg.norm(data.v, axis=1),
        "rotor_speed_sum": wsum,
        "rotor_speed_rate": rate,
        "thrust_sum_omega2": data.S,
        "t": data.t,
    }
    if not np.any(np.isfinite(data.d_down)):
        f.pop("d_down")
    if not np.any(np.isfinite(data.d_up)):
        f.pop("d_up")
    return f


def explained(x: np.ndarray, y: np.ndarray, bins: int = 24) -> float:
    """Share of ``var(y)`` explained by the mean of ``y`` per quantile bin of ``x``."""
    vy = np.var(y)
    if vy <= 0 or np.ptp(x) <= 0:
        return 0.0
    edges = np.unique(np.quantile(x, np.linspace(0, 1, bins + 1)))
    if len(edges) < 3:
        return 0.0
    idx = np.clip(np.searchsorted(edges, x, side="right") - 1, 0, len(edges) - 2)
    means = np.bincount(idx, weights=y) / np.maximum(np.bincount(idx), 1)
    # a small-sample correction: bins explain ~bins/K of the variance by chance
    r2 = 1.0 - np.var(y - means[idx]) / vy
    return float(max(0.0, r2 - (len(edges) - 1) / len(y)))


def trend_explained(x: np.ndarray, y: np.ndarray, degree: int = 2) -> float:
    """Share of ``var(y)`` explained by a polynomial of ``degree`` in ``x`` (a slow drift)."""
    vy = np.var(y)
    if vy <= 0 or np.ptp(x) <= 0:
        return 0.0
    z = (x - x.mean()) / np.ptp(x)
    V = np.vander(z, degree + 1)
    c = np.linalg.lstsq(V, y, rcond=None)[0]
    return float(max(0.0, 1.0 - np.var(y - V @ c) / vy - degree / len(y)))


def drivers(data: GapData, rs: np.ndarray, top: int = 6, min_score: float = 0.05) -> list[dict]:
    """Features ranked by how much of the smoothed residual they explain (best axis).

    Time since start is scored as a slow trend only (quadratic): binned finely, time would
    "explain" any residual confined to some moments of the flight, whatever drives it."""
    out = []
    for name, x in features(data).items():
        score = trend_explained if name == "t" else explained
        scores = [score(x, rs[:, j]) for j in range(3)]
        j = int(np.argmax(scores))
        if scores[j] >= min_score:
            out.append({"feature": name, "score": round(scores[j], 4), "axis": AXES[j]})
    out.sort(key=lambda d: -d["score"])
    return out[:top]
