"""Which order of the rotor columns the roll and pitch accelerations follow: known orders, noise, bad inputs."""

import dataclasses

import numpy as np
import pytest
from synthetic import inverse_dynamics_flight

from uavturb.commands.identify import format_identification, rotor_order_warning
from uavturb.physics.vehicle import HEXAROTOR, QUADROTOR, Vehicle
from uavturb.sysid import identifiability as idf
from uavturb.sysid.identification import identify
from uavturb.sysid.rotor_order import GIVEN, OTHER, UNDECIDED, candidate_orders, rotor_order


def _torques_followed(vehicle: Vehicle, order: np.ndarray, noise: float, seed: int = 0, rows: int = 3000):
    """(w2 as recorded, dw): rotor speeds squared whose vehicle.yaml rotor j is recorded in column order[j], and an
    angular acceleration that follows the true torques (plus noise of ``noise`` times their spread)."""
    rng = np.random.default_rng(seed)
    n = len(vehicle.rotor_angles)
    true = 400.0**2 + 2e4 * rng.standard_normal((rows, n))
    recorded = np.empty_like(true)
    recorded[:, order] = true  # recorded[:, order[j]] = true[:, j]
    torque = true @ vehicle.mixer()[1:3].T
    dw = np.zeros((rows, 3))
    dw[:, :2] = torque / torque.std(axis=0) + noise * rng.standard_normal((rows, 2))
    return recorded, dw


@pytest.mark.parametrize("order", [(0, 1, 2, 3), (1, 2, 3, 0), (3, 2, 1, 0), (0, 2, 1, 3), (2, 0, 3, 1)])
def test_the_order_the_torques_follow_is_found_among_all_of_a_quadrotor(order):
    w2, dw = _torques_followed(QUADROTOR, np.array(order), noise=1.0)
    found = rotor_order([w2], [dw], QUADROTOR.mixer())
    assert found.orders == 24
    if order == (0, 1, 2, 3):
        assert found.verdict == GIVEN and min(found.given) > 0.6 and max(found.best_other_correlations) < 0.75
        assert "vehicle.yaml's order" in found.sentence()
    else:
        assert found.verdict == OTHER and found.best_other == order and min(found.best_other_correlations) > 0.6
        assert found.alike == 0  # each rotor moved on its own: no other order comes near
        assert found.sentence().startswith("the rotor columns are in another order than vehicle.yaml's angles: read "
                                           f"as {', '.join(f'w_{c}' for c in order)}")


def test_a_hexarotor_compares_all_720_orders_and_an_octorotor_its_rotations_and_reflections():
    order = np.array([2, 3, 4, 5, 0, 1])
    w2, dw = _torques_followed(HEXAROTOR, order, noise=1.0)
    found = rotor_order([w2], [dw], HEXAROTOR.mixer())
    assert found.orders == 720 and found.verdict == OTHER and found.best_other == tuple(order)
    octo = candidate_orders(8)
    assert octo.shape == (16, 8) and tuple(octo[0]) == tuple(range(8))
    assert len({tuple(o) for o in octo}) == 16 and (7, 6, 5, 4, 3, 2, 1, 0) in {tuple(o) for o in octo}


def test_rotors_moved_alike_leave_the_order_among_them_open():
    """Two rotors whose speeds move together (a controller that splits a torque between them alike): the orders
    that swap them follow equally well, and none is named as the order."""
    w2, dw = _torques_followed(QUADROTOR, np.array([1, 2, 3, 0]), noise=1.0)
    w2[:, 1] = w2[:, 2] + 1e-3 * np.random.default_rng(2).standard_normal(len(w2))  # columns 1 and 2 alike
    found = rotor_order([w2], [dw], QUADROTOR.mixer())
    assert found.verdict == OTHER and found.alike >= 1
    assert found.sentence().startswith("the rotor columns are in another order than vehicle.yaml's angles, which the "
                                       f"flight does not tell: {found.alike + 1} orders'")
    # an inertia read above its bound does not name an order either
    est = {"k_T": 8.5e-6, "k_M": 1.4e-7, "J_x": 2.28, "J_y": 0.046, "J_z": 0.098, "theta_0": 5.7e-6,
           "theta_1": 0.215 * 8.5e-6 / 2.28, "theta_2": 1.4e-6, "theta_3": 2.8, "accel_bias": np.zeros(3)}
    se = {k: (np.full(3, 0.001) if k == "accel_bias" else 0.001 * abs(v)) for k, v in est.items()}
    st = idf.assess(est, se, {a: idf.AxisExcitation(0.3, 1.0, 0.99) for a in idf.AXES}, {}, has_imu=True,
                    rotor_order=found, mass=1.5, arm_length=0.215, rotor_radius=0.1, jx_equals_jy=False)
    assert st["theta_1"].reason == idf.OUT_OF_ORDER
    assert "times it: rotor columns out of order, which order the flight does not tell)" in st["theta_1"].why


