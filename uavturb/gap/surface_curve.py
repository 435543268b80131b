"""The measured surface curve of ``gap-report.md``: thrust ratio ``T_IGE/T_OGE`` against rotor-plane height.

This module measures the curve, model-free; :mod:`uavturb.gap.surface_laws` fits the registry's surface
laws to it and builds the report's ``surface_curve``; :mod:`uavturb.gap.report` plots it.

For each hover-like sample the rotors must be making ``thrust_needed`` [N] (the measured force along
the body z axis); the nominal model says ``thrust_modelled = k_T,rec sum(w^2)`` [N], with each
recording's own thrust coefficient. Their ratio, normalised per recording by its median far from the
surface, is the extra thrust per rotor speed squared the surface gives (``effects.md``, "Surface effects
on real vehicles"). It is binned in the rotor-plane height ``d`` (``recordings.md``, "Heights over
surfaces").

Choices (each stated where it is made):

- **Far from the surface** (normalisation): ``d > far_m``; by default ``far_m = FAR_RADII r``
  (10 rotor radii: Cheeseman-Bennett at ``mu = 3`` adds 0.2 % there; a multirotor law with a strong body
  term can still add ~1 %). A large vehicle in a motion-capture room may never hover 10 rotor radii up
  (1.3 m with 10-inch propellers): where a recording has too few samples there, ``far_m`` comes down to
  ``FAR_SHARE`` of the highest hover height, never under :data:`MIN_FAR_RADII` rotor radii, with a note
  (the laws are compared normalised the same way, so this moves no fitted value; the ratios then read the
  extra thrust over that height's). Without ``r``, the top of the flights: ``FAR_SHARE`` of the highest
  hover height of all recordings. A recording with fewer than :data:`MIN_FAR` samples above ``far_m`` cannot be
  normalised: it is left out, with a note. A law is compared with the curve normalised as the curve is
  (:meth:`SurfaceCurve.far_level`): what the law still adds at each recording's median far height is
  divided out, so a slowly fading law is not read as 0.4-1 % weaker than it is.
- **Bins** (near range ``d <= far_m``, where the laws are steep): adaptive, consecutive in height, each
  with at least :data:`MIN_BIN_N` samples and :data:`MIN_BLOCKS` time blocks (about
  ``n / MAX_BINS`` samples each), or the edges given.
- **Honest errors**: a bin's standard error is the larger of the cluster-robust one over time blocks of
  ``block_s`` within each recording (samples in one hover are not independent) and, where two or more
  recordings contribute, the standard error of the recordings' mean (sessions, batteries, height
  references differ); with the error a coarse rotor-speed resolution leaves (``resolution``) added in
  quadrature: in a steady hover every rotor's speed rounds alike for seconds, so the thrust's rounding does not
  average out over a bin (a small quadrotor hovering at 148 rad/s recorded to 1 rad/s: 0.4 % of thrust). Each
  recording's normalisation error (its level's noise, and how much the level moves with the far heights it is
  read over, :func:`level_height_term`) is shared by all its bins and added in quadrature too.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Callable

import numpy as np

from uavturb.errors import InputError
from uavturb.numerics.blocks import unique_inverse

#: default far height in rotor radii (normalisation above it)
FAR_RADII = 10.0
#: lowest far height in rotor radii where the flights never went FAR_RADII up (Cheeseman-Bennett at mu = 3
#: adds 0.75 % there, divided out of every law compared; the surface's lift is steepest within 2-3 radii)
MIN_FAR_RADII = 5.0
#: without a rotor radius: far = this share of the highest hover height over all recordings
FAR_SHARE = 0.5
#: samples above ``far_m`` a recording needs to be normalised
MIN_FAR = 30
#: samples and time blocks each adaptive bin needs; bins aimed at
MIN_BIN_N, MIN_BLOCKS, MAX_BINS = 30, 3, 12
#: samples a recording needs in a bin for its mean to count in the between-recording error
MIN_RECORDING_N = 5

@dataclass(frozen=True)
class SurfaceBin:
    """One height bin. ``lo``, ``hi``, ``d_m`` [m] (edges, mean rotor-plane height); ``ratio`` (mean) and
    ``stderr`` [-], the whole error; ``stderr_level`` [-] its part from the recordings' normalisation,
    shared with the other bins of the same recordings; ``n`` samples, ``blocks`` time blocks,
    ``recordings`` (group ids contributing); ``stderr_resolution`` [-] its part from the rotor speeds'
    resolution (:func:`measured_curve`'s ``resolution``)."""

    lo: float
    hi: float
    d_m: float
    n: int
    ratio: float
    stderr: float
    blocks: int
    recordings: tuple[int, ...]
    stderr_level: float = 0.0
    stderr_resolution: float = 0.0


@dataclass
class SurfaceCurve:
    """The measured curve: bins, how it was normalised, and the samples behind it (for jackknives).

    Attributes
    ----------
    bins : list of SurfaceBin, by height
    far_m : m, normalisation height; levels : {group: median raw ratio above far_m}
    far_d : {group: median rotor-plane height [m] of the samples its level is the median of} (``inf`` where
        those mostly had no surface below)
    notes : sentences on what was left out and why
    level_error : {group: relative standard error of its level} (cluster-robust over time blocks, times
        ``sqrt(pi/2)`` for a median, and :func:`level_height_term` in quadrature)
    d, ratio, group, block : (M,) the near samples used (m, normalised ratio, recording, time block)
    edges : (B+1,) m, bin edges
    """

    bins: list[SurfaceBin]
    far_m: float
    levels: dict[int, float]
    notes: list[str]
    level_error: dict[int, float]
    d: np.ndarray = field(repr=False)
    ratio: np.ndarray = field(repr=False)
    group: np.ndarray = field(repr=False)
    block: np.ndarray = field(repr=False)
    edges: np.ndarray = field(repr=False)
    far_d: dict[int, float] = field(default_factory=dict)

    def far_points(self, use: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """``(heights [m], weights)`` at which a law's far level is taken (:meth:`far_level`): each normalised
        recording's median far height, weighted by its share of the near samples (where ``use``; all where None)."""
        sel = np.ones(len(self.group), bool) if use is None else np.asarray(use, bool)
        gs = [g for g in sorted(self.far_d) if np.any(sel & (self.group == g))]
        w = np.array([np.sum(sel & (self.group == g)) for g in gs], float)
        return np.array([self.far_d[g] for g in gs], float), (w / w.sum() if len(w) else w)

    def far_level(self, law: Callable[[np.ndarray], np.ndarray]) -> float:
        """What the normalisation makes of a surface law ``law`` (``d [m] -> ratio``): its value at each
        recording's median far height (a law monotone in height has its median there), weighted as
        :meth:`far_points` over every sample; 1 where no far height is known. A measured ratio that follows
        the law reads ``law(d) / far_level(law)``."""
        d, w = self.far_points()
        if not len(d):
            return 1.0
        return float(np.sum(w * np.asarray(law(d), float)))

    def columns(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(d_m, ratio, stderr)`` of the bins, each ``(B,)``."""
        return (np.array([b.d_m for b in self.bins]), np.array([b.ratio for b in self.bins]),
                np.array([b.stderr for b in self.bins]))


def _check_inputs(d, thrust_needed, thrust_modelled, group, hover, t):
    arrays = {"d": d, "thrust_needed": thrust_needed, "thrust_modelled": thrust_modelled, "group": group,
              "hover": hover}
    if t is not None:
        arrays["t"] = t
    out = {k: np.asarray(v) for k, v in arrays.items()}
    K = len(out["d"])
    for k, v in out.items():
        if v.ndim != 1 or len(v) != K:
            raise InputError("surface curve", f"'{k}' must have shape ({K},) like 'd', got {v.shape}")
    return out


def _far_height(d: np.ndarray, ok: np.ndarray, group: np.ndarray, far_m: float | None, r: float | None
                ) -> tuple[float, str | None]:
    """The normalisation height [m] (module docstring) and a note where it came down from ``FAR_RADII r``."""
    if far_m is not None:
        return float(far_m), None
    finite = d[ok & np.isfinite(d)]
    top = FAR_SHARE * float(finite.max()) if len(finite) else np.inf
    if r is None:
        return top, None
    far = FAR_RADII * float(r)

    def short(h: float) -> int:  # recordings with too few samples above h to be normalised
        return sum(int(np.sum(ok & (group == g) & (d > h)) < MIN_FAR) for g in np.unique(group[ok]))

    lower = max(MIN_FAR_RADII * float(r), min(far, top))
    if lower >= far or short(far) == 0 or short(lower) >= short(far):
        return far, None
    return lower, (f"normalised above {lower:.2f} m ({lower / float(r):.1f} rotor radii) rather than {far:.2f} m "
                   f"({FAR_RADII:.0f} rotor radii), which the flights hovered above too seldom: the ratios read the "
                   f"extra thrust over that height's, and every law is compared normalised the same way")


def _median_error(x: np.ndarray, group: np.ndarray, block: np.ndarray) -> float:
    """Standard error of the median of ``x``: the cluster-robust error of its mean (:func:`bin_stats`) times
    ``sqrt(pi/2)``; 0 where it cannot be formed."""
    _, se, _, _ = bin_stats(x, group, block)
    return float(np.nan_to_num(se) * np.sqrt(np.pi / 2))


def level_height_term(raw: np.ndarray, d: np.ndarray, group: np.ndarray, block: np.ndarray
                      ) -> tuple[float, float, float]:
    """How much one recording's far level [-, relative] depends on the heights it is taken over, and the two
    halves it is read from.

    The far samples are split at their median height; the term is half the difference of the two halves'
    median ratios, less (in quadrature) what their own errors make of such a difference, over the level: a far
    range still inside the surface's reach, or a thrust per speed squared that drifts with height for any other
    reason, leaves the normalisation uncertain by about that much, in every bin at once (Neural-Swarm's 67 g
    walks: 0.995 of the level at 0.23-0.26 m, 1.005 at 0.33-0.38 m). 0 where the samples span no height
    (every far sample at one height) or either half has fewer than ``MIN_FAR / 2`` samples.

    Parameters
    ----------
    raw, d, group, block : (n,) the recording's far samples: raw ratio, rotor-plane height [m], recording and
        time block (cluster) ids

    Returns
    -------
    (term, lower, upper): the relative term and the halves' medians over the level (nan where not formed)
    """
    lower = d <= np.median(d)
    if min(lower.sum(), (~lower).sum()) < MIN_FAR // 2:
        return 0.0, float("nan"), float("nan")
    level = float(np.median(raw))
    lo, hi = (float(np.median(raw[m])) for m in (lower, ~lower))
    noise = [_median_error(raw[m], group[m], block[m]) for m in (lower, ~lower)]
    term2 = (0.5 * (hi - lo)) ** 2 - 0.25 * (noise[0] ** 2 + noise[1] ** 2)
    return float(np.sqrt(max(term2, 0.0)) / level), lo / level, hi / level


def _normalise(raw, d, ok, group, block, far_m, names
               ) -> tuple[dict[int, float], dict[int, float], dict[int, float], list[str]]:
    """Median raw ratio above ``far_m`` per recording, its relative standard error (sample noise and
    :func:`level_height_term` in quadrature), the median height of those samples [m], and notes for recordings
    that never went far or whose level depends on the height it is read at."""
    levels, errors, heights, notes, drifting = {}, {}, {}, [], []
    for g in np.unique(group[ok]):
        far = ok & (group == g) & (d > far_m)
        name = names[g] if names is not None else f"recording {g}"
        if far.sum() < MIN_FAR:
            notes.append(f"{name} left out: it hovered above {far_m:.3f} m (far from the surface) in only "
                         f"{int(far.sum())} samples (needs {MIN_FAR}), so its thrust level cannot be normalised")
            continue
        levels[int(g)] = float(np.median(raw[far]))
        heights[int(g)] = float(np.median(d[far]))
        noise = _median_error(raw[far], group[far], block[far]) / levels[int(g)]
        term, lo, hi = level_height_term(raw[far], d[far], group[far], block[far])
        errors[int(g)] = float(np.hypot(noise, term))
        if term > noise:
            drifting.append(f"{name} {lo:.4f} below {np.median(d[far]):.2f} m and {hi:.4f} above, ± {100 * term:.2g} %")
    if drifting:
        notes.append("the far samples' thrust per rotor speed squared still changes with height (over the level, by "
                     "halves of their heights: " + "; ".join(drifting) + "): half the difference, beyond the halves' "
                     "noise, is in each recording's normalisation error, which every bin of it shares")
    return levels, errors, heights, notes


def _blocks(group: np.ndarray, t: np.ndarray | None, block_s: float) -> np.ndarray:
    """Cluster ids: time blocks of ``block_s`` [s] within each recording (the recording without ``t``)."""
    if t is None:
        return group.astype(np.int64)
    out = np.empty(len(group), np.int64)
    for g in np.unique(group):
        m = group == g
        out[m] = np.floor((t[m] - t[m].min()) / block_s).astype(np.int64)
    return group.astype(np.int64) * 10_000_000 + out


def _adaptive_edges(d: np.ndarray, block: np.ndarray) -> np.ndarray:
    """Consecutive height bins with at least ``MIN_BIN_N`` samples and ``MIN_BLOCKS`` blocks each."""
    order = np.argsort(d, kind="stable")
    ds, bs = d[order], block[order]
    target = max(MIN_BIN_N, int(np.ceil(len(ds) / MAX_BINS)))
    cuts, start, seen = [], 0, set()
    for i in range(len(ds)):
        seen.add(int(bs[i]))
        if i + 1 - start >= target and len(seen) >= MIN_BLOCKS and i + 1 < len(ds) and ds[i + 1] > ds[i]:
            cuts.append(i + 1)
            start, seen = i + 1, set()
    if cuts and (len(ds) - cuts[-1] < target or len(set(bs[cuts[-1]:].tolist())) < MIN_BLOCKS):
        cuts.pop()  # too little left: the remainder joins the last bin
    inner = [0.5 * (ds[c - 1] + ds[c]) for c in cuts]
    return np.array([ds[0], *inner, ds[-1]], float)


def bin_of(d: np.ndarray, edges: np.ndarray) -> np.ndarray:
    """Bin index of each height (-1 outside ``[edges[0], edges[-1]]``)."""
    idx = np.searchsorted(edges, d, side="right") - 1
    idx[d == edges[-1]] = len(edges) - 2
    return np.where((d < edges[0]) | (d > edges[-1]), -1, idx)


def bin_stats(x: np.ndarray, group: np.ndarray, block: np.ndarray) -> tuple[float, float, int, tuple[int, ...]]:
    """``(mean, stderr, blocks, recordings)`` of one bin's ratios (module docstring, honest errors)."""
    n, mean = len(x), float(np.mean(x))
    e = x - mean
    ub, inv = unique_inverse(block)
    se_c = np.nan
    if len(ub) >= 2:
        sums = np.bincount(inv, weights=e)
        se_c = float(np.sqrt(len(ub) / (len(ub) - 1) * np.sum(sums**2)) / n)
    ug, ig = unique_inverse(group)
    recs = [int(g) for g, count in zip(ug, np.bincount(ig, minlength=len(ug))) if count >= MIN_RECORDING_N]
    se_b = np.nan
    if len(recs) >= 2:
        means = np.array([np.mean(x[group == g]) for g in recs])
        se_b = float(np.std(means, ddof=1) / np.sqrt(len(recs)))
    se = np.nanmax([se_c, se_b]) if np.isfinite([se_c, se_b]).any() else np.nan
    return mean, float(se), len(ub), tuple(int(g) for g in ug)


def measured_curve(d, thrust_needed, thrust_modelled, group, *, hover, far_m: float | None = None,
                   bins=None, block_s: float = 1.0, t=None, r: float | None = None,
                   names: list[str] | None = None, resolution=None) -> SurfaceCurve:
    """Bin the measured thrust ratio in rotor-plane height (module docstring for every choice).

    Parameters
    ----------
    d : (K,) rotor-plane height over the surface below [m] (``inf`` where none)
    thrust_needed : (K,) N, measured force along the body z axis the rotors must be making
    thrust_modelled : (K,) N, ``k_T,rec sum(w^2)`` with each recording's own thrust coefficient
    group : (K,) int, recording index
    hover : (K,) bool, hover-like samples to use (small acceleration and tilt, in the air)
    far_m : m, normalisation height (default ``FAR_RADII r``, or ``FAR_SHARE`` of the top height)
    bins : None (adaptive), an int (that many quantile bins) or (B+1,) edges [m]
    block_s : s, time blocks for the cluster-robust errors
    t : (K,) s, time (without it each recording is one cluster)
    r : m, rotor radius (for the default ``far_m``)
    names : recording names for the notes
    resolution : (K,) -, the relative thrust error each sample's rotor-speed resolution leaves (None: none),
        added in quadrature to each bin's error as its mean over the bin (:func:`resolution_error`)
    """
    a = _check_inputs(d, thrust_needed, thrust_modelled, group, hover, t)
    d, need, model = (a[k].astype(float) for k in ("d", "thrust_needed", "thrust_modelled"))
    group, hover = a["group"].astype(np.int64), a["hover"].astype(bool)
    tt = a["t"].astype(float) if t is not None else None
    if block_s <= 0:
        raise InputError("surface curve", f"block_s must be positive, got {block_s}")
    ok = hover & np.isfinite(need) & np.isfinite(model) & (model > 0) & ~np.isnan(d) & (d > 0)
    far, far_note = _far_height(d, ok, group, far_m, r)
    with np.errstate(divide="ignore", invalid="ignore"):
        raw = need / model
    blocks = _blocks(group, tt, block_s)
    levels, level_error, far_d, notes = _normalise(raw, d, ok, group, blocks, far, names)
    notes = ([far_note] if far_note else []) + notes
    near = ok & np.isin(group, list(levels)) & np.isfinite(d) & (d <= far)
    ratio = raw[near] / np.array([levels[int(g)] for g in group[near]])
    res = np.zeros(int(near.sum())) if resolution is None else np.asarray(resolution, float)[near]
    dn, gn, bn = d[near], group[near], blocks[near]
    if len(dn) < MIN_BIN_N:
        notes.append(f"only {len(dn)} hover samples under {far:.3f} m: no surface curve")
        return SurfaceCurve([], far, levels, notes, level_error, dn, ratio, gn, bn, np.array([]), far_d)
    if bins is None:
        edges = _adaptive_edges(dn, bn)
    elif np.ndim(bins) == 0:
        edges = np.unique(np.quantile(dn, np.linspace(0, 1, int(bins) + 1)))
    else:
        edges = np.asarray(bins, float)
    idx = bin_of(dn, edges)
    out = []
    for k in range(len(edges) - 1):
        m = idx == k
        if m.sum() < 2:
            continue
        mean, se, nb, recs = bin_stats(ratio[m], gn[m], bn[m])
        share = np.array([np.mean(gn[m] == g) for g in recs])
        se_level = mean * float(np.sqrt(np.sum((share * np.array([level_error[g] for g in recs])) ** 2)))
        se_res = mean * float(np.mean(res[m]))
        out.append(SurfaceBin(float(edges[k]), float(edges[k + 1]), float(np.mean(dn[m])), int(m.sum()), mean,
                              float(np.sqrt(se**2 + se_level**2 + se_res**2)), nb, recs, se_level, se_res))
    return SurfaceCurve(out, far, levels, notes, level_error, dn, ratio, gn, bn, edges, far_d)


def too_few_bins_note(curve: SurfaceCurve, needed: int = 2) -> str:
    """The sentence saying why ``curve`` judges no law's shape: it holds fewer than ``needed`` height bins (a
    one-parameter law needs two, the fewest any law of the registry needs), with how many hover-like samples and
    time blocks lay under its normalisation height and what a bin asks of them."""
    blocks = len(set(zip(curve.group.tolist(), curve.block.tolist())))
    return (f"{len(curve.bins)} height bin(s) from {len(curve.d)} hover-like samples in {blocks} time blocks "
            f"under {curve.far_m:.2f} m (a bin needs {MIN_BIN_N} samples from {MIN_BLOCKS} blocks): too few to "
            f"judge a law's shape, which needs {needed} bins or more; hover at several low heights, a few seconds "
            f"each, to measure it")


def resolution_error(quantum: float, rotor_speeds: np.ndarray) -> np.ndarray | None:
    """(K,) -, the relative thrust error rotor speeds ``(K, N)`` [rad/s] recorded to ``quantum`` [rad/s] leave in a
    steady hover: every rotor off by the same rounding ``e``, uniform in ``+-quantum/2``, moves ``sum(w^2)`` by
    ``2 e / w`` of itself (standard deviation ``quantum / (sqrt(3) w)``, ``w`` the rotors' mean speed); rotors
    rounded apart would leave ``1 / sqrt(N)`` of it. None for streams that are not quantised."""
    if quantum <= 0:
        return None
    w = np.mean(np.abs(np.asarray(rotor_speeds, float)), axis=1)
    with np.errstate(divide="ignore"):
        return np.where(w > 0, quantum / (np.sqrt(3.0) * w), 0.0)


def shifted_curve(curve: SurfaceCurve, dz: float) -> SurfaceCurve:
    """``curve`` with every height moved by ``dz`` [m] (the height reference off by ``dz``), ratios unchanged."""
    bins = [replace(b, lo=b.lo + dz, hi=b.hi + dz, d_m=b.d_m + dz) for b in curve.bins]
    return replace(curve, bins=bins, d=curve.d + dz, edges=curve.edges + dz,
                   far_d={g: h + dz for g, h in curve.far_d.items()})


#: rotor radii within which the measured curve's bins count as lift evidence (Cheeseman-Bennett at mu = 3
#: adds 1.2 % at 4 r, and more below)
LIFT_RADII = 4.0


def lift_z(curve: SurfaceCurve | None, r: float) -> float:
    """How many standard errors the measured curve's bins within :data:`LIFT_RADII` ``r`` of the surface
    stand above 1: the model-free evidence of a surface lift, independent of any law.

    The weighted mean of ``ratio - 1`` over those bins (weights ``1/own^2``, ``own`` a bin's error less its
    normalisation part, which the bins share) over its standard error, widened once by the largest
    normalisation error (a recording's level moves all its bins together: counted in each bin's weight as well,
    it had been counted twice). 0 without such bins."""
    if curve is None or not curve.bins:
        return 0.0
    near = [b for b in curve.bins if b.d_m <= LIFT_RADII * r and np.isfinite(b.stderr) and b.stderr > 0]
    if not near:
        return 0.0
    own = np.array([np.sqrt(max(b.stderr**2 - b.stderr_level**2, 1e-6 * b.stderr**2)) for b in near])
    w = 1.0 / own**2
    excess = float(np.sum(w * np.array([b.ratio - 1.0 for b in near])) / np.sum(w))
    level = max((b.stderr_level for b in near), default=0.0)
    return excess / float(np.sqrt(1.0 / np.sum(w) + level**2))


#: s, time blocks over which :func:`voltage_drift` averages before its regression (samples a few hundredths of a
#: second apart are not independent)
DRIFT_BLOCK_S = 1.0
#: |slope| / its error, and the largest shift of a bin [share of thrust], from which :func:`voltage_drift` speaks
DRIFT_Z, DRIFT_SHIFT = 3.0, 0.002


def voltage_drift(curve: SurfaceCurve, d: np.ndarray, raw: np.ndarray, voltage_dev: np.ndarray, group: np.ndarray,
                  t: np.ndarray, use: np.ndarray) -> dict | None:
    """How far the measured curve's bins may be moved by a thrust level that follows the battery's voltage within
    each recording, which no named effect takes off: the far samples' raw ratio is regressed on the voltage (each
    recording's own level and mean voltage removed, :data:`DRIFT_BLOCK_S` block means), and each bin's shift is
    that slope times how far its samples' mean voltage lies from the far samples'. On Neural-Swarm's December 32 g
    walks the far samples read 15 +- 5 % of their thrust per volt more (the dataset's thrust map under-corrects the
    voltage) and hovered early, at higher voltage, than the bins 10-20 cm up: those read up to 0.4 % low, part of
    their dip under 1.

    Parameters
    ----------
    curve : the measured curve (its far height, edges and normalised recordings)
    d, raw, voltage_dev, group, t : (K,) rotor-plane height [m], thrust needed over modelled [-], voltage less the
        recording's mean [V], recording, time [s]
    use : (K,) bool, the hover samples the curve was measured on

    Returns
    -------
    None where the slope is not :data:`DRIFT_Z` errors from zero or no bin moves by :data:`DRIFT_SHIFT`; else
    ``{"slope_per_V", "stderr_per_V", "shifts": (B,) [-], "largest": [-], "at_m": m}``.
    """
    ok = use & np.isfinite(voltage_dev) & np.isfinite(raw) & np.isin(group, list(curve.levels))
    far = ok & (d > curve.far_m)
    xs, ys = [], []
    for g in np.unique(group[far]):
        rows = far & (group == g)
        y = raw[rows] / curve.levels[int(g)]
        block = np.floor((t[rows] - t[rows].min()) / DRIFT_BLOCK_S).astype(int)
        _, inv = unique_inverse(block)
        n = np.bincount(inv)
        xb, yb = np.bincount(inv, voltage_dev[rows]) / n, np.bincount(inv, y) / n
        xs.append(xb - xb.mean())
        ys.append(yb - yb.mean())
    if not xs or sum(len(x) for x in xs) < 5:
        return None
    x, y = np.concatenate(xs), np.concatenate(ys)
    sxx = float(x @ x)
    if sxx <= 0:
        return None
    slope = float(x @ y) / sxx
    dof = max(len(x) - len(xs) - 1, 1)
    stderr = float(np.sqrt(np.sum((y - slope * x) ** 2) / dof / sxx))
    if not abs(slope) >= DRIFT_Z * stderr:
        return None
    idx = bin_of(d, curve.edges)
    far_v = float(np.mean(voltage_dev[far]))
    shifts = []
    for b in curve.bins:
        k = int(np.searchsorted(curve.edges, b.lo, side="right") - 1)
        rows = ok & (idx == k) & (d <= curve.far_m)
        shifts.append(slope * (float(np.mean(voltage_dev[rows])) - far_v) if rows.any() else 0.0)
    shifts = np.array(shifts)
    worst = int(np.argmax(np.abs(shifts))) if len(shifts) else 0
    if not len(shifts) or abs(shifts[worst]) < DRIFT_SHIFT:
        return None
    return {"slope_per_V": slope, "stderr_per_V": stderr, "shifts": shifts, "largest": float(shifts[worst]),
            "at_m": float(curve.bins[worst].d_m)}
