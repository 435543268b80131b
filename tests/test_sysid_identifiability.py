"""What a flight determines: identified constants, and the others with their reasons (known truths)."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest
from synthetic import inverse_dynamics_flight

from uavturb.cli import main
from uavturb.errors import InputError
from uavturb.commands.identify import format_identification
from uavturb.io.recording import GroundTruth, Recording, Rotors
from uavturb.io.writer import write_recording
from uavturb.physics.vehicle import HEXAROTOR
from uavturb.sysid import identifiability as idf
from uavturb.sysid.identification import identify
from uavturb.sysid.least_squares import lstsq

YAW = ("J_z", "k_M", "theta_2", "theta_3")


@pytest.fixture(scope="module")
def yawing():
    fd, _ = inverse_dynamics_flight(HEXAROTOR, duration=40.0, seed=4, acc_bias=(0.0, 0.0, 0.05))
    return identify([fd], HEXAROTOR)


@pytest.fixture(scope="module")
def fixed_heading():
    """Motion capture only, small roll/pitch manoeuvres, the heading never changes."""
    fd, _ = inverse_dynamics_flight(HEXAROTOR, duration=40.0, seed=4, rate_amp=(0.3, 0.3, 0.0))
    return dataclasses.replace(fd, acc=None)


def test_a_flight_with_yaw_excitation_identifies_everything(yawing):
    assert yawing.not_identified == []
    assert all(s.reason == "identified" and s.why == "" for s in yawing.status.values())
    v = yawing.apply(HEXAROTOR.with_params(thrust_coefficient=None, moment_coefficient=None, inertia=None))
    assert v.moment_coefficient == pytest.approx(HEXAROTOR.moment_coefficient, rel=0.05)
    assert v.inertia[2] == pytest.approx(HEXAROTOR.inertia[2], rel=0.05)
    assert yawing.status["accel_bias"].value[2] == pytest.approx(0.05, abs=0.01)
    assert yawing.excitation["yaw"].rate_std > idf.RATE_MIN and yawing.excitation["yaw"].share > 0.9


def test_a_fixed_heading_flight_does_not_excite_yaw(fixed_heading):
    ident = identify([fixed_heading], HEXAROTOR)
    for name in YAW:
        assert ident.status[name].reason == "not excited", (name, ident.status[name])
        assert "no yaw manoeuvre" in ident.status[name].why
    assert ident.status["accel_bias"].reason == "absent"
    for name in ("k_T", "J_x", "J_y", "theta_0", "theta_1"):
        assert ident.status[name].identifiable, (name, ident.status[name].why)
    assert ident.thrust_coefficient == pytest.approx(HEXAROTOR.thrust_coefficient, rel=0.01)
    assert ident.excitation["yaw"].rate_std < 0.01

    text = format_identification(ident)
    results, _, undetermined = text.partition("not determined by these flights")
    assert "J_x" in results and "J_z" not in results and "k_M" not in results
    jz_line = next(line for line in undetermined.splitlines() if line.strip().startswith("J_z"))
    assert jz_line.split()[1] == "-" and "not excited" in jz_line  # not estimated: no gyroscopic terms
    th2_line = next(line for line in undetermined.splitlines() if line.strip().startswith("theta_2"))
    assert "[" in th2_line and "not excited" in th2_line  # estimated, shown in brackets, not as a result
    assert "accelerometer bias" in undetermined and "absent" in undetermined


def test_a_held_heading_with_a_noisy_gyro_does_not_give_theta_2():
    """Differentiated gyro noise alone lifts the yaw acceleration over ACC_MIN (as on real Crazyflies): the yaw torque
    then only answers noise, and theta_2 = k_M/J_z is not a result."""
    fd, _ = inverse_dynamics_flight(HEXAROTOR, duration=40.0, seed=4, rate_amp=(0.3, 0.3, 0.0), gyro_noise=0.03)
    ident = identify([fd], HEXAROTOR)
    assert ident.excitation["yaw"].acc_std > idf.ACC_MIN  # the acceleration test alone would pass
    assert ident.status["theta_2"].reason == "not excited"
    assert "yaw rate std" in ident.status["theta_2"].why


def test_noisy_rotor_commands_shrink_the_torque_slope_and_say_so():
    """Rotor speeds recorded with 25 % noise: least squares shrinks theta_2 to the column's share of the variance;
    the share is read, and theta_2 is not given as a result. (With the torques filtered as the derivative filters
    them, 20 % noise left 79 % of the share, where the value smoother had left 66 %.)"""
    fd, _ = inverse_dynamics_flight(HEXAROTOR, duration=40.0, seed=4, rate_amp=(1.6, 1.6, 0.3), rotor_noise=0.25)
    ident = identify([fd], HEXAROTOR)
    truth = HEXAROTOR.moment_coefficient / HEXAROTOR.inertia[2]
    share = ident.excitation["yaw"].share
    assert share < idf.SHARE_MIN and ident.theta[2] < 0.75 * truth  # shrunk, as the share says
    assert ident.theta[2] / share == pytest.approx(truth, rel=0.05)  # the reverse regression's bound holds the truth
    st = ident.status["theta_2"]
    assert st.reason == "ill-conditioned" and "rotor-torque column carries 71 %" in st.why
    assert "up to 1.4 times the estimate" in st.why
    assert not ident.status["k_M"].identifiable
    clean = identify([inverse_dynamics_flight(HEXAROTOR, duration=40.0, seed=4, rate_amp=(1.6, 1.6, 0.3))[0]],
                     HEXAROTOR)
    assert clean.status["theta_2"].identifiable and clean.excitation["yaw"].share > 0.95


def test_apply_falls_back_to_nominal_values_or_stops(fixed_heading):
    ident = identify([fixed_heading], HEXAROTOR)
    nominal = HEXAROTOR.with_params(inertia=(0.01, 0.02, 0.123), moment_coefficient=2e-7)
    v = ident.apply(nominal)
    assert v.inertia[2] == 0.123 and v.moment_coefficient == 2e-7  # not the flight's estimates
    assert v.inertia[0] == pytest.approx(HEXAROTOR.inertia[0], rel=0.02)  # identified, not vehicle.yaml's 0.01
    assert any(f.startswith("J_z = 0.123 from vehicle.yaml") for f in ident.fallbacks(nominal))
    with pytest.raises(InputError) as e:
        ident.apply(HEXAROTOR.with_params(inertia=None, moment_coefficient=None))
    assert e.value.where in ("J_z", "k_M")
    assert "no yaw manoeuvre" in e.value.problem and "fly yaw steps" in e.value.problem
    assert "vehicle.yaml" in e.value.problem


def test_noise_only_regression_is_ill_conditioned():
    fd, _ = inverse_dynamics_flight(HEXAROTOR, duration=40.0, seed=5)
    rng = np.random.default_rng(0)
    scrambled = dataclasses.replace(fd, rotor_speeds=fd.rotor_speeds[rng.permutation(len(fd.t))])
    ident = identify([scrambled], HEXAROTOR)
    for name in ("J_x", "J_y", "J_z", "k_M", "theta_1", "theta_2"):
        assert ident.status[name].reason == "ill-conditioned", (name, ident.status[name])
    assert ident.excitation["roll"].share < 0.05  # the torque column explains nothing


def test_wrong_rotor_directions_give_an_impossible_moment_coefficient():
    fd, _ = inverse_dynamics_flight(HEXAROTOR, duration=40.0, seed=6)
    flipped = HEXAROTOR.with_params(rotor_directions=tuple(-s for s in HEXAROTOR.rotor_directions))
    ident = identify([fd], flipped)
    assert ident.status["k_M"].reason == "physically impossible"
    assert "not positive" in ident.status["k_M"].why
    assert ident.status["k_T"].identifiable


def _est(**over):
    est = {"k_T": 8.5e-6, "k_M": 1.4e-7, "J_x": 0.035, "J_y": 0.046, "J_z": 0.098, "theta_0": 5.7e-6,
           "theta_1": 5.3e-5, "theta_2": 1.4e-6, "theta_3": 2.8, "accel_bias": np.zeros(3)}
    est.update(over)
    se = {k: (np.full(3, 0.001) if k == "accel_bias" else 0.001 * abs(v)) for k, v in est.items()}
    return est, se


EXCITED = {a: idf.AxisExcitation(0.3, 1.0, 0.99) for a in idf.AXES}
GEOMETRY = dict(mass=1.5, arm_length=0.215, rotor_radius=0.1, jx_equals_jy=False)


def test_physical_bounds():
    est, se = _est()
    ok = idf.assess(est, se, EXCITED, {}, has_imu=True, **GEOMETRY)
    assert all(s.identifiable for s in ok.values())  # the Firefly's own inertia (J_z = 1.21 (J_x + J_y)) passes
    est, se = _est(J_z=0.14)  # 1.7 (J_x + J_y): no rigid body
    st = idf.assess(est, se, EXCITED, {}, has_imu=True, **GEOMETRY)
    assert [n for n in ("J_x", "J_y", "J_z") if not st[n].identifiable] == ["J_z"]
    assert st["J_z"].reason == "physically impossible" and "triangle" in st["J_z"].why
    assert st["k_M"].reason == "physically impossible" and "computed from J_z" in st["k_M"].why
    est, se = _est(J_x=0.73)  # the value: beyond the whole mass at the propeller tips
    st = idf.assess(est, se, EXCITED, {}, has_imu=True, **GEOMETRY)
    assert st["J_x"].reason == "physically impossible" and "m (l + r)^2 = 0.149" in st["J_x"].why
    est, se = _est(k_M=2e-6)  # drag torque above thrust x radius
    st = idf.assess(est, se, EXCITED, {}, has_imu=True, **GEOMETRY)
    assert st["k_M"].reason == "physically impossible"
    # rotor columns in another order: theta_1 = l k_T / J_x 58 times too small puts J_x at 2.28 kg m^2; theta_1 is
    # no result either (it had been printed as one, +- 28 %)
    est, se = _est(theta_1=8.07e-7, J_x=0.215 * 8.56e-6 / 8.07e-7)
    st = idf.assess(est, se, EXCITED, {}, has_imu=True, **GEOMETRY)
    assert (st["theta_1"].reason == "physically impossible"
            and "J_x = l k_T / theta_1 at 2.28 kg m^2" in st["theta_1"].why)
    assert st["theta_1"].why.endswith("(rotor columns in another order than vehicle.yaml's angles?)")
    # the same 15-times-too-small slope where the rotor-torque column carries 5 % of the roll acceleration's variance:
    # noise in the recorded speeds can shrink the slope 20 times, and the order is not asked about
    est, se = _est(theta_1=5.3e-5 / 15, J_x=0.215 * 8.56e-6 / (5.3e-5 / 15))
    noisy_roll = EXCITED | {"roll": idf.AxisExcitation(0.3, 1.0, 0.05)}
    st = idf.assess(est, se, noisy_roll, {}, has_imu=True, **GEOMETRY)
    assert st["theta_1"].reason == "ill-conditioned" and "another order" not in st["theta_1"].why
    assert "(3.5 times it: within what noise in the recorded rotor speeds does to the slope (up to 20 times))" \
        in st["theta_1"].why
    # 100 times too small (23 times the bound): beyond what that noise does, so the order is asked about again
    est, se = _est(theta_1=5.3e-5 / 100, J_x=0.215 * 8.56e-6 / (5.3e-5 / 100))
    st = idf.assess(est, se, noisy_roll, {}, has_imu=True, **GEOMETRY)
    assert st["theta_1"].why.endswith("(rotor columns in another order than vehicle.yaml's angles?)")
    # a column that carries 1 % tells nothing of the order: both are said
    st = idf.assess(est, se, EXCITED | {"roll": idf.AxisExcitation(0.3, 1.0, 0.01)}, {}, has_imu=True, **GEOMETRY)
    assert st["theta_1"].why.endswith("(23 times it: noise in the recorded rotor speeds, whose torque column carries "
                                      "1 % of the acceleration's variance, or rotor columns in another order than "
                                      "vehicle.yaml's angles?)")


def test_collinear_columns_are_ill_conditioned():
    rng = np.random.default_rng(1)
    x = rng.normal(size=500)
    A = np.stack([x, x + 1e-5 * rng.normal(size=500), np.ones(500)], 1)
    fit = lstsq(A, x + rng.normal(0, 0.1, 500), lag=1)
    assert fit.cond > idf.COND_MAX
    assert lstsq(np.stack([x, np.ones(500)], 1), x, lag=1).cond < 2
    est, se = _est()
    st = idf.assess(est, se, EXCITED, {"yaw": fit.cond}, has_imu=True, **GEOMETRY)
    assert st["theta_2"].reason == "ill-conditioned" and "collinear" in st["theta_2"].why
    assert st["k_M"].reason == "ill-conditioned"


def test_identify_json_carries_the_status(fixed_heading, tmp_path, capsys):
    fd = fixed_heading
    zeros = np.zeros((len(fd.t_ns), 3))
    rec = Recording(vehicle=HEXAROTOR.with_params(inertia=None, moment_coefficient=None),
                    ground_truth=GroundTruth(fd.t_ns, fd.p, fd.q, fd.v, zeros, zeros),
                    rotors=Rotors(fd.t_ns.copy(), fd.rotor_speeds))
    path = write_recording(rec, tmp_path / "mocap_only")
    assert main(["identify", str(path), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["thrust_coefficient"] == pytest.approx(HEXAROTOR.thrust_coefficient, rel=0.01)
    p = out["parameters"]
    assert set(p) == set(idf.PARAMETERS)
    assert p["k_T"]["identifiable"] and p["k_T"]["value"] == pytest.approx(out["thrust_coefficient"])
    assert not p["J_z"]["identifiable"] and p["J_z"]["why"].startswith("the flight has no yaw manoeuvre")
    assert p["accel_bias"] == {"value": None, "stderr": None, "identifiable": False, "reason": "absent",
                               "why": p["accel_bias"]["why"]}
    assert set(out["not_identified"]) == {*YAW, "accel_bias"}
    # residual forces need only k_T: without J_z (vehicle.yaml has none) the torques are left out, and
    # one line says which constants are missing
    assert main(["residuals", str(path), "--out", str(tmp_path / "r.csv")]) == 0
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "J_z" in err and "torques left out" in err and "vehicle.yaml" in err
    table = np.genfromtxt(tmp_path / "r.csv", delimiter=",", names=True)
    assert np.all(np.isnan(table["tau_Bz_N_m"])) and np.all(np.isfinite(table["F_z_N"]))
