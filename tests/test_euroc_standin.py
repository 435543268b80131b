"""EuRoC's cam0 in the camera registry, the stand-in Vicon-room flights (``--kind euroc_room``) and
training data rendered through cam0: known answers from the published calibration and from geometry."""

from __future__ import annotations

import os
from types import SimpleNamespace

os.environ.setdefault("PYOPENGL_PLATFORM", "egl")

import numpy as np  # noqa: E402
import pytest  # noqa: E402
import trimesh  # noqa: E402
import yaml  # noqa: E402

from uavturb.cli import main  # noqa: E402
from uavturb.data.datamodules import dataset_camera  # noqa: E402
from uavturb.data.recordings import cam0_camera, recording_camera, recording_sequence  # noqa: E402
from uavturb.errors import InputError  # noqa: E402
from uavturb.io import align, sensor_yaml, shards  # noqa: E402
from uavturb.io.body_frame import to_body  # noqa: E402
from uavturb.io.reader import read_recording  # noqa: E402
from uavturb.io.recording import GroundTruth, Recording  # noqa: E402
from uavturb.io.vehicle_file import SHIPPED_DIR, load_vehicle  # noqa: E402
from uavturb.physics import quaternion as quat  # noqa: E402
from uavturb.scene import camera  # noqa: E402
from uavturb.sim.flights import euroc_standin  # noqa: E402
from uavturb.scene.layouts import floor_boxes, room_size  # noqa: E402
from uavturb.scene.queries import surface_below  # noqa: E402
from uavturb.sim.flights.plans import EUROC_ROOM  # noqa: E402
from uavturb.scene import procedural  # noqa: E402
from uavturb.scene.heights import SurfaceIndex  # noqa: E402
from uavturb.scene.procedural import generate_scene  # noqa: E402
from uavturb.scene.projection import camera_pose_world, depth_from_points  # noqa: E402
from uavturb.sim.core.render import SceneRenderer, random_poses  # noqa: E402
from uavturb.sim.dataset import generation  # noqa: E402
from uavturb.sim.dataset.generation import dataset_config  # noqa: E402
from uavturb.sim.dataset.presets import get_preset  # noqa: E402
from uavturb.sim.dataset.pretraining_pairs import pairs_config  # noqa: E402
from uavturb.sim.flights.simulate import make_reference  # noqa: E402

#: EuRoC MAV dataset, mav0/cam0/sensor.yaml (every sequence): the numbers as published
EUROC_INTRINSICS = [458.654, 457.296, 367.215, 248.375]
EUROC_T_BS = [0.0148655429818, -0.999880929698, 0.00414029679422, -0.0216401454975,
              0.999557249008, 0.0149672133247, 0.025715529948, -0.064676986768,
              -0.0257744366974, 0.00375618835797, 0.999660727178, 0.00981073058949,
              0.0, 0.0, 0.0, 1.0]
EUROC_DISTORTION = [-0.28340811, 0.07395907, 0.00019359, 1.76187114e-05]


def _firefly():
    return euroc_standin.flyable(load_vehicle(SHIPPED_DIR / "firefly.yaml"))


def _assert_is_euroc_cam0(cam):
    assert list(cam.intrinsics) == EUROC_INTRINSICS
    assert tuple(cam.resolution) == (752, 480) and cam.rate_hz == 20.0
    assert list(np.asarray(cam.T_BS).ravel()) == EUROC_T_BS
    assert cam.distortion_model == "radial-tangential" and list(cam.distortion) == EUROC_DISTORTION


# --- the registry --------------------------------------------------------------------------------


def test_cam0_registry_round_trips_through_sensor_yaml(tmp_path):
    spec = camera.camera_spec("euroc_cam0")
    _assert_is_euroc_cam0(spec.sensor())
    sensor_yaml.write_camera_yaml(tmp_path / "sensor.yaml", spec.sensor())
    _assert_is_euroc_cam0(sensor_yaml.read_camera_yaml(tmp_path / "sensor.yaml"))
    with pytest.raises(InputError, match="unknown camera 'cam9' \\(known: forward, euroc_cam0\\)"):
        camera.camera_spec("cam9")


