"""Laws of effects.md and the Cheeseman-Bennett identification."""

import numpy as np
import pytest

from uavturb.errors import InputError
from uavturb.physics import ground_effect as ge
from uavturb.physics import quaternion as quat
from uavturb.physics.effects import (
    EFFECTS,
    EffectInputs,
    effect_force,
    format_effects,
    lag_rotor_speeds,
    parse_effects,
)
from uavturb.physics.vehicle import QUADROTOR


def inputs(K=4, yaw=0.0, v=(1.0, 0.0, 0.0), w=500.0, d_down=0.5, d_up=1.5, t=10.0):
    q = np.tile(quat.from_euler(0.0, 0.0, yaw), (K, 1))
    return EffectInputs(q=q, v=np.tile(v, (K, 1)), rotor_speeds=np.full((K, 6), w), k_T=8.54858e-6,
                        rotor_radius=0.1, d_down=np.full(K, d_down), d_up=np.full(K, d_up), t=np.full(K, t))


def test_vocabulary_is_the_contract():
    assert {n: e.params for n, e in EFFECTS.items()} == {
        "ground_effect": ("mu",), "ceiling_effect": ("kappa",), "rotor_drag": ("k_d",), "body_drag": ("c_d",),
        "wind": ("f_x", "f_y"), "battery_sag": ("s",), "motor_lag": ("tau",), "ground_effect_multirotor": ("K_b",),
        "ground_effect_exponential": ("A", "lam"), "battery_voltage": ("k_V",)}


def test_ground_effect_law_values():
    x = inputs(d_down=0.2)
    T = 8.54858e-6 * 6 * 500.0**2
    rho = 2.0 * (0.1 / (4 * 0.2)) ** 2
    F = effect_force("ground_effect", {"mu": 2.0}, x)
    assert np.allclose(F[:, :2], 0) and np.allclose(F[:, 2], T * rho / (1 - rho))


def test_ground_effect_paper_figure_scale():
    """Paper's quadrotor: hover at 150 rad/s, k_T 5.45e-6, r 0.01 m; mu 1, d = 1 cm."""
    T = QUADROTOR.thrust_coefficient * 4 * 150.0**2
    f = ge.phi(np.array([0.01, 1.0, np.inf]), np.full(3, T), 1.0, 0.01)
    rho = (0.01 / 0.04) ** 2
    assert f[0] == pytest.approx(T * rho / (1 - rho))
    assert f[1] == pytest.approx(T * 1e-4 / 16 / (1 - 1e-4 / 16))
    assert f[2] == 0.0


def test_ground_effect_clip_is_the_papers():
    r, mu = 0.1, 2.0
    d_min = ge.min_height(mu, r)
    assert d_min == pytest.approx(0.1 * np.sqrt(2) / 4)
    f = ge.phi(np.array([d_min * 0.5, d_min, d_min * 1.01]), np.full(3, 10.0), mu, r)
    assert f[0] == f[1] == pytest.approx(0.1e-6 * 9.81)
    assert f[2] > 100.0  # just above the pole the law is huge


def test_rotor_drag_is_body_horizontal_and_opposes_motion():
    x = inputs(yaw=np.pi / 2, v=(0.0, 2.0, 0.5))  # flying forward (body +x is world +y), climbing
    F = effect_force("rotor_drag", {"k_d": 8e-5}, x)
    assert np.allclose(F[0], [0.0, -8e-5 * 6 * 500 * 2.0, 0.0])


def test_body_drag_wind_battery_ceiling():
    x = inputs(v=(3.0, 4.0, 0.0))
    assert np.allclose(effect_force("body_drag", {"c_d": 0.1}, x)[0], [-1.5, -2.0, 0.0])
    assert np.allclose(effect_force("wind", {"f_x": 0.3, "f_y": -0.2}, x)[0], [0.3, -0.2, 0.0])
    T = 8.54858e-6 * 6 * 500.0**2
    assert np.allclose(effect_force("battery_sag", {"s": 1e-3}, x)[0], [0, 0, -1e-3 * 10.0 * T])
    rho = 2.0 * (0.1 / (4 * 1.5)) ** 2
    assert effect_force("ceiling_effect", {"kappa": 2.0}, x)[0, 2] == pytest.approx(T * rho / (1 - rho))


