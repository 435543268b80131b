"""Identification and residuals on flights with known parameters."""

import dataclasses

import numpy as np
import pytest
from synthetic import inverse_dynamics_flight

from uavturb.commands.identify import format_identification
from uavturb.io.reader import load_recordings
from uavturb.numerics.stream_updates import rounding_share
from uavturb.physics.vehicle import HEXAROTOR, QUADROTOR
from uavturb.sim.flights.condition_schema import Conditions
from uavturb.sim.flights.conditions import generate_conditioned_flight
from uavturb.sysid.accelerometer import flight_accel_bias
from uavturb.sysid.identification import identify
from uavturb.sysid.residuals import residual_forces


@pytest.mark.parametrize("vehicle", [HEXAROTOR, QUADROTOR], ids=["hex", "quad"])
def test_identification_recovers_known_parameters(vehicle):
    # the paper's quadrotor hovers at 150 rad/s: a 1 rad/s quantum would be 40 % of its roll signal
    quantum = 1.0 if vehicle is HEXAROTOR else 0.01
    fd, _ = inverse_dynamics_flight(vehicle, seed=4, acc_bias=(0.0, 0.0, 0.05), rotor_quantum=quantum)
    ident = identify([fd], vehicle)
    assert ident.thrust_coefficient == pytest.approx(vehicle.thrust_coefficient, rel=0.01)
    J = np.array(vehicle.inertia)
    assert ident.theta[3] == pytest.approx(J[2] / J[0], rel=0.10)
    assert ident.inertia[0] == pytest.approx(J[0], rel=0.05)
    assert ident.moment_coefficient == pytest.approx(vehicle.moment_coefficient, rel=0.15)
    assert ident.accel_bias[2] == pytest.approx(0.05, abs=0.01)
    assert 0 < ident.thrust_coefficient_se < 0.005 * ident.thrust_coefficient
    assert np.all(ident.inertia_se > 0) and np.all(np.isfinite(ident.theta_se))


def test_unequal_roll_and_pitch_inertia_is_found():
    v = HEXAROTOR.with_params(inertia=(0.030, 0.050, 0.0977))
    fd, _ = inverse_dynamics_flight(v, seed=2, rate_amp=(1.0, 1.0, 0.5))
    ident = identify([fd], v)
    assert ident.model == "general"
    assert ident.inertia[0] == pytest.approx(0.030, rel=0.05)
    assert ident.inertia[1] == pytest.approx(0.050, rel=0.05)


def test_residual_recovers_a_known_force_from_imu_and_mocap():
    def push(t):
        return np.stack([0.4 * np.sin(0.5 * t), 0.3 * np.ones_like(t), -0.5 * (t > 30)], 1)

    fd, truth = inverse_dynamics_flight(HEXAROTOR, seed=3, f_ext=push, rotor_quantum=0)
    imu = residual_forces(fd, HEXAROTOR, source="imu")
    moc = residual_forces(fd, HEXAROTOR, source="mocap")
    inner = slice(50, -50)
    err_imu = imu.force[inner] - truth["F_ext"][inner]
    # the IMU residual is the noise of m * acc (0.028 m/s^2 * 1.5 kg); the MoCap one has no sensor noise here
    assert np.sqrt(np.mean(err_imu**2)) < 0.06
    assert np.abs(np.mean(err_imu, axis=0)).max() < 0.01
    steady = (fd.t > 2) & (fd.t < 28) | (fd.t > 32) & (fd.t < 58)
    assert np.abs(moc.force[steady] - truth["F_ext"][steady]).max() < 0.02


def test_sessions_that_differ_in_thrust_level_widen_k_T_s_error_to_their_spread(tmp_path):
    """Two flights of one vehicle, the second's thrust per rotor speed squared 4 % higher (another battery, other
    propellers): each recording's own k_T is given, 4 % apart, and the pooled k_T's stated error covers their
    spread (each lands within two errors of it), where its sample error alone was a small fraction of a percent."""
    paths = []
    for seed, level in ((41, 1.0), (42, 1.04)):
        path = tmp_path / f"level-{level}"
        generate_conditioned_flight("hex", {}, duration=20.0, kind="mixed", seed=seed,
                                    conditions=Conditions(thrust_level=level), out=path)
        paths.append(path)
    ident = identify(load_recordings(paths))
    (k1, se1), (k2, se2) = ident.thrust_coefficient_per_recording.values()
    assert k2 / k1 == pytest.approx(1.04, abs=0.01) and max(se1, se2) < 0.005 * k1
    k, se = ident.thrust_coefficient, ident.thrust_coefficient_se
    # their spread, what a surface's lift changes (the flights take off and land) and the speeds' rounding to
    # 1 rad/s (each a small part beside a 4 % spread)
    rounding = max(rounding_share(r.rotors.speeds, 1.0) for r in load_recordings(paths)) * k
    assert se == pytest.approx(np.sqrt(np.std([k1, k2], ddof=1) ** 2 + (ident.surface_term or 0.0) ** 2
                                       + rounding ** 2), rel=1e-6)
    assert se < 1.01 * np.std([k1, k2], ddof=1)
    assert all(abs(x - k) < 2 * se for x in (k1, k2))
    assert set(ident.to_dict()["thrust_coefficient_per_recording"]) == {str(p) for p in paths}
    alone = identify(load_recordings(paths[:1]))
    assert alone.thrust_coefficient_per_recording == {} and alone.thrust_coefficient_se < 0.005 * k1


