"""The real-time-iteration MPC on the physics core's quaternion model."""

from __future__ import annotations

import numpy as np
import pytest

from uavturb.physics.dynamics import dynamics_for, physical_params
from uavturb.physics.vehicle import HEXAROTOR, QUADROTOR
from uavturb.sim.core import mpc
from uavturb.sim.core.signals import Constant, hover, Reference, Waypoints


def test_box_qp_known_answers_and_against_qrqp():
    H = np.diag([1.0, 2.0, 4.0])
    g = np.array([-2.0, 4.0, -2.0])
    x, act, it = mpc.box_qp(H, g, -np.ones(3), np.ones(3))
    assert np.allclose(x, [1.0, -1.0, 0.5]) and act.tolist() == [1, -1, 0]
    rng = np.random.default_rng(0)
    for n in (8, 48):
        M = rng.normal(size=(n, n))
        H = M @ M.T + 0.1 * np.eye(n)
        g = 5 * rng.normal(size=n)
        lb, ub = -np.ones(n), np.ones(n)
        x, act, it = mpc.box_qp(H, g, lb, ub)
        ref = mpc._qrqp(n)(h=H, g=g, lbx=lb, ubx=ub)
        xr = np.asarray(ref["x"]).ravel()
        f = lambda z: 0.5 * z @ H @ z + g @ z  # noqa: E731
        assert np.all(x >= lb - 1e-12) and np.all(x <= ub + 1e-12)
        assert f(x) == pytest.approx(f(xr), rel=1e-8, abs=1e-8)


def test_flat_attitude():
    yaw = np.array([0.0, 0.7, -2.5])
    q = mpc.flat_attitude(np.zeros((3, 3)), yaw)
    assert np.allclose(q, np.c_[np.cos(yaw / 2), np.zeros((3, 2)), np.sin(yaw / 2)])
    from uavturb.physics import quaternion as quat

    rng = np.random.default_rng(1)
    a = rng.normal(size=(20, 3)) * 3
    yaw = rng.uniform(-3, 3, 20)
    q = mpc.flat_attitude(a, yaw)
    R = quat.to_rotation_matrix(q)
    b3 = a + [0, 0, 9.81]
    assert np.allclose(R[:, :, 2], b3 / np.linalg.norm(b3, axis=1, keepdims=True))
    # the heading: body x projected on the ground points along the yaw
    bx = R[:, :2, 0]
    assert np.allclose(np.arctan2(bx[:, 1], bx[:, 0]), yaw, atol=0.3)


def test_prediction_is_the_physics_core():
    """The MPC's rollout is Dynamics.rk4 of uavturb.physics.dynamics, step for step."""
    c = mpc.MPCController(QUADROTOR, hover((0, 0, 1)), horizon=5, substeps=2, compile=False)
    dyn, theta = dynamics_for(QUADROTOR), physical_params(QUADROTOR)
    x = np.r_[0.1, 0.2, 1.0, np.cos(0.2), 0.0, 0.0, np.sin(0.2), 0.3, 0.0, -0.1, 0.5, -0.2, 0.1]
    U = np.random.default_rng(0).uniform(0.4, 0.6, size=(4, 5))
    f = np.array([0.0, 0.01, 0.02])
    X, A, B = (np.asarray(a) for a in c.roll(x, U, np.tile(np.r_[theta, f][:, None], (1, 5))))
    xs = x.copy()
    for k in range(5):
        for _ in range(2):
            xs = dyn.step(xs, U[:, k] * c.w_max, theta, 0.02, f)
        assert np.allclose(X[:, k], xs, atol=1e-12)
    # Jacobians agree with finite differences of the same model
    eps = 1e-6
    du = np.zeros((4, 5))
    du[1, 0] = eps
    X2 = np.asarray(c.roll(x, U + du, np.tile(np.r_[theta, f][:, None], (1, 5)))[0])
    assert np.allclose((X2[:, 0] - X[:, 0]) / eps, B[:, 1], rtol=1e-4, atol=1e-6)


