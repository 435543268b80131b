"""The fit's profiled error (``fit.Profile``) and its thrust columns: what makes them fast gives the numbers of
the plain computation to the bit (the nonlinear searches compare errors, so a rounding change could move them)."""

from __future__ import annotations

import numpy as np
import pytest

from uavturb.gap.design import GapData, lag_key, stack_target, thrust_columns
from uavturb.gap.fit import HELDOUT_RTOL, Profile, _nl_values, fit_model
from uavturb.gap.selection import FoldFits, folds
from uavturb.physics import quaternion as quat
from uavturb.physics.dynamics import GRAVITY
from uavturb.physics.effects import lag_rotor_speeds


def _hover(K: int = 3000, seed: int = 2) -> tuple[GapData, dict]:
    """A tilting hover at 200 Hz over a floor 0.05-0.5 m below, rotor commands held 0.1 s through a 30 ms lag,
    ground effect mu = 2; the truth."""
    rng = np.random.default_rng(seed)
    t = np.arange(K) * 0.005
    mass, k_T, r, mu, tau = 1.2, 8e-6, 0.1, 2.0, 0.03
    hover = np.sqrt(mass * GRAVITY / (4 * k_T))
    w = np.repeat(hover * (1 + 0.08 * rng.uniform(-1, 1, (K // 20, 4))), 20, axis=0)
    q = quat.from_euler(0.1 * np.sin(t), 0.1 * np.cos(0.7 * t), 0.3 * t)  # roll, pitch, yaw [rad]
    R = quat.to_rotation_matrix(q)
    d = 0.05 + 0.45 * (0.5 + 0.5 * np.sin(0.4 * t))
    S = np.sum(lag_rotor_speeds(t, w, tau) ** 2, axis=1)
    rho = mu * (r / (4 * d)) ** 2
    y = k_T * S[:, None] * R[:, :, 2]
    y[:, 2] += k_T * S * rho / (1 - rho)
    y += rng.normal(0, 0.02, (K, 3))
    data = GapData(np.zeros(K, int), t, np.zeros((K, 3)), y, R, w, rng.normal(0, 1, (K, 3)), d, np.full(K, np.inf),
                   mass, r, ["hover"], "mocap", imu=np.zeros(K, bool), fits_bias=False)
    return data, {"k_T": k_T, "mu": mu, "tau": tau}


def _plain_thrust_columns(data: GapData, battery: bool, S: np.ndarray, surf: np.ndarray) -> np.ndarray:
    """The columns as first written (stacked copies of ``S R e_z``)."""
    zb = data.R[:, :, 2]
    thrust = S[:, None] * zb
    thrust[:, 2] += S * surf
    cols = [thrust] + ([-(data.t * S)[:, None] * zb] if battery else [])
    return np.stack([c.T.reshape(-1) for c in cols], axis=1)


@pytest.mark.parametrize("effects", [{"ground_effect"}, {"ground_effect", "battery_sag"}])
def test_thrust_columns_are_the_plain_ones_to_the_bit(effects):
    data, _ = _hover()
    S = data.S * 1.01
    surf = np.linspace(0.0, 0.2, len(data))
    D, names = thrust_columns(data, effects, S, surf)
    assert names == (["k_T", "k_T*s"] if "battery_sag" in effects else ["k_T"])
    assert D.shape == (3 * len(data), len(names)) and D.flags.c_contiguous
    assert np.array_equal(D, _plain_thrust_columns(data, "battery_sag" in effects, S, surf))
    # the first column is S R e_z with the surface's extra along z of W
    k = 17
    assert np.allclose(D[[k, len(data) + k, 2 * len(data) + k], 0], S[k] * data.R[k, :, 2] + [0, 0, S[k] * surf[k]])


def test_profile_remembers_errors_at_the_values_it_computes_at():
    data, _ = _hover()
    prof = Profile(data, frozenset({"motor_lag", "ground_effect"}), stack_target(data.y))
    tau = 0.0301
    assert lag_key(tau * (1 + 1e-4)) == lag_key(tau)
    first = prof.sse({"motor_lag": tau, "ground_effect": 2.0})
    # one cached step of tau: the same columns, so the same error, and no new evaluation
    assert prof.sse({"motor_lag": tau * (1 + 1e-4), "ground_effect": 2.0}) == first
    assert len(prof._sse) == 1
    assert prof.sse({"motor_lag": tau, "ground_effect": 2.0 * (1 + 1e-9)}) != first  # mu is taken as given
    fresh = Profile(data, frozenset({"motor_lag", "ground_effect"}), stack_target(data.y))
    assert fresh.sse({"motor_lag": tau * (1 + 1e-4), "ground_effect": 2.0}) == first


def test_fit_finds_the_known_lag_and_ground_effect():
    data, truth = _hover()
    fit = fit_model(data, {"motor_lag", "ground_effect"}, with_stderr=False)
    assert fit.nonlinear["motor_lag"] == pytest.approx(truth["tau"], rel=0.05)
    assert fit.nonlinear["ground_effect"] == pytest.approx(truth["mu"], rel=0.05)
    assert fit.coef["k_T"] == pytest.approx(truth["k_T"], rel=0.01)


def test_selection_fits_each_effect_set_once_and_finish_agrees(monkeypatch):
    """select() asks for the same held-out fits again (backward check, finish): each set is fitted once, and the
    selection is the one a fresh finish() computes."""
    from uavturb.gap import selection

    data, truth = _hover(K=4000)
    calls = []
    real = selection.fit_model
    monkeypatch.setattr(selection, "fit_model", lambda d, effects, **kw: calls.append(
        (len(d), d.t[0], d.t[-1], frozenset(effects), kw.get("with_stderr", True))) or real(d, effects, **kw))
    sel = selection.select(data, ["ground_effect", "motor_lag", "wind"])
    assert set(sel.chosen) == {"ground_effect", "motor_lag"}
    assert len(calls) == len(set(calls))  # no fit repeated on the same rows
    monkeypatch.setattr(selection, "fit_model", real)
    again = selection.finish(data, frozenset(), sel.steps)
    assert again.final.coef == sel.final.coef and again.final.nonlinear == sel.final.nonlinear
    assert again.final_heldout.rmse == sel.final_heldout.rmse and again.base_heldout.rmse == sel.base_heldout.rmse


@pytest.mark.parametrize("true_k", [0, 1, 333, 700, 1024])
def test_lattice_minimum_finds_the_lattice_point_of_a_smooth_minimum_in_few_evaluations(true_k):
    from uavturb.gap.fit import GRID_POINTS, LATTICE_STEPS, lattice_minimum

    top = (GRID_POINTS - 1) * LATTICE_STEPS
    calls = []

    def f(k):  # smooth, asymmetric, its minimum 0.3 lattice steps off a lattice point (clipped to the range)
        calls.append(k)
        x = (k - min(true_k + 0.3, top)) / top
        return x**2 + 0.5 * x**3 + 1.0

    assert lattice_minimum(f) == true_k
    assert len(calls) == len(set(calls)) and len(calls) <= GRID_POINTS + 8 + 12
    assert all(0 <= k <= top for k in calls)


def test_parabola_gain_known_answers():
    from uavturb.gap.fit import parabola_gain

    f = [(x - 3.3) ** 2 + 1.0 for x in (0.0, 4.0, 8.0)]
    assert parabola_gain((0.0, 4.0, 8.0), tuple(f)) == pytest.approx(0.49)  # (4 - 3.3)^2 under f(4)
    g = [2.0 * (x - 9.5) ** 2 for x in (6.0, 8.0, 12.0)]  # unequal spacing, the vertex beyond the right point
    assert parabola_gain((6.0, 8.0, 12.0), tuple(g)) == pytest.approx(4.5)
    assert parabola_gain((0.0, 1.0, 2.0), (1.0, 2.0, 1.0)) == np.inf  # opens downwards
    assert parabola_gain((0.0, 1.0, 2.0), (3.0, 2.0, 1.0)) == np.inf  # a line


@pytest.mark.parametrize("level", [1e-3, 1e3])
def test_lattice_minimum_stops_refining_where_little_is_left_to_gain(level):
    """With a tolerance the search stops once the parabola through its best value and neighbours promises less
    than ``rtol`` of the value: on a minimum shallow against the error's level after a few steps, close enough;
    on one deep against it (a strong effect over little noise) at the lattice point itself."""
    from uavturb.gap.fit import GRID_POINTS, LATTICE_STEPS, lattice_minimum

    top = (GRID_POINTS - 1) * LATTICE_STEPS
    true_k = 333.3

    def f(k):
        calls.append(k)
        x = (k - true_k) / top
        return x**2 + 0.5 * x**3 + level

    calls = []
    exact = lattice_minimum(f)
    exact_calls = len(calls)
    calls = []
    k = lattice_minimum(f, rtol=HELDOUT_RTOL)
    assert exact == 333
    assert f(k) - f(exact) <= HELDOUT_RTOL * f(exact)  # within the tolerance of the lattice's best
    if level > 1:
        assert len(calls) - 1 < exact_calls  # stopped earlier (the last call is this test's own)
    else:
        assert k == exact


def test_lattice_values_span_the_search_range_with_the_coarse_grid_on_it():
    from uavturb.gap.design import NONLINEAR
    from uavturb.gap.fit import GRID_POINTS, LATTICE_STEPS, lattice_value

    name, lo, hi = "motor_lag", NONLINEAR["motor_lag"][1], NONLINEAR["motor_lag"][2]
    top = (GRID_POINTS - 1) * LATTICE_STEPS
    assert lattice_value(name, 0) == pytest.approx(lo) and lattice_value(name, top) == pytest.approx(hi)
    grid = np.geomspace(lo, hi, GRID_POINTS)
    assert [lattice_value(name, i * LATTICE_STEPS) for i in range(GRID_POINTS)] == pytest.approx(grid, rel=1e-12)
    step = lattice_value(name, 501) / lattice_value(name, 500) - 1
    assert 0.002 < step < 0.01  # finer than the honest errors, coarse enough for searches to meet


@pytest.mark.parametrize("recordings", [1, 3])
def test_folds_fitted_together_are_the_fits_on_each_folds_rows(recordings):
    """The held-out test's folds fitted from one profile cut in pieces give the residuals of fitting each fold on
    its own training rows (same nonlinear values, coefficients to rounding), both protocols."""
    data, _ = _hover(K=3000)
    data.group = np.repeat(np.arange(recordings), -(-len(data) // recordings))[: len(data)]
    data.names = [f"rec{g}" for g in range(recordings)]
    effects = frozenset({"ground_effect", "motor_lag"})
    protocol, masks = folds(data)
    assert protocol == ("leave-one-recording-out" if recordings > 1 else "last-30%-of-each-recording")
    together = FoldFits(data, masks).heldout(effects)
    apart = []
    for train, test in masks:  # searched as the folds search (HELDOUT_RTOL)
        fit = fit_model(data.subset(train), effects, with_stderr=False, rtol=HELDOUT_RTOL)
        apart.append(fit.residual(data.subset(test)))
    apart = np.concatenate(apart)
    assert together.resid.shape == apart.shape == (sum(int(te.sum()) for _, te in masks), 3)
    assert np.allclose(together.resid, apart, rtol=1e-7, atol=1e-9 * np.abs(apart).max())
    # the test rows' times, recordings and 1 s blocks, in fold order, held once for every effect set (memory)
    test_t = np.concatenate([data.t[te] for _, te in masks])
    test_g = np.concatenate([data.group[te] for _, te in masks])
    assert np.array_equal(together.t, test_t) and np.array_equal(together.group, test_g)
    assert np.array_equal(together.blocks, test_g * 100000 + np.floor(test_t).astype(int))
    fits = FoldFits(data, masks)
    one, other = fits.heldout(effects), fits.heldout(frozenset({"ground_effect"}))
    assert other.t is one.t and other.group is one.group and other.blocks is one.blocks
    assert np.array_equal(one.resid, together.resid) and not np.array_equal(other.resid, one.resid)


def test_thrust_columns_written_into_a_wider_array_by_columns_are_the_same_to_the_bit():
    """The profile writes the columns into one column-major array beside y and the fixed columns
    (``out``): the same numbers as a new array, in that very array; a mismatched ``out`` is refused."""
    data, _ = _hover()
    effects = {"ground_effect", "battery_sag"}
    S, surf = data.S * 1.01, np.linspace(0.0, 0.2, len(data))
    wide = np.full((3 * len(data), 4), np.nan, order="F")
    D, names = thrust_columns(data, effects, S, surf, out=wide[:, :2])
    assert np.shares_memory(D, wide) and np.array_equal(wide[:, :2], thrust_columns(data, effects, S, surf)[0])
    assert np.isnan(wide[:, 2:]).all()  # the columns beside are left alone
    with pytest.raises(ValueError, match="shape"):
        thrust_columns(data, effects, S, surf, out=wide[:, :3])


def _three_recordings(effects: frozenset[str], shared: dict | None = None, still: bool = False
                      ) -> tuple[GapData, Profile, list[np.ndarray], list[np.ndarray]]:
    """The hover cut in three recordings (``still``: no velocity), a profile of ``effects`` cut in the held-out
    folds' pieces (as ``FoldFits`` cuts it), the pieces and the folds' flags."""
    data, _ = _hover(K=3000)
    if still:
        data.v = np.zeros_like(data.v)
    data.group = np.repeat(np.arange(3), 1000)
    data.names = ["a", "b", "c"]
    fits = FoldFits(data, folds(data)[1])
    prof = Profile(data, effects, stack_target(data.y), fits.pieces, {} if shared is None else shared,
                   folds=fits.uses)
    return data, prof, fits.pieces, fits.uses


@pytest.mark.parametrize("effects", [frozenset({"ground_effect", "motor_lag"}),
                                     frozenset({"ground_effect", "wind"}),  # fixed columns beside
                                     frozenset({"ground_effect", "body_drag"})])  # a column of zeros: rank-deficient
def test_the_folds_errors_solved_together_are_each_folds_own(effects):
    """Every fold's least-squares error at a value, solved side by side (a pseudo-inverse cut as lstsq cuts it),
    is the error of that fold's own solve; asked for one fold, the profile holds them all."""
    data, prof, _, uses = _three_recordings(effects, still="body_drag" in effects)
    if "body_drag" in effects:  # its column is zero where nothing moves
        assert prof.nf == 1 and not np.any(prof._DyF[:, -1]) and np.linalg.matrix_rank(prof.FF.sum(axis=0)) == 0
    values = {k: v for k, v in {"ground_effect": 2.5, "motor_lag": 0.04}.items() if k in effects}
    assert len(uses) == 3 and all(u.sum() == 2 for u in uses)
    first = prof.sse(values, uses[1])
    assert len(prof._sse) == 3  # the other folds' errors at that value came with it
    for use in uses:
        own = prof._solved(_nl_values(values), use)[1]
        assert own > 0 and prof.sse(values, use) == pytest.approx(own, rel=1e-10)
    assert first == prof.sse(values, uses[1])
    prof.sse(values, np.array([True, False, False]))  # a union of pieces that is no fold: solved on its own
    assert len(prof._sse) == 4


def test_shared_sums_are_one_products_numbers_whoever_computed_them_first():
    """Profiles without fixed columns share their sums (a selection step's searches return to the same values);
    a profile with fixed columns computes its own, so the shared numbers never depend on which came first."""
    shared: dict = {}
    at = _nl_values({"ground_effect": 2.0})
    data, windy, pieces, uses = _three_recordings(frozenset({"ground_effect", "wind"}), shared)
    windy.sse({"ground_effect": 2.0}, uses[0])
    assert shared == {}  # computed beside its fixed columns: not shared
    bare = Profile(data, frozenset({"ground_effect"}), stack_target(data.y), pieces, shared, folds=uses)
    bare.sse({"ground_effect": 2.0}, uses[0])
    assert len(shared) == 1
    again = Profile(data, frozenset({"ground_effect"}), stack_target(data.y), pieces, shared, folds=uses)
    assert again._sums_at(at)[0] is bare._sums_at(at)[0]
    # the windy profile's own product gives the same sums, to rounding
    assert np.allclose(windy._sums_at(at)[0], bare._sums_at(at)[0], rtol=1e-12)
    assert np.allclose(windy._sums_at(at)[2], bare._sums_at(at)[2], rtol=1e-12)
