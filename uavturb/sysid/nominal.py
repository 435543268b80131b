"""The nominal model's own unknowns, anchored so that they cannot swallow an effect.

Two unknowns of the nominal model trade against the effects the gap finder looks for:

**Accelerometer bias.** Along the thrust axis a constant ``b_z`` is nearly the same regressor as the
thrust coefficient at hover (``m R e_z`` against ``S R e_z``, ``S`` the sum of squared rotor speeds):
a joint fit lets ``b_z`` take part of the thrust and of every law along it (the ground effect). On
real flights that joint fit put ``k_T`` 8-57 % below what ``uavturb identify`` finds, with ``b_z``
of 0.65-5.8 m/s^2. Where a recording has an IMU *and* motion capture, the bias is not a fit
parameter at all: it is what the accelerometer reads beyond the specific force the motion capture
shows, ``b = mean(a_imu - R^T (v_dot + g e_z))`` in B
(:func:`uavturb.sysid.accelerometer.anchored_bias`), measured without any model of the thrust, so it
cannot trade with one. ``identify`` takes the same bias off its IMU rows, so the two agree.

**Thrust level.** Recordings of one vehicle made on different days, batteries or propellers differ
in thrust per rotor speed squared by a few percent (``recordings.md``). Pooled under one ``k_T``,
the difference leaks into whatever else differs between the recordings: on real Crazyflie
sessions 3-5 % apart it moved the ground effect's ``mu`` from about 4.6 to 6.45 and invented a
battery sag. :func:`thrust_levels` measures each recording's level far from any surface (where no
surface law acts) and, where the levels differ beyond their honest errors and by more than
:data:`LEVEL_PRACTICAL` (``gap-report.md``: "each gets its own thrust coefficient"), each
recording's rows carry their level. Where fewer than two recordings fly beyond a surface law's reach
(a large vehicle in a low room: a multirotor law reaches 1.3 m on a 1.5 kg hexarotor), the levels are
measured *at matched heights* instead (:func:`matched_height_levels`): whatever a surface adds at a
height, it adds to every recording alike, so the recordings' ratios at the same heights give their
relative levels without any law, and so without swallowing one.

**Thrust map.** The nominal thrust is ``k_T sum(w^2)`` in the *recorded* speeds. Commanded speeds are
often a normalised command times a scale (``rotor_speed_scale``), while a motor's true speed is affine
in its command, ``w = a + b u`` with an idle speed ``a``: the recorded speeds are then off by an
offset, ``w_true ~ beta (w + delta)``, exact at hover and wrong as the speeds move. Near the floor the
rotors turn slower, so the thrust there is underestimated and the ground effect overestimated (a
simulated idle of a quarter of the hover speed read an exponential law 6 % of thrust too strong at
1.3 rotor radii, with a curve that fitted it at chi^2/dof 0.2). :func:`speed_offset` measures
``delta`` as what makes thrust per ``sum((w + delta)^2)`` constant *within cells* of one recording at one
height (:func:`offset_cells`): whatever a surface adds at a height it adds to the whole cell, so the
speeds' rise and fall as the vehicle manoeuvres reads the offset without any surface law (a large vehicle
in a low room never leaves every law's reach). The finder carries what it does to each named effect in
its error budget (``thrust map``, :mod:`uavturb.gap.uncertainty`). It is a reading, not a correction: the
speeds vary by a few percent in flight, and other physics that depends on the thrust level (inflow in a
climb) leans the same way.

Where the battery's voltage is logged, the offset is read jointly with the thrust's slope in the voltage,
and a voltage that sags under load moves thrust per command squared as the offset does: only the voltage's
changes that the load does not make tell the two apart, and its noise pulls the slope read towards 0, and
the offset up. The reading's error carries the **voltage noise** term: how far the offset moves where the
slope is read with the noise the battery stream itself shows taken into account (:func:`speed_offset`).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Callable

import numpy as np

from uavturb.numerics.blocks import block_labels, jackknife_se
from uavturb.sysid.accelerometer import BLOCK_S

#: relative difference of thrust levels under which recordings share one thrust coefficient
LEVEL_PRACTICAL = 0.005
#: chi^2 per degree of freedom of the levels' differences above which they differ (with honest errors)
LEVEL_CHI2 = 9.0
#: rows a recording needs far from surfaces to measure its level there
LEVEL_MIN_ROWS = 50
#: most height bins (pooled quantiles of the rotor plane's height) of :func:`matched_height_levels`; fewer
#: where the recordings are short (a bin per :data:`MATCHED_ROWS_PER_BIN` rows of the shortest), never under 3
MATCHED_BINS = 8
MATCHED_ROWS_PER_BIN = 40
#: rows a recording needs in a height bin to measure its level there
MATCHED_MIN_ROWS = 20
#: standard errors from zero from which the thrust per rotor speed squared is read to follow the battery's voltage
#: within the recordings (:func:`level_voltage_slope`), so that the levels are measured with the thrust taken back
#: to each recording's mean voltage: a voltage falling through a flight had made the cells flown late read low, and
#: two flights of one vehicle without any level difference, commanded speeds on a battery sagging 8 % under load,
#: read levels 0.8 % apart, which then kept the voltage's law off the held-out recordings (z 1.9 against 13-23 on
#: other seeds) and named a sag in time in its place
LEVEL_VOLTAGE_Z = 3.0
#: rows a 1 s block needs to join :func:`level_voltage_slope`, and its height bins (pooled quantiles)
LEVEL_VOLTAGE_BLOCK_ROWS = 5
LEVEL_VOLTAGE_BINS = 16


@dataclass(frozen=True)
class ThrustLevels:
    """Each recording's thrust per rotor speed squared, relative to their pooled value.

    Attributes
    ----------
    k_T : (G,) N/(rad/s)^2, each recording's thrust coefficient far from surfaces (nan: not measurable)
    stderr : (G,) N/(rad/s)^2, from 1 s block ratios
    level : (G,) -, the level applied to each recording's thrust (all 1 where they do not differ)
    differ : whether the recordings differ in thrust level (and each got its own)
    why : one sentence with the numbers
    basis : where the levels were measured: ``"far from surfaces"``, ``"matched heights"`` (``k_T`` then
        holds each recording's coefficient at those heights, the surfaces' common lift included) or
        ``"none"``
    """

    k_T: np.ndarray
    stderr: np.ndarray
    level: np.ndarray
    differ: bool
    why: str
    basis: str = "far from surfaces"

    @property
    def relative(self) -> np.ndarray:
        """(G,) -, each recording's measured level over their weighted mean (nan where not measured)."""
        ok = np.isfinite(self.k_T) & np.isfinite(self.stderr)
        if not ok.any():
            return np.full(len(self.k_T), np.nan)
        w = 1.0 / np.maximum(self.stderr[ok], 1e-300) ** 2
        return self.k_T / float(np.sum(w * self.k_T[ok]) / np.sum(w))

    @property
    def spread_percent(self) -> float:
        """%, range of the measured levels (max - min over their mean); 0 for one recording."""
        k = self.k_T[np.isfinite(self.k_T)]
        return float(100.0 * np.ptp(k) / np.mean(k)) if len(k) > 1 else 0.0