def test_each_order_is_read_at_the_shift_where_its_torques_follow():
    """Commands that lead the rotors by 30 ms (three rows at 100 Hz): the order is found 30 ms ahead, where as
    stamped a noise-like torque follows nothing."""
    w2, dw = _torques_followed(QUADROTOR, np.array([1, 2, 3, 0]), noise=0.5)
    later = np.full_like(dw, np.nan)
    later[3:] = dw[:-3]  # the acceleration three rows after its torque
    usable = np.ones(len(w2), bool)
    as_stamped = rotor_order([w2], [later], QUADROTOR.mixer())
    assert as_stamped.verdict == UNDECIDED and max(as_stamped.best_other_correlations) < 0.2
    found = rotor_order([w2], [later], QUADROTOR.mixer(), dt=[0.01], usable=[usable])
    assert found.verdict == OTHER and found.best_other == (1, 2, 3, 0) and found.lead_s == pytest.approx(0.03)
    assert found.sentence().endswith(", the recorded speeds taken 30 ms ahead")
    # over two flights, one of them sampled at 50 Hz: the same shift in seconds
    slow_w2, slow_dw = _torques_followed(QUADROTOR, np.array([1, 2, 3, 0]), noise=0.5, seed=1)
    slow_later = np.full_like(slow_dw, np.nan)
    slow_later[1:] = slow_dw[:-1]  # 20 ms at 50 Hz
    both = rotor_order([w2, slow_w2], [later, slow_later], QUADROTOR.mixer(), dt=[0.01, 0.02],
                       usable=[usable, np.ones(len(slow_w2), bool)])
    assert both.verdict == OTHER and both.best_other == (1, 2, 3, 0)


def test_accelerations_that_follow_no_torque_decide_nothing():
    w2, _ = _torques_followed(QUADROTOR, np.arange(4), noise=1.0)
    dw = np.random.default_rng(5).standard_normal((len(w2), 3))
    found = rotor_order([w2], [dw], QUADROTOR.mixer())
    assert found.verdict == UNDECIDED and max(map(abs, found.given)) < 0.1
    assert found.sentence().startswith("the flight does not tell the rotor columns' order")


def test_too_few_finite_rows_or_one_rotor_read_nothing():
    w2, dw = _torques_followed(QUADROTOR, np.arange(4), noise=1.0, rows=400)
    dw[:250] = np.nan  # 150 finite rows left
    assert rotor_order([w2], [dw], QUADROTOR.mixer()) is None
    assert rotor_order([w2[:, :1]], [dw], QUADROTOR.mixer()[:, :1]) is None