def test_scaled_intrinsics_known_answers():
    K = camera.EUROC_CAM0.K(32, 32)  # centred 480 x 480 crop (from x = 136 px), scaled by 32 / 480
    s = 32 / 480
    assert np.allclose(K, [[458.654 * s, 0, (367.215 - 136 + 0.5) * s - 0.5],
                           [0, 457.296 * s, (248.375 + 0.5) * s - 0.5], [0, 0, 1]], rtol=0, atol=1e-12)
    assert np.allclose(K[:2, 2], [14.947667, 16.091667], atol=1e-6)
    assert np.allclose(camera.EUROC_CAM0.K(376, 240), [[229.327, 0, 183.3575], [0, 228.648, 123.9375], [0, 0, 1]])
    assert np.array_equal(camera.EUROC_CAM0.K(), [[458.654, 0, 367.215], [0, 457.296, 248.375], [0, 0, 1]])


def test_cam0_mount_looks_forward_20_deg_down_under_the_body():
    T_BC = camera.body_mount("euroc_cam0")
    T_BS = load_vehicle(SHIPPED_DIR / "firefly.yaml").T_BS_matrix
    assert np.allclose(T_BC, T_BS @ np.reshape(EUROC_T_BS, (4, 4)), atol=1e-12)
    z = T_BC[:3, 2]  # optical axis in B
    assert np.degrees(np.arcsin(-z[2])) == pytest.approx(19.4, abs=0.1) and z[0] > 0.9
    assert np.allclose(T_BC[:3, 0], [0, -1, 0], atol=0.05)  # image right = body -y
    assert camera.hang_below_body("euroc_cam0") == pytest.approx(0.130, abs=5e-4)
    assert camera.hang_below_body("forward") == 0.0 and euroc_standin.landed_height() == 0.16


def test_point_projects_to_the_pinhole_pixel_through_the_body_and_sensor_frames():
    """A point at x_C = (0.5, -0.3, 2.5) m from cam0 lands at (fu 0.2 + cu, fv (-0.12) + cv) -- 136 px
    left in the 480 x 480 crop evaluate uses -- through T_WB T_BS(vehicle.yaml) T_SC(cam0)."""
    vehicle = euroc_standin.with_vi_sensor(_firefly())
    q, p = quat.from_euler(0.05, -0.1, 2.0), np.array([1.0, -2.0, 1.3])
    gt = GroundTruth(t_ns=np.array([0]), p=p[None], q=q[None], v=np.zeros((1, 3)), b_w=np.zeros((1, 3)),
                     b_a=np.zeros((1, 3)))
    rec = euroc_standin.with_cam0(Recording(vehicle=vehicle, ground_truth=gt))
    cam = cam0_camera(rec, 480)
    T_WC = camera_pose_world(q, p, cam.T_BC)
    x_W = T_WC @ np.array([0.5, -0.3, 2.5, 1.0])
    u, v = 458.654 * 0.2 + 367.215 - 136, 457.296 * -0.12 + 248.375  # 322.9458, 193.4995
    depth = depth_from_points(x_W[None, :3], T_WC, cam.K, 480, 480, point_size=1e-3, fill_area=0)
    rows, cols = np.nonzero(depth)
    assert (rows.tolist(), cols.tolist()) == ([round(v)], [round(u)]) and depth[193, 323] == pytest.approx(2.5)


# --- rendering through cam0 --------------------------------------------------------------------------


