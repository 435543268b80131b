"""Synthetic flights: controller, references, simulator and what the sensors record."""

from __future__ import annotations

import numpy as np
import pytest

from uavturb.errors import InputError
from uavturb.physics import quaternion as quat
from uavturb.physics.dynamics import dynamics_for, physical_params
from uavturb.physics.effects import lag_rotor_speeds, parse_effects
from uavturb.physics.vehicle import HEXAROTOR, QUADROTOR
from uavturb.scene.layouts import table_room
from uavturb.scene.queries import surface_below
from uavturb.sim.core.controller import GeometricController
from uavturb.sim.core.signals import hover
from uavturb.sim.flights.plans import excitation, low_passes, mixed, over_table, table_bounds
from uavturb.sim.flights.sensors import SensorNoise
from uavturb.sim.flights.simulate import EUROC_T0_NS, generate_flight, make_reference, simulate_flight

from other_vehicles import HEAVY_HEX

E_Z = np.array([0.0, 0.0, 1.0])


def _ratio_error(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.max(np.abs(a - b)) / max(np.max(np.abs(b)), 1e-12))


# --- references ---------------------------------------------------------------------


@pytest.mark.parametrize("make", [excitation, low_passes, mixed])
def test_reference_derivatives_are_consistent_and_seeded(make):
    ref = make(40.0, seed=3)
    t = np.arange(0.0, ref.duration, 0.002)
    sp = ref(t)
    for f, df in ((sp.p, sp.v), (sp.v, sp.a), (sp.a, sp.j)):
        num = np.gradient(f, t, axis=0)[2:-2]
        assert np.max(np.abs(num - df[2:-2])) < 0.02 * max(1.0, np.max(np.abs(df)))
    assert np.max(np.abs(np.gradient(sp.yaw, t)[2:-2] - sp.yaw_rate[2:-2])) < 1e-3
    again = make(40.0, seed=3)(t)
    assert np.array_equal(again.p, sp.p) and np.array_equal(again.yaw, sp.yaw)
    assert not np.allclose(make(40.0, seed=4)(t).p, sp.p)
    # starts and ends at rest
    for end in (ref(0.0), ref(ref.duration)):
        assert np.allclose(end.v, 0.0, atol=1e-9) and abs(end.yaw_rate) < 1e-9


def test_excitation_is_rich_and_bounded():
    ref = excitation(60.0, seed=0)
    sp = ref(np.arange(0.0, 60.0, 0.01))
    speed = np.linalg.norm(sp.v[:, :2], axis=1)
    assert 1.0 < speed.max() < 2.5  # horizontal speeds up to about 2 m/s
    assert np.all((sp.p[:, 2] > 0.9) & (sp.p[:, 2] < 1.6))  # around 1-1.5 m
    assert np.ptp(np.unwrap(sp.yaw)) > np.pi  # the yaw sweeps through headings
    assert np.max(np.abs(sp.yaw_acc)) <= 0.5 + 1e-9


def test_low_passes_stay_clear_of_the_table():
    room = table_room()
    ref = low_passes(120.0, seed=1, room=room)
    sp = ref(np.arange(0.0, ref.duration, 0.01))
    over = over_table(room, sp.p[:, 0], sp.p[:, 1])
    assert over.any() and (~over).any()
    height = sp.p[:, 2] - surface_below(room, sp.p[:, :2])
    assert height.min() >= 0.06 - 1e-9
    assert np.any(over & (height < 0.5))  # low over the table
    assert "edge_pass" in ref.notes


# --- controller -----------------------------------------------------------------------


@pytest.mark.parametrize("vehicle", [HEXAROTOR, QUADROTOR])
def test_allocation_inverts_the_mixer(vehicle):
    ctrl = GeometricController(vehicle)
    w, sat = ctrl.allocate(vehicle.mass * 9.81, np.zeros(3))
    assert not sat and np.allclose(w, vehicle.hover_speed(), rtol=1e-12)
    wrench = np.array([vehicle.mass * 9.81, 0.3, -0.2, 0.05]) * np.array([1.0, *(3 * [vehicle.mass * 0.01])])
    w, sat = ctrl.allocate(wrench[0], wrench[1:])
    assert not sat and np.allclose(vehicle.allocation() @ w**2, wrench, rtol=1e-9)