def _level_of(y_thrust: np.ndarray, S: np.ndarray, t: np.ndarray) -> tuple[float, float]:
    """(k [N/(rad/s)^2], stderr): ratio estimator ``sum(y) / sum(S)`` and its error from block sums."""
    labels = block_labels(t, BLOCK_S)
    _, inv = np.unique(labels, return_inverse=True)
    ys, ss = np.bincount(inv, weights=y_thrust), np.bincount(inv, weights=S)
    k = float(ys.sum() / ss.sum())
    B = len(ys)
    if B < 4:
        return k, float("inf")
    # linearised ratio estimator over blocks: var(k) = sum((y_b - k S_b)^2) / S^2 * B / (B - 1)
    return k, float(np.sqrt(np.sum((ys - k * ss) ** 2) * B / (B - 1)) / ss.sum())


def _judged(k: np.ndarray, se: np.ndarray, names: list[str], basis: str, where: str) -> ThrustLevels:
    """Whether measured levels ``k`` (G,) with errors ``se`` differ: chi^2 of their differences over
    :data:`LEVEL_CHI2` per degree of freedom *and* a spread over :data:`LEVEL_PRACTICAL`; ``where`` says
    where they were measured, for the sentence."""
    ok = np.isfinite(k) & np.isfinite(se)
    level = np.ones(len(k))
    w = 1.0 / np.maximum(se[ok], 1e-300) ** 2
    mean = float(np.sum(w * k[ok]) / np.sum(w))
    chi2_dof = float(np.sum(w * (k[ok] - mean) ** 2) / (ok.sum() - 1))
    spread = float(np.ptp(k[ok]) / mean)
    listing = ", ".join(f"{n} {100 * (kg / mean - 1):+.1f} %" for n, kg, o in zip(names, k, ok) if o)
    differ = chi2_dof > LEVEL_CHI2 and spread > LEVEL_PRACTICAL
    if differ:
        level[ok] = k[ok] / mean
        why = (f"the recordings differ in thrust per rotor speed squared {where} ({listing}; "
               f"chi^2/dof = {chi2_dof:.1f}): each gets its own thrust coefficient")
    else:
        why = (f"the recordings' thrust levels {where} agree ({listing}; chi^2/dof = {chi2_dof:.1f}, "
               f"spread {100 * spread:.1f} %): one thrust coefficient")
    return ThrustLevels(k, se, level, differ, why, basis)