@pytest.mark.skipif(mpc.shutil.which("cc") is None, reason="no C compiler")
def test_compiled_matches_virtual_machine():
    slow = mpc.MPCController(QUADROTOR, hover((0, 0, 1)), compile=False)
    fast = mpc.MPCController(QUADROTOR, hover((0, 0, 1)), compile=True)
    assert fast.compiled and not slow.compiled
    x = np.r_[0.05, 0.0, 0.9, 1.0, 0.0, 0.0, 0.0, 0.1, 0.0, 0.0, 0.0, 0.0, 0.0]
    assert np.allclose(slow.update(x, 0.0), fast.update(x, 0.0), rtol=1e-10)


@pytest.mark.parametrize("vehicle", [QUADROTOR, HEXAROTOR])
def test_step_response_within_bounds(vehicle):
    x0 = np.zeros(13)
    x0[3] = 1.0
    x0[0], x0[2] = -0.2, 0.9  # 0.2 m behind and 0.1 m below the hover point
    out = mpc.track(vehicle, hover((0.0, 0.0, 1.0), yaw=0.5), 3.0, x0=x0)
    e, w = out["error"], out["omega"]
    assert e[0] == pytest.approx(np.hypot(0.2, 0.1))
    assert e[25] < 0.01 and e[50:].max() < 1e-3  # 1 s: < 1 cm; 2 s on: < 1 mm
    yaw = 2 * np.arctan2(out["x"][-1, 6], out["x"][-1, 3])
    assert yaw == pytest.approx(0.5, abs=0.01)
    assert w.min() >= 0.0 and w.max() <= vehicle.max_rotor_speed


def test_saturating_climb_respects_rotor_bounds():
    x0 = np.zeros(13)
    x0[3], x0[2] = 1.0, 0.6
    out = mpc.track(QUADROTOR, hover((0.0, 0.0, 1.0)), 3.0, x0=x0)
    w = out["omega"]
    assert w.max() == pytest.approx(QUADROTOR.max_rotor_speed)  # the bound is reached...
    assert w.min() >= 0.0 and w.max() <= QUADROTOR.max_rotor_speed + 1e-9  # ...never exceeded
    assert out["error"][-1] < 1e-3


def test_line_tracking_with_unknown_force():
    """2 m/s straight line with a steady upward push of 10% of the weight (ground-effect-like):
    tracked within 1 cm, and the force estimate converges to the push."""
    ref = Reference(Waypoints((0.0, 1.0, 5.0, 6.0), (0.0, 0.0, 4.0, 4.0)), Constant(0.5), Constant(1.0),
                    Constant(0.0), 7.0)
    f = np.array([0.0, 0.0, 0.1 * QUADROTOR.mass * 9.81])
    out = mpc.track(QUADROTOR, ref, 7.0, f_ext=f)
    assert out["error"].max() < 0.01
    assert np.allclose(out["controller"].f_hat, f, atol=0.02 * f[2])
    speed = np.linalg.norm(out["x"][:, 7:10], axis=1).max()
    assert speed == pytest.approx(2.1875, rel=0.02)  # the septic step's peak speed: 35/16 x 4 m / 4 s


def test_deterministic():
    x0 = np.zeros(13)
    x0[3], x0[0] = 1.0, 0.1
    a = mpc.track(QUADROTOR, hover((0, 0, 1)), 1.0, x0=x0)
    b = mpc.track(QUADROTOR, hover((0, 0, 1)), 1.0, x0=x0)
    assert np.array_equal(a["x"], b["x"]) and np.array_equal(a["omega"], b["omega"])


def test_bad_options():
    from uavturb.errors import InputError

    with pytest.raises(InputError, match="horizon"):
        mpc.MPCController(QUADROTOR, hover((0, 0, 1)), horizon=0)


@pytest.mark.parametrize("vehicle", [QUADROTOR, HEXAROTOR])
def test_hover_command_is_the_hover_speed(vehicle):
    """At rest on its hover set-point, the MPC commands every rotor at the hover speed
    sqrt(m g / (N k_T)) (the CasADi model's thrust balances the weight), within 0.1 %."""
    c = mpc.MPCController(vehicle, hover((0.0, 0.0, 1.0)), compile=False)
    x = np.zeros(13)
    x[2], x[3] = 1.0, 1.0
    w = c.update(x, 0.0)
    hover_speed = np.sqrt(vehicle.mass * 9.81 / (vehicle.rotor_count * vehicle.thrust_coefficient))
    np.testing.assert_allclose(w, hover_speed, rtol=1e-3)
