"""Known answers for the CasADi model of the paper's eq. 1."""

import casadi as ca
import numpy as np
import pytest

from uavturb.physics import quaternion as quat
from uavturb.physics.dynamics import (
    GRAVITY,
    dynamics_for,
    physical_params,
    rotation_matrix_sym,
)
from uavturb.physics.vehicle import HEXAROTOR, QUADROTOR


@pytest.mark.parametrize("vehicle", [HEXAROTOR, QUADROTOR], ids=["hex", "quad"])
def test_hover_is_an_equilibrium(vehicle):
    d = dynamics_for(vehicle)
    x = np.r_[0, 0, 1.0, 1, 0, 0, 0, 0, 0, 0, 0, 0, 0]
    w = np.full(vehicle.rotor_count, vehicle.hover_speed())
    assert np.allclose(d.xdot(x, w, physical_params(vehicle)), 0.0, atol=1e-9)


def test_wrench_matches_recordings_md():
    """T = k_T sum w^2, tau_x = k_T l sum sin(a) w^2, tau_y = -k_T l sum cos(a) w^2, tau_z = -k_M sum s w^2."""
    v = HEXAROTOR
    rng = np.random.default_rng(0)
    w = rng.uniform(300, 800, size=(5, 6))
    T, tau = dynamics_for(v).thrust_torque(w, physical_params(v))
    a = np.deg2rad(v.rotor_angles_deg)
    s = np.array(v.rotor_directions)
    kT, kM, l = v.thrust_coefficient, v.moment_coefficient, v.arm_length
    assert np.allclose(T, kT * (w**2).sum(1))
    assert np.allclose(tau[:, 0], kT * l * (np.sin(a) * w**2).sum(1))
    assert np.allclose(tau[:, 1], -kT * l * (np.cos(a) * w**2).sum(1))
    assert np.allclose(tau[:, 2], -kM * (s * w**2).sum(1))


def test_counter_clockwise_rotors_yaw_the_body_clockwise():
    v = HEXAROTOR
    w = np.full(6, v.hover_speed())
    w[np.array(v.rotor_directions) > 0] += 20.0
    xd = dynamics_for(v).xdot(np.r_[0, 0, 1.0, 1, 0, 0, 0, 0, 0, 0, 0, 0, 0], w, physical_params(v))[0]
    assert xd[12] < 0  # w_z decreasing: clockwise seen from above


def test_free_fall_and_tilted_thrust():
    v = HEXAROTOR
    d, th = dynamics_for(v), physical_params(v)
    x = np.r_[0, 0, 1.0, 1, 0, 0, 0, 0, 0, 0, 0, 0, 0]
    assert np.allclose(d.xdot(x, np.zeros(6), th)[0, 7:10], [0, 0, -GRAVITY])
    # rolled by +30 deg about x: thrust R e_z points towards -y
    q = quat.from_euler(np.deg2rad(30.0), 0.0, 0.0)
    x[3:7] = q
    w = np.full(6, v.hover_speed())
    acc = d.xdot(x, w, th)[0, 7:10]
    assert np.allclose(acc, [0, -GRAVITY * np.sin(np.pi / 6), GRAVITY * (np.cos(np.pi / 6) - 1)], atol=1e-9)


def test_external_force_enters_as_force_over_mass():
    v = HEXAROTOR
    x = np.r_[0, 0, 1.0, 1, 0, 0, 0, 0, 0, 0, 0, 0, 0]
    w = np.full(6, v.hover_speed())
    xd = dynamics_for(v).xdot(x, w, physical_params(v), f_ext=np.array([1.5, 0, 0]))[0]
    assert xd[7] == pytest.approx(1.5 / v.mass)


def test_symbolic_rotation_matches_numpy():
    q = quat.normalize(np.random.default_rng(1).normal(size=(10, 4)))
    qs = ca.SX.sym("q", 4)
    f = ca.Function("R", [qs], [rotation_matrix_sym(qs)])
    for qi in q:
        assert np.allclose(np.array(f(qi)), quat.to_rotation_matrix(qi))


def test_rk4_conserves_angular_momentum_of_a_torque_free_spin():
    v = HEXAROTOR
    d, th = dynamics_for(v), physical_params(v)
    J = np.array(v.inertia)
    x = np.r_[0, 0, 0, 1, 0, 0, 0, 0, 0, 0, 1.0, 0.5, 2.0]
    L0 = quat.rotate(x[3:7], J * x[10:13])
    for _ in range(2000):  # 2 s at 1 ms; rotors off, gravity only
        x = d.step(x, np.zeros(6), th, 1e-3)
    L1 = quat.rotate(x[3:7], J * x[10:13])
    assert np.allclose(L0, L1, rtol=1e-6, atol=1e-8)
    assert np.linalg.norm(x[3:7]) == pytest.approx(1.0, abs=1e-12)
    assert x[2] == pytest.approx(-0.5 * GRAVITY * 4.0, rel=1e-9)


def test_step_many_equals_step():
    v = QUADROTOR
    d, th = dynamics_for(v), physical_params(v)
    rng = np.random.default_rng(2)
    X = np.concatenate([rng.normal(size=(4, 3)), quat.normalize(rng.normal(size=(4, 4))), rng.normal(size=(4, 6))], 1)
    W = rng.uniform(100, 200, size=(4, 4))
    many = d.step_many(X, W, th, 0.002)
    for i in range(4):
        assert np.allclose(many[i], d.step(X[i], W[i], th, 0.002))
