"""``uavturb generate flight`` under real recordings' troubles: each readable, each with its known truth."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest
import yaml
from scipy.signal import savgol_filter

from uavturb.cli import main
from uavturb.io.reader import load_recordings, read_recording
from uavturb.io.writer import write_recording
from uavturb.physics import quaternion as quat
from uavturb.physics.dynamics import GRAVITY
from uavturb.physics.effects import EffectInputs, body_drag_force, rotor_drag_force
from uavturb.physics.vehicle import HEXAROTOR
from uavturb.sim.flights import conditions as C
from uavturb.sim.flights.condition_schema import Conditions
from uavturb.sim.flights.sensors import SensorNoise
from uavturb.sim.flights.simulate import make_reference, simulate_flight


@pytest.fixture(scope="module")
def flight():
    """A noise-free 12 s excitation flight of the hexarotor (exact truths)."""
    ref = make_reference("excitation", 12.0, 3, HEXAROTOR)
    rec, truth = simulate_flight(HEXAROTOR, ref, duration=12.0, noise=SensorNoise.none(), seed=3)
    return rec, truth


def _conditioned(flight, tmp_path, **kw):
    rec, truth = flight
    c = C.condition(rec, truth, Conditions(**kw), true_vehicle=HEXAROTOR, effects={}, seed=1,
                    w_max=2.5 * HEXAROTOR.hover_speed())
    write_recording(c.recording, tmp_path / "rec", extras=c.extras)
    return c, tmp_path / "rec"


def test_mocap_only_50hz_with_jitter(flight, tmp_path):
    _, truth = flight
    c, path = _conditioned(flight, tmp_path, no_imu=True, rate_hz=50, jitter_ms=3)
    assert not (path / "mav0" / "imu0").exists()
    rec = read_recording(path)
    for t_ns in (rec.ground_truth.t_ns, rec.rotors.t_ns):
        dt_ms = np.diff(t_ns) * 1e-6
        assert 14 <= dt_ms.min() and dt_ms.max() <= 26 and np.std(dt_ms) > 1.0  # 20 ms +- 2 x 3 ms
        assert np.median(dt_ms) == pytest.approx(20.0, abs=1.0)
    # every row is the state at its own timestamp
    t = rec.seconds(rec.ground_truth.t_ns)
    p_true = np.stack([np.interp(t, truth.t, truth.x[:, i]) for i in range(3)], 1)
    assert np.abs(rec.ground_truth.p - p_true).max() < 1e-4  # m
    assert c.truth["streams"] == {**c.truth["streams"], "rate_hz": 50, "jitter_ms": 3}


def test_motor_commands_follow_the_affine_curve(flight, tmp_path):
    _, truth = flight
    c, path = _conditioned(flight, tmp_path, motor_commands=True)
    mc = c.truth["motor_commands"]
    raw = np.loadtxt(path / "mav0" / "rotors0" / "data.csv", delimiter=",", comments="#")[:, 1:]
    assert raw.min() >= 0.0 and raw.max() <= 1.0 and mc["clipped_samples"] == 0
    np.testing.assert_allclose(mc["a"] + mc["b"] * raw, truth.rotor_commands, atol=1e-6)  # the true speeds
    rec = read_recording(path)
    assert rec.vehicle.rotor_speed_scale == pytest.approx(mc["rotor_speed_scale"])
    w_h = HEXAROTOR.hover_speed()
    assert mc["rotor_speed_scale"] * mc["u_hover"] == pytest.approx(w_h)  # exact at hover
    err = rec.rotors.speeds - truth.rotor_commands  # the nominal model's error: a (w - w_h) / (w_h - a)
    np.testing.assert_allclose(err, mc["a"] * (truth.rotor_commands - w_h) / (w_h - mc["a"]), atol=1e-6)


def test_motor_commands_are_written_as_commanded_whatever_the_vehicle_file_said(flight, tmp_path):
    """A vehicle file saying its rotor speeds are measured (an ESC-telemetry quadrotor), flown with motor commands
    in rotors0: the recording's vehicle.yaml says commanded (it had kept measured, and a probe's finder read the
    commands' map as speeds: mu 3.77 +- 0.39 for 3); with measured rotors it says measured."""
    rec, truth = flight
    said_measured = (dataclasses.replace(rec, vehicle=rec.vehicle.with_params(rotor_speed_source="measured")), truth)
    assert read_recording(_conditioned(said_measured, tmp_path / "a")[1]).vehicle.rotor_speed_source == "measured"
    _, path = _conditioned(said_measured, tmp_path / "b", motor_commands=True)
    assert read_recording(path).vehicle.rotor_speed_source == "commanded"
    _, path = _conditioned(flight, tmp_path / "c", measured_rotors=True)
    assert read_recording(path).vehicle.rotor_speed_source == "measured"


