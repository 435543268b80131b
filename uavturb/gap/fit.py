"""Fit the gap model for a given set of effects: linear coefficients by least squares,
nonlinear ones (``mu``, ``kappa``, ``tau``) by profiling the training error over a log grid,
refined by a bounded scalar search. Standard errors from the linearised model with a
Newey-West covariance (``physics/least_squares.py``)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from uavturb.gap.design import (
    AMPLITUDE,
    NONLINEAR,
    THRUST_FACTOR,
    GapData,
    amplitude_names,
    amplitude_shapes,
    difference_points,
    design,
    effective_S,
    fixed_columns,
    lag_key,
    stack_target,
    surface_extra,
    thrust_columns,
    thrust_factor_names,
    unstack,
)
from uavturb.physics.effects import EFFECTS
from uavturb.sysid.least_squares import lstsq

GRID_POINTS = 9

#: (fits, rows times fits, rows): fits of several effect sets, or of several parts of the data, are computed side by
#: side in processes forked from this one (:class:`~uavturb.numerics.processes.ForkedPool`) where a held-out test
#: has this many folds (or the data this many parts) or more, on this many rows times fits or more, and on this many
#: rows or fewer: where the time goes to thousands of small fits in Python rather than to arithmetic on long
#: arrays. With fewer folds each set's fit is quick, and starting the processes (10-80 ms, and the pages they copy
#: as they write) cost more than it saved: two 5-minute flights (15,000 rows, two folds) took 2.2-2.7 s forked
#: against 2.0-2.2 s, a take-off and two walks (three folds) gained nothing. On long rows the arithmetic shares
#: two cores badly and each child's arrays come on top of the parent's: an hour in twelve 5-minute recordings
#: (90,000 rows) took 11.9-12.4 s forked against 11.3-11.9 s, with 220-280 MB more. Six to twelve one-minute walks
#: (9,500-19,000 rows) gained 10-20 %
FORKED_WORK = (4, 20_000, 40_000)


def forking_worth(rows: int, fits: int) -> bool:
    """Whether ``fits`` fits on ``rows`` rows in all (a held-out test's folds; parts of the data) are worth computing
    in forked processes (:data:`FORKED_WORK`)."""
    return fits >= FORKED_WORK[0] and rows * fits >= FORKED_WORK[1] and rows <= FORKED_WORK[2]


@dataclass
class ModelFit:
    """A fitted gap model.

    Attributes
    ----------
    effects : the effects in the model
    nonlinear : fitted ``mu`` / ``kappa`` / ``tau`` of the nonlinear effects in it
    coef : linear coefficients by name (``k_T``, ``b_x`` ..., ``k_d`` ...)
    stderr : standard errors of every coefficient and nonlinear parameter
    rmse : N, training RMS of the residual force norm
    """

    effects: frozenset[str]
    nonlinear: dict[str, float]
    coef: dict[str, float]
    stderr: dict[str, float]
    rmse: float

    def predict(self, data: GapData) -> np.ndarray:
        """Modelled force ``(K, 3)`` [N] in W."""
        A, names = design(data, set(self.effects), self._nl())
        return unstack(A @ np.array([self.coef[n] for n in names]))

    def residual(self, data: GapData) -> np.ndarray:
        return data.y - self.predict(data)

    def _over_k_T(self, coef: str) -> tuple[float, float]:
        """A coefficient that carries ``k_T`` (``k_T*s``, ``k_T*k_V``, ``k_T*A``) over ``k_T``, and its standard
        error (the two errors combined as if independent)."""
        kT, kx = self.coef["k_T"], self.coef[coef]
        x = kx / kT
        se = abs(x) * np.hypot(self.stderr.get(coef, np.nan) / max(abs(kx), 1e-300),
                               self.stderr.get("k_T", np.nan) / kT)
        return x, se

    def _nl(self) -> dict[str, float]:
        return _nl_values(self.nonlinear)

    def effect_params(self, name: str) -> tuple[dict[str, float], dict[str, float]]:
        """Parameters of one effect in ``effects.md`` names and units, with standard errors."""
        if name in AMPLITUDE:  # a surface law's amplitude (k_T*A over k_T) and its searched parameter
            a, se_a = self._over_k_T(AMPLITUDE[name])
            p = NONLINEAR[name][0]
            values = {EFFECTS[name].amplitude: a, p: self.nonlinear[name]}
            errors = {EFFECTS[name].amplitude: se_a, p: self.stderr.get(p, float("nan"))}
            return ({k: values[k] for k in EFFECTS[name].params}, {k: errors[k] for k in EFFECTS[name].params})
        if name in NONLINEAR:
            p = NONLINEAR[name][0]
            return {p: self.nonlinear[name]}, {p: self.stderr.get(p, float("nan"))}
        if name in THRUST_FACTOR:  # a law scaling the thrust coefficient: k_T*p over k_T
            (p,) = EFFECTS[name].params
            x, se = self._over_k_T(THRUST_FACTOR[name])
            return {p: x}, {p: se}
        keys = EFFECTS[name].params
        return {k: self.coef[k] for k in keys}, {k: self.stderr.get(k, float("nan")) for k in keys}


def _nl_values(nonlinear: dict[str, float]) -> dict[str, float]:
    out = {spec[0]: 0.0 for spec in NONLINEAR.values()}
    for effect, value in nonlinear.items():
        out[NONLINEAR[effect][0]] = value
    return out


def _solve(A: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, float]:
    """Least squares by scaled normal equations (fast for tall, thin problems); returns coef, SSE."""
    scale = np.linalg.norm(A, axis=0)
    scale[scale == 0] = 1.0
    As = A / scale
    G = As.T @ As
    c = np.linalg.lstsq(G, As.T @ y, rcond=1e-12)[0]
    r = y - As @ c
    return c / scale, float(r @ r)


#: the values a search of a nonlinear parameter may take: a log lattice from its lower to its upper bound with
#: this many steps between two points of the coarse grid (0.4-0.75 % apart: far under any honest error). Every
#: search lands on the same values, so that the folds of a held-out test, searched apart, share the columns and
#: the sums of products they computed (:class:`Profile`'s pieces)
LATTICE_STEPS = 128
#: refining steps at most after the grids (parabolic, or bisections; each one evaluation, 3-6 on a smooth minimum)
MAX_REFINE = 12
#: a held-out fold's search stops refining where the parabola through its best value and that value's evaluated
#: neighbours reaches less than this share of the error under it (:func:`lattice_minimum`'s ``rtol``). A fold's
#: fit only predicts the recording it leaves out: a training error within 1e-4 of its minimum moves its prediction
#: by as little. The fits whose values are reported (on all data, on each recording alone) refine to the lattice's
#: neighbours. On six cf50 walks a quarter fewer column evaluations (13,195 -> 9,933), every named value and error
#: the same; a coarser lattice instead (every fourth point) lost a simulated battery sag beside a strong ground
#: effect, whose held-out residual 1.3 % of mu off the optimum had raised by 8 %
HELDOUT_RTOL = 1e-4


def lattice_value(effect: str, k: int) -> float:
    """The value of ``effect``'s searched parameter at lattice index ``k`` (0: the lower bound,
    ``(GRID_POINTS - 1) * LATTICE_STEPS``: the upper)."""
    lo, hi = NONLINEAR[effect][1], NONLINEAR[effect][2]
    return float(lo * (hi / lo) ** (k / ((GRID_POINTS - 1) * LATTICE_STEPS)))


def parabola_gain(x: tuple[float, float, float], f: tuple[float, float, float]) -> float:
    """How far under ``f[1]`` the parabola through the points ``(x[i], f[i])`` (``x`` increasing) reaches at its
    vertex: ``f[1] - min``; inf where it opens downwards or is a line (nothing bounds what is left)."""
    (xl, xb, xr), (fl, fb, fr) = x, f
    a = ((fr - fb) / (xr - xb) - (fb - fl) / (xb - xl)) / (xr - xl)
    if not a > 0:
        return float("inf")
    slope = (fb - fl) / (xb - xl) + a * (xb - xl)  # the parabola's slope at xb
    return slope * slope / (4.0 * a)


def lattice_minimum(f: Callable[[int], float], rtol: float = 0.0) -> int:
    """The lattice index ``k`` that minimises ``f`` (:data:`LATTICE_STEPS`): the coarse grid of
    :data:`GRID_POINTS` values, quarter steps either side of its best, then parabolic steps through the
    best value and its evaluated neighbours (a bisection of the wider side where the parabola does not
    help, or where the best value is the last evaluated on one side, as at a bound of the range) until its
    neighbours on the lattice are known, or, with ``rtol`` > 0, until that parabola reaches less than ``rtol``
    times the best value under it (:data:`HELDOUT_RTOL`). ``f`` is called once per index."""
    seen: dict[int, float] = {}

    def at(k: int) -> float:
        if k not in seen:
            seen[k] = f(k)
        return seen[k]

    top = (GRID_POINTS - 1) * LATTICE_STEPS
    i = min(range(0, top + 1, LATTICE_STEPS), key=at)
    for k in range(max(0, i - LATTICE_STEPS), min(top, i + LATTICE_STEPS) + 1, LATTICE_STEPS // 4):
        at(k)
    for _ in range(MAX_REFINE):
        best = min(seen, key=lambda k: (seen[k], k))
        left = max((k for k in seen if k < best), default=None)
        right = min((k for k in seen if k > best), default=None)
        gap_left, gap_right = (best - left if left is not None else 0), (right - best if right is not None else 0)
        if max(gap_left, gap_right) <= 1:
            break  # the best value's neighbours on the lattice are known (or it sits at a bound)
        k = None
        if left is not None and right is not None:  # the parabola's vertex through the three
            fl, fb, fr = seen[left], seen[best], seen[right]
            if rtol > 0 and parabola_gain((left, best, right), (fl, fb, fr)) < rtol * abs(fb):
                break  # what is left to gain lies under the tolerance
            den = (best - left) * (fb - fr) - (best - right) * (fb - fl)
            if den:
                k = int(round(best - 0.5 * ((best - left) ** 2 * (fb - fr) - (best - right) ** 2 * (fb - fl)) / den))
        if k is None or not (best - gap_left < k < best + gap_right) or k in seen:  # no parabolic step: halve
            k = best + gap_right // 2 if gap_right >= gap_left else best - gap_left // 2  # the wider side
        at(k)
    return min(seen, key=lambda k: (seen[k], k))


class Profile:
    """Least-squares error as a function of the nonlinear parameters, fast: the sums of products of the fixed
    columns (bias, linear effects) with each other and with ``y`` are computed once; each evaluation then
    needs only the dependent columns' products (``design.thrust_columns``).

    ``pieces`` (row indices of the samples) split the rows: the sums are kept per piece, and the error is that
    of the fit on any union of pieces (``use``, one flag a piece). The folds of a held-out test are such unions
    (each recording a piece, or the first 70 % and last 30 % of one): they share every evaluation, each a
    pass over the rows, instead of repeating it on their own rows.

    Each evaluation writes the dependent columns ``D`` into one array beside ``y`` and the fixed columns ``F``, and
    takes ``D^T [D | y | F]`` in one product a piece (three had cost twice as much: with a dozen recordings the
    calls, not the arithmetic, take the time).

    ``shared`` (a dict, kept by the caller): where profiles of other effect sets on the same ``data``, ``y`` and
    ``pieces`` pass the same dict, a profile without fixed columns keeps its sums there, and finds those another
    such profile with the same dependent columns computed (the bias-free candidates of a selection step and the
    steps' searches return to the same values); a profile with fixed columns computes its own, since its product
    with them costs what a new one of the dependent columns does. (The sums of one set of dependent columns come
    from a product of one width, the same numbers whichever profile computed them first.)

    ``folds`` (one flag a piece each: the held-out folds' unions of pieces): an error asked for on one of them is
    solved on all of them at once (:meth:`_folds_sse`), as the folds' searches try the same values."""

    def __init__(self, data: GapData, effects: frozenset[str], y: np.ndarray,
                 pieces: list[np.ndarray] | None = None, shared: dict | None = None,
                 folds: list[np.ndarray] | None = None):
        self.data, self.effects = data, set(effects)
        K = len(data)
        pieces = [np.arange(K)] if pieces is None else pieces
        # each piece's rows of the stacked (x, y, z) design: three slices where its samples are consecutive
        self._rows = [[slice(int(p[0]) + j * K, int(p[-1]) + 1 + j * K) for j in range(3)]
                      if len(p) and p[-1] - p[0] + 1 == len(p) else [p + j * K for j in range(3)] for p in pieces]
        self.n = np.array([len(p) for p in pieces])
        F, self.fixed_names = fixed_columns(data, self.effects)
        self.FF = np.stack([sum(F[r].T @ F[r] for r in rows) for rows in self._rows])
        self.Fy = np.stack([sum(F[r].T @ y[r] for r in rows) for rows in self._rows])
        self.yy = np.array([sum(float(y[r] @ y[r]) for r in rows) for rows in self._rows])
        # the effective rotor speeds depend on tau only, the surface laws on mu / kappa only: a profile over
        # one of them reuses the other's (a lagged sum over a flight-hour costs more than the whole fit)
        self._S: dict[float, np.ndarray] = {}
        self._surf: dict[tuple, tuple[np.ndarray, list[np.ndarray]]] = {}
        self._surface = [EFFECTS[e].searched_param for e in sorted(self.effects) if EFFECTS[e].surface is not None]
        # the sums at each value the columns are really computed at (a search returns to values it tried, the
        # folds try the same lattice values, and taus one cached grid step apart, design.lag_key, give the same
        # columns), and the dependent columns' names
        self._sums: dict[tuple, tuple[np.ndarray, np.ndarray, np.ndarray]] = {}
        self._sse: dict[tuple, float] = {}
        # the dependent columns' names (:func:`~uavturb.gap.design.thrust_columns`), and the effects those columns
        # depend on: the nonlinear ones and the laws scaling the thrust coefficient (the others are fixed columns)
        self.dependent_names = ["k_T"] + thrust_factor_names(self.effects) + amplitude_names(self.effects)
        self._dependent = frozenset(e for e in self.effects if e in NONLINEAR or e in THRUST_FACTOR)
        self._shared = {} if shared is None else shared
        # (3K, nd + 1 + nf): the dependent columns, written at each evaluation, then y and the fixed columns; by
        # columns (Fortran order), so that each column is written and read as one run of memory
        nd = len(self.dependent_names)
        self._DyF = np.empty((len(y), nd + 1 + F.shape[1]), order="F")
        self._DyF[:, nd] = y
        self._DyF[:, nd + 1:] = F
        self.nf = F.shape[1]
        # the folds' unions of pieces (one flag a piece each), whose errors at a value are solved together
        self._folds = None if not folds else np.array(folds, dtype=float)
        self._fold_flags = [np.asarray(f, bool).tobytes() for f in folds or ()]

    def _columns(self, values: dict[str, float]) -> np.ndarray:
        tau = round(values["tau"], 12) if "motor_lag" in self.effects else 0.0
        if tau not in self._S:
            self._S = {tau: effective_S(self.data, self.effects, values)}
        key = tuple(round(values[p], 12) for p in self._surface)
        if key not in self._surf:
            self._surf = {key: (surface_extra(self.data, self.effects, values),
                                amplitude_shapes(self.data, self.effects, values))}
        return thrust_columns(self.data, self.effects, self._S[tau], *self._surf[key],
                              out=self._DyF[:, :len(self.dependent_names)])[0]

    def _key(self, values: dict[str, float]) -> tuple:
        return ((lag_key(values["tau"]) if "motor_lag" in self.effects else 0.0,)
                + tuple(values[p] for p in self._surface))

    def _sums_at(self, values: dict[str, float]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Per piece: ``D^T D``, ``D^T F``, ``D^T y`` of the dependent columns ``D`` at ``values`` (from ``shared``
        where a profile without fixed columns and with the same dependent columns computed them)."""
        key = self._key(values)
        if key not in self._sums:
            nd = len(self.dependent_names)
            found = self._shared.get((self._dependent, key)) if self.nf == 0 else None
            if found is None:
                sums = self._piece_sums(self._columns(values), self._DyF)
                found = sums[:, :, :nd], sums[:, :, nd + 1:], sums[:, :, nd]
                if self.nf == 0:
                    self._shared[(self._dependent, key)] = found
            self._sums[key] = found
        return self._sums[key]

    def _piece_sums(self, D: np.ndarray, X: np.ndarray) -> np.ndarray:
        """Per piece: ``D^T X`` (``X``: ``[D | y | F]``). A piece of consecutive samples is three slices of the
        stacked (x, y, z) rows, taken together as one batch of three products (a third of the calls: with a dozen
        recordings the calls, not the arithmetic, had taken most of the time)."""
        K = len(self.data)
        if not all(isinstance(r[0], slice) for r in self._rows):
            return np.stack([sum(D[r].T @ X[r] for r in rows) for rows in self._rows])
        D3, X3 = D.reshape(3, K, -1), X.reshape(3, K, -1)
        out = []
        for rows in self._rows:
            a, b = rows[0].start, rows[0].stop
            out.append((D3[:, a:b].transpose(0, 2, 1) @ X3[:, a:b]).sum(axis=0))
        return np.stack(out)[..., 0] if X.ndim == 1 else np.stack(out)

    def _solved(self, values: dict[str, float], use: np.ndarray | None) -> tuple[np.ndarray, float]:
        """Coefficients (dependent columns, then fixed) and the error of the fit on the pieces ``use``."""
        DD, DF, Dy = self._sums_at(values)
        u = slice(None) if use is None else use
        nd = DD.shape[1]
        G = np.empty((nd + self.FF.shape[1],) * 2)
        G[:nd, :nd] = DD[u].sum(axis=0)
        G[:nd, nd:] = DF[u].sum(axis=0)
        G[nd:, :nd] = G[:nd, nd:].T
        G[nd:, nd:] = self.FF[u].sum(axis=0)
        b = np.concatenate([Dy[u].sum(axis=0), self.Fy[u].sum(axis=0)])
        d = np.sqrt(np.diag(G))
        d[d == 0] = 1.0
        c = np.linalg.lstsq(G / np.outer(d, d), b / d, rcond=1e-13)[0]
        return c / d, max(float(self.yy[u].sum()) - float(c @ (b / d)), 0.0)

    def _folds_sse(self, values: dict[str, float]) -> np.ndarray:
        """(folds,) N^2, the least-squares error at ``values`` of the fit on each fold's pieces, solved side by side:
        ``y'y - b' G^+ b`` of each fold's scaled normal equations, the pseudo-inverse cut where :func:`_solved`'s
        ``lstsq`` cuts (eigenvalues of the symmetric ``G`` under 1e-13 of its largest); the same errors to the last
        digits or so. One solve a fold had cost more than the sums the folds share (a fold's search at a value
        is its solve only)."""
        DD, DF, Dy = self._sums_at(values)
        P, nd = DD.shape[:2]
        p = nd + self.nf
        Gp = np.empty((P, p, p))
        Gp[:, :nd, :nd] = DD
        Gp[:, :nd, nd:] = DF
        Gp[:, nd:, :nd] = DF.transpose(0, 2, 1)
        Gp[:, nd:, nd:] = self.FF
        U = self._folds
        G = (U @ Gp.reshape(P, -1)).reshape(-1, p, p)
        b = U @ np.concatenate([Dy, self.Fy], axis=1)
        d = np.sqrt(np.einsum("fii->fi", G))
        d[d == 0] = 1.0
        w, V = np.linalg.eigh(G / (d[:, :, None] * d[:, None, :]))
        q = np.einsum("fji,fj->fi", V, b / d)  # the scaled b in the eigenvectors' basis
        kept = np.abs(w) > 1e-13 * np.abs(w).max(axis=1, keepdims=True)
        explained = np.sum(np.where(kept, q * q / np.where(kept, w, 1.0), 0.0), axis=1)
        return np.maximum(U @ self.yy - explained, 0.0)

    def sse(self, nl: dict[str, float], use: np.ndarray | None = None) -> float:
        """Least-squares error [N^2] with the nonlinear parameters ``nl`` on the pieces ``use`` (None: all). Where
        ``use`` is one of the profile's ``folds``, every fold's error at ``nl`` is computed at once
        (:meth:`_folds_sse`): the folds' searches try the same values."""
        values = _nl_values(nl)
        flags = None if use is None else use.tobytes()
        key = (self._key(values), flags)
        if key not in self._sse:
            if flags in self._fold_flags:
                self._sse.update({(key[0], f): float(e) for f, e in zip(self._fold_flags, self._folds_sse(values))})
            else:
                self._sse[key] = self._solved(values, use)[1]
        return self._sse[key]

    def fit(self, nl: dict[str, float], use: np.ndarray | None = None) -> ModelFit:
        """The model at ``nl`` fitted on the pieces ``use`` (no standard errors)."""
        values = _nl_values(nl)
        c, sse = self._solved(values, use)
        n = int(self.n.sum() if use is None else self.n[use].sum())
        return ModelFit(frozenset(self.effects), dict(nl),
                        dict(zip(self.dependent_names + self.fixed_names, map(float, c))),
                        {}, float(np.sqrt(sse / max(n, 1))))


def search_nonlinear(prof: Profile, effects: frozenset[str], fixed: dict[str, float] | None = None,
                     use: np.ndarray | None = None, rtol: float = 0.0) -> dict[str, float]:
    """The nonlinear parameters of ``effects`` that minimise the profile's error on the pieces ``use``:
    coordinate descent over :func:`lattice_minimum` (twice round where two are free; ``rtol`` its tolerance);
    those in ``fixed`` are held. A parameter whose effect fits best absent is 0 (a simulator effect the real
    flights lack), not its lattice's lower bound."""
    fixed = dict(fixed or {})
    free = [e for e in sorted(effects) if e in NONLINEAR and e not in fixed]
    nl = {e: fixed.get(e, lattice_value(e, (GRID_POINTS - 1) * LATTICE_STEPS // 2)) for e in effects if e in NONLINEAR}
    for _ in range(2 if len(free) > 1 else 1):
        for e in free:
            nl[e] = lattice_value(e, lattice_minimum(lambda k: prof.sse(nl | {e: lattice_value(e, k)}, use), rtol))
            if prof.sse(nl | {e: 0.0}, use) <= prof.sse(nl, use):
                nl[e] = 0.0
    return nl


def _linearised(data: GapData, effects: frozenset[str], nl: dict[str, float], free: list[str], A: np.ndarray,
                coef: np.ndarray) -> tuple[np.ndarray, list[str]]:
    """(3K, P) the model linearised about its fit: the design ``A`` with a column per free nonlinear parameter (the
    central difference of the prediction, at the coefficients ``coef``), and those parameters' names. A parameter
    at 0 (absent: no derivative in the log-parametrised search) has no column."""
    cols, extra = [A], []
    for e in free:
        p = nl[e]
        if p == 0.0:
            continue
        hi, lo = difference_points(e, p)
        Ap, _ = design(data, effects, _nl_values(nl | {e: hi}))
        Am, _ = design(data, effects, _nl_values(nl | {e: lo}))
        cols.append(((Ap - Am) @ coef / (hi - lo))[:, None])
        extra.append(NONLINEAR[e][0])
    return np.hstack(cols), extra


def information_shares(data: GapData, fit: ModelFit, name: str, labels: np.ndarray) -> dict[str, np.ndarray]:
    """Per parameter of the effect ``name`` (``effects.md`` units): (B,) the share of its least-squares variance
    that the rows of each label ``0 .. B - 1`` of ``labels`` (K,) carry, from ``fit`` linearised on ``data``
    (every nonlinear parameter free): ``g' C J_b' J_b C g / g' C g`` with ``C = (J' J)^-1`` and ``g`` the
    parameter's gradient in the model's coefficients. The shares sum to 1; a label whose rows alone pin the
    parameter has a share near 1 (a slow flight's one near-floor stretch, :func:`uavturb.gap.uncertainty.
    error_budget`)."""
    nl = dict(fit.nonlinear)
    free = sorted(e for e in fit.effects if e in NONLINEAR)
    A, names = design(data, fit.effects, _nl_values(nl))
    coef = np.array([fit.coef[n] for n in names])
    J, extra = _linearised(data, fit.effects, nl, free, A, coef)
    scale = np.linalg.norm(J, axis=0)
    scale[scale == 0] = 1.0
    Js = J / scale
    C = np.linalg.pinv(Js.T @ Js, rcond=1e-12)
    columns = names + extra
    by_param = {NONLINEAR[e][0]: e for e in free}
    base = fit.effect_params(name)[0]

    def params_at(j: int, step: float) -> dict[str, float]:
        column = columns[j]
        if column in by_param:
            moved = ModelFit(fit.effects, nl | {by_param[column]: nl[by_param[column]] + step}, fit.coef, {}, fit.rmse)
        else:
            moved = ModelFit(fit.effects, nl, fit.coef | {column: fit.coef[column] + step}, {}, fit.rmse)
        return moved.effect_params(name)[0]

    values = np.array([fit.coef[c] if c not in by_param else nl[by_param[c]] for c in columns])
    grads = {k: np.zeros(len(columns)) for k in base}
    for j, v in enumerate(values):
        step = 1e-6 * max(abs(v), 1e-12)
        up, down = params_at(j, step), params_at(j, -step)
        for k in base:
            grads[k][j] = (up[k] - down[k]) / (2 * step) / scale[j]  # per unit of the scaled column
    rows = np.tile(np.asarray(labels), 3)  # the stacked rows: x, y, z of every sample
    B = int(np.max(labels)) + 1
    out = {}
    for k, g in grads.items():
        # each label's sum over its rows (one label a sample reads every sample's share at the cost of one pass)
        per = np.bincount(rows, weights=(Js @ (C @ g)) ** 2, minlength=B)
        total = per.sum()
        out[k] = per / total if total > 0 and np.isfinite(total) else np.full(B, np.nan)
    return out


def fit_model(data: GapData, effects: set[str] | frozenset[str], *, lag: int = 50,
              fixed_nonlinear: dict[str, float] | None = None, with_stderr: bool = True,
              rtol: float = 0.0) -> ModelFit:
    """Fit the model with ``effects`` on ``data``.

    Parameters
    ----------
    data : training samples
    effects : effect names (``effects.md``)
    lag : Newey-West lag [samples] for the standard errors
    fixed_nonlinear : nonlinear parameters held at given values instead of fitted
    rtol : the nonlinear searches' tolerance (:func:`lattice_minimum`; a held-out fold's fit:
        :data:`HELDOUT_RTOL`)
    """
    effects = frozenset(effects)
    y = stack_target(data.y)
    fixed = dict(fixed_nonlinear or {})
    free = [e for e in sorted(effects) if e in NONLINEAR and e not in fixed]
    nl = search_nonlinear(Profile(data, effects, y), effects, fixed, rtol=rtol) if free else \
        {e: fixed[e] for e in effects if e in NONLINEAR}
    A, names = design(data, effects, _nl_values(nl))
    coef, sse = _solve(A, y)
    stderr: dict[str, float] = {}
    if with_stderr:
        J, extra = _linearised(data, effects, nl, free, A, coef)
        groups = np.concatenate([data.group + 1000 * k for k in range(3)])
        lin = lstsq(J, y - A @ coef, lag=lag, groups=groups)  # the increments are ~0; we want the covariance
        se = lin.stderr
        stderr = dict(zip(names + extra, (float(s) for s in se)))
        stderr.update({NONLINEAR[e][0]: float("nan") for e in free if nl[e] == 0.0})
    rmse = float(np.sqrt(sse / len(data)))
    return ModelFit(effects, {e: nl[e] for e in effects if e in NONLINEAR}, dict(zip(names, map(float, coef))),
                    stderr, rmse)


def robust_nominal(data: GapData, offset: np.ndarray | None = None, *, iterations: int = 12,
                   cutoff: float = 4.5) -> ModelFit:
    """The nominal model (thrust coefficient and accelerometer bias, no effect) fitted by
    iteratively reweighted least squares with Tukey's biweight on the residual force norm.

    Used to *locate* the mismatch: a missing effect confined to some segments (near a surface,
    at speed) must stand out of the nominal model's residual instead of bending its fit. An
    ordinary least-squares fit can fail badly here: near the floor the controller lowers the
    rotor speeds exactly where the missing lift is, and the z accelerometer bias (collinear with
    the thrust column at hover) then takes the whole thrust. Rows whose residual norm exceeds
    ``cutoff`` robust standard deviations get no weight.

    Parameters
    ----------
    data : samples
    offset : (K, 3) N, force of the simulator's own effects, taken off ``data.y`` first
    """
    y = stack_target(data.y - (0.0 if offset is None else offset))
    A, names = design(data, set(), _nl_values({}))
    K = len(data)
    # start: thrust coefficient alone (no bias), which cannot degenerate
    coef = np.zeros(A.shape[1])
    coef[0] = _solve(A[:, :1], y)[0][0]
    w = np.ones(K)
    for _ in range(iterations):
        r = unstack(y - A @ coef)
        norm = np.linalg.norm(r, axis=1)
        s = np.median(norm) / 1.538  # median of a 3-D Gaussian norm is 1.538 sigma
        u = norm / max(cutoff * s, 1e-12)
        w = np.where(u < 1, (1 - u**2) ** 2, 0.0)
        sw = np.sqrt(np.tile(w, 3))
        c_new, _ = _solve(A * sw[:, None], y * sw)
        if np.allclose(c_new, coef, rtol=1e-6, atol=0):
            coef = c_new
            break
        coef = c_new
    r = y - A @ coef
    return ModelFit(frozenset(), {}, dict(zip(names, map(float, coef))), {}, float(np.sqrt(np.sum(r**2) / K)))
