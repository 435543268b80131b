"""Recording folders: write → read round trip, validation of each stream, atomic writes, alignment."""

from __future__ import annotations

import shutil

import numpy as np
import pytest
from conftest import T0_NS, make_recording

from uavturb.errors import InputError
from uavturb.io import align, euroc_csv, ply
from uavturb.io.reader import (
    GROUNDTRUTH_CSV,
    IMU_CSV,
    ROTORS_CSV,
    VEHICLE_YAML,
    VICON_CSV,
    read_recording,
)
from uavturb.io.writer import write_recording
from uavturb.physics import quaternion as quat
from uavturb.physics.vehicle import HEXAROTOR, QUADROTOR


@pytest.fixture
def folder(tmp_path, recording):
    path = tmp_path / "flight"
    write_recording(recording, path)
    return path


def close(a, b):
    np.testing.assert_allclose(a, b, rtol=1e-9, atol=1e-12)


def test_round_trip_all_streams(folder, recording):
    back = read_recording(folder)
    assert back.path == folder and back.vehicle == recording.vehicle
    g, h = back.ground_truth, recording.ground_truth
    assert np.array_equal(g.t_ns, h.t_ns) and g.t_ns.dtype == np.int64
    for a, b in ((g.p, h.p), (g.q, h.q), (g.v, h.v), (g.b_w, h.b_w), (g.b_a, h.b_a)):
        close(a, b)
        # each column block its own array: no view keeps the parsed sixteen-column table alive (memory)
        assert a.base is None or a.base.nbytes == a.nbytes
    assert np.array_equal(back.imu.t_ns, recording.imu.t_ns) and back.imu.rate_hz == 200.0
    close(back.imu.gyro, recording.imu.gyro), close(back.imu.acc, recording.imu.acc)
    assert np.array_equal(back.imu.T_BS, np.eye(4))
    assert np.array_equal(back.rotors.t_ns, recording.rotors.t_ns)
    close(back.rotors.speeds, recording.rotors.speeds)  # through rotor_speed_scale = 4.104 and back
    raw = euroc_csv.read_csv(folder / ROTORS_CSV, 7)[1]
    close(raw * 4.104, recording.rotors.speeds)
    assert np.array_equal(back.points, recording.points)
    c, d = back.cam0, recording.cam0
    assert np.array_equal(c.t_ns, d.t_ns) and c.files == d.files and c.resolution == d.resolution
    close(c.T_BS, d.T_BS), close(c.intrinsics, d.intrinsics), close(c.distortion, d.distortion)
    assert (folder / "mav0/cam0/data").is_dir()
    assert np.array_equal(back.vicon.t_ns, recording.vicon.t_ns)
    close(back.vicon.p, recording.vicon.p), close(back.vicon.q, recording.vicon.q)
    assert (folder / GROUNDTRUTH_CSV).read_text().splitlines()[0] == euroc_csv.GROUNDTRUTH_HEADER
    assert not list(folder.parent.glob("*.tmp-*"))


def test_optional_streams_and_load_points(tmp_path, recording):
    recording.imu = recording.rotors = recording.vicon = None
    recording.cam0.t_ns, recording.cam0.files = np.zeros(0, dtype=np.int64), []
    write_recording(recording, tmp_path / "r")
    back = read_recording(tmp_path / "r", load_points=False)
    assert back.imu is None and back.rotors is None and back.vicon is None and back.points is None
    assert back.cam0.files == [] and back.cam0.resolution == (752, 480)  # sensor.yaml alone
    with pytest.raises(InputError, match="rotors0/data.csv: file not found"):
        read_recording(tmp_path / "r", require_rotors=True)
    with pytest.raises(InputError, match="imu0/data.csv: file not found"):
        read_recording(tmp_path / "r", require_imu=True)


def test_euroc_folder_without_vehicle_yaml(folder):
    (folder / VEHICLE_YAML).unlink()
    with pytest.raises(InputError) as e:
        read_recording(folder)
    assert str(folder / VEHICLE_YAML) in str(e.value) and "file not found" in str(e.value)
    rec = read_recording(folder, vehicle=HEXAROTOR)
    assert rec.vehicle == HEXAROTOR  # scale 1: rotors0 values read as rad/s


def test_missing_folder_and_ground_truth(tmp_path, folder):
    with pytest.raises(InputError, match="nowhere: recording folder not found"):
        read_recording(tmp_path / "nowhere")
    (folder / GROUNDTRUTH_CSV).unlink()
    with pytest.raises(InputError, match="state_groundtruth_estimate0/data.csv: file not found"):
        read_recording(folder)


def test_separators_in_a_folder(folder, recording):
    gt = folder / GROUNDTRUTH_CSV
    gt.write_text(gt.read_text().replace(",", ", "))
    close(read_recording(folder).ground_truth.p, recording.ground_truth.p)


