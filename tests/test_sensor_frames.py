"""Sensor frame S vs rotor frame B (recordings.md): vehicle.yaml's T_BS, readers that move the
ground truth and the IMU into B, the thrust-axis and rotor-column checks, import-euroc's T_BS,
and motion-capture-only flights at 50 Hz.

The S-frame twins of simulated flights are made here with independent code (scipy rotations,
numpy gradients), not with uavturb.physics.frames.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import yaml
from scipy.spatial.transform import Rotation

from uavturb.cli import main
from uavturb.commands.identify import format_identification, identify_recordings
from uavturb.data.recordings import recording_sequence
from uavturb.errors import InputError
from uavturb.io.reader import load_recordings, read_recording
from uavturb.io.recording import Camera, GroundTruth, Imu, Recording, Rotors
from uavturb.io.vehicle_file import load_vehicle, save_vehicle
from uavturb.io.writer import write_recording
from uavturb.physics.vehicle import HEXAROTOR, Vehicle
from uavturb.scene.camera import forward_camera
from uavturb.sim.flights.simulate import generate_flight
from uavturb.sysid.identification import identify
from uavturb.sysid.residuals import residual_forces

#: EuRoC V1 vicon0/sensor.yaml T_BS: the Vicon (rotor) frame's pose in S
EUROC_T_S_VICON = np.array([[0.33638, -0.01749, 0.94156, 0.06901], [-0.02078, -0.99972, -0.01114, -0.02781],
                            [0.94150, -0.01582, -0.33665, -0.12395], [0.0, 0.0, 0.0, 1.0]])


def euroc_like_T_BS(lever=(0.06, -0.03, -0.08)) -> np.ndarray:
    """A pose of S in B like EuRoC's (x_S within 20 deg of up), exactly orthonormal, lever arm ~10 cm."""
    R_SB = Rotation.from_matrix(EUROC_T_S_VICON[:3, :3]).as_matrix()  # nearest rotation
    T = np.eye(4)
    T[:3, :3] = R_SB.T
    T[:3, 3] = lever
    return T


def as_tuple(T: np.ndarray):
    return tuple(tuple(float(x) for x in row) for row in T)


def to_sensor_frame(rec: Recording, T_BS: np.ndarray) -> Recording:
    """The recording an IMU and a state estimate at S would have made (independent of uavturb's frames).

    x_B = R_BS x_S + t: attitude R_WS = R_WB R_BS, position p_S = p_B + R_WB t, velocity
    v_S = v_B + R_WB (w x t), gyro R_BS^T w, accelerometer R_BS^T (f_B + dw/dt x t + w x (w x t)).
    """
    R_BS, t = T_BS[:3, :3], T_BS[:3, 3]
    gt, imu = rec.ground_truth, rec.imu
    assert np.array_equal(gt.t_ns, imu.t_ns)
    R_WB = Rotation.from_quat(gt.q[:, [1, 2, 3, 0]])  # scipy: x, y, z, w
    q_WS = (R_WB * Rotation.from_matrix(R_BS)).as_quat()[:, [3, 0, 1, 2]]
    w = imu.gyro - gt.b_w  # rad/s in B
    s = (imu.t_ns - imu.t_ns[0]) * 1e-9
    dw = np.gradient(w, s, axis=0)
    lever = np.cross(dw, t) + np.cross(w, np.cross(w, t))
    to_S = lambda x: x @ R_BS  # noqa: E731  (R_BS^T x, row-wise)
    gt_S = GroundTruth(t_ns=gt.t_ns, p=gt.p + R_WB.apply(t), q=q_WS, v=gt.v + R_WB.apply(np.cross(w, t)),
                       b_w=to_S(gt.b_w), b_a=to_S(gt.b_a))
    imu_S = Imu(t_ns=imu.t_ns, gyro=to_S(imu.gyro), acc=to_S(imu.acc + lever), T_BS=np.eye(4), rate_hz=imu.rate_hz)
    return replace(rec, vehicle=rec.vehicle.with_params(T_BS=as_tuple(T_BS)), ground_truth=gt_S, imu=imu_S, frame="S")


@pytest.fixture(scope="module")
def flight():
    return generate_flight("hex", "wind:f_x=0.6,f_y=-0.3", duration=20.0, seed=3)


# --- vehicle.yaml ------------------------------------------------------------------------


