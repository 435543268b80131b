"""Raw EuRoC ROS1 bags: a bag written here with ``rosbags`` reads back into a Recording."""

from __future__ import annotations

import numpy as np
import pytest
from rosbags.rosbag1 import Writer
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from uavturb.cli import main
from uavturb.errors import InputError
from uavturb.io import rosbag
from uavturb.io.euroc_import import import_euroc
from uavturb.io.reader import read_recording
from uavturb.io.sensor_yaml import _dump, _matrix
from uavturb.io.vehicle_file import named_vehicle
from uavturb.io.writer import write_recording
from uavturb.physics.vehicle import HEXAROTOR, QUADROTOR

T0 = 1403636579_000_000_000
MOTOR_MSG = "std_msgs/Header header\nint16[6] motor_speed\n"
MOTOR_TYPE = "asctec_hl_comm/msg/MotorSpeed"


def stamp_of(store, t_ns):
    Time = store.types["builtin_interfaces/msg/Time"]
    return store.types["std_msgs/msg/Header"](seq=0, stamp=Time(sec=t_ns // 10**9, nanosec=t_ns % 10**9),
                                               frame_id="")


def truth(t_ns):
    s = (np.asarray(t_ns) - T0) * 1e-9
    p = np.stack([0.5 * s, -0.25 * s + 1.0, 0.1 * s**2], axis=-1)
    half = 0.4 * s / 2
    q = np.stack([np.cos(half), 0 * s, 0 * s, np.sin(half)], axis=-1)  # yaw at 0.4 rad/s
    v = np.stack([0.5 + 0 * s, -0.25 + 0 * s, 0.2 * s], axis=-1)
    return p, q, v


def write_bag(path, *, n_motor=6, motors=True, vicon=True, motor_offset_ns=0, imu_R=None):
    """A small EuRoC-like bag; ``imu_R`` (3, 3) rotates the IMU's vectors (into a sensor frame S)."""
    store = get_typestore(Stores.ROS1_NOETIC)
    store.register(get_types_from_msg(MOTOR_MSG.replace("[6]", f"[{n_motor}]"), MOTOR_TYPE))
    Imu, Vec = store.types["sensor_msgs/msg/Imu"], store.types["geometry_msgs/msg/Vector3"]
    Quat = store.types["geometry_msgs/msg/Quaternion"]
    TS, Tf = store.types["geometry_msgs/msg/TransformStamped"], store.types["geometry_msgs/msg/Transform"]
    Motor = store.types[MOTOR_TYPE]
    t_vicon = T0 + np.arange(100) * 10_000_000  # 100 Hz, 1 s
    t_imu = T0 + 2_500_000 + np.arange(200) * 5_000_000
    t_motor = T0 + motor_offset_ns + 1_000_000 + np.arange(40) * 25_000_000
    with Writer(path) as w:
        c_imu = w.add_connection(rosbag.IMU_TOPIC, "sensor_msgs/msg/Imu", typestore=store)
        c_vicon = w.add_connection(rosbag.VICON_TOPIC, "geometry_msgs/msg/TransformStamped", typestore=store)
        c_motor = w.add_connection(rosbag.MOTOR_TOPIC, MOTOR_TYPE, typestore=store)
        R = np.eye(3) if imu_R is None else np.asarray(imu_R, float)
        for k, t in enumerate(t_imu.tolist()):
            gx, gy, gz = (R @ [0.01 * k, -0.02, 0.4]).tolist()
            ax, ay, az = (R @ [0.1, 0.2, 9.81 + 1e-3 * k]).tolist()
            msg = Imu(header=stamp_of(store, t), orientation=Quat(x=0.0, y=0.0, z=0.0, w=1.0),
                      orientation_covariance=np.zeros(9), angular_velocity=Vec(x=gx, y=gy, z=gz),
                      angular_velocity_covariance=np.zeros(9), linear_acceleration=Vec(x=ax, y=ay, z=az),
                      linear_acceleration_covariance=np.zeros(9))
            w.write(c_imu, t + 777, store.serialize_ros1(msg, "sensor_msgs/msg/Imu"))  # record time != stamp
        if vicon:
            p, q, _ = truth(t_vicon)
            for t, pk, qk in zip(t_vicon.tolist(), p.tolist(), q.tolist()):
                tf = Tf(translation=Vec(x=pk[0], y=pk[1], z=pk[2]), rotation=Quat(x=qk[1], y=qk[2], z=qk[3], w=qk[0]))
                msg = TS(header=stamp_of(store, t), child_frame_id="firefly_sbx", transform=tf)
                w.write(c_vicon, t, store.serialize_ros1(msg, "geometry_msgs/msg/TransformStamped"))
        if motors:
            for k, t in enumerate(t_motor.tolist()):
                speeds = np.array([100 + k + i for i in range(n_motor)], dtype=np.int16)
                w.write(c_motor, t, store.serialize_ros1(Motor(header=stamp_of(store, t), motor_speed=speeds),
                                                         MOTOR_TYPE))
    return t_vicon, t_imu, t_motor


def test_bag_reads_into_a_recording(tmp_path):
    bag = tmp_path / "MH_01.bag"
    t_vicon, t_imu, t_motor = write_bag(bag)
    rec = rosbag.read_rosbag(bag, HEXAROTOR, rotor_speed_scale=3.0)
    gt = rec.ground_truth
    p, q, v = truth(t_vicon)
    assert np.array_equal(gt.t_ns, t_vicon)
    np.testing.assert_allclose(gt.p, p, atol=1e-12)
    np.testing.assert_allclose(gt.q, q, atol=1e-12)
    np.testing.assert_allclose(gt.v, v, atol=1e-9)  # quadratic positions: differentiation is exact
    assert np.all(gt.b_w == 0) and np.all(gt.b_a == 0)
    assert np.array_equal(rec.vicon.t_ns, t_vicon)
    assert np.array_equal(rec.imu.t_ns, t_imu)  # header stamps, not record times
    np.testing.assert_allclose(rec.imu.gyro[:, 0], 0.01 * np.arange(200))
    np.testing.assert_allclose(rec.imu.acc[:, 2], 9.81 + 1e-3 * np.arange(200))
    assert np.array_equal(rec.rotors.t_ns, t_motor)
    expected = 3.0 * (100 + np.arange(40)[:, None] + np.arange(6)[None, :])
    np.testing.assert_array_equal(rec.rotors.speeds, expected)
    assert rec.vehicle.rotor_speed_scale == 3.0 and rec.path == bag


def test_bag_imports_to_a_folder_that_reads_back(tmp_path):
    """Through ``uavturb import euroc``'s function: the recording checks run before anything is written."""
    bag = tmp_path / "V1_01.bag"
    write_bag(bag)
    rec = import_euroc(bag, tmp_path / "V1_01", vehicle=HEXAROTOR, rotor_speed_scale=3.0)
    back = read_recording(tmp_path / "V1_01")
    np.testing.assert_allclose(back.rotors.speeds, rec.rotors.speeds, rtol=1e-12)
    np.testing.assert_allclose(back.ground_truth.v, rec.ground_truth.v, rtol=1e-12, atol=1e-15)
    assert back.vehicle.rotor_speed_scale == 3.0


def test_bag_without_motor_topic_and_default_scale(tmp_path):
    bag = tmp_path / "b.bag"
    write_bag(bag, motors=False)
    rec = rosbag.read_rosbag(bag, HEXAROTOR)
    assert rec.rotors is None and rec.imu is not None and rec.vehicle == HEXAROTOR


@pytest.mark.parametrize("kwargs, vehicle, expected", [
    ({"vicon": False}, HEXAROTOR, "topic '/vicon/firefly_sbx/firefly_sbx' has 0 messages"),
    ({}, QUADROTOR, "/fcu/motor_speed: has 6 rotor speed columns but the vehicle 'quad-paper' has rotor_count 4"),
    ({"motor_offset_ns": 5_000_000_000}, HEXAROTOR, "/fcu/motor_speed: does not overlap the vicon stream"),
])
def test_bag_errors(tmp_path, kwargs, vehicle, expected):
    bag = tmp_path / "b.bag"
    write_bag(bag, **kwargs)
    with pytest.raises(InputError) as e:
        rosbag.read_rosbag(bag, vehicle)
    assert str(bag) in str(e.value) and expected in str(e.value)


def test_not_a_bag(tmp_path):
    with pytest.raises(InputError, match="x.bag: file not found"):
        rosbag.read_rosbag(tmp_path / "x.bag", HEXAROTOR)
    (tmp_path / "x.bag").write_text("hello")
    with pytest.raises(InputError, match="x.bag: not a readable ROS1 bag"):
        rosbag.read_rosbag(tmp_path / "x.bag", HEXAROTOR)


def test_velocity_from_irregular_positions():
    t = np.cumsum(np.random.default_rng(0).integers(4_000_000, 16_000_000, size=50)).astype(np.int64)
    s = (t - t[0]) * 1e-9
    p = np.stack([2 * s, s**2, 0 * s], axis=1)
    v = rosbag.velocity_from_positions(t, p)
    np.testing.assert_allclose(v[:, 0], 2.0, atol=1e-9)
    np.testing.assert_allclose(v[1:-1, 1], 2 * s[1:-1], atol=1e-9)  # central differences: exact inside


def test_import_euroc_asl_folder_plus_bag_rotors(tmp_path, capsys):
    """A downloaded EuRoC sequence: ASL folder (no vehicle.yaml, no rotors0) + its bag's motor
    speeds, with the shipped Firefly vehicle file, becomes a recording of recordings.md."""
    import shutil

    from conftest import make_recording

    t_vicon, _, t_motor = write_bag(tmp_path / "V1_01.bag")
    rec = make_recording(duration=1.0)
    rec.rotors = None
    # EuRoC's frames: the ASL's ground truth and IMU in S, the Vicon (rotor) frame's pose in S in
    # vicon0/sensor.yaml; the recording is written from B into S with T_BS = that pose's inverse
    T_S_vicon = np.array([[0.33638, -0.01749, 0.94156, 0.06901], [-0.02078, -0.99972, -0.01114, -0.02781],
                          [0.94150, -0.01582, -0.33665, -0.12395], [0.0, 0.0, 0.0, 1.0]])
    T_BS = np.linalg.inv(T_S_vicon)
    rec.vehicle = rec.vehicle.with_params(T_BS=tuple(map(tuple, T_BS.tolist())))
    # the ASL folder's ground truth spans the bag's time
    shift = t_vicon[0] - rec.ground_truth.t_ns[0]
    for stream in (rec.ground_truth, rec.imu, rec.vicon, rec.cam0):
        stream.t_ns = stream.t_ns + shift
    write_recording(rec, tmp_path / "asl")
    (tmp_path / "asl" / "vehicle.yaml").unlink()
    shutil.rmtree(tmp_path / "asl" / "mav0" / "rotors0", ignore_errors=True)
    _dump(tmp_path / "asl" / "mav0" / "vicon0" / "sensor.yaml",
          {"sensor_type": "visual-inertial", "comment": "vicon", "T_BS": _matrix(T_S_vicon)}, "Vicon in S")
    raw = read_recording(tmp_path / "asl", vehicle=rec.vehicle, frame="S")
    assert np.mean(raw.imu.acc[:, 0]) > 8.0  # EuRoC-like: x_S points up

    assert main(["import", "euroc", str(tmp_path / "V1_01.bag"), "--asl", str(tmp_path / "asl"), "--vehicle", "firefly",
                 "--rotor-speed-scale", "4.0", "--out", str(tmp_path / "V1_01")]) == 0
    back = read_recording(tmp_path / "V1_01", require_rotors=True)
    assert back.vehicle.name == "firefly" and back.vehicle.rotor_count == 6
    np.testing.assert_array_equal(back.rotors.t_ns, t_motor)
    np.testing.assert_allclose(back.rotors.speeds[:, 0], 4.0 * (100 + np.arange(40)))
    # the ASL's ground truth, not the bag's, back in B (EuRoC's 5-decimal rotation is 7e-6 from a
    # rotation: the general and the rigid inverse of T_S_vicon differ by 1e-6 m here)
    np.testing.assert_allclose(back.ground_truth.p, rec.ground_truth.p, atol=1e-5)
    assert back.points is not None and len(back.points) == len(rec.points)
    # T_BS from the sequence's vicon0/sensor.yaml: the inverse of the Vicon frame's pose in S
    np.testing.assert_allclose(np.array(back.vehicle.T_BS), T_BS, atol=1e-5)
    np.testing.assert_allclose(back.imu.acc.mean(0), rec.imu.acc.mean(0), atol=1e-3)  # in B again

    # bag whose motors lie outside the ASL folder's time span: one line, nothing written
    write_bag(tmp_path / "late.bag", motor_offset_ns=10**12)
    assert main(["import", "euroc", str(tmp_path / "late.bag"), "--asl", str(tmp_path / "asl"),
                 "--out", str(tmp_path / "late")]) == 2
    err = capsys.readouterr().err
    assert "late.bag" in err and "overlap" in err and not (tmp_path / "late").exists()


def test_import_euroc_bag_only_uses_the_presets_T_BS(tmp_path, capsys):
    """Without an ASL folder the shipped Firefly's T_BS applies: the bag's IMU in a EuRoC-like S
    (x up) reads +z in B; the same bag with its IMU in B stops with one line on T_BS."""
    firefly = named_vehicle("firefly")
    R_BS = firefly.T_BS_matrix[:3, :3]
    np.testing.assert_allclose(R_BS @ [9.2, 0.0, -3.3], [0.0, -0.1, 9.8], atol=0.06)  # hover: S -> B is up
    write_bag(tmp_path / "V1.bag", imu_R=R_BS.T)
    assert main(["import", "euroc", str(tmp_path / "V1.bag"), "--out", str(tmp_path / "V1")]) == 0
    back = read_recording(tmp_path / "V1", require_rotors=True)
    assert back.vehicle.T_BS == firefly.T_BS
    raw = read_recording(tmp_path / "V1", frame="S")
    assert np.mean(raw.imu.acc[:, 0]) > 8.0  # stored in S, as EuRoC
    assert np.mean(back.imu.acc[:, 2]) > 9.5  # physics sees +z_B

    write_bag(tmp_path / "flat.bag")  # IMU already in B: the Firefly's T_BS turns it sideways
    assert main(["import", "euroc", str(tmp_path / "flat.bag"), "--out", str(tmp_path / "flat")]) == 2
    err = capsys.readouterr().err.strip()
    assert "vehicle 'firefly': T_BS: the mean specific force in flight points" in err and "\n" not in err
    assert not (tmp_path / "flat").exists()