def test_rotor_count_mismatch(tmp_path, recording):
    write_recording(recording, tmp_path / "r")
    (tmp_path / "r" / VEHICLE_YAML).unlink()
    with pytest.raises(InputError) as e:
        read_recording(tmp_path / "r", vehicle=QUADROTOR)
    msg = str(e.value)
    assert "rotors0/data.csv" in msg and "6 rotor speed columns" in msg and "rotor_count 4" in msg
    recording.vehicle = QUADROTOR
    with pytest.raises(InputError, match="rotor_count 4"):
        write_recording(recording, tmp_path / "q")
    assert not (tmp_path / "q").exists()


def test_negative_rotor_speed(folder):
    path = folder / ROTORS_CSV
    lines = path.read_text().splitlines()
    lines[3] = lines[3].split(",", 1)[0] + ",-1" + ",1" * 5
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(InputError, match=r"rotors0/data.csv: line 4: negative rotor speed -1.0 for rotor 0 "
                       r"\(speeds are magnitudes; vehicle.yaml's rotor_directions gives each rotor's spin\)$"):
        read_recording(folder)


@pytest.mark.parametrize("name", [IMU_CSV, ROTORS_CSV])
def test_streams_not_overlapping_ground_truth(tmp_path, recording, name):
    stream = recording.imu if name == IMU_CSV else recording.rotors
    stream.t_ns = stream.t_ns + 3_000_000_000  # starts after the 2 s of ground truth end
    write_recording(recording, tmp_path / "r")
    with pytest.raises(InputError) as e:
        read_recording(tmp_path / "r")
    assert name in str(e.value) and "does not overlap the ground truth in time" in str(e.value)


@pytest.mark.parametrize("name, column", [(GROUNDTRUTH_CSV, 4), (VICON_CSV, 4)])
def test_quaternion_norm(folder, name, column):
    path = folder / name
    lines = path.read_text().splitlines()
    fields = lines[5].split(",")
    fields[column] = "0.5"
    fields[column + 1:column + 4] = ["0", "0", "0"]
    lines[5] = ",".join(fields)
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(InputError) as e:
        read_recording(folder)
    assert f"{name}: quaternion at line 6 has norm 0.5 (expected 1)" in str(e.value)


def test_quaternions_normalised_and_continuous(folder, recording):
    path = folder / GROUNDTRUTH_CSV
    t, x = euroc_csv.read_csv(path, 17)
    x[1::2, 3:7] *= -1.001  # sign flips every other row, norm off by 1e-3: tolerated
    euroc_csv.write_csv(path, euroc_csv.GROUNDTRUTH_HEADER, t, x)
    q = read_recording(folder).ground_truth.q
    close(np.linalg.norm(q, axis=1), 1.0)
    assert np.all(np.sum(q[1:] * q[:-1], axis=1) > 0)
    close(q, recording.ground_truth.q)


def test_malformed_stream_names_the_file(folder):
    path = folder / IMU_CSV
    path.write_text(path.read_text() + f"{T0_NS},1,2,3\n")
    with pytest.raises(InputError) as e:
        read_recording(folder)
    assert str(path) in str(e.value) and "expected 7 columns, found 4" in str(e.value)


def test_atomic_write_leaves_nothing_on_failure(tmp_path, recording, monkeypatch):
    def broken(*args, **kwargs):
        raise OSError("disk full")

    monkeypatch.setattr(ply, "write_ply", broken)
    with pytest.raises(InputError, match="cannot be written \(disk full\)"):
        write_recording(recording, tmp_path / "flight")
    assert list(tmp_path.iterdir()) == []


def test_overwrite(tmp_path, recording, folder):
    with pytest.raises(InputError, match="already exists"):
        write_recording(recording, folder)
    recording.points = None
    write_recording(recording, folder, overwrite=True)
    assert read_recording(folder).points is None
    assert sorted(p.name for p in folder.parent.iterdir()) == ["flight"]


def test_longer_recording_without_camera_folder(tmp_path):
    rec = make_recording(duration=20.0, seed=3)
    write_recording(rec, tmp_path / "r")
    shutil.rmtree(tmp_path / "r" / "mav0" / "cam0")
    back = read_recording(tmp_path / "r")
    assert len(back.ground_truth) == 4000 and back.cam0 is None
    close(back.ground_truth.p, rec.ground_truth.p)


# --- alignment --------------------------------------------------------------------------