def test_vehicle_T_BS_round_trips_exactly(tmp_path):
    T = as_tuple(euroc_like_T_BS())
    v = HEXAROTOR.with_params(T_BS=T)
    save_vehicle(v, tmp_path / "vehicle.yaml")
    text = (tmp_path / "vehicle.yaml").read_text()
    back = load_vehicle(tmp_path / "vehicle.yaml")
    assert back.T_BS == T and back == v
    save_vehicle(back, tmp_path / "again.yaml")
    assert (tmp_path / "again.yaml").read_text() == text
    # absent: identity, and not written
    save_vehicle(HEXAROTOR, tmp_path / "plain.yaml")
    assert "T_BS" not in yaml.safe_load((tmp_path / "plain.yaml").read_text())
    assert np.array_equal(load_vehicle(tmp_path / "plain.yaml").T_BS_matrix, np.eye(4))
    # the matrix used is the nearest exact rotation
    R = load_vehicle(tmp_path / "vehicle.yaml").T_BS_matrix[:3, :3]
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-14)


@pytest.mark.parametrize("value, expected", [
    ([[1, 0, 0], [0, 1, 0], [0, 0, 1]], "key 'T_BS' must be 4 rows of 4 numbers"),
    ([[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 1, 1]], "key 'T_BS' must end with the row [0, 0, 0, 1]"),
    ([[2, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]],
     "key 'T_BS': the upper-left 3x3 block is not a rotation"),
    ([[-1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]], "not a rotation"),
    ([[1, 0, 0, "a"], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]], "key 'T_BS' holds a non-numeric"),
])
def test_vehicle_T_BS_bad(tmp_path, value, expected):
    d = HEXAROTOR.to_dict()
    d["T_BS"] = value
    with pytest.raises(InputError) as e:
        Vehicle.from_dict(d, where=tmp_path / "vehicle.yaml")
    assert str(e.value).startswith(f"{tmp_path / 'vehicle.yaml'}: ") and expected in str(e.value)


# --- the readers move S into B -------------------------------------------------------------


def spinning_recording(T_BS: np.ndarray, omega: float = 2.0, n: int = 400) -> tuple[Recording, np.ndarray]:
    """B hovers level at (0, 0, 1) and yaws at ``omega`` rad/s; what S (pose T_BS in B) records."""
    t_ns = 10**18 + np.arange(n, dtype=np.int64) * 5_000_000
    s = (t_ns - t_ns[0]) * 1e-9
    R_WB = Rotation.from_euler("z", omega * s[:, None])
    R_BS, r = T_BS[:3, :3], T_BS[:3, 3]
    w_W = np.array([0.0, 0.0, omega])
    rW = R_WB.apply(r)
    p_S = np.array([0.0, 0.0, 1.0]) + rW
    v_S = np.cross(w_W, rW)
    a_S = np.cross(w_W, v_S)  # centripetal
    f_S = (R_WB * Rotation.from_matrix(R_BS)).inv().apply(a_S + [0.0, 0.0, 9.81])
    q_WS = (R_WB * Rotation.from_matrix(R_BS)).as_quat()[:, [3, 0, 1, 2]]
    z = np.zeros((n, 3))
    gt = GroundTruth(t_ns=t_ns, p=p_S, q=q_WS, v=v_S, b_w=z + [1e-3, 0, 0], b_a=z + [0.0, 0.02, 0.0])
    imu = Imu(t_ns=t_ns, gyro=np.tile(R_BS.T @ w_W, (n, 1)), acc=f_S, T_BS=np.eye(4), rate_hz=200.0)
    rotors = Rotors(t_ns=t_ns, speeds=np.full((n, 6), 500.0) + np.arange(n)[:, None] % 7)
    veh = HEXAROTOR.with_params(T_BS=as_tuple(T_BS))
    return Recording(vehicle=veh, ground_truth=gt, imu=imu, rotors=rotors, frame="S"), R_WB.as_quat()[:, [3, 0, 1, 2]]


def test_reader_expresses_state_and_imu_in_B(tmp_path):
    T = euroc_like_T_BS(lever=(0.1, 0.0, -0.05))
    rec, q_WB = spinning_recording(T)
    write_recording(rec, tmp_path / "spin")
    raw = read_recording(tmp_path / "spin", frame="S")
    np.testing.assert_array_equal(raw.ground_truth.p, rec.ground_truth.p)  # stored as given
    back = read_recording(tmp_path / "spin")
    gt, imu = back.ground_truth, back.imu
    assert back.frame == "B"
    inner = slice(20, -20)  # away from the derivative windows' edges
    np.testing.assert_allclose(gt.p[inner], np.tile([0.0, 0.0, 1.0], (360, 1)), atol=1e-9)  # B sits still
    # omega from the attitude by a quadratic fit over 0.05 s: 1e-4 relative at 2 rad/s, 1.5e-5 m/s at 0.11 m
    np.testing.assert_allclose(gt.v[inner], 0.0, atol=5e-5)
    assert np.all(np.abs(np.sum(gt.q * q_WB, axis=1)) > 1 - 1e-12)  # the same attitude (q or -q)
    np.testing.assert_allclose(imu.gyro, np.tile([0.0, 0.0, 2.0], (400, 1)), atol=1e-12)
    np.testing.assert_allclose(imu.acc[inner], np.tile([0.0, 0.0, 9.81], (360, 1)), atol=1e-9)  # centripetal removed
    np.testing.assert_allclose(gt.b_w, np.tile(T[:3, :3] @ [1e-3, 0, 0], (400, 1)), atol=1e-15)
    np.testing.assert_allclose(gt.b_a, np.tile(T[:3, :3] @ [0, 0.02, 0], (400, 1)), atol=1e-15)
    # written back (from B) the files hold S again
    write_recording(back, tmp_path / "again")
    again = read_recording(tmp_path / "again", frame="S")
    np.testing.assert_allclose(again.ground_truth.p, rec.ground_truth.p, atol=1e-12)
    np.testing.assert_allclose(again.ground_truth.v, rec.ground_truth.v, atol=1e-12)
    np.testing.assert_allclose(again.imu.acc, rec.imu.acc, atol=1e-12)