# --- flights ------------------------------------------------------------------------


@pytest.mark.parametrize("vehicle", [HEXAROTOR, QUADROTOR])
def test_hover_holds_position(vehicle):
    ref = hover((0.0, 0.0, 1.0), yaw=0.3, duration=10.0)
    effects = parse_effects("wind:f_x=0.3" if vehicle is HEXAROTOR else "")
    _, truth = simulate_flight(vehicle, ref, effects=effects, seed=1)
    err = np.linalg.norm(truth.x[:, :3] - ref(0.0).p, axis=1)
    assert err.max() < 0.05


@pytest.mark.parametrize("vehicle", [HEXAROTOR, QUADROTOR])
def test_excitation_tracking(vehicle):
    ref = make_reference("excitation", 20.0, seed=2, vehicle=vehicle)
    _, truth = simulate_flight(vehicle, ref, effects=parse_effects("rotor_drag" if vehicle is HEXAROTOR else ""))
    assert truth.tracking_rms() < 0.3
    w = truth.x[:, 10:13]
    # roll/pitch rates while yawing: the gyroscopic products are excited
    assert np.max(np.abs(w[:, 0] * w[:, 2])) > 0.05 and np.max(np.abs(w[:, 1] * w[:, 2])) > 0.05


def test_specific_force_is_the_analytic_one():
    ref = make_reference("low_passes", 15.0, seed=0, vehicle=HEXAROTOR)
    effects = parse_effects("wind:f_x=0.4,f_y=-0.2,rotor_drag,ground_effect,body_drag")
    rec, truth = simulate_flight(HEXAROTOR, ref, effects=effects, noise=SensorNoise.none())
    q = rec.ground_truth.q
    T = HEXAROTOR.thrust_coefficient * np.sum(truth.rotor_speeds**2, axis=1)
    analytic = (T[:, None] * E_Z + quat.rotate_inverse(q, truth.force)) / HEXAROTOR.mass
    assert _ratio_error(rec.imu.acc, analytic) < 1e-9
    assert np.array_equal(rec.imu.gyro, truth.x[:, 10:13])
    assert np.abs(truth.force[:, 2]).max() > 0.1  # ground effect did act
    # the recorded heights are those of the room
    room = table_room()
    p = truth.x[:, :3]
    x0, x1, y0, y1 = table_bounds(room)
    far = (np.minimum(np.abs(p[:, 0] - x0), np.abs(p[:, 0] - x1)) > 0.1) & \
          (np.minimum(np.abs(p[:, 1] - y0), np.abs(p[:, 1] - y1)) > 0.1)
    expected = p[:, 2] - surface_below(room, p[:, :2])
    assert np.max(np.abs(truth.d_down[far] - expected[far])) < 0.03
    assert np.max(np.abs(truth.d_up - (room.ceiling_height - p[:, 2]))) < 0.03


def test_wind_is_recovered_from_imu_and_rotors():
    ref = make_reference("excitation", 10.0, seed=1, vehicle=HEXAROTOR)
    rec, truth = simulate_flight(HEXAROTOR, ref, effects=parse_effects("wind:f_x=0.5"), noise=SensorNoise.none())
    R = quat.to_rotation_matrix(rec.ground_truth.q)
    T = HEXAROTOR.thrust_coefficient * np.sum(rec.rotors.speeds**2, axis=1)
    f = HEXAROTOR.mass * np.einsum("kij,kj->ki", R, rec.imu.acc) - T[:, None] * R[:, :, 2]
    assert _ratio_error(f, np.tile([0.5, 0.0, 0.0], (len(f), 1))) < 1e-6
    assert np.allclose(truth.effect_force, [0.5, 0.0, 0.0])