def test_sensor_frame_has_the_lever_arm_accelerations(flight, tmp_path):
    _, truth = flight
    c, path = _conditioned(flight, tmp_path, sensor_frame="euroc")
    rec_s = read_recording(path, frame="S")
    np.testing.assert_allclose(np.asarray(rec_s.vehicle.T_BS), C.EUROC_T_BS, atol=1e-12)
    assert np.linalg.norm(C.EUROC_T_BS[:3, 3]) == pytest.approx(0.10)
    mean_acc = rec_s.imu.acc.mean(axis=0)
    np.testing.assert_allclose(mean_acc, [9.2, 0.0, -3.3], atol=0.25)  # recordings.md's EuRoC reading
    # the IMU is the specific force of S's own trajectory (differentiated twice here, independently)
    t = rec_s.seconds(rec_s.ground_truth.t_ns)
    a_w = savgol_filter(rec_s.ground_truth.p, 21, 3, deriv=2, delta=t[1] - t[0], axis=0)
    f_s = quat.rotate_inverse(rec_s.ground_truth.q, a_w + np.array([0.0, 0.0, GRAVITY]))
    inner = slice(50, -50)
    assert np.sqrt(np.mean((f_s[inner] - rec_s.imu.acc[inner]) ** 2)) < 0.02  # m/s^2
    # ... which a plain rotation of B's reading is not: the lever arm's terms are felt
    plain = truth.specific_force @ C.EUROC_T_BS[:3, :3]
    assert (np.sqrt(np.mean((f_s[inner] - plain[inner]) ** 2))
            > 5 * np.sqrt(np.mean((f_s[inner] - rec_s.imu.acc[inner]) ** 2)))
    # readers that follow recordings.md put it back into B: B's positions and the thrust axis
    (rec_b,) = load_recordings([path])
    p_true = np.stack([np.interp(rec_b.seconds(rec_b.ground_truth.t_ns), truth.t, truth.x[:, i]) for i in range(3)], 1)
    assert np.abs(rec_b.ground_truth.p - p_true).max() < 1e-6
    np.testing.assert_allclose(rec_b.imu.acc[inner], truth.specific_force[inner], atol=0.05)


def test_wind_push_at_hover_is_the_drag_law():
    k_d, c_d, vw = 8.06e-5, 0.05, (1.5, -0.5)
    push = C.wind_push_at_hover(HEXAROTOR, k_d, c_d, vw)
    w_h = HEXAROTOR.hover_speed()
    x = EffectInputs(q=np.array([[1.0, 0, 0, 0]]), v=-np.array([[vw[0], vw[1], 0.0]]),
                     rotor_speeds=np.full((1, 6), w_h), k_T=HEXAROTOR.thrust_coefficient, rotor_radius=0.1)
    law = rotor_drag_force(x, k_d) + body_drag_force(x, c_d)  # drag on the airspeed v - v_w at rest
    np.testing.assert_allclose(push, law[0, :2], rtol=1e-12)
    assert law[0, 2] == 0.0


def test_wind_acts_as_drag_on_the_airspeed_in_the_simulator():
    c = C.generate_conditioned_flight("hex", "", duration=10.0, kind="excitation", seed=2,
                                      conditions=Conditions(wind_speed=(2.0, 1.0)), noise=SensorNoise.none())
    push = c.truth["equivalent_effects"]["wind"]
    assert c.truth["effects"] == {"rotor_drag": {"k_d": 8.06e-5}, "body_drag": {"c_d": 0.05}}
    # the flight hovers on average: the simulated effect force averages to the push at hover
    rec = c.recording
    t = rec.seconds(rec.ground_truth.t_ns)
    a_w = savgol_filter(rec.ground_truth.v, 11, 2, deriv=1, delta=t[1] - t[0], axis=0)
    thrust = HEXAROTOR.thrust_coefficient * np.sum(rec.rotors.speeds**2, axis=1)
    R = quat.to_rotation_matrix(rec.ground_truth.q)
    F_ext = HEXAROTOR.mass * (a_w + np.array([0, 0, GRAVITY])) - thrust[:, None] * R[:, :, 2]
    np.testing.assert_allclose(F_ext[200:-200, :2].mean(axis=0), [push["f_x"], push["f_y"]], rtol=0.15, atol=0.02)