def test_identity_T_BS_changes_nothing(tmp_path, recording):
    write_recording(recording, tmp_path / "r")
    back = read_recording(tmp_path / "r")
    assert np.array_equal(back.ground_truth.v, recording.ground_truth.v)
    assert np.array_equal(back.imu.acc, recording.imu.acc)


# --- twins: S = B and a rotated, offset S identify the same k_T -----------------------------


def test_rotated_sensor_twin_identifies_the_same_k_T(tmp_path, flight):
    write_recording(flight, tmp_path / "b")
    write_recording(to_sensor_frame(flight, euroc_like_T_BS()), tmp_path / "s")
    raw = read_recording(tmp_path / "s", frame="S")
    assert np.mean(raw.imu.acc[:, 0]) > 8.5  # x_S points up: EuRoC-like
    k_b = identify_recordings([tmp_path / "b"]).thrust_coefficient
    k_s = identify_recordings([tmp_path / "s"]).thrust_coefficient
    assert k_s == pytest.approx(k_b, rel=0.02)
    assert k_b == pytest.approx(HEXAROTOR.thrust_coefficient, rel=0.05)

    # the same recording without T_BS: one line naming vehicle.yaml and T_BS, exit 2
    save_vehicle(flight.vehicle, tmp_path / "s" / "vehicle.yaml")
    with pytest.raises(InputError) as e:
        load_recordings([tmp_path / "s"])
    msg = str(e.value)
    assert msg.startswith(f"{tmp_path / 's' / 'vehicle.yaml'}: T_BS: the mean specific force in flight points ")
    angle = float(msg.split("points ")[1].split(" deg")[0])
    # z_B read in S is R_BS^T e_z = EuRoC's R_S,vicon e_z = (0.942, -0.011, -0.337): 110 deg from z_S
    assert angle == pytest.approx(np.degrees(np.arccos(-0.33665)), abs=2.0) and "\n" not in msg
    f = np.array([float(x) for x in msg.split("reads (")[1].split(")")[0].split(",")])
    np.testing.assert_allclose(f / np.linalg.norm(f), [0.942, -0.011, -0.337], atol=0.02)
    assert main(["identify", str(tmp_path / "s")]) == 2


# --- dead or frozen rotor columns ------------------------------------------------------------


@pytest.mark.parametrize("value, expected", [(0.0, "column w_3 is 0 throughout the flight"),
                                             (612.0, "column w_3 holds the constant value 612 throughout")])
def test_dead_rotor_column(tmp_path, flight, value, expected):
    speeds = flight.rotors.speeds.copy()
    speeds[:, 3] = value
    write_recording(replace(flight, rotors=Rotors(t_ns=flight.rotors.t_ns, speeds=speeds)), tmp_path / "r")
    with pytest.raises(InputError) as e:
        load_recordings([tmp_path / "r"])
    assert str(e.value).startswith(f"{tmp_path / 'r' / 'mav0/rotors0/data.csv'}: ") and expected in str(e.value)


# --- evaluate's depth images: cam0's T_BS is relative to S ------------------------------------