@pytest.mark.parametrize("width, height", [(752, 480), (32, 32), (128, 128)])
def test_render_through_cam0_matches_a_ray_cast_on_a_flat_floor(width, height):
    """The body hovers level 1.2 m up; cam0 (0.13 m lower, 19.4 deg down) sees the floor: the depth at
    the principal point (1/z interpolated, exact for a plane) is the ray cast's, and every pixel is."""
    floor = trimesh.creation.box(extents=(60.0, 60.0, 0.1))
    floor.apply_translation((0.0, 0.0, -0.05))
    K = camera.EUROC_CAM0.K(width, height)
    T_WC = camera_pose_world(np.array([1.0, 0, 0, 0]), np.array([0.0, 0.0, 1.2]), camera.body_mount("euroc_cam0"))
    with SceneRenderer(floor, width, height, K=K) as r:
        depth = r.depth(T_WC).astype(float)
    axis = T_WC[:3, 2]
    hit, _, _ = floor.ray.intersects_location([T_WC[:3, 3]], [axis])
    t = float(np.min(np.linalg.norm(hit - T_WC[:3, 3], axis=1)))  # along the unit optical axis: the z-depth
    assert t == pytest.approx((1.2 - 0.12997) / np.sin(np.radians(19.446)), rel=1e-3)
    cu, cv = K[0, 2], K[1, 2]
    j, i = int(np.floor(cu)), int(np.floor(cv))
    a, b = cu - j, cv - i
    inv = 1.0 / depth[i:i + 2, j:j + 2]
    at_pp = 1.0 / ((1 - b) * ((1 - a) * inv[0, 0] + a * inv[0, 1]) + b * ((1 - a) * inv[1, 0] + a * inv[1, 1]))
    assert at_pp == pytest.approx(t, rel=2e-4)
    v, u = np.mgrid[0:height, 0:width]
    rays = np.stack([(u - cu) / K[0, 0], (v - cv) / K[1, 1], np.ones(u.shape)], -1) @ T_WC[:3, :3].T
    with np.errstate(divide="ignore"):
        z = np.where(rays[..., 2] < 0, -T_WC[2, 3] / rays[..., 2], 0.0)
    seen = (z > 0) & (z < 19.0) & (depth > 0)
    assert seen.mean() > 0.6 and np.max(np.abs(depth[seen] / z[seen] - 1)) < 2e-3


def test_forward_camera_through_intrinsics_equals_the_fov_camera():
    """The renderer's calibrated-camera path, given the forward camera's own K, renders what its
    field-of-view path renders (so the two conventions for the principal point agree)."""
    scene = procedural.generate_scene(3)
    poses = random_poses(scene, 4, seed=1)
    with SceneRenderer(scene, 48, 40, 70.0) as a:
        K = a.K.copy()
        ref = [a.depth(T) for T in poses]
    with SceneRenderer(scene, 48, 40, K=K) as b:
        for T, d in zip(poses, ref):
            got = b.depth(T)
            assert np.array_equal(got > 0, d > 0) and np.max(np.abs(got - d)) < 1e-5


# --- the stand-in flight plan ------------------------------------------------------------------------


@pytest.mark.parametrize("seed, duration", [(0, 40.0), (1, 90.0), (2, 60.0), (3, 144.0)])
def test_stand_in_height_profile(seed, duration):
    """Take-off from the floor, 0.5-2 m over the surface below between take-off and landing (some of it
    over furniture), landing on the floor; 2-8 s below 0.3 m in all, at most 4 s at each end."""
    ref = make_reference("euroc_room", duration, seed, _firefly())
    assert ref.duration == pytest.approx(duration)
    t = np.arange(0.0, duration + 1e-9, 0.005)
    sp = ref(t)
    surface = surface_below(EUROC_ROOM, sp.p[:, :2])
    d = sp.p[:, 2] - surface
    assert surface[0] == surface[-1] == 0.0  # starts and ends on the floor, at rest
    assert d[0] == d[-1] == pytest.approx(0.16) and np.all(np.abs(sp.v[[0, -1]]) < 1e-12)
    low = d < 0.3
    up, down = np.argmax(d >= 0.5), len(d) - 1 - np.argmax(d[::-1] >= 0.5)
    assert 2.0 <= low.sum() * 0.005 <= 8.0
    assert low[:up].sum() * 0.005 <= 4.0 and low[down:].sum() * 0.005 <= 4.0 and not low[up:down].any()
    cruise = d[up:down + 1]
    assert cruise.min() >= 0.5 - 1e-9 and cruise.max() <= 2.0 + 1e-9
    assert np.mean(surface[up:down + 1] > 0) > 0.05  # over furniture for a while
    assert t[down] - t[up] > 0.6 * duration
    assert np.all(np.abs(sp.p[:, :2]) < np.array(room_size(EUROC_ROOM)) / 2 - 0.5)


def test_stand_in_needs_time_and_a_flyable_vehicle():

    with pytest.raises(InputError, match="--duration: a euroc_room flight needs at least 2[0-9] s"):
        make_reference("euroc_room", 15.0, 0, _firefly())
    with pytest.raises(InputError, match="thrust_coefficient and moment_coefficient are needed"):
        euroc_standin.flyable(load_vehicle(SHIPPED_DIR / "firefly.yaml").with_params(arm_length=0.3))
    v = _firefly()
    assert (v.thrust_coefficient, v.max_rotor_speed) == (8.54858e-06, 838.0) and v.moment_coefficient > 0