def test_generate_flight_cli_with_troubles(tmp_path, capsys):
    out = tmp_path / "rec"
    args = ["generate", "flight", "--duration", "6", "--kind", "excitation", "--seed", "5", "--out", str(out),
            "--fixed-heading", "--accel-bias-walk", "0.01", "--mass-error", "0.05", "--wind-speed", "1,-0.5",
            "--rate-hz", "100", "--jitter-ms", "1"]
    assert main(args) == 0
    truth = yaml.safe_load((out / "truth.yaml").read_text())
    rec = read_recording(out)
    assert rec.vehicle.mass == pytest.approx(1.5 * 1.05) and truth["vehicle"]["mass"] == 1.5
    assert truth["conditions"]["mass_error"]["fraction"] == 0.05
    # the heading never changes (the controller holds the reference's constant yaw)
    R = quat.to_rotation_matrix(rec.ground_truth.q)
    yaw = np.unwrap(np.arctan2(R[:, 1, 0], R[:, 0, 0]))
    assert np.degrees(np.ptp(yaw)) < 2.0 and truth["conditions"]["fixed_heading"]["yaw_rad"] == pytest.approx(yaw[0],
                                                                                                               abs=0.02)
    # the bias walks with the stated density; the state file keeps the initial bias
    bias = np.loadtxt(out / "truth" / "accel_bias.csv", delimiter=",", comments="#")
    steps = np.diff(bias[:, 1:], axis=0)
    assert np.std(steps) == pytest.approx(0.01 * np.sqrt(0.005), rel=0.1)
    np.testing.assert_array_equal(rec.ground_truth.b_a, np.zeros_like(rec.ground_truth.b_a))
    assert truth["conditions"]["accel_bias_walk"]["sigma"] == 0.01
    # the wind's push at hover, from the law with the vehicle's coefficients
    w = truth["conditions"]["wind_speed"]
    assert truth["equivalent_effects"]["wind"] == w["push_at_hover"]
    assert w["push_at_hover"]["f_x"] == pytest.approx(C.wind_push_at_hover(HEXAROTOR, w["k_d"], w["c_d"], (1, -0.5))[0])
    assert 9.5 <= np.median(np.diff(rec.ground_truth.t_ns)) * 1e-6 <= 10.5


@pytest.mark.parametrize("option, value, named", [("--jitter-ms", "12", "--jitter-ms"), ("--rate-hz", "0", "--rate-hz"),
                                                  ("--wind-speed", "1", "--wind-speed"),
                                                  ("--mass-error", "2", "--mass-error")])
def test_bad_condition_options_give_one_line(tmp_path, capsys, option, value, named):
    out = tmp_path / "rec"
    assert main(["generate", "flight", "--duration", "2", "--out", str(out), "--rate-hz", "50", option, value]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and named in err and "Traceback" not in err
    assert not out.exists()


def test_identify_on_a_fixed_heading_mocap_flight_reports_yaw_not_excited(tmp_path, capsys):
    out = tmp_path / "fixed"
    assert main(["generate", "flight", "--duration", "10", "--kind", "excitation", "--seed", "7", "--out", str(out),
                 "--fixed-heading", "--no-imu", "--rate-hz", "100"]) == 0
    capsys.readouterr()
    assert main(["identify", str(out), "--json"]) == 0
    p = json.loads(capsys.readouterr().out)["parameters"]
    assert p["k_T"]["identifiable"] and p["k_T"]["value"] == pytest.approx(HEXAROTOR.thrust_coefficient, rel=0.02)
    for name in ("J_z", "k_M"):
        assert p[name]["reason"] == "not excited" and "yaw" in p[name]["why"], p[name]
    assert p["accel_bias"]["reason"] == "absent"
