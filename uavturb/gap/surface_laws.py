"""The effect registry's surface laws against a measured surface curve (:mod:`uavturb.gap.surface_curve`):
weighted fits with honest errors, the report's ``surface_curve``, the finder's curve
(:func:`finder_surface_curve`), and a better law named from it (:func:`law_named_from_curve`).

- **Honest errors**: a law's parameter error is the larger of the fit's (scaled by ``sqrt(chi2/dof)``
  where that exceeds 1; the fit uses the bins' full covariance, in which a recording's normalisation
  error is shared by all its bins) and, with two or more recordings, the standard deviation of the
  values fitted to each recording alone, because a recording's offset moves all its bins together, which
  per-bin errors do not show, and ``gap-report.md`` asks that each recording's own fit land within about
  two errors of the joint value; with one recording, a jackknife over time blocks. A law is compared with
  each bin's mean ratio through its own mean over the bin's samples, normalised as the curve is (divided
  by its value at the recordings' far heights, :meth:`~uavturb.gap.surface_curve.SurfaceCurve.far_level`).
- **A law fits** where ``chi2/dof <`` :data:`LAW_FITS_CHI2_DOF` (3): with honest errors the right law
  gives ``chi2/dof`` about 1 (standard deviation ``sqrt(2/dof)``, 0.5 at 8 dof), so 3 is four such
  deviations above it, and a p-value under 1 % from 5 dof on.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any, Callable

import numpy as np
from scipy.linalg import cholesky, solve_triangular
from scipy.optimize import least_squares
from scipy.special import chdtrc  # chi^2 survival function (scipy.stats' chi2.sf) without scipy.stats

from uavturb.errors import InputError
from uavturb.gap.design import GapData, dependent_columns
from uavturb.gap.explain import explanation
from uavturb.gap.fit import ModelFit, _nl_values
from uavturb.gap.surface_curve import (
    MIN_BIN_N,
    SurfaceCurve,
    bin_of,
    bin_stats,
    measured_curve,
    resolution_error,
    shifted_curve,
    too_few_bins_note,
    voltage_drift,
)
from uavturb.gap.uncertainty import HONEST_Z, honest_stderr, presence_z, with_systematic
from uavturb.numerics.blocks import jackknife_se
from uavturb.numerics.processes import ForkedPool, forked_state
from uavturb.physics.constants import GRAVITY
from uavturb.physics.effects import EFFECTS, FlightFacts
from uavturb.physics.ground_effect import hover_induced_velocity

#: chi^2/dof under which a law's shape fits the bins (module docstring)
LAW_FITS_CHI2_DOF = 3.0
#: slices of each bin's height range at which a law is evaluated when fitting (:class:`_BinnedLaw`)
_SUB_BINS = 64
#: residual [standard errors] given to a bin where a law does not hold (its pole), to steer fits away
_POLE_RESIDUAL = 1e3


@dataclass
class LawFit:
    """A surface law fitted to the bins of a :class:`SurfaceCurve`.

    Attributes
    ----------
    law : effect name; param : its (first) parameter's name
    value : fitted value of ``param``; stderr : its honest error, ``max(stderr_fit, spread_between)`` with two or more
        recordings (``max(stderr_fit, stderr_jackknife)`` with one): what a recording's own fit may
        differ from ``value`` by (``gap-report.md``: an error bar covers the spread between recordings);
        with many recordings it exceeds the standard error of the joint value (``stderr_jackknife``)
    params, stderrs : every parameter's fitted value and honest error, by name (laws with several parameters)
    fit_errors, resampled : every parameter's ``stderr_fit`` and its ``spread_between`` (two or more
        recordings) or ``stderr_jackknife`` (one), by name
    stderr_fit : from the weighted fit (scaled by ``sqrt(chi2/dof)`` where > 1)
    stderr_jackknife : standard error of the joint value, jackknife over recordings (over time blocks
        with one recording); nan where it cannot be formed
    spread_between : standard deviation of the values fitted to each recording alone (same bins; nan
        with one recording)
    level, level_stderr : the far level (1, or fitted with ``free_level``)
    chi2, dof, chi2_dof, p_value : goodness of fit over the bins used
    values : (B,) the law's ratio in each bin (averaged over the bin's samples where the curve has them)
    law_fits : ``chi2_dof < LAW_FITS_CHI2_DOF``; in_range : the value lies in the effect's physical range
    why : one sentence with the numbers; evaluate : ``d [m] -> ratio`` with the fitted values (plots)
    """

    law: str
    param: str
    value: float
    stderr: float
    stderr_fit: float
    stderr_jackknife: float
    spread_between: float
    level: float
    level_stderr: float
    chi2: float
    dof: int
    chi2_dof: float
    p_value: float
    values: np.ndarray
    law_fits: bool
    in_range: bool
    why: str
    evaluate: Callable[[np.ndarray], np.ndarray] = field(repr=False)
    params: dict[str, float] = field(default_factory=dict)
    stderrs: dict[str, float] = field(default_factory=dict)
    fit_errors: dict[str, float] = field(default_factory=dict)
    resampled: dict[str, float] = field(default_factory=dict)

    def describe(self) -> str:
        """``mu = 2.1 ± 0.3`` (every parameter, with its honest error)."""
        return ", ".join(f"{k} = {v:.3g} ± {self.stderrs.get(k, float('nan')):.2g}" for k, v in self.params.items())


class _BinnedLaw:
    """A law's ratio averaged over each bin's samples (exact against the bin's mean ratio, whatever the
    spread of heights in it); at the bins' mean heights where the curve holds no samples. For speed the
    samples of each bin are grouped in :data:`_SUB_BINS` equal slices of its height range and the law is
    evaluated at each slice's mean height, weighted by its count. Every value is divided by the law's far
    level over the samples compared (:meth:`~uavturb.gap.surface_curve.SurfaceCurve.far_level`)."""

    def __init__(self, curve: SurfaceCurve, spec, r: float, geometry: dict, free_level: bool):
        self.curve, self.spec, self.r, self.geometry, self.free_level = curve, spec, r, geometry, free_level
        self.len_params = len(spec.params)
        self.idx = bin_of(curve.d, curve.edges) if len(curve.d) else np.array([], int)
        lo_edges = curve.edges[:-1]
        self.bin_k = np.array([int(np.searchsorted(lo_edges, b.lo, side="right") - 1) for b in curve.bins], int)
        if len(curve.d):
            nb = len(curve.edges) - 1
            inside = self.idx >= 0
            k = np.where(inside, self.idx, 0)
            width = np.maximum(np.diff(curve.edges)[k], 1e-12)
            frac = np.clip((curve.d - curve.edges[k]) / width, 0.0, 1.0 - 1e-9)
            self.sub = np.where(inside, k * _SUB_BINS + (frac * _SUB_BINS).astype(int), -1)
            n = np.bincount(self.sub[inside], minlength=nb * _SUB_BINS)
            sums = np.bincount(self.sub[inside], weights=curve.d[inside], minlength=nb * _SUB_BINS)
            with np.errstate(invalid="ignore", divide="ignore"):
                self.sub_d = np.where(n > 0, sums / np.maximum(n, 1), np.nan)
            self.sub_bin = np.arange(nb * _SUB_BINS) // _SUB_BINS
        self._all: Callable[[np.ndarray], np.ndarray] | None = None

    def at(self, d: np.ndarray, z: np.ndarray) -> np.ndarray:
        """The law at heights ``d`` [m] with ``z`` (its parameters, then the far level where it is free), as
        the curve reads it (normalised at its far heights)."""
        level = z[self.len_params] if self.free_level else 1.0
        return level * self._ratio(d, z) / self.curve.far_level(lambda h: self._ratio(h, z))

    def _ratio(self, d: np.ndarray, z: np.ndarray) -> np.ndarray:
        """The law's thrust ratio at heights ``d`` [m] with the parameters in ``z`` (not normalised)."""
        return self.spec.ratio_at(d, z[:self.len_params], self.r, **self.geometry)

    def bins(self, z: np.ndarray) -> np.ndarray:
        """(B,) the law in each bin, over all its samples (:meth:`over` every sample, set up once: a fit calls this
        a hundred times, and the setup's counts over the samples had cost more than the law)."""
        if self._all is None:
            self._all = self.over(None)
        return self._all(z)

    def over(self, use: np.ndarray | None) -> Callable[[np.ndarray], np.ndarray]:
        """``z -> (B,)`` the law in each bin over the samples where ``use`` (all where None)."""
        if not len(self.curve.d):
            return lambda z: self.at(self.curve.columns()[0], z)
        sel = self.sub >= 0 if use is None else (self.sub >= 0) & use
        counts = np.bincount(self.sub[sel], minlength=len(self.sub_d))
        present = counts > 0
        nb = len(self.curve.edges) - 1
        n = np.bincount(self.sub_bin, weights=counts, minlength=nb)
        d = self.sub_d[present]
        far_d, far_w = self.curve.far_points(use)

        def law(z: np.ndarray) -> np.ndarray:
            level = z[self.len_params] if self.free_level else 1.0
            both = self._ratio(np.concatenate([d, far_d]), z)
            far = float(np.sum(far_w * both[len(d):])) if len(far_d) else 1.0
            vals = np.zeros(len(self.sub_d))
            vals[present] = level * both[:len(d)] / far
            sums = np.bincount(self.sub_bin, weights=counts * vals, minlength=nb)
            with np.errstate(invalid="ignore", divide="ignore"):
                return (sums / n)[self.bin_k]
        return law