# --- a flown stand-in flight, written and read back ------------------------------------------------


@pytest.fixture(scope="module")
def flight(tmp_path_factory):
    out = tmp_path_factory.mktemp("euroc") / "V1_standin"
    assert main(["generate", "flight", "--vehicle", "firefly", "--kind", "euroc_room", "--duration", "32",
                 "--seed", "1", "--noise", "none", "--effects", "ground_effect:mu=2", "--out", str(out)]) == 0
    return out


def test_flight_is_written_like_euroc(flight):
    rec = read_recording(flight)
    _assert_is_euroc_cam0(rec.cam0)
    assert len(rec.cam0.t_ns) == 0 and not (flight / "mav0/cam0/data.csv").exists()  # sensor.yaml alone
    assert rec.vehicle.T_BS == load_vehicle(SHIPPED_DIR / "firefly.yaml").T_BS  # ground truth stored in S
    truth = yaml.safe_load((flight / "truth.yaml").read_text())
    assert truth["kind"] == "euroc_room" and truth["stand_in"]["cam0"] == "euroc_cam0"
    assert truth["stand_in"]["landed_height_m"] == 0.16 and len(truth["stand_in"]["room"]["boxes"]) == 4

    centres = np.array([[(b[0] + b[1]) / 2, (b[2] + b[3]) / 2, 2.0] for b in floor_boxes(EUROC_ROOM)])
    tops = np.array([b[4] for b in floor_boxes(EUROC_ROOM)])  # 0.75 (table), 0.45, 0.2, 0.6
    assert np.allclose(SurfaceIndex(rec.points).d_down(centres), 2.0 - tops, atol=0.02)  # the cloud has the furniture
    assert np.allclose(SurfaceIndex(rec.points).d_up(centres), 3.2 - 2.0, atol=0.02)  # and the 3.2 m ceiling


def test_flown_flight_takes_off_cruises_and_lands(flight):
    rec = to_body(read_recording(flight))
    t = rec.seconds(rec.ground_truth.t_ns)
    d = SurfaceIndex(rec.points).d_down(rec.ground_truth.p)
    assert np.all(np.abs(d[t < 0.5] - 0.16) < 0.02) and np.all(np.abs(d[t > t[-1] - 0.5] - 0.16) < 0.02)
    assert 2.0 <= np.mean(d < 0.3) * t[-1] <= 8.0
    mid = (t > 10.0) & (t < 20.0)
    assert np.all((d[mid] > 0.45) & (d[mid] < 2.05))


def test_evaluate_projects_through_cam0(flight):
    """``uavturb evaluate``'s depth frames of the stand-in (the cloud projected through cam0 at 20 Hz)
    agree with the room's mesh rendered through cam0 at the true poses, at every height: in cruise and
    in the ground-effect frames near the floor, down to the landed vehicle whose camera is 3 cm over it
    (where a 3 cm scan's splats span half the image: they are drawn on their surface's plane)."""
    rec = read_recording(flight)
    seq = recording_sequence(rec, rec.vehicle, camera.forward_camera(32, 32, 70.0, 20.0))  # a 32 px model
    assert np.allclose(np.diff(seq.t), 0.05) and len(seq) == 641  # cam0's 20 Hz over 32 s
    assert np.allclose(seq.camera.T_BC, camera.body_mount("euroc_cam0"), atol=1e-9)
    assert np.allclose(seq.camera.K, camera.EUROC_CAM0.K(32, 32))
    gt = to_body(rec).ground_truth
    frames = np.r_[np.flatnonzero(seq.d >= 0.5)[::25], np.flatnonzero(seq.d < 0.36)[::4]]
    t_ns = rec.t0_ns + np.round(seq.t[frames] * 1e9).astype(np.int64)
    T_WC = camera_pose_world(align.interpolate_quaternions(gt.t_ns, gt.q, t_ns), align.interpolate(gt.t_ns, gt.p, t_ns),
                             seq.camera.T_BC)
    errors = []
    with SceneRenderer(EUROC_ROOM.mesh, 32, 32, K=seq.camera.K) as r:
        for k, T in zip(frames, T_WC):
            ref, got = r.depth(T), seq.depth[k]
            ok = (ref > 0) & (got > 0)
            assert ok.sum() > 0.95 * (ref > 0).sum()
            errors.append(np.median(np.abs(got[ok] / ref[ok] - 1)))
    errors = np.array(errors)
    low = seq.d[frames] < 0.36
    assert (~low).sum() >= 10 and low.sum() >= 10
    assert np.median(errors[~low]) < 0.005 and errors[~low].max() < 0.03
    # near the floor (before: 44-59 % short, every splat of the floor at one depth)
    assert np.median(errors[low]) < 0.02 and errors[low].max() < 0.04