def test_cam0_is_posed_through_T_BS(tmp_path, flight):
    """A rotated, offset S: cam0/sensor.yaml holds the camera's pose in S (EuRoC). The depth images
    equal those of the S = B twin whose cam0 holds the camera's pose in B."""
    model = forward_camera(16, 16, yfov_deg=70.0, pitch_deg=30.0)  # a model's camera: its image size
    T_BC = model.T_BC  # camera pose in B
    T_BS = euroc_like_T_BS()
    cam = Camera(intrinsics=np.array([20.0, 20.0, 15.5, 11.5]), resolution=(32, 24), T_BS=T_BC)
    write_recording(replace(flight, cam0=cam), tmp_path / "b")
    twin = to_sensor_frame(flight, T_BS)
    T_SC = np.linalg.inv(T_BS) @ T_BC  # what EuRoC's cam0/sensor.yaml would hold
    write_recording(replace(twin, cam0=replace(cam, T_BS=T_SC)), tmp_path / "s")

    seqs = []
    for name in ("b", "s"):
        rec = read_recording(tmp_path / name, require_rotors=True)
        seqs.append(recording_sequence(rec, HEXAROTOR, model, frame_dt=1.0))
    b, s = seqs
    np.testing.assert_allclose(s.camera.T_BC, T_BC, atol=1e-12)
    assert len(b) == len(s) > 10 and (b.depth > 0).mean() > 0.9
    np.testing.assert_allclose(s.depth, b.depth, atol=1e-4)
    np.testing.assert_allclose(s.p, b.p, atol=1e-9)
    # the camera taken as relative to B (the old reading) would look elsewhere
    wrong = replace(read_recording(tmp_path / "s"), vehicle=HEXAROTOR)
    assert not np.allclose(recording_sequence(wrong, HEXAROTOR, model, frame_dt=1.0).depth, b.depth,
                           atol=0.05)


# --- motion capture only, 50 Hz, jittered --------------------------------------------------------


def mocap_only_50hz(flight: Recording, seed: int = 0, jitter_ns: int = 3_000_000) -> Recording:
    """``flight`` without imu0: ground truth and rotor speeds at 50 Hz on independently jittered
    timestamps (+-3 ms), interpolated from the 200 Hz streams (scipy's slerp for attitudes)."""
    from scipy.spatial.transform import Slerp

    rng = np.random.default_rng(seed)
    gt = flight.ground_truth

    def jittered(start: int) -> np.ndarray:
        t = np.arange(start, gt.t_ns[-1], 20_000_000, dtype=np.int64)
        return np.sort(t + rng.integers(-jitter_ns, jitter_ns + 1, len(t)))[1:-1]

    src = (gt.t_ns - gt.t_ns[0]) * 1e-9
    t_gt, t_rot = jittered(int(gt.t_ns[0])), jittered(int(gt.t_ns[0]) + 7_000_000)
    s, sr = (t_gt - gt.t_ns[0]) * 1e-9, (t_rot - gt.t_ns[0]) * 1e-9
    lin = lambda x, at: np.column_stack([np.interp(at, src, c) for c in x.T])  # noqa: E731
    q = Slerp(src, Rotation.from_quat(gt.q[:, [1, 2, 3, 0]]))(s).as_quat()[:, [3, 0, 1, 2]]
    z = np.zeros((len(s), 3))
    return replace(flight, imu=None, ground_truth=GroundTruth(t_ns=t_gt, p=lin(gt.p, s), q=q, v=lin(gt.v, s), b_w=z,
                                                              b_a=z),
                   rotors=Rotors(t_ns=t_rot, speeds=lin(flight.rotors.speeds, sr)))


def test_mocap_only_50hz_flight(tmp_path, flight):
    """No IMU, 50 Hz, jittered: k_T as the simulator's, no accelerometer bias, residuals that
    find the injected steady push (0.6, -0.3, 0) N with a noise floor measured on the data."""
    write_recording(mocap_only_50hz(flight), tmp_path / "m50")
    (rec,) = load_recordings([tmp_path / "m50"])
    assert rec.imu is None and np.ptp(np.diff(rec.ground_truth.t_ns)) > 4_000_000  # jittered
    ident = identify([rec])
    assert ident.thrust_coefficient == pytest.approx(HEXAROTOR.thrust_coefficient, rel=0.02)
    assert ident.accel_bias is None and ident.to_dict()["accel_bias"] is None
    assert "accelerometer bias" in format_identification(ident) and "absent" in format_identification(ident)

    res = residual_forces(rec, ident.apply(rec.vehicle))
    assert res.source == "mocap"
    inner = (res.t > 1.0) & (res.t < res.t[-1] - 1.0)  # the reference's start and end are left out
    F, injected = res.force[inner], np.array([0.6, -0.3, 0.0])
    np.testing.assert_allclose(F.mean(axis=0), injected, atol=0.05)  # N
    noise = np.sqrt(np.mean((F - injected) ** 2, axis=0))  # N, what is not the push: ~0.1 N per axis
    floor = res.noise_floor()
    np.testing.assert_allclose(floor, noise, rtol=0.15)  # the floor measured without knowing the push
    rms = np.sqrt(np.mean(np.sum(F**2, axis=1)))
    assert rms == pytest.approx(np.sqrt(injected @ injected + floor @ floor), rel=0.05)