def test_interpolate_exact_on_linear_data():
    t_src = T0_NS + np.arange(0, 2_000_000_000, 5_000_000, dtype=np.int64)
    s = (t_src - T0_NS) * 1e-9
    values = np.stack([3.0 * s + 1.0, -2.0 * s], axis=1)
    t_dst = T0_NS + np.array([0, 1, 2_500_000, 7_654_321, 1_995_000_000], dtype=np.int64)
    sd = (t_dst - T0_NS) * 1e-9
    out = align.interpolate(t_src, values, t_dst)
    np.testing.assert_allclose(out, np.stack([3.0 * sd + 1.0, -2.0 * sd], axis=1), rtol=0, atol=1e-12)
    assert align.interpolate(t_src, values[:, 0], t_dst).shape == (5,)


def test_slerp_recovers_constant_rate_rotation():
    rate = np.array([0.3, -0.2, 1.1])  # rad/s, constant body rate about a fixed axis
    axis, speed = rate / np.linalg.norm(rate), np.linalg.norm(rate)

    def q_at(t_ns):
        angle = speed * (np.asarray(t_ns) - T0_NS) * 1e-9
        return np.concatenate([np.cos(angle / 2)[:, None], np.sin(angle / 2)[:, None] * axis], axis=1)

    t_src = T0_NS + np.arange(0, 1_000_000_000, 100_000_000, dtype=np.int64)
    q_src = q_at(t_src)
    q_src[1::2] *= -1  # sign flips must not matter
    t_dst = T0_NS + np.array([50_000_000, 123_456_789, 777_777_777], dtype=np.int64)
    out = align.interpolate_quaternions(t_src, q_src, t_dst)
    expected = q_at(t_dst) * np.sign(np.sum(out * q_at(t_dst), axis=1))[:, None]
    np.testing.assert_allclose(out, expected, atol=1e-9)
    assert np.allclose(quat.to_rotation_matrix(out), quat.to_rotation_matrix(q_at(t_dst)), atol=1e-9)


def test_slerp_in_chunks_is_slerp_whole(monkeypatch):
    """:func:`quat.slerp` interpolates ``SLERP_CHUNK`` destination rows at a time (memory): each row is what it is
    interpolated whole, to the bit, with chunks cutting anywhere (and times clamped at both ends)."""
    rng = np.random.default_rng(4)
    t_src, q_src = np.sort(rng.uniform(0.0, 10.0, 300)), rng.normal(size=(300, 4))
    t_dst = np.sort(rng.uniform(-0.5, 10.5, 1001))
    whole = quat.slerp(t_src, q_src, t_dst)
    monkeypatch.setattr(quat, "SLERP_CHUNK", 7)
    np.testing.assert_array_equal(quat.slerp(t_src, q_src, t_dst), whole)
    np.testing.assert_allclose(np.linalg.norm(whole, axis=1), 1.0, rtol=1e-12)
    np.testing.assert_array_equal(whole[0], quat.make_continuous(quat.normalize(q_src))[0])  # clamped: the first
    assert quat.slerp(t_src, q_src, np.zeros(0)).shape == (0, 4)


def test_rotation_matrices_any_leading_shape():
    """``R(q)`` of one quaternion, of a series and of a grid of them: the same matrices, orthonormal, z_B of a
    half turn about x pointing down."""
    q = np.random.default_rng(5).normal(size=(5, 6, 4))
    R = quat.to_rotation_matrix(q)
    assert R.shape == (5, 6, 3, 3) and quat.to_rotation_matrix(q[2, 3]).shape == (3, 3)
    np.testing.assert_array_equal(quat.to_rotation_matrix(q[2, 3]), R[2, 3])
    np.testing.assert_array_equal(quat.to_rotation_matrix(q.reshape(-1, 4)).reshape(5, 6, 3, 3), R)
    np.testing.assert_allclose(np.einsum("...ji,...jk->...ik", R, R), np.broadcast_to(np.eye(3), R.shape), atol=1e-12)
    np.testing.assert_allclose(quat.to_rotation_matrix([0.0, 1.0, 0.0, 0.0])[:, 2], [0.0, 0.0, -1.0], atol=1e-15)


def test_overlap():
    a = np.array([0, 10, 20], dtype=np.int64)
    assert align.overlap(a, np.array([5, 30])) == (5, 20)
    assert align.overlap(a, np.array([5, 30]), np.array([-1, 15])) == (5, 15)
    assert align.require_overlap(a, np.array([15, 40]), "x.csv") == (15, 20)
    with pytest.raises(InputError, match=r"x.csv: cannot be aligned with the ground truth, which holds 1 row\(s\) at "
                                         r"one instant \(7 ns\): a recording needs a flight's worth of rows"):
        align.require_overlap(np.array([7], dtype=np.int64), np.array([7]), "x.csv")
    with pytest.raises(InputError, match="x.csv: does not overlap the ground truth in time"):
        align.require_overlap(a, np.array([21, 40]), "x.csv")