def test_short_stand_in_fails_in_one_line(tmp_path, capsys):
    assert main(["generate", "flight", "--kind", "euroc_room", "--duration", "10", "--out", str(tmp_path / "x")]) == 2
    err = capsys.readouterr().err
    assert "--duration: a euroc_room flight needs at least" in err and err.count("\n") == 1
    assert not (tmp_path / "x").exists()


# --- training data through cam0; existing presets unchanged ----------------------------------------


#: config hashes of the presets before the camera field existed (main at d7e471a): seed 0, by controller,
#: and of the pre-training pairs
HASHES = {"tiny": ("328da3ba72d27e99", "3aeff8a2495cf0c7", "60e0002d24fd9451"),
          "quick": ("9a66ea676e2b0ead", "2ec1dfe8e674bbfb", "b611741b5f04c1b1"),
          "medium": ("2a8207ad5f7eb63e", "00a30c283d3a0b11", "d03640c27c6413f4"),
          "paper": ("98aba24ced6b5e36", "01e8124bc9789e99", "b071594ac7c6b04a")}


def test_existing_presets_keep_their_config_hashes():

    for name, (mpc, geometric, pairs) in HASHES.items():
        p = get_preset(name)
        assert p.camera == "forward" and "camera" not in p.to_dict()
        assert (shards.config_hash(dataset_config(p, 0, "mpc")), shards.config_hash(dataset_config(p, 0, "geometric")),
                shards.config_hash(pairs_config(p, 0))) == (mpc, geometric, pairs)
        e = get_preset(name, camera="euroc_cam0")
        assert e.to_dict()["camera"] == "euroc_cam0" and shards.config_hash(dataset_config(e, 0, "mpc")) != mpc
        assert shards.config_hash(pairs_config(e, 0)) != pairs
    with pytest.raises(InputError,
                       match="preset tiny: camera: 'cam9' is not allowed; allowed: one of forward, euroc_cam0"):
        get_preset("tiny", camera="cam9")


def test_sim_shards_through_cam0(tmp_path):
    """``generate sim --set camera=euroc_cam0``: cam0's intrinsics at the preset's 24 px, its mount on the
    body, and landed heights raised to 0.16 m so the camera stays over the floor."""
    m = generation.generate_sim("tiny", tmp_path / "eu", seed=0, progress=False, camera="euroc_cam0", width=24,
                             height=24, controller="geometric")
    assert m.config["preset"]["camera"] == "euroc_cam0"
    folder = m.folders("train")[0]
    meta = shards.read_meta(folder)
    tr = shards.read_trajectory(folder, mmap=False)
    assert np.allclose(meta["camera"]["K"], camera.EUROC_CAM0.K(24, 24))
    assert np.allclose(meta["camera"]["T_BC"], camera.body_mount("euroc_cam0"))
    assert tr.depth.shape[1:] == (24, 24) and tr.d.min() > 0.15 and abs(tr.d[0] - 0.16) < 0.01

    with SceneRenderer(generate_scene(meta["scene_seed"]), 24, 24, K=camera.EUROC_CAM0.K(24, 24)) as r:
        k = len(tr.t) // 2
        ref = r.depth(camera_pose_world(tr.state[k, 3:7], tr.state[k, :3], camera.body_mount("euroc_cam0")))
    assert np.array_equal(ref, tr.depth[k])
    # a model trained on these shards carries this camera, and a recording without cam0 is seen through it
    cam = dataset_camera(tmp_path / "eu")
    assert (cam.name, cam.width, cam.height, cam.frame_dt) == ("euroc_cam0", 24, 24, pytest.approx(0.05))
    assert np.allclose(cam.K, camera.EUROC_CAM0.K(24, 24)) and np.allclose(cam.T_BC, camera.body_mount("euroc_cam0"))
    assert recording_camera(SimpleNamespace(cam0=None), cam) is cam