def test_motor_lag_records_commands():
    tau = 0.03
    ref = make_reference("excitation", 10.0, seed=0, vehicle=HEXAROTOR)
    rec, truth = simulate_flight(HEXAROTOR, ref, effects=parse_effects(f"motor_lag:tau={tau}"),
                                 noise=SensorNoise.none())
    assert np.array_equal(rec.rotors.speeds, truth.rotor_commands)
    assert np.max(np.abs(truth.rotor_commands - truth.rotor_speeds)) > 1.0
    # commands change only at control instants, which are record instants: the recorded
    # commands and effects.md's exact lag give back the actual speeds
    assert _ratio_error(lag_rotor_speeds(truth.t, truth.rotor_commands, tau), truth.rotor_speeds) < 1e-9
    R = quat.to_rotation_matrix(rec.ground_truth.q)
    T_cmd = HEXAROTOR.thrust_coefficient * np.sum(rec.rotors.speeds**2, axis=1)
    f = HEXAROTOR.mass * np.einsum("kij,kj->ki", R, rec.imu.acc) - T_cmd[:, None] * R[:, :, 2]
    assert np.max(np.abs(f - truth.lag_force)) < 1e-9
    assert np.abs(truth.lag_force).max() > 0.01  # N: the lag did change the thrust


def test_states_follow_the_dynamics():
    """Without effects and lag, each recorded state is Dynamics.step applied to the previous one."""
    ref = make_reference("excitation", 2.0, seed=0, vehicle=QUADROTOR)
    _, truth = simulate_flight(QUADROTOR, ref, noise=SensorNoise.none())
    dyn, theta = dynamics_for(QUADROTOR), physical_params(QUADROTOR)
    for k in (0, 57, 300):
        x = truth.x[k]
        for _ in range(5):
            x = dyn.step(x, truth.rotor_speeds[k], theta, 0.001)
        assert np.max(np.abs(x - truth.x[k + 1])) < 1e-12


def test_noise_timestamps_and_determinism():
    ref = hover((0.0, 0.0, 1.2), duration=5.0)
    noise = SensorNoise(gyro_bias=(0.01, -0.02, 0.005), acc_bias=(0.05, 0.0, -0.1))
    a, ta = simulate_flight(HEXAROTOR, ref, noise=noise, seed=5)
    b, _ = simulate_flight(HEXAROTOR, ref, noise=noise, seed=5)
    c, _ = simulate_flight(HEXAROTOR, ref, noise=noise, seed=6)
    t = a.ground_truth.t_ns
    assert t.dtype == np.int64 and t[0] == EUROC_T0_NS and np.all(np.diff(t) == 5_000_000)
    for x, y in ((a.imu.acc, b.imu.acc), (a.imu.gyro, b.imu.gyro), (a.ground_truth.p, b.ground_truth.p),
                 (a.rotors.speeds, b.rotors.speeds)):
        assert np.array_equal(x, y)
    assert not np.array_equal(a.imu.acc, c.imu.acc)
    # white noise of the stated density at 200 Hz, around the true biases
    gyro_err = a.imu.gyro - ta.x[:, 10:13] - np.asarray(noise.gyro_bias)
    assert np.std(gyro_err) == pytest.approx(1.7e-4 * np.sqrt(200.0), rel=0.1)
    assert np.allclose(np.mean(a.imu.acc - ta.specific_force, axis=0), noise.acc_bias, atol=0.01)
    assert np.allclose(a.ground_truth.b_a, noise.acc_bias) and np.allclose(a.ground_truth.b_w, noise.gyro_bias)
    assert np.std(a.ground_truth.p - ta.x[:, :3]) == pytest.approx(1e-3, rel=0.1)
    assert np.all(np.mod(a.rotors.speeds, 1.0) == 0.0)


def test_written_recording_reads_back(tmp_path):
    pytest.importorskip("uavturb.io.writer")
    reader = pytest.importorskip("uavturb.io.reader")
    out = tmp_path / "flight"
    rec = generate_flight("quad", "rotor_drag", duration=3.0, kind="excitation", seed=1, out=out)
    back = reader.read_recording(out)
    assert np.array_equal(back.ground_truth.t_ns, rec.ground_truth.t_ns)
    assert np.array_equal(back.imu.t_ns, rec.imu.t_ns) and np.array_equal(back.rotors.t_ns, rec.rotors.t_ns)
    for x, y in ((back.ground_truth.p, rec.ground_truth.p), (back.ground_truth.q, rec.ground_truth.q),
                 (back.ground_truth.v, rec.ground_truth.v), (back.imu.gyro, rec.imu.gyro),
                 (back.imu.acc, rec.imu.acc), (back.rotors.speeds, rec.rotors.speeds)):
        np.testing.assert_allclose(x, y, rtol=1e-12, atol=1e-12)
    assert back.points is not None and back.points.shape == rec.points.shape
    assert back.vehicle == rec.vehicle