def test_motor_lag_step_response_is_first_order():
    t = np.arange(0, 0.5, 0.001)
    w = np.where(t >= 0.1, 600.0, 500.0)[:, None] * np.ones((1, 6))
    out = lag_rotor_speeds(t, w, 0.025)
    # the command steps at sample i0, held until i0 + 1: w(t_i0 + k dt) = 600 - 100 exp(-k dt / tau)
    i0 = int(np.argmax(t >= 0.1))
    assert out[i0, 0] == 500.0
    assert out[i0 + 25, 0] == pytest.approx(500 + 100 * (1 - np.exp(-1)), rel=1e-9)
    # non-uniform time steps follow the same law
    t2 = np.sort(np.r_[t, t[:-1] + 0.0005])
    w2 = np.where(t2 >= 0.1, 600.0, 500.0)[:, None] * np.ones((1, 6))
    out2 = lag_rotor_speeds(t2, w2, 0.025)
    assert np.interp(0.3, t2, out2[:, 0]) == pytest.approx(np.interp(0.3, t, out[:, 0]), abs=0.5)


def test_parse_effects():
    e = parse_effects("wind:f_x=0.3,f_y=-0.1,rotor_drag:k_d=8e-5,ground_effect")
    assert e == {"wind": {"f_x": 0.3, "f_y": -0.1}, "rotor_drag": {"k_d": 8e-5}, "ground_effect": {"mu": 2.0}}
    assert parse_effects(format_effects(e)) == e
    assert parse_effects("none") == {}
    for bad, word in [("gust:k=1", "unknown effect"), ("wind:f_z=1", "unknown parameter"),
                      ("wind:f_x=abc", "must be a number"), ("f_x=1", "before any effect")]:
        with pytest.raises(InputError, match=word):
            parse_effects(bad)


def test_bfgs_recovers_alpha_beta():
    rng = np.random.default_rng(0)
    k_T, mu, r = 8.54858e-6, 2.2, 0.1
    d = rng.uniform(0.08, 1.0, 4000)
    S = rng.uniform(0.9, 1.1, 4000) * 6 * 490.0**2
    f = ge.phi(d, k_T * S, mu, r) + rng.normal(0, 0.05, 4000)
    fit = ge.identify_alpha_beta(f, d, S)
    assert fit.mu(r) == pytest.approx(mu, rel=0.03)
    assert fit.k_T() == pytest.approx(k_T, rel=0.03)
    beta = mu * r**2 / 16
    assert fit.beta == pytest.approx(beta, rel=0.03) and fit.alpha == pytest.approx(k_T * beta, rel=0.03)


def test_alpha_beta_standard_errors_match_the_scatter_of_repeated_fits():
    """The stated standard errors are the spread of the estimates over fresh noise (white noise here), and
    flights that stay at one height do not separate alpha from beta: no standard error is claimed."""
    k_T, mu, r = 8.54858e-6, 2.0, 0.1
    fits = []
    for seed in range(30):
        rng = np.random.default_rng(seed)
        d = rng.uniform(0.16, 0.6, 600)
        S = rng.uniform(0.9, 1.1, 600) * 6 * 535.0**2
        fits.append(ge.identify_alpha_beta(ge.phi(d, k_T * S, mu, r) + rng.normal(0, 0.02, 600), d, S))
    beta = np.array([f.beta for f in fits])
    stated = np.median([f.stderr_beta for f in fits])
    assert 0.7 < np.std(beta, ddof=1) / stated < 1.4
    assert np.mean(np.abs(beta - mu * r**2 / 16) < 2 * np.array([f.stderr_beta for f in fits])) > 0.85
    flat = ge.identify_alpha_beta(np.full(50, 0.7) + np.random.default_rng(1).normal(0, 0.01, 50), np.full(50, 0.16),
                                  np.full(50, 1.7e6))
    assert np.isnan(flat.stderr_beta) and np.isnan(flat.stderr_alpha)
