"""The one camera model (uavturb.scene.camera): the forward camera's intrinsics and mount from two
numbers, the JSON record a trained model carries and its checks, and the camera a shard dataset's
manifest names (known answers; no rendering)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from uavturb.data import synthetic
from uavturb.data.datamodules import dataset_camera
from uavturb.errors import InputError
from uavturb.io import shards
from uavturb.scene.camera import (
    EUROC_CAM0,
    CameraModel,
    body_mount,
    camera_from_record,
    forward_camera,
    forward_intrinsics,
    forward_rotation,
    named_camera,
    registered_camera,
)
from uavturb.systems import HeightModule


def test_forward_intrinsics_known_answers():
    # 90 deg vertical field of view: the focal length is half the image height
    np.testing.assert_allclose(forward_intrinsics(64, 48, 90.0), [[24, 0, 31.5], [0, 24, 23.5], [0, 0, 1]])
    # 60 deg on 32 px: f = 16 / tan(30 deg) = 27.7128 px
    assert forward_intrinsics(32, 32, 60.0)[0, 0] == pytest.approx(16 * np.sqrt(3))
    with pytest.raises(InputError, match="yfov_deg: must be in \\(0, 180\\), got 180"):
        forward_intrinsics(32, 32, 180.0)


def test_synthetic_pixel_rays_are_the_forward_cameras():
    K = forward_intrinsics(20, 12, 70.0)
    rays = synthetic.pixel_rays((12, 20), 70.0)
    j, i = 13, 4
    np.testing.assert_array_equal(rays[i, j], [(j - K[0, 2]) / K[0, 0], (i - K[1, 2]) / K[1, 1], 1.0])
    # a ray re-projects onto its own pixel
    u, v, w = K @ rays[i, j]
    assert (u / w, v / w) == (pytest.approx(j), pytest.approx(i))


def test_forward_mount_known_answers():
    # level: optical z along body x, image right along body -y, image down along body -z
    np.testing.assert_allclose(forward_rotation(0.0), [[0, 0, 1], [-1, 0, 0], [0, -1, 0]], atol=1e-15)
    R = forward_rotation(30.0)
    np.testing.assert_allclose(R[:, 2], [np.cos(np.pi / 6), 0, -np.sin(np.pi / 6)], atol=1e-15)  # looks down
    np.testing.assert_allclose(R.T @ R, np.eye(3), atol=1e-15)
    cam = forward_camera(16, 16, 70.0, 30.0, frame_dt=0.05)
    np.testing.assert_array_equal(cam.T_BC[:3, :3], R)
    np.testing.assert_array_equal(cam.T_BC[:3, 3], 0.0)  # at the body origin
    assert cam.source == "default forward camera (pitch 30 deg down, vertical fov 70 deg)"


def test_synthetic_camera_rotation_is_the_forward_mount_on_a_yawed_level_body():
    yaw, pitch = np.array([0.0, 0.7, -2.5]), np.array([45.0, 10.0, 80.0])
    R_WC = synthetic.camera_rotation(yaw, pitch)
    for k in range(3):
        c, s = np.cos(yaw[k]), np.sin(yaw[k])
        R_WB = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        np.testing.assert_allclose(R_WC[k], R_WB @ forward_rotation(pitch[k]), atol=1e-12)


def test_records_round_trip_through_json():
    for cam in (forward_camera(24, 16, 70.0, 20.0, frame_dt=0.05), registered_camera("euroc_cam0", 32, 32)):
        back = camera_from_record(json.loads(json.dumps(cam.record())), "x.ckpt")
        assert isinstance(back, CameraModel)
        assert (back.name, back.width, back.height, back.source, back.frame_dt) == \
            (cam.name, cam.width, cam.height, cam.source, cam.frame_dt)
        np.testing.assert_array_equal(back.K, cam.K)
        np.testing.assert_array_equal(back.T_BC, cam.T_BC)
    eu = registered_camera("euroc_cam0", 32, 32)
    np.testing.assert_array_equal(eu.K, EUROC_CAM0.K(32, 32))
    np.testing.assert_array_equal(eu.T_BC, body_mount("euroc_cam0"))
    assert named_camera("euroc_cam0", 32, 32, 1.0, 2.0).record() == eu.record()  # fov and pitch unused
    assert named_camera("forward", 8, 8, 70.0, 20.0).record() == forward_camera(8, 8, 70.0, 20.0).record()


@pytest.mark.parametrize("change, problem", [
    ({"K": None}, "camera K must be a 3x3 matrix of finite numbers"),
    ({"K": [[0.0, 0, 8], [0, 10.0, 8], [0, 0, 1]]}, "camera K needs positive focal lengths"),
    ({"T_BC": [[2.0, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]}, "camera T_BC is no rigid motion"),
    ({"T_BC": [[1.0, 0, 0]]}, "camera T_BC must be a 4x4 matrix"),
    ({"width": 0}, "camera image size must be >= 1 px, got 0 x 16"),
    ({"frame_dt": -0.05}, "camera frame_dt must be a positive number of seconds, got -0.05"),
])
def test_bad_records_are_one_line_naming_where_they_came_from(change, problem):
    record = {**forward_camera(16, 16, 70.0, 20.0).record(), **change}
    with pytest.raises(InputError) as e:
        camera_from_record(record, "runs/best.ckpt")
    assert str(e.value).startswith("runs/best.ckpt: ") and problem in str(e.value) and "\n" not in str(e.value)
    record = forward_camera(16, 16, 70.0, 20.0).record()
    del record["T_BC"]
    with pytest.raises(InputError, match="camera lacks T_BC"):
        camera_from_record(record, "m")
    with pytest.raises(InputError, match="model camera: camera K needs positive focal lengths"):
        HeightModule(camera={**forward_camera(16, 16, 70.0, 20.0).record(), "K": np.zeros((3, 3)).tolist()})


def test_a_datasets_camera_from_its_manifest(tmp_path):
    # the synthetic generator's: forward camera with its pitch and field of view, 20 Hz
    synthetic.make_synthetic_dataset(tmp_path / "syn", n_scenes=3, trajs_per_scene=1, T=8, size=12, seed=0,
                                     pitch_deg=25.0, yfov_deg=60.0)
    cam = dataset_camera(tmp_path / "syn")
    assert cam.record() == forward_camera(12, 12, 60.0, 25.0, frame_dt=0.05).record()
    # a simulator preset's: its camera and camera_hz under "preset" (the preset's entries win)
    syn = shards.read_manifest(tmp_path / "syn")
    shards.write_manifest(tmp_path / "syn", syn.splits, {"dt": 0.1, "preset": {
        "camera": "euroc_cam0", "yfov_deg": 70.0, "pitch_deg": 20.0, "camera_hz": 40.0}})
    cam = dataset_camera(tmp_path / "syn")
    assert (cam.name, cam.width, cam.frame_dt) == ("euroc_cam0", 12, 0.025)
    np.testing.assert_array_equal(cam.K, EUROC_CAM0.K(12, 12))
    # a config naming no camera, or no manifest: no camera (a model trained on it is refused later)
    shards.write_manifest(tmp_path / "syn", syn.splits, {"seed": 1})
    assert dataset_camera(tmp_path / "syn") is None
    assert dataset_camera(tmp_path / "nothing") is None