@pytest.mark.parametrize("vehicle", [HEXAROTOR, QUADROTOR])
def test_excitation_identifies_inertia(vehicle):
    """With realistic noise and rotor-speed quantisation, the excitation pins J_x, J_y and, through
    the gyroscopic terms, J_z: w_dot_x = l k_T u_1 / J_x + (J_y - J_z) / J_x w_y w_z (recordings.md)."""
    from scipy.signal import savgol_filter

    ref = make_reference("excitation", 30.0, seed=4, vehicle=vehicle)
    rec, _ = simulate_flight(vehicle, ref, seed=4)
    w = savgol_filter(rec.imu.gyro, 11, 3, axis=0)
    w_dot = savgol_filter(rec.imu.gyro, 11, 3, deriv=1, delta=0.005, axis=0)
    u = (vehicle.mixer() @ (rec.rotors.speeds**2).T).T
    lk = vehicle.arm_length * vehicle.thrust_coefficient
    coef = []
    for axis, (ui, gyro_term) in enumerate(((u[:, 1], w[:, 1] * w[:, 2]), (u[:, 2], w[:, 0] * w[:, 2]))):
        A = np.stack([ui, gyro_term, np.ones_like(ui)], axis=1)[10:-10]
        coef.append(np.linalg.lstsq(A, w_dot[10:-10, axis], rcond=None)[0])
    J_x, J_y = lk / coef[0][0], lk / coef[1][0]
    J_z = 0.5 * ((J_y - coef[0][1] * J_x) + (J_x + coef[1][1] * J_y))
    assert np.allclose([J_x, J_y, J_z], vehicle.inertia, rtol=0.1)
    assert J_z / J_x == pytest.approx(vehicle.inertia[2] / vehicle.inertia[0], rel=0.1)


def test_a_vehicle_resting_in_ground_effect_starts_without_sinking():
    """The controller starts as if it had rested in the effect force at the rotor plane's heights, where the
    laws act: preloaded at the body origin's, a hexarotor whose rotors sit 15 cm above it started with an
    exponential ground law's lift 15 cm lower (17.7 % of the weight for 7.3 %) and sank 2.6 cm through the
    floor it rested on."""
    vehicle = HEXAROTOR.with_params(rotor_plane_z=0.15)
    ref = make_reference("low_passes", 3.0, seed=2000, vehicle=vehicle)
    _, truth = simulate_flight(vehicle, ref, effects=parse_effects("ground_effect_exponential:A=0.2,lam=1.7"),
                               noise=SensorNoise.none())
    z = truth.x[:, 2]
    assert z[truth.t < 1.5].min() > z[0] - 0.006  # m: the take-off's first dip, as without any effect


def test_a_flight_the_controller_loses_is_refused_not_written(tmp_path):
    """A ground effect of mu = 4 on a 2.5 kg hexarotor's 0.127 m rotors throws the vehicle off its reference at
    take-off: the flight had been written regardless, its height running from -5.6 to 30.7 m, and the gap finder
    then analysed it as a real one."""
    vehicle = tmp_path / "hex25.yaml"
    vehicle.write_text(HEAVY_HEX)
    out = tmp_path / "lost"
    with pytest.raises(InputError, match=r"generate flight: the simulated vehicle lost its reference at t = \d"):
        generate_flight(vehicle=str(vehicle), effects="ground_effect:mu=4", duration=5.0, kind="low_passes", seed=5,
                        out=out)
    assert not out.exists()
    generate_flight(vehicle=str(vehicle), effects="ground_effect:mu=2", duration=5.0, kind="low_passes", seed=5,
                    out=out)  # a ground effect it holds
    assert (out / "vehicle.yaml").exists()
