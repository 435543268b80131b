"""Identification and residuals on flights with known parameters."""

import numpy as np
import pytest
from synthetic import inverse_dynamics_flight

from uavturb.io.reader import load_recordings
from uavturb.physics.vehicle import HEXAROTOR, QUADROTOR
from uavturb.sim.flights.condition_schema import Conditions
from uavturb.sim.flights.conditions import generate_conditioned_flight
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
    assert se == pytest.approx(np.std([k1, k2], ddof=1), rel=1e-6)
    assert all(abs(x - k) < 2 * se for x in (k1, k2))
    assert set(ident.to_dict()["thrust_coefficient_per_recording"]) == {str(p) for p in paths}
    alone = identify(load_recordings(paths[:1]))
    assert alone.thrust_coefficient_per_recording == {} and alone.thrust_coefficient_se < 0.005 * k1