def _weighted_fit(model: Callable[[np.ndarray], np.ndarray], y: np.ndarray, se: np.ndarray, spec,
                  free_level: bool, chol: np.ndarray | None = None, start: np.ndarray | None = None):
    """Least squares of ``(y - model(z)) / se`` over the law's search bounds (bins where ``y`` is finite),
    or of ``chol^-1 (y - model(z))`` with ``chol`` the Cholesky factor of the covariance of those bins;
    a grid picks the start (a grid of each parameter for laws with several), or ``start`` where given (a refit
    on part of the samples starts where the fit on all of them ended: 80 grid points a refit were a second of
    an hour's analysis). Returns ``(z, whitened residuals, jacobian)``, ``z`` the parameters in
    ``spec.params``' order, then the level where it is free."""
    bounds = spec.shape_bounds
    ok = np.isfinite(y)

    def resid(z: np.ndarray) -> np.ndarray:
        m = model(z)[ok]
        raw = np.where(np.isfinite(m), y[ok] - m, _POLE_RESIDUAL * se[ok])
        return raw / se[ok] if chol is None else solve_triangular(chol, raw, lower=True)

    if len(bounds) == 1:
        lo, hi = bounds[0]
        axes = [np.concatenate([np.linspace(lo, hi, 41), np.geomspace(max(lo, 1e-3), hi, 41)])]
    else:
        axes = [np.unique(np.concatenate([np.linspace(lo, hi, 8), np.geomspace(max(lo, 1e-3 * hi), hi, 8)]))
                for lo, hi in bounds]
    grid = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, len(bounds))
    level0 = 1.0
    if free_level:  # the level that matches the upper half of the bins at the grid's middle value
        far = ok & (np.arange(len(y)) >= len(y) // 2)
        middle = np.array([np.median(a) for a in axes] + [1.0])
        level0 = float(np.clip(np.median(y[far] / model(middle)[far]), 0.6, 1.4))
    tail = [level0] if free_level else []
    if start is not None and np.all(np.isfinite(start)):
        z0 = np.asarray(start, float)
    else:
        costs = [np.sum(resid(np.array([*p, *tail])) ** 2) for p in grid]
        z0 = np.array([*grid[int(np.argmin(costs))], *tail])
    box = ([b[0] for b in bounds] + ([0.5] if free_level else []),
           [b[1] for b in bounds] + ([1.5] if free_level else []))
    z0 = np.clip(z0, np.array(box[0]) + 1e-9, np.array(box[1]) - 1e-9)
    sol = least_squares(resid, z0, bounds=box, x_scale="jac")
    return sol.x, resid(sol.x), sol.jac


def _units(curve: SurfaceCurve) -> tuple[np.ndarray, np.ndarray]:
    """``(label per sample, units)``: the recordings, or with a single recording up to 10 chunks of its
    time blocks."""
    recs = np.unique(curve.group)
    if len(recs) >= 2:
        return curve.group, recs
    ub = np.unique(curve.block)
    chunks = np.array_split(ub, max(1, min(10, len(ub))))
    labels = np.zeros(len(curve.block), np.int64)
    for i, c in enumerate(chunks):
        labels[np.isin(curve.block, c)] = i
    return labels, np.arange(len(chunks))


def _rebin(curve: SurfaceCurve, law: _BinnedLaw, use: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(ratio, stderr)`` of each bin (same edges) from the samples where ``use``, the errors as
    :func:`measured_curve` gives them (level errors included); nan where a bin has under 2 samples."""
    out = np.full((2, len(law.bin_k)), np.nan)
    for i, k in enumerate(law.bin_k):
        m = use & (law.idx == k)
        if m.sum() < 2:
            continue
        mean, se, _, recs = bin_stats(curve.ratio[m], curve.group[m], curve.block[m])
        share = np.array([np.mean(curve.group[m] == g) for g in recs])
        level = mean * float(np.sqrt(np.sum((share * np.array([curve.level_error.get(g, 0.0) for g in recs])) ** 2)))
        out[:, i] = mean, np.hypot(se, level)
    return out[0], out[1]


def _refit(curve: SurfaceCurve, law: _BinnedLaw, keep_bins: np.ndarray, se: np.ndarray | None, free_level: bool,
           use: np.ndarray, start: np.ndarray | None = None) -> np.ndarray:
    """(P,) the law's parameters fitted to the bins rebinned (same edges) from the samples where ``use``,
    weighted by ``se`` (by their own errors where None), from ``start`` (the grid where None); nan with too
    few bins."""
    n = len(law.spec.params)
    means, own = _rebin(curve, law, use)
    weights = own if se is None else se
    means = np.where(keep_bins & np.isfinite(weights) & (weights > 0), means, np.nan)
    if np.isfinite(means).sum() < n + (2 if free_level else 1):
        return np.full(n, np.nan)
    return np.asarray(_weighted_fit(law.over(use), means, weights, law.spec, free_level, start=start)[0][:n], float)


def _resampled(curve: SurfaceCurve, law: _BinnedLaw, keep_bins: np.ndarray, se: np.ndarray, free_level: bool,
               start: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """``(jackknife standard error of each parameter, standard deviation of single-recording values)``, each
    (P,): leave out each recording in turn (each of up to 10 chunks of time blocks with one recording) and
    refit; and, with two or more recordings, fit each recording alone; each refit from ``start`` (the fit on
    every sample). nan where they cannot be formed."""
    nan = np.full(len(law.spec.params), np.nan)
    if len(curve.d) == 0:
        return nan, nan
    labels, units = _units(curve)
    loo = np.array([_refit(curve, law, keep_bins, se, free_level, labels != u, start) for u in units])
    loo = loo[np.all(np.isfinite(loo), axis=1)]
    se_jack = jackknife_se(loo) if len(loo) >= 2 else nan
    if len(np.unique(curve.group)) < 2:
        return se_jack, nan
    alone = np.array([_refit(curve, law, keep_bins, None, free_level, curve.group == g, start) for g in units])
    alone = alone[np.all(np.isfinite(alone), axis=1)]
    return se_jack, np.std(alone, axis=0, ddof=1) if len(alone) >= 2 else nan


def _bin_covariance(curve: SurfaceCurve, binned: _BinnedLaw) -> np.ndarray:
    """(B, B) covariance of the bins' ratios: each bin's own error (``stderr`` less its level part) on the
    diagonal, plus the normalisation errors the bins of one recording share:
    ``sum_g (share_bg ratio_b e_g)(share_b'g ratio_b' e_g)`` with ``e_g`` the recording's relative level error."""
    _, y, se = curve.columns()
    own = np.array([b.stderr**2 - b.stderr_level**2 for b in curve.bins])
    cov = np.diag(np.maximum(own, 1e-12 * se**2))
    if not len(curve.d) or not curve.level_error:
        return cov
    for g, err in curve.level_error.items():
        mine = curve.group == g
        share = np.array([np.mean(mine[binned.idx == k]) if np.any(binned.idx == k) else 0.0 for k in binned.bin_k])
        col = share * y * err
        cov += np.outer(col, col)
    return cov


def fit_law(curve: SurfaceCurve, law: str, r: float, *, free_level: bool = False, resample: bool = True,
            start: np.ndarray | None = None, **geometry) -> LawFit:
    """Weighted least squares (weights ``1/stderr^2``) of a surface law's ``T_IGE/T_OGE`` to the bins.

    Parameters
    ----------
    curve : the measured curve
    law : effect name with a ``ratio`` (``ground_effect``, ``ground_effect_multirotor``)
    r : m, rotor radius
    free_level : also fit the far level (the curve's normalisation height may still feel the surface)
    resample : refit on each recording alone (or, with one, a jackknife over time blocks) for the honest
        error; without, the error is the fit's alone (enough where only the shape's chi^2 is read)
    start : the law's parameters (then the level where it is free) to start the search from (None: a grid)
    geometry : ``arm_length`` [m], ``rotor_count`` (laws that use the rotor spacing)
    """
    spec = EFFECTS.get(law)
    if spec is None or spec.ratio is None or not spec.shape_bounds:
        known = ", ".join(n for n, e in EFFECTS.items() if e.ratio is not None)
        raise InputError("surface curve", f"'{law}' is no surface law with a thrust ratio (known: {known})")
    d, y, se = curve.columns()
    keep = np.isfinite(se) & (se > 0)
    nlaw = len(spec.params)
    npar = nlaw + (1 if free_level else 0)
    if keep.sum() < npar + 1:
        raise InputError("surface curve", f"{int(keep.sum())} bins with errors: too few to fit {law}")
    binned = _BinnedLaw(curve, spec, r, geometry, free_level)
    chol = cholesky(_bin_covariance(curve, binned)[np.ix_(keep, keep)], lower=True)
    z, res, J = _weighted_fit(binned.bins, np.where(keep, y, np.nan), se, spec, free_level, chol, start)
    chi2, dof = float(np.sum(res**2)), int(keep.sum()) - npar
    chi2_dof = chi2 / dof if dof > 0 else float("nan")
    try:
        cov = np.linalg.inv(J.T @ J)
    except np.linalg.LinAlgError:
        cov = np.full((npar, npar), np.nan)
    se_fit = np.sqrt(np.maximum(np.diag(cov), 0.0)) * (np.sqrt(max(chi2_dof, 1.0)) if np.isfinite(chi2_dof) else 1.0)
    nan = np.full(nlaw, np.nan)
    se_jack, spread = _resampled(curve, binned, keep, se, free_level, z) if resample else (nan, nan)
    between = len(np.unique(curve.group)) >= 2
    stderrs = [_larger(se_fit[i], (spread if between else se_jack)[i]) for i in range(nlaw)]
    params = {k: float(v) for k, v in zip(spec.params, z[:nlaw])}
    in_range = spec.physical_range.violation(params, None) is None
    fit = LawFit(law, spec.params[0], float(z[0]), stderrs[0], float(se_fit[0]), float(se_jack[0]), float(spread[0]),
                 float(z[nlaw]) if free_level else 1.0, float(se_fit[nlaw]) if free_level else 0.0, chi2, dof,
                 chi2_dof, float(chdtrc(dof, chi2)) if dof > 0 else float("nan"), binned.bins(z),
                 bool(np.isfinite(chi2_dof) and chi2_dof < LAW_FITS_CHI2_DOF), in_range, "",
                 lambda dd: binned.at(dd, z), params, dict(zip(spec.params, stderrs)),
                 {k: float(v) for k, v in zip(spec.params, se_fit)},
                 {k: float(v) for k, v in zip(spec.params, spread if between else se_jack)})
    fit.why = _why(fit, d[keep], res, spec)
    return fit


def _larger(a: float, b: float) -> float:
    """The larger of two errors, ignoring nan (nan where both are)."""
    finite = [float(x) for x in (a, b) if np.isfinite(x)]
    return max(finite) if finite else float("nan")


def curve_budget(curve: SurfaceCurve, fit: LawFit, r: float, height_reference_m: float, **geometry
                 ) -> dict[str, dict[str, float]]:
    """The error budget (:mod:`uavturb.gap.uncertainty`'s terms and layout) of a law named from the measured
    curve: **sample** (the weighted fit's error), **height reference** (half the change of each parameter when
    every height is moved by ``+-height_reference_m`` [m], added in quadrature to the sample term) and
    **between recordings** (each recording's curve fitted alone) or, with one recording, **between blocks**
    (the jackknife over time blocks); the stated error is the largest."""
    moved = []
    for dz in (height_reference_m, -height_reference_m):
        try:
            moved.append(fit_law(shifted_curve(curve, dz), fit.law, r, resample=False, **geometry).params)
        except (InputError, ValueError, np.linalg.LinAlgError):
            moved.append(None)
    label = "between_recordings" if len(np.unique(curve.group)) >= 2 else "between_blocks"
    budget = {}
    for k in fit.params:
        sample, spread = fit.fit_errors.get(k, float("nan")), fit.resampled.get(k, float("nan"))
        height = (abs(moved[0][k] - moved[1][k]) / 2.0 if all(m is not None for m in moved) else float("nan")) \
            if height_reference_m > 0 else 0.0
        terms = {"sample": sample, "height_reference": height, label: spread}
        finite = {t: v for t, v in terms.items() if np.isfinite(v)}
        widened = float(np.hypot(sample, height)) if np.isfinite(height) else sample
        budget[k] = terms | {"stderr": _larger(widened, spread),
                             "limited_by": max(finite, key=finite.get) if finite else "unknown"}
    return budget


#: m, how far every height is moved, either way and in steps, looking for a height reference that is off (a floor
#: scanned or a motion-capture origin a few centimetres away from where the other stands)
HEIGHT_OFFSET_SEARCH_M, HEIGHT_OFFSET_STEP_M = 0.06, 0.0025
#: chi^2 by which the moved curve must fit better (a law's parameters free at each height offset)
HEIGHT_OFFSET_DELTA_CHI2 = 4.0


@dataclass(frozen=True)
class HeightOffset:
    """A surface law whose shape fits the measured curve only with every height moved: ``dz_m`` [m] added to the
    heights (negative: the flights' heights read high over the scanned surface), the law's chi^2/dof there and as
    measured, and its parameters there."""

    law: str
    dz_m: float
    chi2_dof: float
    chi2_dof_as_measured: float
    params: dict[str, float]

    def sentence(self) -> str:
        return (f"`{self.law}`'s shape does not fit the measured curve at the recorded heights (chi^2/dof = "
                f"{self.chi2_dof_as_measured:.3g}) but does with every height moved by {100 * self.dz_m:+.1f} cm "
                f"(chi^2/dof = {self.chi2_dof:.2g}; there {_values_text(self.params)}): a point cloud's floor and the "
                f"motion capture's heights {abs(100 * self.dz_m):.1f} cm apart read so, and every stated error covers "
                f"heights off by that much")


def height_offset(curve: SurfaceCurve, fit: LawFit, r: float, **geometry) -> HeightOffset | None:
    """The height offset at which ``fit``'s law (fitted as measured, not fitting: ``law_fits`` False) fits the
    curve's shape (chi^2/dof under :data:`LAW_FITS_CHI2_DOF`, chi^2 lower by :data:`HEIGHT_OFFSET_DELTA_CHI2`),
    searched within :data:`HEIGHT_OFFSET_SEARCH_M`; None where it fits as measured or nowhere. A hexarotor's
    flights whose motion capture read 5 cm over the scanned floor had named mu = 5.4 +- 1.3 (truth 2): its law
    fit the curve at chi^2/dof 19.9 as measured and 0.02 with the heights 5 cm lower, mu = 2.00 there. (A law whose
    shape a shift leaves alone, the exponential one, never finds one: a shift scales its amplitude.)"""
    if not _may_read_offset(fit):
        return None
    best, lowest, start = None, min(b.lo for b in curve.bins), None
    for dz in np.arange(-HEIGHT_OFFSET_SEARCH_M, HEIGHT_OFFSET_SEARCH_M + HEIGHT_OFFSET_STEP_M / 2,
                        HEIGHT_OFFSET_STEP_M):
        if abs(dz) < HEIGHT_OFFSET_STEP_M / 2 or lowest + dz <= 0.0:
            continue
        try:  # each offset's fit starts where its neighbour's ended (the grid each time was most of the search)
            moved = fit_law(shifted_curve(curve, float(dz)), fit.law, r, resample=False, start=start, **geometry)
        except (InputError, ValueError, np.linalg.LinAlgError):
            start = None
            continue
        start = np.array(list(moved.params.values()), float)
        if np.isfinite(moved.chi2) and moved.in_range and (best is None or moved.chi2 < best[1].chi2):
            best = (float(dz), moved)
    if best is None:
        return None
    dz = best[0]
    try:  # the offset found, fitted from a grid
        moved = fit_law(shifted_curve(curve, dz), fit.law, r, resample=False, **geometry)
    except (InputError, ValueError, np.linalg.LinAlgError):
        return None
    if not moved.law_fits or not moved.in_range or moved.chi2 > fit.chi2 - HEIGHT_OFFSET_DELTA_CHI2:
        return None
    return HeightOffset(fit.law, dz, moved.chi2_dof, fit.chi2_dof, dict(moved.params))


def _may_read_offset(fit: LawFit) -> bool:
    """Whether :func:`height_offset` scans ``fit``'s law: it does not fit as measured, over a degree of freedom."""
    return not fit.law_fits and bool(np.isfinite(fit.chi2)) and fit.dof >= 1


def first_height_offset(curve: SurfaceCurve, fits: dict[str, LawFit], laws: list[str], r: float,
                        **geometry) -> HeightOffset | None:
    """The :func:`height_offset` of the first of ``laws`` (keys of ``fits``) that reads one, None where none does.
    The laws that may read one are scanned side by side in forked processes
    (:class:`~uavturb.numerics.processes.ForkedPool`; each scan is a chain of fits, each started from its
    neighbour's, that cannot be split): twelve one-minute walks scanned three laws in 1.3 s, one after the other."""
    may_read = [law for law in laws if _may_read_offset(fits[law])]
    with ForkedPool((curve, fits, r, geometry)) as pool:
        done = pool.map(_height_offset_in_child, may_read)
    for law in laws:
        found = done[law] if law in done else height_offset(curve, fits[law], r, **geometry)
        if found is not None:
            return found
    return None


def _height_offset_in_child(law: str) -> HeightOffset | None:
    """In a child of :func:`first_height_offset`: the height offset ``law``'s fit reads."""
    curve, fits, r, geometry = forked_state()
    return height_offset(curve, fits[law], r, **geometry)


def law_fits(curve: SurfaceCurve, laws: list[str], r: float, *, resample: bool = True,
             **geometry) -> dict[str, LawFit]:
    """:func:`fit_law` of each of ``laws`` to ``curve``, those that cannot be fitted (too few bins, no
    convergence) left out; side by side in forked processes (:class:`~uavturb.numerics.processes.ForkedPool`)
    where several are resampled (each refitted on every recording alone and every one left out)."""
    with ForkedPool((curve, r, resample, geometry)) as pool:
        done = pool.map(_law_fit_in_child, laws) if resample else {}
    fits = {}
    for name in laws:  # in the order asked; those a child could not fit, fitted (or refused) here
        if name in done:  # its plotting function made here (a closure over the curve cannot come back)
            values = [done[name].params[k] for k in EFFECTS[name].params]
            fits[name] = replace(done[name], evaluate=law_on_curve(curve, name, values, r, **geometry))
            continue
        try:
            fits[name] = fit_law(curve, name, r, resample=resample, **geometry)
        except (InputError, ValueError, np.linalg.LinAlgError):
            continue
    return fits


def _law_fit_in_child(law: str) -> LawFit:
    """In a child of :func:`law_fits`: ``law`` fitted to the curve, without its plotting function (a closure, which
    cannot be sent back)."""
    curve, r, resample, geometry = forked_state()
    return replace(fit_law(curve, law, r, resample=resample, **geometry), evaluate=None)


def _why(fit: LawFit, d: np.ndarray, res: np.ndarray, spec) -> str:
    worst = int(np.argmax(np.abs(res)))
    verdict = ("its shape fits the measured curve" if fit.law_fits else
               "its shape does not fit the measured curve")
    level = "" if fit.level == 1.0 else f" and a far level of {fit.level:.4f}"
    rng = "" if fit.in_range else (f"; {spec.physical_range.quantity} lies outside its physical range "
                                   f"[{spec.physical_range.lo:.3g}, {spec.physical_range.hi:.3g}]")
    return (f"{fit.law} with {fit.describe()}{level} gives chi^2/dof = "
            f"{fit.chi2_dof:.2f} over {len(d)} bins ({fit.dof} dof; a fitting law gives about 1, the threshold is "
            f"{LAW_FITS_CHI2_DOF:g}): {verdict} (largest miss {abs(res[worst]):.1f} standard errors at "
            f"{d[worst]:.3f} m){rng}.")


def surface_curve_report(curve: SurfaceCurve, fits: dict[str, LawFit], chosen: str | None = None) -> dict | None:
    """``report.json``'s ``surface_curve`` (``gap-report.md``), for the law ``chosen`` (default: the lowest
    ``chi2/dof``), with the other laws under ``alternatives``; None where there are no bins."""
    if not curve.bins:
        return None
    if not fits:
        raise InputError("surface curve", "no law was fitted to the surface curve")
    chosen = chosen if chosen is not None else min(fits, key=lambda k: fits[k].chi2_dof)
    if chosen not in fits:
        raise InputError("surface curve", f"'{chosen}' was not fitted (fitted: {', '.join(fits)})")
    fit = fits[chosen]

    def law_entry(lf: LawFit) -> dict:
        params = dict(lf.params) | ({} if lf.level == 1.0 else {"level": lf.level})
        stderr = dict(lf.stderrs) | ({} if lf.level == 1.0 else {"level": lf.level_stderr})
        return {"law": lf.law, "params": params, "stderr": stderr, "chi2_dof": lf.chi2_dof, "dof": lf.dof,
                "p_value": lf.p_value, "law_fits": lf.law_fits, "in_range": lf.in_range, "why": lf.why,
                "values": [float(v) for v in lf.values]}

    bins = [{"d_m": b.d_m, "n": b.n, "ratio": b.ratio, "stderr": b.stderr, "law": float(v), "lo_m": b.lo,
             "hi_m": b.hi, "blocks": b.blocks, "recordings": list(b.recordings)}
            | ({"stderr_resolution": b.stderr_resolution} if b.stderr_resolution > 0 else {})
            for b, v in zip(curve.bins, fit.values)]
    head = law_entry(fit)
    return {"surface": "ground", "bins": bins, "law_fits": fit.law_fits, "why": fit.why, "law": chosen,
            "params": head["params"], "stderr": head["stderr"], "chi2_dof": fit.chi2_dof, "dof": fit.dof,
            "far_m": curve.far_m, "notes": list(curve.notes),
            "alternatives": [law_entry(lf) for name, lf in fits.items() if name != chosen]}


def law_in_bins(curve: SurfaceCurve, law: str, value, r: float, **geometry) -> np.ndarray:
    """(B,) the surface law ``law`` at its parameter ``value`` (a sequence in its parameters' order for a law
    with several) in each bin of ``curve`` (averaged over the bin's samples and normalised as the curve is, as
    :func:`fit_law` compares it)."""
    return _BinnedLaw(curve, EFFECTS[law], r, geometry, False).bins(_fixed_level(value))


def law_band(curve: SurfaceCurve, law: str, params: dict[str, float], stderr: dict[str, float], r: float,
             **geometry) -> np.ndarray:
    """(B,) how far the surface law ``law`` moves in each bin of ``curve`` (as :func:`law_in_bins` computes it)
    within the stated errors ``stderr`` of its parameters ``params``: per parameter, half the change between its
    value one error below and one above (the others held; within its search bounds,
    :attr:`~uavturb.physics.effects.EffectSpec.shape_bounds`), the parameters' in quadrature; nan where an error is
    not finite. Beside the measured ratio it says whether the named law is known to 2 % of thrust in a bin (a
    take-off's mu = 6.3 +- 3.1 is not)."""
    spec = EFFECTS[law]
    values = np.array([params[k] for k in spec.params], float)
    total = np.zeros(len(curve.bins))
    for j, k in enumerate(spec.params):
        se = float(stderr.get(k, np.nan))
        if not np.isfinite(se):
            return np.full(len(curve.bins), np.nan)
        bottom, top = spec.shape_bounds[j] if len(spec.shape_bounds) > j else (-np.inf, np.inf)
        lo, hi = values.copy(), values.copy()
        lo[j], hi[j] = max(values[j] - se, bottom), min(values[j] + se, top)
        total += ((law_in_bins(curve, law, hi, r, **geometry) - law_in_bins(curve, law, lo, r, **geometry)) / 2) ** 2
    return np.sqrt(total)


def law_on_curve(curve: SurfaceCurve, law: str, value, r: float, **geometry) -> Callable[[np.ndarray], np.ndarray]:
    """``d [m] -> ratio``: the surface law ``law`` at ``value`` (a sequence in its parameters' order for a law with
    several) normalised as ``curve`` is (its far level divided out), for a plot beside the curve's bins."""
    binned, z = _BinnedLaw(curve, EFFECTS[law], r, geometry, False), _fixed_level(value)
    return lambda d: binned.at(np.asarray(d, float), z)


def _fixed_level(value) -> np.ndarray:
    """A law's parameters ``value`` (one number or a sequence) with the far level 1 after them, as
    :class:`_BinnedLaw` reads them."""
    return np.append(np.atleast_1d(value), 1.0).astype(float)


#: m/s^2 and deg: hover-like samples for the measured curve (the law is a steady-flow law)
HOVER_ACCELERATION = 1.5
HOVER_TILT_DEG = 15.0
#: share of the rotors' hover induced velocity (:func:`~uavturb.physics.ground_effect.hover_induced_velocity`) over
#: which a sample's axial speed (along z_B) makes it no hover: a climb through the rotors' own inflow lowers the thrust
#: per rotor speed squared, a descent raises it (Neural-Swarm's random walks 15-40 cm up, where the floor adds little:
#: -3.4 % per m/s on both Crazyflies, 0.15-0.21 per induced velocity), so 5 % keeps that under about 1 %; the 32 g
#: take-off's climbs through 9-15 cm at 0.2-0.6 m/s read 2-4 % under its hovers and bent its curve under 1 there
HOVER_INFLOW_SHARE = 0.05
#: 1/s: the modelled thrust's rate of change, as a share of itself, over which a sample is no hover (a lag or a
#: late stream of 50 ms the model lacks misreads its thrust by more than 2.5 %)
HOVER_THRUST_RATE = 0.5
#: largest difference [share of thrust] between the named law and the measured ratio in a bin for the
#: report to call them in agreement
AGREEMENT = 0.02
#: systematic terms of the values in time that a law named from the curve at its own values keeps: what a late or
#: slow stream does to the law's values moves the steady hovers' thrust and heights as well
CARRIED_TERMS = ("rotor_timing", "stream_rate")


def law_named_from_curve(effects: list[dict[str, Any]], curve_report: dict | None, curve: SurfaceCurve | None,
                         curve_fits: dict[str, LawFit], data: GapData, facts: FlightFacts, height_uncertainty: float
                         ) -> tuple[list[dict[str, Any]], dict | None]:
    """``effects`` and the report's ``surface_curve`` with a surface law the finder named replaced by a better
    law of the registry where the named law's shape does not fit the measured curve and the other's does
    (``effects.md``: "a law from the literature that fits better may be named instead").

    The finder found the surface effect in time (its held-out gain stays with the entry) with a law whose shape
    misses the curve; another law of the same surface, which the finder tried in time without beating it on
    held-out forces beyond noise (a shape differs most near the floor, where a flight spends a few seconds),
    is named with the values fitted to the measured curve, whose honest errors cover the spread between
    recordings and the height reference (:func:`uavturb.gap.surface_laws.curve_budget`). The law it replaces
    is kept under ``time_domain``. Among several laws that fit, the lowest ``chi2/dof``; only laws inside their physical
    range, whose lift stands :data:`~uavturb.gap.uncertainty.HONEST_Z` statistical errors from zero (as every
    named effect's), and that describe every bin within :data:`~uavturb.gap.surface_laws.AGREEMENT` (2 % of
    thrust) and closer than the finder's law at its value: a ``chi2/dof`` under 3 alone lets a law miss a bin with a
    large error by 8 % (a simulated Cheeseman-Bennett flight whose lowest bin read 1.19 for the law's 1.10). The same
    law at the curve's values keeps the values in time's :data:`CARRIED_TERMS` (rotor timing, stream rate) in its
    error; another law's parameters are not the same numbers, and its error is the curve's. Called by
    the finder (:mod:`uavturb.gap.finder`) on its named effects' entries (``effects``) and its ``surface_curve``."""
    if curve_report is None or curve is None:
        return effects, curve_report
    _, ratio, _ = curve.columns()
    named = curve_report.get("named")  # the finder's law at its values in time, against the curve
    named_miss = float((named or {}).get("largest_difference", np.inf))

    def describes(f) -> bool:  # within AGREEMENT of every bin, and closer than the finder's own law
        miss = float(np.nanmax(np.abs(ratio - f.values)))
        return miss <= AGREEMENT and miss < named_miss

    out = []
    for e in effects:
        own = curve_fits.get(e["name"])
        spec = EFFECTS[e["name"]]
        if spec.surface is None or own is None:
            out.append(e)
            continue
        if own.law_fits:  # the shape fits: the curve's values where the finder's miss a bin and the curve's do not
            better = [own] if named is not None and named_miss > AGREEMENT and own.in_range and describes(own) else []
        else:
            better = [f for n, f in curve_fits.items() if n != e["name"]
                      and EFFECTS[n].surface == spec.surface and f.law_fits and f.in_range and describes(f)]
        if not better:
            out.append(e)
            continue
        fit = min(better, key=lambda f: f.chi2_dof)
        budget = curve_budget(curve, fit, data.rotor_radius, height_uncertainty, **data.geometry)
        if not presence_z(budget, fit.params, EFFECTS[fit.law].presence_params) >= HONEST_Z:
            out.append(e)  # its lift not pinned (an 18 s take-off at 50 Hz: A = 1.33 +- 1.23): the finder's law stays
            continue
        if fit is own:
            budget = with_systematic(budget, "surface_curve", {k: abs(float(v) - float(e["params"][k])) / 2.0
                                                             for k, v in fit.params.items()})
            for term in CARRIED_TERMS:  # what the streams' timing and rate do to the law's values, in its units
                found = {k: b[term] for k, b in e.get("error_budget", {}).items() if term in b}
                budget = with_systematic(budget, term, found) if found else budget
            why = (f"The finder found the effect in time at {_values_text(e['params'])}, which misses the measured "
                   f"surface curve by {100 * named_miss:.1f} % of thrust in a bin; the law's shape fits the curve "
                   f"(chi^2/dof {fit.chi2_dof:.1f}) and its fit there describes every bin within "
                   f"{100 * AGREEMENT:.0f} %, so these values are the curve's (the steady hovers the law describes; "
                   f"the flights' climbs, descents and thrust steps lean on the values in time), and their error "
                   f"carries half the difference.")
        else:
            why = (f"The finder found the effect in time with {e['name']}, whose held-out gain this entry reports; "
                   f"that law's shape misses the measured surface curve (chi^2/dof {own.chi2_dof:.1f}) where this "
                   f"one fits it ({fit.chi2_dof:.1f}), so these values are this law's fit to the curve.")
        out.append({
            "name": fit.law, "params": dict(fit.params), "stderr": honest_stderr(budget),
            "explanation": f"{explanation(fit.law, fit.params, facts)} {why}",
            "heldout_rmse_before_N": e["heldout_rmse_before_N"], "heldout_rmse_after_N": e["heldout_rmse_after_N"],
            "z_heldout": e.get("z_heldout"), "error_budget": budget, "named_from": "surface_curve",
            "time_domain": {k: e[k] for k in ("name", "params", "stderr", "error_budget", "named_for") if k in e},
        })
        curve_report = _curve_report_naming(curve, curve_fits, fit, own, e["params"])
    return out, curve_report


def _curve_report_naming(curve: SurfaceCurve, curve_fits: dict[str, LawFit], fit: LawFit, replaced: LawFit,
                         replaced_params: dict[str, float]) -> dict:
    """The report's ``surface_curve`` for the law ``fit`` named from the measured curve in place of ``replaced``
    (the same law where only its values, ``replaced_params``, missed the curve)."""
    report = surface_curve_report(curve, curve_fits, fit.law)  # its bins' law: this fit's values
    for b in report["bins"]:
        b["law_fitted_to_curve"] = b["law"]  # named from this fit: the same values
    worst = float(np.nanmax(np.abs([b["ratio"] - b["law"] for b in report["bins"]])))
    report["named"] = {"law": fit.law, "params": dict(fit.params), "largest_difference": worst,
                       "agrees": worst <= AGREEMENT}
    if fit is replaced:
        report["why"] += (f" The finder's {fit.law} at its values in time ({_values_text(replaced_params)}) missed "
                          f"this curve by more than {100 * AGREEMENT:.0f} % of thrust in a bin; the law is named at "
                          f"its fit to the curve, differing from the measured ratio by at most {100 * worst:.1f} %.")
    else:
        report["why"] += (f" The finder's {replaced.law} does not fit this curve (chi^2/dof {replaced.chi2_dof:.2f}); "
                          f"{fit.law} does and is named, differing from the measured ratio by at most "
                          f"{100 * worst:.1f} % of thrust in a bin.")
    return report


def finder_surface_curve(data: GapData, final: ModelFit, *, resample: bool = True
                         ) -> tuple[dict | None, SurfaceCurve | None, dict[str, LawFit]]:
    """The ``surface_curve`` of a gap report (``gap-report.md``), measured on the finder's samples.

    The thrust the rotors must make is the measured force along the body z axis less every force of
    ``final`` (a :class:`~uavturb.gap.fit.ModelFit`) that is not a surface law; the modelled thrust is
    ``k_T`` times each recording's thrust level and (lagged) ``sum(w^2)``. Every surface law of the
    registry that acts below is fitted to the bins; the bins' ``law`` is the law ``final`` names, at the
    finder's value (where it names one), else the best-fitting law.
    """
    if not np.any(np.isfinite(data.d_down)):
        return None, None, {}
    surface = {e for e in final.effects if EFFECTS[e].surface == "d_down"}
    rest = ModelFit(final.effects - surface, {e: v for e, v in final.nonlinear.items() if e not in surface},
                    final.coef, final.stderr, final.rmse)
    zb = data.R[:, :, 2]
    D, _ = dependent_columns(data, set(rest.effects), _nl_values(rest.nonlinear))
    thrust_direction = D[:, 0].reshape(3, -1).T  # (K, 3): S_eff R e_z, the k_T column without surface laws
    modelled = final.coef["k_T"] * np.einsum("ki,ki->k", thrust_direction, zb)  # (K,) N along z_B
    needed = modelled + np.einsum("ki,ki->k", data.y - rest.predict(data), zb)
    acc = data.y / data.mass - np.array([0.0, 0.0, GRAVITY])
    hover = (np.linalg.norm(acc, axis=1) < HOVER_ACCELERATION) & (zb[:, 2] > np.cos(np.radians(HOVER_TILT_DEG))) \
        & steady_thrust(modelled, data.t, data.group)
    slow = slow_axially(data)
    try:
        curve = measured_curve(data.d_down, needed, modelled, data.group, hover=hover & slow, t=data.t,
                               r=data.rotor_radius, names=data.names,
                               resolution=resolution_error(data.rotor_quantum, data.rotor_speeds))
    except InputError:
        return None, None, {}
    curve.notes.extend(_hover_notes(curve, data, needed / modelled, hover, slow,
                                    "battery_voltage" in final.effects))
    if not curve.bins:
        if len(curve.d) >= MIN_BIN_N:  # (fewer: measured_curve's own note says so)
            curve.notes.append(too_few_bins_note(curve))
        return None, curve, {}
    geometry = data.geometry
    below = [name for name, spec in EFFECTS.items() if spec.surface == "d_down" and spec.ratio is not None]
    fits = law_fits(curve, below, data.rotor_radius, resample=resample, **geometry)
    if not fits:
        curve.notes.append(too_few_bins_note(curve))
        return None, curve, {}
    named = sorted(surface)
    chosen = named[0] if named and named[0] in fits else None
    report = surface_curve_report(curve, fits, chosen)
    if named:
        spec = EFFECTS[named[0]]
        params, _ = final.effect_params(named[0])
        values = [params[k] for k in spec.params]
        # normalised as the measured curve is (law_in_bins), by the law's value far from the floor (the
        # finder's k_T carries the law's far tail)
        law = law_in_bins(curve, named[0], values, data.rotor_radius, **geometry)
        for b, v in zip(report["bins"], law):
            b["law_fitted_to_curve"], b["law"] = b["law"], float(v)
        worst = float(np.nanmax(np.abs([b["ratio"] - b["law"] for b in report["bins"]])))
        report["named"] = {"law": named[0], "params": dict(params), "largest_difference": worst,
                           "agrees": worst <= AGREEMENT}
        report["why"] += (f" The named {named[0]} at the finder's {_values_text(params)} differs from the measured "
                          f"ratio by at most {100 * worst:.1f} % of thrust in a bin.")
    return report, curve, fits


def _hover_notes(curve: SurfaceCurve, data: GapData, raw: np.ndarray, hover: np.ndarray, slow: np.ndarray,
                 voltage_named: bool) -> list[str]:
    """The measured curve's notes on its hover samples: how many climbed or descended too fast (``hover`` but not
    ``slow``, :func:`slow_axially`), and where the far samples' thrust level follows the battery's voltage
    (:func:`~uavturb.gap.surface_curve.voltage_drift`; not where ``battery_voltage`` is named, which takes it off).
    ``raw`` (K,): thrust needed over modelled."""
    notes = []
    if data.voltage_dev is not None and not voltage_named and curve.bins:
        drift = voltage_drift(curve, data.d_down, raw, data.voltage_dev, data.group, data.t, hover & slow)
        if drift is not None:
            notes.append(
                f"the far samples' thrust per rotor speed squared follows the battery's voltage within each recording "
                f"({100 * drift['slope_per_V']:+.2g} ± {100 * drift['stderr_per_V']:.1g} % per volt, which no named "
                f"effect takes off), and the bins were flown at other voltages than the far samples: that moves "
                f"them by up to {100 * drift['largest']:+.1f} % of thrust (at {drift['at_m']:.3f} m), which the "
                f"curve does not correct")
    axial = int(np.sum(hover & ~slow & (data.d_down <= curve.far_m)))
    if axial:
        notes.append(f"{axial} otherwise hover-like samples under {curve.far_m:.2f} m climbed or descended faster "
                     f"than {HOVER_INFLOW_SHARE * _induced_velocity(data):.2g} m/s ({100 * HOVER_INFLOW_SHARE:.0f} % "
                     f"of the rotors' hover induced velocity) and are left out: axial flight changes the rotors' "
                     f"inflow, and so their thrust per speed squared")
    return notes


def slow_axially(data: GapData) -> np.ndarray:
    """(K,) bool: samples whose speed along the body z axis is under :data:`HOVER_INFLOW_SHARE` of the rotors'
    hover induced velocity (momentum theory on ``data``'s mass, rotor count and radius): a surface law is a hover
    law, and axial flight changes the rotors' inflow, so their thrust per speed squared, as the floor does."""
    return np.abs(np.einsum("ki,ki->k", data.v, data.R[:, :, 2])) < HOVER_INFLOW_SHARE * _induced_velocity(data)


def _induced_velocity(data: GapData) -> float:
    """m/s, the rotors' hover induced velocity of ``data``'s vehicle (momentum theory)."""
    return hover_induced_velocity(float(data.mass), data.rotor_speeds.shape[1], float(data.rotor_radius))


def steady_thrust(thrust: np.ndarray, t: np.ndarray, group: np.ndarray) -> np.ndarray:
    """(K,) bool: samples whose ``thrust`` (K,) [N] changes by less than :data:`HOVER_THRUST_RATE` of itself per
    second (``t`` (K,) s, each recording's ``group`` apart). A surface law is a steady-flow law: where the rotors
    speed up or slow down fast (a lift-off, a landing's flare), a lag or a late stream that the model lacks
    misreads the thrust, and near the floor those rows are the low bins' (the 32 g take-off's lowest bin read
    1.107 with them, 1.089 without; its steady hovers there 1.07-1.08)."""
    rate = np.zeros(len(thrust))
    for g in np.unique(group):
        rows = np.flatnonzero(group == g)
        if len(rows) > 1:
            rate[rows] = np.gradient(thrust[rows], t[rows])
    return np.abs(rate) <= HOVER_THRUST_RATE * np.abs(thrust)


def _values_text(params: dict[str, float]) -> str:
    """``mu = 6.36`` or ``A = 0.401, lam = 1.72``."""
    return ", ".join(f"{k} = {v:.3g}" for k, v in params.items())
