"""The sparse-regression peer of the gap finder: PySINDy (sequentially thresholded least squares,
STLSQ) over the same candidate features as :func:`uavturb.gap.design.design`, at its best
(threshold chosen on held-out recordings, then a bagged ensemble). Surface laws enter its library
at a fixed typical coefficient and motor lag as its first-order expansion ``-tau d(sum w^2)/dt``,
since a library is linear. Used by ``uavturb gap-proof`` beside the finder.
"""

from __future__ import annotations

import numpy as np

from uavturb.gap.design import GapData, design, lagged_S, stack_target
from uavturb.gap.selection import folds
from uavturb.physics.effects import EFFECTS

#: relative STLSQ thresholds PySINDy's held-out choice picks from (multiples of the RMS target)
SINDY_THRESHOLDS = tuple(float(x) for x in np.geomspace(0.002, 0.5, 13))


#: bagged models of PySINDy's ensemble (its documentation's default)
SINDY_MODELS = 20


def sindy_library(data: GapData) -> tuple[np.ndarray, list[str]]:
    """PySINDy's candidate library ``Theta (3K, P)`` and labels: the regressors of
    :func:`uavturb.gap.design.design` with every effect in, surface laws at ``mu = kappa = 2``
    split out of the thrust column, plus a first-order motor-lag column."""
    # the peer's vocabulary: effects.md's seven (no alternative laws of one physics, lag as its own column)
    effects = {n for n, e in EFFECTS.items() if e.alternative_to is None} - {"motor_lag"}
    A, names = design(data, effects, {"mu": 2.0, "kappa": 2.0, "tau": 0.0})
    base, _ = design(data, set(), {"mu": 0.0, "kappa": 0.0, "tau": 0.0})
    Ag, _ = design(data, {"ground_effect"}, {"mu": 2.0, "kappa": 0.0, "tau": 0.0})
    Ac, _ = design(data, {"ceiling_effect"}, {"mu": 0.0, "kappa": 2.0, "tau": 0.0})
    dS = (lagged_S(data, 1e-9) - lagged_S(data, 0.01)) / 0.01  # ~ d(sum w^2)/dt: first order in tau
    lag_col = stack_target(-dS[:, None] * data.R[:, :, 2])
    cols = [base[:, 0]] + [A[:, i] for i, n in enumerate(names) if n != "k_T"] + [
        Ag[:, 0] - base[:, 0], Ac[:, 0] - base[:, 0], lag_col]
    labels = ["k_T"] + [n for n in names if n != "k_T"] + ["ground_effect", "ceiling_effect", "motor_lag"]
    return np.stack(cols, 1), labels


def _sindy_fit(Theta: np.ndarray, y: np.ndarray, threshold: float, ensemble: bool, seed: int) -> np.ndarray:
    """Coefficients of PySINDy's STLSQ (bagged ensemble, median of the models, when ``ensemble``)
    on unit-norm columns; ``threshold`` is relative to the RMS of ``y``."""
    import pysindy as ps

    scale = np.linalg.norm(Theta, axis=0)
    scale[scale == 0] = 1.0
    opt = ps.STLSQ(threshold=threshold * np.linalg.norm(y) / np.sqrt(len(y)), alpha=0.0, normalize_columns=False)
    if ensemble:
        np.random.seed(seed)  # PySINDy's bagging draws from numpy's global generator
        opt = ps.EnsembleOptimizer(opt, bagging=True, n_models=SINDY_MODELS)
    opt.fit(Theta / scale, y)
    return np.asarray(opt.coef_).ravel() / scale


def sindy_threshold(data: GapData, Theta: np.ndarray, y: np.ndarray, *, ensemble: bool = True,
                    seed: int = 0) -> tuple[float, dict[float, float]]:
    """The threshold with the least held-out error, on the same held-out protocol as uavturb
    (whole recordings held out): PySINDy's documentation chooses the threshold by
    cross-validation. Returns it and the held-out RMS per threshold; ties go to the sparser."""
    _, fm = folds(data)
    rows = lambda m: np.tile(m, 3)  # noqa: E731  (the stacked x, y, z rows of samples m)
    errs = {}
    for th in SINDY_THRESHOLDS:
        sse, n = 0.0, 0
        for train, test in fm:
            c = _sindy_fit(Theta[rows(train)], y[rows(train)], th, ensemble, seed)
            r = y[rows(test)] - Theta[rows(test)] @ c
            sse, n = sse + float(r @ r), n + int(test.sum())
        errs[th] = float(np.sqrt(sse / max(n, 1)))
    best = min(errs.values())
    return max(th for th, e in errs.items() if e <= best * (1 + 1e-6)), errs


def sindy_names(data: GapData, threshold: float | None = None, *, ensemble: bool = True,
                seed: int = 0) -> dict[str, dict[str, float]]:
    """Named terms by PySINDy at its best: STLSQ on the nominal model's candidate library
    (:func:`sindy_library`), its threshold chosen on held-out data (:func:`sindy_threshold`,
    plain STLSQ for speed) unless given, then bagged as an ensemble at that threshold
    (``EnsembleOptimizer``, median of :data:`SINDY_MODELS` models).
    Returns effect → its parameters in effects.md names and units (surface laws and the lag
    through their library columns' first-order scaling)."""
    Theta, labels = sindy_library(data)
    y = stack_target(data.y)
    if threshold is None:  # chosen with plain STLSQ (the ensemble's median follows the same threshold)
        threshold, _ = sindy_threshold(data, Theta, y, ensemble=False, seed=seed)
    coef = _sindy_fit(Theta, y, threshold, ensemble, seed)
    kT = coef[0]
    c = dict(zip(labels, coef))
    named: dict[str, dict[str, float]] = {}
    for name, spec in EFFECTS.items():  # linear laws: their library columns are their parameters (design.py)
        if spec.linear and not spec.along_thrust and any(c.get(p) for p in spec.params):
            named[name] = {p: c[p] for p in spec.params}
    if c["k_T*s"]:
        named["battery_sag"] = {"s": c["k_T*s"] / kT}
    # surface columns are k_T S G(2, d), G ~ rho ~ coefficient for small rho: coefficient k_T mu / 2
    if c["ground_effect"]:
        named["ground_effect"] = {"mu": 2.0 * c["ground_effect"] / kT}
    if c["ceiling_effect"]:
        named["ceiling_effect"] = {"kappa": 2.0 * c["ceiling_effect"] / kT}
    if c["motor_lag"]:  # -d(sum w^2)/dt R e_z: coefficient k_T tau to first order
        named["motor_lag"] = {"tau": c["motor_lag"] / kT}
    return named

