"""Fit the gap model for a given set of effects: linear coefficients by least squares,
nonlinear ones (``mu``, ``kappa``, ``tau``) by profiling the training error over a log grid,
refined by a bounded scalar search. Standard errors from the linearised model with a
Newey-West covariance (``physics/least_squares.py``)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import minimize_scalar

from uavturb.gap.design import (
    AMPLITUDE,
    NONLINEAR,
    GapData,
    amplitude_shapes,
    difference_points,
    design,
    effective_S,
    fixed_columns,
    lag_key,
    stack_target,
    surface_extra,
    thrust_columns,
    unstack,
)
from uavturb.physics.effects import EFFECTS
from uavturb.sysid.least_squares import lstsq

GRID_POINTS = 9


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
        """A coefficient that carries ``k_T`` (``k_T*s``, ``k_T*A``) over ``k_T``, and its standard error (the
        two errors combined as if independent)."""
        kT, kx = self.coef["k_T"], self.coef[coef]
        x = kx / kT
        se = abs(x) * np.hypot(self.stderr.get(coef, np.nan) / max(abs(kx), 1e-300), self.stderr.get("k_T", np.nan) / kT)
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
        if name == "battery_sag":
            s, se = self._over_k_T("k_T*s")
            return {"s": s}, {"s": se}
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


class _Profile:
    """Least-squares error as a function of the nonlinear parameters, fast: the Gram matrix of
    the fixed columns (bias, linear effects) and their products with ``y`` are computed once;
    each evaluation then needs only the dependent columns' products (``design.thrust_columns``)."""

    def __init__(self, data: GapData, effects: frozenset[str], y: np.ndarray):
        self.data, self.effects, self.y = data, set(effects), y
        self.F, _ = fixed_columns(data, self.effects)
        self.FF, self.Fy, self.yy = self.F.T @ self.F, self.F.T @ y, float(y @ y)
        # the effective rotor speeds depend on tau only, the surface laws on mu / kappa only: a profile over
        # one of them reuses the other's (a lagged sum over a flight-hour costs more than the whole fit)
        self._S: dict[float, np.ndarray] = {}
        self._surf: dict[tuple, tuple[np.ndarray, list[np.ndarray]]] = {}
        self._surface = [EFFECTS[e].searched_param for e in sorted(self.effects) if EFFECTS[e].surface is not None]
        # the error at each value the columns are really computed at (a search returns to values it tried, and
        # taus one cached grid step apart, design.lag_key, give the same columns)
        self._sse: dict[tuple, float] = {}

    def _columns(self, values: dict[str, float]) -> np.ndarray:
        tau = round(values["tau"], 12) if "motor_lag" in self.effects else 0.0
        if tau not in self._S:
            self._S = {tau: effective_S(self.data, self.effects, values)}
        key = tuple(round(values[p], 12) for p in self._surface)
        if key not in self._surf:
            self._surf = {key: (surface_extra(self.data, self.effects, values),
                                amplitude_shapes(self.data, self.effects, values))}
        return thrust_columns(self.data, self.effects, self._S[tau], *self._surf[key])[0]

    def sse(self, nl: dict[str, float]) -> float:
        values = _nl_values(nl)
        key = (lag_key(values["tau"]) if "motor_lag" in self.effects else 0.0,) + tuple(values[p] for p in self._surface)
        if key not in self._sse:
            self._sse[key] = self._sse_at(values)
        return self._sse[key]

    def _sse_at(self, values: dict[str, float]) -> float:
        D = self._columns(values)
        nd = D.shape[1]
        G = np.empty((nd + self.FF.shape[0],) * 2)
        G[:nd, :nd] = D.T @ D
        G[:nd, nd:] = D.T @ self.F
        G[nd:, :nd] = G[:nd, nd:].T
        G[nd:, nd:] = self.FF
        b = np.concatenate([D.T @ self.y, self.Fy])
        d = np.sqrt(np.diag(G))
        d[d == 0] = 1.0
        c = np.linalg.lstsq(G / np.outer(d, d), b / d, rcond=1e-13)[0]
        return max(self.yy - float(c @ (b / d)), 0.0)


def fit_model(data: GapData, effects: set[str] | frozenset[str], *, lag: int = 50,
              fixed_nonlinear: dict[str, float] | None = None, with_stderr: bool = True) -> ModelFit:
    """Fit the model with ``effects`` on ``data``.

    Parameters
    ----------
    data : training samples
    effects : effect names (``effects.md``)
    lag : Newey-West lag [samples] for the standard errors
    fixed_nonlinear : nonlinear parameters held at given values instead of fitted
    """
    effects = frozenset(effects)
    y = stack_target(data.y)
    fixed = dict(fixed_nonlinear or {})
    free = [e for e in sorted(effects) if e in NONLINEAR and e not in fixed]
    nl = {e: fixed.get(e, np.sqrt(NONLINEAR[e][1] * NONLINEAR[e][2])) for e in effects if e in NONLINEAR}
    prof = _Profile(data, effects, y) if free else None
    for _ in range(2 if len(free) > 1 else 1):  # coordinate descent over the nonlinear parameters
        for e in free:
            lo, hi = NONLINEAR[e][1], NONLINEAR[e][2]
            grid = np.geomspace(lo, hi, GRID_POINTS)
            sse = [prof.sse(nl | {e: g}) for g in grid]
            i = int(np.argmin(sse))
            a, b = np.log(grid[max(i - 1, 0)]), np.log(grid[min(i + 1, len(grid) - 1)])
            res = minimize_scalar(lambda z: prof.sse(nl | {e: np.exp(z)}), bounds=(a, b),
                                  method="bounded", options={"xatol": 1e-2})  # 1 %: far under any honest error
            nl[e] = float(np.exp(res.x)) if res.fun <= sse[i] else float(grid[i])
            # the effect may be absent altogether (a simulator effect the real flights lack):
            # its parameter is then 0, not the grid's lower bound
            if prof.sse(nl | {e: 0.0}) <= min(res.fun, sse[i]):
                nl[e] = 0.0
    A, names = design(data, effects, _nl_values(nl))
    coef, sse = _solve(A, y)
    stderr: dict[str, float] = {}
    if with_stderr:
        # linearise in the nonlinear parameters (central differences of the prediction)
        cols, extra = [A], []
        for e in free:
            p = nl[e]
            if p == 0.0:  # absent: no derivative in the log-parametrised search, no standard error
                continue
            hi, lo = difference_points(e, p)
            Ap, _ = design(data, effects, _nl_values(nl | {e: hi}))
            Am, _ = design(data, effects, _nl_values(nl | {e: lo}))
            cols.append(((Ap - Am) @ coef / (hi - lo))[:, None])
            extra.append(NONLINEAR[e][0])
        J = np.hstack(cols)
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