def matched_height_levels(group: np.ndarray, t: np.ndarray, y_thrust: np.ndarray, S: np.ndarray,
                          height: np.ndarray, use: np.ndarray, bins: int = MATCHED_BINS
                          ) -> tuple[np.ndarray, np.ndarray, int]:
    """Each recording's thrust coefficient at matched heights, without a surface law.

    In each height bin ``b`` and recording ``g`` the ratio estimator ``k_gb = sum(y) / sum(S)`` (error
    from 1 s blocks) is, whatever the surface adds at that height, ``k_T level_g (1 + G_b)``; the
    weighted least-squares fit of ``log k_gb = a_g + c_b`` over the bins that two or more recordings
    share gives ``exp(a_g)``, each recording's level up to one common factor, and its error.

    Parameters
    ----------
    group : (K,) int, recording index; t : (K,) s
    y_thrust : (K,) N, the force along the body z axis the rotors made; S : (K,) (rad/s)^2
    height : (K,) m, the rotor plane's height over the surface below
    use : (K,) bool, rows in flight out of every other surface's reach
    bins : most height bins, pooled quantiles of ``height[use]`` (fewer for short recordings)

    Returns
    -------
    k : (G,) N/(rad/s)^2, each recording's coefficient at the matched heights, scaled so that their
        weighted mean is the pooled ratio over the cells used (nan: no shared bin)
    stderr : (G,) N/(rad/s)^2
    shared : bins that two or more recordings share
    """
    G = int(group.max()) + 1 if len(group) else 0
    k, se = np.full(G, np.nan), np.full(G, np.nan)
    ok_rows = use & np.isfinite(height) & (S > 0)
    shortest = int(np.bincount(group[ok_rows], minlength=G).min()) if G else 0
    bins = max(3, min(bins, shortest // MATCHED_ROWS_PER_BIN))
    if G < 2 or shortest < 3 * MATCHED_MIN_ROWS:
        return k, se, 0
    edges = np.unique(np.quantile(height[ok_rows], np.linspace(0.0, 1.0, bins + 1)))
    cell_bin = np.clip(np.searchsorted(edges, height, side="right") - 1, 0, len(edges) - 2)
    cells = []  # (g, b, log k, se of log k, sum y, sum S)
    for b in range(len(edges) - 1):
        for g in range(G):
            m = ok_rows & (group == g) & (cell_bin == b)
            if m.sum() < MATCHED_MIN_ROWS:
                continue
            kc, sc = _level_of(y_thrust[m], S[m], t[m])
            if np.isfinite(sc) and kc > 0 and sc > 0:
                cells.append((g, b, np.log(kc), sc / kc, y_thrust[m].sum(), S[m].sum()))
    per_bin = np.bincount([c[1] for c in cells], minlength=len(edges) - 1) if cells else np.zeros(1, int)
    cells = [c for c in cells if per_bin[c[1]] >= 2]
    cells = _at_the_bins_heights(cells, group, t, y_thrust, S, height, ok_rows & (height > 0), cell_bin)
    groups = sorted({c[0] for c in cells})
    shared = sorted({c[1] for c in cells})
    if len(groups) < 2:
        return k, se, len(shared)
    gi, bi = {g: i for i, g in enumerate(groups)}, {b: i for i, b in enumerate(shared)}
    A = np.zeros((len(cells) + 1, len(groups) + len(shared)))
    y = np.zeros(len(cells) + 1)
    w = np.zeros(len(cells) + 1)
    for r, (g, b, lk, sl, _, _) in enumerate(cells):
        A[r, gi[g]] = 1.0
        A[r, len(groups) + bi[b]] = 1.0
        y[r], w[r] = lk, 1.0 / sl**2
    A[-1, :len(groups)] = 1.0  # the levels' logs sum to zero: one common factor is the bins'
    w[-1] = float(np.max(w[:-1])) * 1e6
    sw = np.sqrt(w)
    coef, *_ = np.linalg.lstsq(A * sw[:, None], y * sw, rcond=None)
    cov = np.linalg.pinv((A * w[:, None]).T @ A)
    a = coef[:len(groups)]
    a_se = np.sqrt(np.clip(np.diag(cov)[:len(groups)], 0.0, None))
    pooled = sum(c[4] for c in cells) / sum(c[5] for c in cells)
    scale = pooled / float(np.exp(a).mean())
    for g, i in gi.items():
        k[g], se[g] = scale * np.exp(a[i]), scale * np.exp(a[i]) * a_se[i]
    return k, se, len(shared)


def _within_cell_blocks(cell: np.ndarray, t: np.ndarray, y_thrust: np.ndarray, S: np.ndarray,
                        *covariates: np.ndarray) -> tuple[np.ndarray, ...] | None:
    """``(c, z, x_1, ...)`` on the 1 s blocks (:data:`BLOCK_S`, at least :data:`LEVEL_VOLTAGE_BLOCK_ROWS` rows) of
    each cell of rows (``cell`` (K,) int): each block's cell index ``c``, its ``log(sum y / sum S)`` and its mean of
    each of ``covariates`` (K,), each less its cell's mean over the cell's blocks, so that what a cell shares (a
    recording's level, a bin's lift) leaves them; None where fewer than 10 blocks."""
    _, blk = np.unique(np.stack([cell, block_labels(t, BLOCK_S)]), axis=1, return_inverse=True)
    blk = blk.ravel()
    n = np.bincount(blk)
    cell_of = np.zeros(len(n), np.int64)
    cell_of[blk] = cell
    keep = n >= LEVEL_VOLTAGE_BLOCK_ROWS
    if keep.sum() < 10:
        return None
    _, c = np.unique(cell_of[keep], return_inverse=True)
    counts = np.bincount(c)

    def within(a: np.ndarray) -> np.ndarray:  # less its cell's mean
        return a - (np.bincount(c, weights=a) / counts)[c]

    z = np.log(np.bincount(blk, weights=y_thrust)[keep] / np.bincount(blk, weights=S)[keep])
    return (c, within(z), *(within((np.bincount(blk, weights=x) / n)[keep]) for x in covariates))


def level_voltage_slope(group: np.ndarray, t: np.ndarray, y_thrust: np.ndarray, S: np.ndarray,
                        voltage_dev: np.ndarray, height: np.ndarray | None, use: np.ndarray) -> tuple[float, float]:
    """``(kappa [1/V], stderr)``: how thrust per rotor speed squared follows the battery's voltage within the
    recordings, ``y / S = k_g (1 + G(h)) (1 + kappa dV)``, read on 1 s blocks of the rows ``use``: each block's
    ``log(sum y / sum S)`` and mean ``dV`` less their cell's (one recording, one height bin of
    :data:`LEVEL_VOLTAGE_BINS` pooled quantiles of ``height``; rows without a finite height a bin of their own), and
    less what the block's mean ``log height`` explains within its cell, so that neither a recording's level nor a
    surface's lift enters it. A battery sagging under load is higher where a surface's lift unloads the rotors: with
    the height left within the bins, kappa on commanded speeds following the voltage by 12.9 % per volt read 21-28 %
    (8 bins), with it 12.1-13.6 % on six pairs of flights. ``(nan, nan)`` where too few blocks or no voltage change.

    Parameters
    ----------
    group : (K,) int; t : (K,) s; y_thrust : (K,) N; S : (K,) (rad/s)^2
    voltage_dev : (K,) V, each row's voltage minus its recording's mean
    height : (K,) m or None; use : (K,) bool
    """
    ok = use & np.isfinite(voltage_dev) & (S > 0) & (y_thrust > 0)
    if ok.sum() < 2 * LEVEL_MIN_ROWS:
        return float("nan"), float("nan")
    finite = ok & np.isfinite(height) & (height > 0) if height is not None else np.zeros(len(ok), bool)
    hbin = np.full(len(ok), LEVEL_VOLTAGE_BINS, np.int64)
    log_h = np.zeros(len(ok))
    if finite.any():
        edges = np.unique(np.quantile(height[finite], np.linspace(0.0, 1.0, LEVEL_VOLTAGE_BINS + 1)))
        hbin[finite] = np.clip(np.searchsorted(edges, height[finite], side="right") - 1, 0, max(len(edges) - 2, 0))
        log_h[finite] = np.log(height[finite])
    idx = np.flatnonzero(ok)
    found = _within_cell_blocks(group[idx] * (LEVEL_VOLTAGE_BINS + 1) + hbin[idx], t[idx], y_thrust[idx], S[idx],
                                voltage_dev[idx], log_h[idx])
    if found is None:
        return float("nan"), float("nan")
    c, z, x, h = found
    counts = np.bincount(c)
    shh = np.bincount(c, weights=h * h)
    for a in (z, x):  # less what the height explains within each cell
        a -= np.divide(np.bincount(c, weights=h * a), shh, out=np.zeros_like(shh), where=shh > 0)[c] * h
    sxx = float(np.sum(x * x))
    dof = len(z) - 2 * len(counts) - 1
    if sxx <= 0.0 or dof < 2:
        return float("nan"), float("nan")
    kappa = float(np.sum(x * z) / sxx)
    return kappa, float(np.sqrt(np.sum((z - kappa * x) ** 2) / dof / sxx))


def _at_the_bins_heights(cells: list[tuple], group: np.ndarray, t: np.ndarray, y_thrust: np.ndarray,
                         S: np.ndarray, height: np.ndarray, ok: np.ndarray, cell_bin: np.ndarray) -> list[tuple]:
    """:func:`matched_height_levels`' ``cells`` ``(g, b, log k, se of log k, sum y, sum S)``, each ``log k`` taken to
    its bin's height: less ``beta_b (log h_gb - log h_b)``, ``log h_gb`` the cell's mean log height (weighted by
    ``S``, as its ratio is), ``log h_b`` the mean of the bin's cells' and ``beta_b`` how ``log(y / S)`` follows the
    log height within the bin's cells (1 s blocks, each less its cell's mean), its error carried into the cell's.
    A bin is wide where a surface's lift is steep: two flights whose rows sat 0.085 and 0.096 m up on average in one
    bin read 22 % and 17 % of lift there, a level 4 % apart that neither has (seed 23's 45 s flights of
    ``gap-proof --suite conditions``). A bin with too few blocks to read its slope is left as it is."""
    out = list(cells)
    for b in sorted({c[1] for c in cells}):
        mine = [i for i, c in enumerate(cells) if c[1] == b]
        masks = {i: ok & (group == cells[i][0]) & (cell_bin == b) for i in mine}
        if any(m.sum() < MATCHED_MIN_ROWS for m in masks.values()):
            continue  # rows at no positive height: the bin is left as it is
        cell_h = {i: float(np.sum(S[m] * np.log(height[m])) / np.sum(S[m])) for i, m in masks.items()}
        rows = np.logical_or.reduce(list(masks.values()))
        found = _within_cell_blocks(group[rows], t[rows], y_thrust[rows], S[rows], np.log(height[rows]))
        if found is None:
            continue
        c, zz, xx = found
        sxx = float(np.sum(xx * xx))
        dof = len(zz) - len(np.unique(c)) - 1
        if sxx <= 0.0 or dof < 3:
            continue
        beta = float(np.sum(xx * zz) / sxx)
        beta_se = float(np.sqrt(np.sum((zz - beta * xx) ** 2) / dof / sxx))
        ref = float(np.mean([cell_h[i] for i in mine]))
        for i in mine:
            g, _, lk, sl, ys, ss = cells[i]
            dh = cell_h[i] - ref
            out[i] = (g, b, lk - beta * dh, float(np.hypot(sl, beta_se * dh)), ys, ss)
    return out


def thrust_levels(group: np.ndarray, t: np.ndarray, y_thrust: np.ndarray, S: np.ndarray, far: np.ndarray,
                  names: list[str], height: np.ndarray | None = None, matched: np.ndarray | None = None,
                  voltage_dev: np.ndarray | None = None) -> ThrustLevels:
    """Each recording's thrust coefficient on its rows far from surfaces (``far``), or, where fewer than
    two recordings have such rows, at matched heights (:func:`matched_height_levels` on the rows
    ``matched`` binned by ``height``), and whether they differ: chi^2 of their differences over
    :data:`LEVEL_CHI2` per degree of freedom *and* a spread over :data:`LEVEL_PRACTICAL`.

    With ``voltage_dev`` (K,) V, each row's battery voltage minus its recording's mean, where the thrust per rotor
    speed squared follows it within the recordings (:func:`level_voltage_slope`, :data:`LEVEL_VOLTAGE_Z` errors from
    zero and up), the levels are measured with the thrust taken back to each recording's mean voltage, as the
    ``battery_voltage`` law counts it; the sentence says so.

    Parameters
    ----------
    group : (K,) int, recording index; t : (K,) s
    y_thrust : (K,) N, the measured force along the body z axis (what the rotors must make)
    S : (K,) (rad/s)^2, sum of squared rotor speeds
    far : (K,) bool, rows in flight farther from every surface than a surface law reaches
    names : recording names, for the sentence
    height : (K,) m, the rotor plane's height over the surface below (for matched heights)
    matched : (K,) bool, rows out of reach of every surface but the one below (for matched heights)
    voltage_dev : (K,) V or None
    """
    if voltage_dev is not None:
        rows = far | matched if matched is not None else far
        kappa, kappa_se = level_voltage_slope(group, t, y_thrust, S, voltage_dev, height, rows)
        if kappa > 0.0 and kappa >= LEVEL_VOLTAGE_Z * kappa_se:
            levels = thrust_levels(group, t, y_thrust / (1.0 + kappa * voltage_dev), S, far, names, height, matched)
            said = (f"; measured with the thrust taken back to each recording's mean voltage: thrust per rotor speed "
                    f"squared follows the battery's voltage within the recordings by {100 * kappa:+.1f} ± "
                    f"{100 * kappa_se:.2g} % per volt")
            return replace(levels, why=levels.why + said)
    G = int(group.max()) + 1 if len(group) else 0
    k = np.full(G, np.nan)
    se = np.full(G, np.nan)
    for g in range(G):
        m = far & (group == g)
        if m.sum() >= LEVEL_MIN_ROWS:
            k[g], se[g] = _level_of(y_thrust[m], S[m], t[m])
    ok = np.isfinite(k) & np.isfinite(se)
    if ok.sum() >= 2:
        return _judged(k, se, names, "far from surfaces", "far from surfaces")
    if G >= 2 and height is not None:
        use = np.ones(len(group), bool) if matched is None else matched
        km, sm, shared = matched_height_levels(group, t, y_thrust, S, height, use)
        if (np.isfinite(km) & np.isfinite(sm)).sum() >= 2:
            return _judged(km, sm, names, "matched heights",
                           f"at matched heights ({shared} height bins flown in two or more recordings: a surface "
                           f"adds the same at the same height, so its lift cancels)")
    why = ("one recording: its thrust coefficient is fitted with the rest" if G == 1 else
           "fewer than two recordings fly far enough from surfaces, or share heights enough, to measure "
           "their thrust levels; they share one thrust coefficient")
    return ThrustLevels(k, se, np.ones(G), False, why, "none")


#: rad/s per rad/s of hover speed: the offsets :func:`speed_offset` searches (an idle speed up to half
#: the hover speed reads as delta up to 1 hover speed; a map bent the other way as negative)
OFFSET_SPAN = (-0.5, 1.0)
#: hover speeds: the offsets of commanded rotor speeds that a thrust map not read leaves open (no reading, or the
#: least residual at an end of :data:`OFFSET_SPAN`): from none to half the hover speed. Neural-Swarm's Crazyflies
#: read 0.06-0.54 of theirs where the reading counts (0.66 in the others' downwash); the blind probe's Crazyflie-like
#: commands with an idle of a third of the hover speed, flown only near the floor, left no reading and named
#: mu = 2.6 for a true 2 on a curve stated +- 0.034
UNREAD_OFFSET_SPAN = (0.0, 0.5)
#: time chunks of the rows for the jackknife of :func:`speed_offset`
OFFSET_CHUNKS = 10
#: rows :func:`speed_offset` needs, and each cell of :func:`offset_cells`
OFFSET_MIN_ROWS, OFFSET_CELL_ROWS = 200, 30
#: rotor radii over the floor from which rows join :func:`offset_cells` (Cheeseman-Bennett at the top of its
#: range, mu = 12, adds 2 % there) and the cells' width in height (a ratio: 5 %, across which that lift moves
#: by a tenth of itself, 0.2 % of thrust)
OFFSET_RADII, OFFSET_CELL_RATIO = 6.0, 1.05
#: |offset| / its jackknife error, and |offset| / hover speed, from which an offset counts: a smaller one moves
#: the thrust of a rotor turning 10 % slower than at hover (near the floor) by under 0.5 %, whatever its z
#: (the simulator's own flights, which have none, read 0.25 % of the hover speed at z 5.6 over an hour)
OFFSET_Z, OFFSET_PRACTICAL = 2.0, 0.025
#: |offset| / its jackknife error from which the recorded speeds are read moved by it (the finder runs again on
#: them): an idle speed in the command map read 44 errors from zero (48 +- 1 rad/s, truth 50) and had left a 30 ms
#: lag read as 54 ms; the Neural-Swarm walks' offsets (3-7 errors), which other physics that depends on the
#: thrust level may lean towards as well, only widen the errors
OFFSET_DECISIVE_Z = 10.0
#: k_V times the mean voltage [-] at which :func:`speed_offset` reads the offset where the battery's voltage is
#: known (``battery_voltage``'s physical range, 0-3, in steps of 0.1): a sag under load makes thrust per command
#: squared fall as thrust rises, as an idle speed does, and read alone the offset took it (a 32 g vehicle's idle
#: speed read three times the truth, 6 errors off)
OFFSET_VOLTAGE_GRID = tuple(float(x) for x in np.linspace(0.0, 3.0, 31))
#: where ``battery_sag`` is named (commanded speeds, no voltage): the shares of the thrust lost over the longest
#: recording at which the offset is read jointly with the sag (0-30 %): a sag in time makes thrust per command
#: squared fall as the commands rise to hold the vehicle up, as an idle speed does (a hexarotor's idle of 32 % of
#: its hover speed read 12 +- 2 %, and the sag s = 1.29e-3 +- 0.07e-3 /s for 1e-3)
OFFSET_SAG_GRID = tuple(float(x) for x in np.linspace(0.0, 0.3, 31))


@dataclass(frozen=True)
class SpeedOffset:
    """The recorded rotor speeds' offset (module docstring, **Thrust map**).

    Attributes
    ----------
    delta : rad/s, the offset that makes thrust per ``sum((w + delta)^2)`` constant within each cell
    stderr : rad/s, jackknife over :data:`OFFSET_CHUNKS` time chunks of the rows used, and the **voltage noise**
        term ``voltage_noise`` beside it (in quadrature)
    w_hover : rad/s, the median mean rotor speed of those rows
    rows : how many rows; cells : in how many cells
    sse_ratio : residual sum of squares at ``delta`` over that at 0 (how much of the thrust's scatter it explains)
    k_V : 1/V, the thrust per command squared's slope in the battery's voltage read with it (0: none known or read)
    at_bound : the least residual lies at an end of :data:`OFFSET_SPAN`: no offset within the plausible range steadies
        the thrust, and the reading is none (Neural-Swarm's swarm walks 0.5-1.3 m up, in the others' downwash, read
        +100 % of the hover speed with a jackknife error of 0: taken as 10 errors from zero, it moved k_T by 7-12 %)
    voltage_noise : rad/s, the **voltage noise** term of a reading with the battery's voltage: how far the offset
        moves where the voltage's slope is read with its noise taken into account (:func:`speed_offset`); 0 without
        a voltage, or where its noise is not known
    k_V_noise_free : 1/V, that slope (nan where the term is not read)
    """

    delta: float
    stderr: float
    w_hover: float
    rows: int
    cells: int
    sse_ratio: float
    k_V: float = 0.0
    at_bound: bool = False
    voltage_noise: float = 0.0
    k_V_noise_free: float = float("nan")

    @property
    def z(self) -> float:
        """``|delta| / stderr``; nan at a bound of the range searched, or with no spread over the jackknife."""
        if self.at_bound or not self.stderr > 0:
            return float("nan")
        return abs(self.delta) / self.stderr

    @property
    def counts(self) -> bool:
        """The offset is read inside the range searched, stands :data:`OFFSET_Z` errors from zero and is at least
        :data:`OFFSET_PRACTICAL` of the hover speed."""
        return bool(self.z >= OFFSET_Z) and abs(self.delta) >= OFFSET_PRACTICAL * self.w_hover

    @property
    def decisive(self) -> bool:
        """It counts and stands :data:`OFFSET_DECISIVE_Z` errors from zero: the speeds are read moved by it."""
        return self.counts and self.z >= OFFSET_DECISIVE_Z

    def open_interval(self) -> tuple[float, float]:
        """rad/s, the offsets this reading leaves open (the **thrust map** term's ends): none to the reading where
        it counts; one standard error either side of it where it does not (within :data:`OFFSET_SPAN`); and
        :func:`unread_interval` where it is none (at a bound)."""
        if self.at_bound or not np.isfinite(self.delta):
            return unread_interval(self.w_hover)
        if self.counts:
            return 0.0, self.delta
        lo, hi = (x * self.w_hover for x in OFFSET_SPAN)
        return max(lo, self.delta - self.stderr), min(hi, self.delta + self.stderr)


def stated_offset(found: SpeedOffset | None, ends: tuple[float, float]) -> float:
    """rad/s, the offset of the recorded (commanded) speeds at which the named effects and the measured surface
    curve are stated: where a reading leaves offsets open (``ends``: :meth:`SpeedOffset.open_interval`), their
    centre, whose half range their errors carry (**thrust map**): the reading halved where it counts short of
    decisive, the reading itself where it does not count but leaves :data:`OFFSET_PRACTICAL` of the hover speed or
    more either side. 0 elsewhere: where the reading leaves no offset that matters, where it is decisive (the whole
    analysis runs again on the speeds moved by it), and where there is no reading (none, or one at an end of the
    range searched): no data then move the speeds the vehicle's files declare, and the idle speeds left open
    (:func:`unread_interval`) bound the error only.

    Stated at 0, a value stood at an end of [0, delta] where the reading counts, and outside [delta - se, delta +
    se] where it does not, its error bar centred elsewhere: a blind study's simulated take-offs, commands idling at
    a quarter of the hover speed read counting but not decisively, named mu 19-44 % high, never low (an idle speed
    is never below 0), and Neural-Swarm's 32 g take-off stated mu at 0 for an interval of 127-675 rad/s. Moved to
    the unread interval's centre, a simulated hexarotor under a low ceiling, its commands exact, read kappa 1.15 for a
    true 2 (1.90 on the recorded speeds)."""
    if found is None or found.at_bound or not np.isfinite(found.delta):
        return 0.0
    if not (np.isfinite(ends[0]) and np.isfinite(ends[1])) or ends[0] == ends[1]:
        return 0.0
    if found.decisive or (not found.counts and ends[1] - ends[0] < 2 * OFFSET_PRACTICAL * found.w_hover):
        return 0.0
    return 0.5 * (float(ends[0]) + float(ends[1]))


def unread_interval(w_hover: float) -> tuple[float, float]:
    """rad/s, the offsets of commanded speeds hovering at ``w_hover`` [rad/s] that no reading narrows
    (:data:`UNREAD_OFFSET_SPAN`)."""
    return UNREAD_OFFSET_SPAN[0] * w_hover, UNREAD_OFFSET_SPAN[1] * w_hover


def moved_speeds(rotor_speeds: np.ndarray, delta: float, w_hover: float | None = None) -> np.ndarray:
    """Recorded rotor speeds ``rotor_speeds`` (K, N) [rad/s] read with an offset ``delta`` [rad/s] (an idle speed in
    the command map, module docstring, **Thrust map**): every turning rotor's ``w`` to ``w + delta``, or where the
    hover speed ``w_hover`` [rad/s] is given to ``(w + delta) w_hover / (w_hover + delta)``, the scale kept exact at
    the hover speed (what the records say there stays, so laws linear in the speeds, such as rotor drag, keep their
    units' meaning). Stopped rotors (0) stay stopped, and none is moved below 0."""
    w = np.asarray(rotor_speeds, float)
    scale = 1.0 if w_hover is None else float(w_hover) / (float(w_hover) + float(delta))
    return np.where(w > 0, np.maximum((w + float(delta)) * scale, 0.0), w)


def hover_speed(rotor_speeds: np.ndarray) -> float:
    """rad/s, the median over rows of the mean rotor speed ``rotor_speeds`` (K, N) where the rotors turn."""
    mean = np.mean(np.asarray(rotor_speeds, float), axis=1)
    spinning = mean[mean > 0]
    return float(np.median(spinning)) if len(spinning) else float("nan")


def offset_cells(group: np.ndarray, d_down: np.ndarray, d_up: np.ndarray, rotor_radius: float, reach: float
                 ) -> np.ndarray:
    """(K,) int, the cell of each row for :func:`speed_offset` (-1: left out): one recording at one height over
    the floor, heights from :data:`OFFSET_RADII` rotor radii up in steps of :data:`OFFSET_CELL_RATIO`, all
    heights beyond ``reach`` [m] (every surface law's) one cell; rows with the ceiling within
    :data:`OFFSET_RADII` rotor radii and cells under :data:`OFFSET_CELL_ROWS` rows are left out (under a flat
    ceiling one height over the floor is one distance to the ceiling too)."""
    d = np.asarray(d_down, float)
    low = OFFSET_RADII * float(rotor_radius)
    use = (d > low) & (np.asarray(d_up, float) > low)
    with np.errstate(divide="ignore", invalid="ignore"):
        step = np.floor(np.log(np.where(use, d, low) / low) / np.log(OFFSET_CELL_RATIO))
    top = np.floor(np.log(max(reach, low) / low) / np.log(OFFSET_CELL_RATIO)) + 1
    step = np.where(d > reach, top, step)
    cell = np.where(use, np.asarray(group, np.int64) * 100_000 + np.minimum(step, top).astype(np.int64), -1)
    labels, inverse, counts = np.unique(cell, return_inverse=True, return_counts=True)
    keep = (labels >= 0) & (counts >= OFFSET_CELL_ROWS)
    ids = np.where(keep, np.cumsum(keep) - 1, -1)
    return ids[inverse]


class _OffsetSums:
    """Each cell's sums of products of ``y``, ``S`` and ``W1`` (speeds in units of the hover speed), from which
    the residual of ``y = k_c (S + 2 delta W1 + n delta^2)`` at any ``delta`` follows without the rows (a search
    and its jackknife read them hundreds of times: an hour of flight holds 700 000 rows)."""

    KEYS = ("yy", "Sy", "Wy", "y", "SS", "WW", "SW", "S", "W", "one")

    def __init__(self, y: np.ndarray, S: np.ndarray, W1: np.ndarray, cell: np.ndarray, chunk: np.ndarray,
                 n_cells: int, n_chunks: int):
        terms = {"yy": y * y, "Sy": S * y, "Wy": W1 * y, "y": y, "SS": S * S, "WW": W1 * W1, "SW": S * W1, "S": S,
                 "W": W1, "one": np.ones(len(y))}
        idx = cell * n_chunks + chunk
        size = n_cells * n_chunks
        self.by_chunk = {k: np.bincount(idx, v, minlength=size).reshape(n_cells, n_chunks) for k, v in terms.items()}
        self.total = {k: v.sum(axis=1) for k, v in self.by_chunk.items()}

    def without(self, chunk: int | None) -> dict[str, np.ndarray]:
        """Each cell's sums over every row, or every row but those of ``chunk``."""
        if chunk is None:
            return self.total
        return {k: self.total[k] - self.by_chunk[k][:, chunk] for k in self.KEYS}


def _offset_sse(sums: dict[str, np.ndarray], n: int, delta: float) -> float:
    """Residual sum of squares of ``y = k_c (S + 2 delta W1 + n delta^2)``, ``k_c`` fitted per cell (``delta``
    in units of the hover speed, as the sums' speeds)."""
    return float(_offset_sse_grid(sums, n, np.array([float(delta)]))[0])


def _offset_sse_grid(sums: dict[str, np.ndarray], n: int, deltas: np.ndarray) -> np.ndarray:
    """(G,) :func:`_offset_sse` at each offset of ``deltas`` (G,), the cells and offsets in one array each."""
    d = np.asarray(deltas, float)[None, :]
    col = {k: v[:, None] for k, v in sums.items()}
    sy = col["Sy"] + 2 * d * col["Wy"] + n * d**2 * col["y"]
    ss = (col["SS"] + 4 * d**2 * col["WW"] + n**2 * d**4 * col["one"] + 4 * d * col["SW"]
          + 2 * n * d**2 * col["S"] + 4 * n * d**3 * col["W"])
    fit = np.divide(sy * sy, ss, out=np.zeros_like(sy), where=ss > 0)
    return np.sum(col["yy"] - fit, axis=0)


def _best_offset(sums: dict[str, np.ndarray], n: int) -> float:
    """The offset [hover speeds] of least residual over :data:`OFFSET_SPAN` (a grid of 61, then a parabola
    through the best point and its neighbours)."""
    grid = np.linspace(OFFSET_SPAN[0], OFFSET_SPAN[1], 61)
    sse = _offset_sse_grid(sums, n, grid)
    i = int(np.argmin(sse))
    if 0 < i < len(grid) - 1:
        a, b, c = sse[i - 1], sse[i], sse[i + 1]
        curv = a - 2 * b + c
        if curv > 0:
            return float(grid[i] + 0.5 * (a - c) / curv * (grid[1] - grid[0]))
    return float(grid[i])


def speed_offset(y_thrust: np.ndarray, rotor_speeds: np.ndarray, cell: np.ndarray, t: np.ndarray,
                 S: np.ndarray | None = None, voltage_dev: np.ndarray | None = None,
                 voltage_mean: float = float("nan"), sag_time: np.ndarray | None = None,
                 voltage_var: np.ndarray | None = None) -> SpeedOffset | None:
    """The offset ``delta`` [rad/s] that makes thrust per ``sum((w + delta)^2)`` constant within each cell
    (module docstring, **Thrust map**); None with fewer than :data:`OFFSET_MIN_ROWS` rows in cells.

    Parameters
    ----------
    y_thrust : (K,) N, the thrust the rotors must make (measured force along the body z axis, less the named
        effects other than the thrust)
    rotor_speeds : (K, N) rad/s, recorded
    cell : (K,) int, :func:`offset_cells` (-1: not used); t : (K,) s
    S : (K,) (rad/s)^2, ``sum(w^2)`` where the thrust sees other sums than the records' (the motor lag's);
        the offset's cross term stays on the recorded speeds
    voltage_dev : (K,) V, the battery's voltage less each recording's mean (``battery_voltage``), and
    voltage_mean : V, its mean: the offset is read jointly with the voltage's slope ``k_V``, the thrust divided by
        ``1 + k_V voltage_dev`` at each ``k_V V`` of :data:`OFFSET_VOLTAGE_GRID`, the least residual refined by a
        parabola through its neighbours (in the jackknife too)
    sag_time : (K,) s, each row's time less its recording's middle, where ``battery_sag`` stands in for a voltage
        (and none is known): the offset is read jointly with the sag ``s`` (``k_V`` then holds it, 1/s), the thrust
        divided by ``1 - s sag_time`` at each share of :data:`OFFSET_SAG_GRID` lost over the longest recording
    voltage_var : (K,) V^2, the variance of ``voltage_dev``'s noise at each row
        (:func:`~uavturb.sysid.flight_data.battery_voltage_noise`): the **voltage noise** term
        (:attr:`SpeedOffset.voltage_noise`, module docstring, **Thrust map**). A noisy voltage divides the thrust by
        a noisy factor, which adds about ``k_V^2 sum(y^2 var / (1 + k_V dv)^4)`` to the residual at the slope
        ``k_V``: the least residual lies at too small a slope, and the offset, which a sag under load imitates, takes
        the rest. The slope read with that sum taken off the residual gives a second offset, and the reading's
        error carries the whole difference (a 67 g vehicle's simulated take-offs, battery read at 10 Hz with 5 mV
        of noise, its voltage sagging under load: the offset read 976-1105 rad/s over eight flights for a true 796,
        each +- 60-90; taken off, the slope gave 668-855)
    """
    m = (np.asarray(cell) >= 0) & np.isfinite(y_thrust)
    if m.sum() < OFFSET_MIN_ROWS:
        return None
    W = np.asarray(rotor_speeds, float)[m]
    y, c = np.asarray(y_thrust, float)[m], np.unique(np.asarray(cell)[m], return_inverse=True)[1]
    W1, n = np.sum(W, axis=1), W.shape[1]
    w_hover = float(np.median(W1 / n))
    S = (np.sum(W**2, axis=1) if S is None else np.asarray(S, float)[m]) / w_hover**2
    order = np.lexsort((np.asarray(t, float)[m], c))  # cells in turn, each in time
    chunk = np.empty(len(y), np.int64)
    for k, rows in enumerate(np.array_split(order, OFFSET_CHUNKS)):
        chunk[rows] = k
    slopes, dv = [0.0], np.zeros(len(y))
    if voltage_dev is not None and np.isfinite(voltage_mean) and voltage_mean > 0:
        slopes, dv = [x / voltage_mean for x in OFFSET_VOLTAGE_GRID], np.asarray(voltage_dev, float)[m]
    elif sag_time is not None:
        span = 2.0 * float(np.max(np.abs(sag_time)))
        slopes, dv = [x / span for x in OFFSET_SAG_GRID] if span > 0 else [0.0], -np.asarray(sag_time, float)[m]
    cached: dict[float, _OffsetSums] = {}

    def sums_at(k: float) -> _OffsetSums:  # the cells' sums with the thrust divided by the voltage's factor
        if k not in cached:
            cached[k] = _OffsetSums(y / np.clip(1.0 + k * dv, 0.1, None), S, W1 / w_hover, c, chunk, int(c.max()) + 1,
                                    OFFSET_CHUNKS)
        return cached[k]

    def at(k: float, without: int | None) -> tuple[float, float]:  # the best offset at slope k, and its residual
        sums = sums_at(k).without(without)
        d = _best_offset(sums, n)
        return d, _offset_sse(sums, n, d)

    def best(without: int | None, noise: Callable[[float], float] | None = None) -> tuple[float, float]:
        """Offset and slope of least residual (less ``noise(k)``, where given): grid, then parabola."""
        found = [at(k, without) for k in slopes]
        sse = [f[1] - (noise(k) if noise is not None else 0.0) for f, k in zip(found, slopes)]
        i = int(np.argmin(sse))
        if 0 < i < len(slopes) - 1:
            a, b, e = sse[i - 1], sse[i], sse[i + 1]
            curv = a - 2 * b + e
            if curv > 0:
                k = slopes[i] + 0.5 * (a - e) / curv * (slopes[1] - slopes[0])
                return at(k, without)[0], k
        return found[i][0], slopes[i]

    delta, k_V = best(None)
    loo = np.array([best(j)[0] for j in range(OFFSET_CHUNKS)])
    se = float(jackknife_se(loo))
    noise_term, k_free = 0.0, float("nan")
    if voltage_var is not None and len(slopes) > 1:
        var = np.asarray(voltage_var, float)[m]
        if np.any(var > 0):
            def noise(k: float) -> float:  # the residual a noisy voltage adds at the slope k [N^2]
                return float(np.sum(k**2 * y**2 * var / np.clip(1.0 + k * dv, 0.1, None) ** 4))
            d_free, k_free = best(None, noise)
            noise_term = abs(d_free - delta)
    total = sums_at(k_V).total
    ratio = _offset_sse(total, n, delta) / _offset_sse(total, n, 0.0)
    at_bound = bool(np.isclose(delta, OFFSET_SPAN[0]) or np.isclose(delta, OFFSET_SPAN[1]))
    return SpeedOffset(delta * w_hover, float(np.hypot(se, noise_term)) * w_hover, w_hover, int(m.sum()),
                       int(c.max()) + 1, float(ratio), float(k_V), at_bound, noise_term * w_hover, float(k_free))