def test_identify_names_the_columns_order_and_says_why_an_inertia_is_read_too_large():
    fd, _ = inverse_dynamics_flight(QUADROTOR, seed=4, rotor_quantum=0.01)
    ident = identify([fd], QUADROTOR)
    assert ident.rotor_order.verdict == GIVEN and rotor_order_warning(ident) is None
    assert ident.to_dict()["rotor_order"]["verdict"] == GIVEN
    shuffled = dataclasses.replace(fd, rotor_speeds=fd.rotor_speeds[:, [1, 2, 3, 0]])  # recorded[:, i] = true[:, q_i]
    wrong = identify([shuffled], QUADROTOR)
    assert wrong.rotor_order.verdict == OTHER and wrong.rotor_order.best_other == (3, 0, 1, 2)  # the inverse of q
    warning = rotor_order_warning(wrong)
    assert "read as w_3, w_0, w_1, w_2" in warning and "rotor_angles_deg" in warning and "--motor-order" in warning
    assert wrong.to_dict()["rotor_order"]["best_other"] == [3, 0, 1, 2]
    from_torques = {n: s for n, s in wrong.status.items() if n in idf.FROM_TORQUES}
    assert all(s.reason == idf.OUT_OF_ORDER and not s.identifiable and "read as w_3, w_0, w_1, w_2" in s.why
               and "rotor_angles_deg" in s.advice() for s in from_torques.values())
    assert wrong.status["k_T"].identifiable and wrong.thrust_coefficient == pytest.approx(ident.thrust_coefficient)
    assert "  J_x " in format_identification(wrong) and "rotor columns out of order: the rotor columns" in \
        format_identification(wrong)


def test_an_inertia_above_its_bound_says_what_the_flight_tells_of_the_order():
    est = {"k_T": 8.5e-6, "k_M": 1.4e-7, "J_x": 0.035, "J_y": 0.046, "J_z": 0.098, "theta_0": 5.7e-6,
           "theta_1": 5.3e-5 / 100, "theta_2": 1.4e-6, "theta_3": 2.8, "accel_bias": np.zeros(3)}
    est["J_x"] = 0.215 * 8.56e-6 / est["theta_1"]  # 23 times the bound
    se = {k: (np.full(3, 0.001) if k == "accel_bias" else 0.001 * abs(v)) for k, v in est.items()}
    excited = {a: idf.AxisExcitation(0.3, 1.0, 0.99) for a in idf.AXES}
    geometry = dict(mass=1.5, arm_length=0.215, rotor_radius=0.1, jx_equals_jy=False)
    w2, dw = _torques_followed(QUADROTOR, np.arange(4), noise=1.0)
    given = rotor_order([w2], [dw], QUADROTOR.mixer())
    st = idf.assess(est, se, excited, {}, has_imu=True, rotor_order=given, **geometry)
    why = st["theta_1"].why
    assert "another order than vehicle.yaml's angles?" not in why
    assert "(23 times it: more than noise in the recorded rotor speeds does to the slope" in why
    assert "the rotor columns are in vehicle.yaml's order (of 24 orders" in why
    w2, dw = _torques_followed(QUADROTOR, np.array([1, 0, 3, 2]), noise=1.0)
    other = rotor_order([w2], [dw], QUADROTOR.mixer())
    st = idf.assess(est, se, excited, {}, has_imu=True, rotor_order=other, **geometry)
    assert st["theta_1"].reason == idf.OUT_OF_ORDER
    assert st["theta_1"].why.startswith("the rotor columns are in another order than vehicle.yaml's angles: read as "
                                        "w_1, w_0, w_3, w_2")
    assert "(23 times it: rotor columns out of order, read as w_1, w_0, w_3, w_2)" in st["theta_1"].why


def test_rotor_directions_given_the_other_way_round_are_named_from_the_yaw():
    fd, _ = inverse_dynamics_flight(QUADROTOR, seed=4, rotor_quantum=0.01)
    right = identify([fd], QUADROTOR)
    assert right.identified("k_M") and "rotor_directions reversed" not in right.status["theta_2"].why
    flipped = QUADROTOR.with_params()
    flipped = dataclasses.replace(flipped, rotor_directions=tuple(-d for d in QUADROTOR.rotor_directions))
    wrong = identify([fd], flipped)
    for name in ("theta_2", "k_M"):
        s = wrong.status[name]
        assert not s.identifiable and "rotor_directions reversed; +1 is counter-clockwise seen from above" in s.why
    assert wrong.rotor_order.verdict == GIVEN  # the roll and pitch torques do not see the directions
    assert wrong.moment_coefficient == pytest.approx(-right.moment_coefficient, rel=1e-6)