def test_the_accelerometer_bias_is_measured_against_the_motion_capture_not_traded_with_k_T():
    """Rotor commands 10 % noisy and an accelerometer reading 0.5 m/s^2 too much along z: the bias is what the IMU
    reads beyond the motion capture, exact; k_T is the motion capture's own (the IMU rows cannot pull it), where a
    bias fitted beside k_T had read 0.53 m/s^2 and moved k_T."""
    fd, _ = inverse_dynamics_flight(HEXAROTOR, duration=40.0, seed=7, rotor_noise=0.1, acc_bias=(0.2, -0.1, 0.5))
    ident = identify([fd], HEXAROTOR)
    assert ident.accel_bias == pytest.approx([0.2, -0.1, 0.5], abs=0.003)
    assert np.all(ident.accel_bias_se < 0.002) and ident.identified("accel_bias")
    mocap_only = identify([dataclasses.replace(fd, acc=None)], HEXAROTOR)
    assert ident.thrust_coefficient == pytest.approx(mocap_only.thrust_coefficient, rel=5e-4)


def test_imus_of_two_sessions_keep_their_own_bias_and_the_pooled_error_covers_them():
    """Two flights whose IMUs read 0.1 and 0.3 m/s^2 too much along x: each recording's bias is given, and the pooled
    bias's stated error covers both."""
    flights = [dataclasses.replace(inverse_dynamics_flight(HEXAROTOR, duration=20.0, seed=s, acc_bias=(bx, 0, 0))[0],
                                   name=f"session{s}") for s, bx in ((4, 0.1), (7, 0.3))]
    ident = identify(flights, HEXAROTOR)
    (b1, _), (b2, _) = ident.accel_bias_per_recording.values()
    assert b1[0] == pytest.approx(0.1, abs=0.005) and b2[0] == pytest.approx(0.3, abs=0.005)
    assert all(abs(b[0] - ident.accel_bias[0]) < 2 * ident.accel_bias_se[0] for b in (b1, b2))
    assert ident.accel_bias_se[0] == pytest.approx(np.std([b1[0], b2[0]], ddof=1), rel=1e-6)
    assert set(ident.to_dict()["accel_bias_per_recording"]) == {"session4", "session7"}
    # their spread (0.14 m/s^2) is no bias to correct with: not a result, and each recording's own is printed
    assert not ident.identified("accel_bias") and "listed apart" in ident.status["accel_bias"].why
    assert "accelerometer bias of each recording: session4 [ 0.1" in format_identification(ident)


def test_a_recording_without_an_imu_beside_one_with_it():
    """One flight with an IMU reading 0.2 m/s^2 too much along z, one with motion capture only: the bias is the IMU's,
    given for that recording, and both recordings' motion capture count for k_T."""
    with_imu = dataclasses.replace(inverse_dynamics_flight(HEXAROTOR, duration=20.0, seed=4,
                                                           acc_bias=(0.0, 0.0, 0.2))[0], name="with")
    mocap_only = dataclasses.replace(inverse_dynamics_flight(HEXAROTOR, duration=20.0, seed=7)[0], name="without",
                                     acc=None)
    ident = identify([with_imu, mocap_only], HEXAROTOR)
    assert ident.identified("accel_bias") and ident.accel_bias[2] == pytest.approx(0.2, abs=0.005)
    assert set(ident.accel_bias_per_recording) == {"with"}
    assert set(ident.thrust_coefficient_per_recording) == {"with", "without"}
    assert ident.thrust_coefficient == pytest.approx(HEXAROTOR.thrust_coefficient, rel=0.01)
    line = next(x for x in format_identification(ident).splitlines() if x.startswith("accelerometer bias of each"))
    assert line.endswith("m/s^2; no IMU: without") and line.startswith("accelerometer bias of each recording: with [")


def test_the_flight_bias_leaves_the_ground_out():
    """A touch-down's impact is in the accelerometer and smoothed out of the motion capture's derivative: over the rows
    in flight the bias is the accelerometer's own (0.1 m/s^2 along z); with the impact's rows counted it is not."""
    fd, _ = inverse_dynamics_flight(HEXAROTOR, duration=20.0, seed=4, acc_bias=(0.0, 0.0, 0.1))
    acc = fd.acc.copy()
    acc[1000:1040, 2] += 30.0  # 0.2 s of impact
    fd = dataclasses.replace(fd, acc=acc)
    in_flight = np.ones(len(fd.t), bool)
    in_flight[990:1050] = False
    assert flight_accel_bias(fd, in_flight).b[2] == pytest.approx(0.1, abs=0.005)
    assert flight_accel_bias(fd, np.ones(len(fd.t), bool)).b[2] > 0.3
    assert flight_accel_bias(dataclasses.replace(fd, acc=None), in_flight) is None


def test_one_recording_whose_thrust_level_steps_states_an_error_that_covers_its_halves():
    """One 40 s flight whose thrust per rotor speed squared steps up 2 % half-way (a battery swapped, a propeller
    changed): the stated error of k_T, the jackknife over time blocks, covers each half's own k_T within about two
    errors, where the sample error alone was a hundredth of that."""
    fd, _ = inverse_dynamics_flight(HEXAROTOR, duration=40.0, seed=4)
    late = fd.t > 20.0
    speeds = fd.rotor_speeds.copy()
    speeds[late] /= np.sqrt(1.02)
    fd = dataclasses.replace(fd, rotor_speeds=speeds)
    ident = identify([fd], HEXAROTOR)
    k, se = ident.thrust_coefficient, ident.thrust_coefficient_se
    halves = [identify([fd.subset(m)], HEXAROTOR).thrust_coefficient for m in (~late, late)]
    assert halves[1] / halves[0] == pytest.approx(1.02, abs=0.002)
    assert all(abs(h - k) < 2.5 * se for h in halves) and se > 0.003 * k
