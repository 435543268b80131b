"""Tests of uavturb.scene.projection: depth images of point clouds, camera poses."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from uavturb.errors import InputError
from uavturb.physics import quaternion as quat
from uavturb.scene.camera import R_BC_FORWARD
from uavturb.scene.heights import sample_mesh_points
from uavturb.scene.projection import (
    PreparedCloud,
    camera_pose_world,
    depth_from_points,
    depth_to_points,
    estimate_normals,
    estimate_spacing,
    intrinsics_matrix,
    prepare_cloud,
)

# EuRoC V1/MH cam0/sensor.yaml: camera (sensor) to body (IMU) and intrinsics [fu, fv, cu, cv]
EUROC_CAM0_T_BS = np.array([
    [0.0148655429818, -0.999880929698, 0.00414029679422, -0.0216401454975],
    [0.999557249008, 0.0149672133247, 0.025715529948, -0.064676986768],
    [-0.0257744366974, 0.00375618835797, 0.999660727178, 0.00981073058949],
    [0.0, 0.0, 0.0, 1.0],
])
EUROC_CAM0_K = intrinsics_matrix(458.654, 457.296, 367.215, 248.375)

W, H = 128, 128
K = intrinsics_matrix(100.0, 100.0, (W - 1) / 2, (H - 1) / 2)
T_BS_FORWARD = np.eye(4)
T_BS_FORWARD[:3, :3] = R_BC_FORWARD


def _box(x0, x1, y0, y1, z0, z1) -> trimesh.Trimesh:
    b = trimesh.creation.box(extents=(x1 - x0, y1 - y0, z1 - z0))
    b.apply_translation(((x0 + x1) / 2, (y0 + y1) / 2, (z0 + z1) / 2))
    return b


def _wall(x: float, half: float = 4.0) -> trimesh.Trimesh:
    """The plane x = const, facing -x, over |y|, |z - 1| <= half."""
    v = np.array([[x, -half, 1 - half], [x, half, 1 - half], [x, half, 1 + half], [x, -half, 1 + half]])
    return trimesh.Trimesh(v, [[0, 1, 2], [0, 2, 3]], process=False)


def _pose(p=(0.0, 0.0, 1.0), roll=0.0, pitch=0.0, yaw=0.0, T_BS=T_BS_FORWARD) -> np.ndarray:
    return camera_pose_world(quat.from_euler(roll, pitch, yaw), np.asarray(p, float), T_BS)


@pytest.mark.parametrize("distance, spacing", [(3.0, 0.02), (0.5, 0.02), (1.5, 0.06)])
def test_plane_gives_constant_analytic_depth_without_holes(distance, spacing):
    # at 0.5 m the splats are ~4 px wide; 6 cm spacing at 1.5 m leaves ~4 px between points
    pts = sample_mesh_points(_wall(distance), spacing, seed=1)
    d = depth_from_points(pts, _pose(), K, W, H)
    assert d.shape == (H, W) and d.dtype == np.float32
    inner = d[2:-2, 2:-2]
    assert np.all(inner > 0), f"{np.sum(inner == 0)} holes"
    np.testing.assert_allclose(inner, distance, rtol=0.01)


def test_plane_seen_at_an_angle_and_round_trip_lands_on_the_floor():
    # floor (z = 0) and a wall at x = 4, camera 1 m up pitched 30 deg down
    pts = sample_mesh_points(trimesh.util.concatenate([_box(-1, 5, -4, 4, -0.02, 0.0), _wall(4.0)]), 0.02, seed=3)
    T_WC = _pose(pitch=np.radians(30.0))
    d = depth_from_points(pts, T_WC, K, W, H)
    assert np.mean(d > 0) > 0.99
    back = depth_to_points(d, K, T_WC)
    dist = np.minimum(np.abs(back[:, 2]), np.abs(back[:, 0] - 4.0))
    assert np.percentile(dist, 99) < 0.03 and np.median(dist) < 0.005
    # analytic floor depth at the image centre: the optical axis hits z = 0 after 1 / sin(30) = 2 m
    assert d[H // 2, W // 2] == pytest.approx(2.0, rel=0.02)


def test_box_in_front_of_a_wall_shows_box_depth_not_wall_depth():
    # sparse (3 cm) scan of a 0.6 m cube whose front face is at x = 1.5, wall at x = 4
    cube = _box(1.5, 2.1, -0.3, 0.3, 0.7, 1.3)
    pts = sample_mesh_points(trimesh.util.concatenate([cube, _wall(4.0)]), 0.03, seed=4)
    T_WC = _pose()
    d = depth_from_points(pts, T_WC, K, W, H)
    # pixels whose ray hits the front face: |y|, |z - 1| < 0.3 at x = 1.5 -> 20 px around the centre
    half = int(100 * 0.3 / 1.5)
    c = (W - 1) / 2
    rows = cols = slice(int(np.ceil(c - half)) + 3, int(np.floor(c + half)) - 2)
    face = d[rows, cols]
    np.testing.assert_allclose(face, 1.5, rtol=0.01)
    # outside the box's silhouette (with a margin for splat bloat) the wall shows
    ring = np.ones_like(d, dtype=bool)
    ring[int(c - half) - 4:int(c + half) + 6, int(c - half) - 4:int(c + half) + 6] = False
    np.testing.assert_allclose(d[ring], 4.0, rtol=0.01)
    # the same cloud drawn as bare pixels shows hidden surfaces (the cube's back faces,
    # the wall) through the gaps of its front face: splats and visibility test close it
    raw = depth_from_points(pts, T_WC, K, W, H, splat_scale=0.01, window=0, fill_area=0)
    assert np.mean(raw[rows, cols] > 1.55) > 0.2


def test_visibility_test_removes_leaks_between_foreground_splats():
    # splats too small to close the face: the leak removal plus hole filling must do it
    cube = _box(1.5, 2.1, -0.3, 0.3, 0.7, 1.3)
    pts = sample_mesh_points(trimesh.util.concatenate([cube, _wall(4.0)]), 0.03, seed=5)
    T_WC = _pose()
    half, c = int(100 * 0.3 / 1.5), (W - 1) / 2
    rows = cols = slice(int(np.ceil(c - half)) + 4, int(np.floor(c + half)) - 3)
    no_test = depth_from_points(pts, T_WC, K, W, H, splat_scale=0.8, window=0)
    with_test = depth_from_points(pts, T_WC, K, W, H, splat_scale=0.8)
    assert np.sum(no_test[rows, cols] > 1.55) > 0  # hidden faces show without the test
    np.testing.assert_allclose(with_test[rows, cols], 1.5, rtol=0.01)


def test_prepared_cloud_subset_and_point_size_agree():
    pts = sample_mesh_points(_wall(2.0), 0.02, seed=6)
    prepared = prepare_cloud(pts)
    assert prepared.points.dtype == np.float32 and prepared.spacing.shape == (len(pts),)
    a = depth_from_points(pts, _pose(), K, W, H)
    b = depth_from_points(prepared, _pose(), K, W, H)
    np.testing.assert_array_equal(a, b)
    left = np.flatnonzero(pts[:, 1] > 0)  # the left half of the wall (body +y)
    c = depth_from_points(prepared, _pose(), K, W, H, subset=left)
    assert np.all(c[2:-2, 2:W // 2 - 2] > 0) and np.all(c[:, W // 2 + 3:] == 0)
    e = depth_from_points(pts, _pose(), K, W, H, point_size=0.02)
    np.testing.assert_allclose(e[2:-2, 2:-2], 2.0, rtol=0.01)


def test_spacing_estimate_for_random_and_grid_scans():
    rnd = sample_mesh_points(_wall(0.0, half=1.5), 0.02, seed=7)[:, [1, 2, 0]]
    g = np.arange(0, 3, 0.02)
    grid = np.column_stack([np.repeat(g, len(g)), np.tile(g, len(g)), np.zeros(len(g) ** 2)])
    for pts in (rnd, grid):
        s, s_global = estimate_spacing(pts)
        assert s_global == pytest.approx(0.02, rel=0.15)
        assert np.median(s) == pytest.approx(0.02, rel=0.15)


def test_near_far_and_empty_view():
    pts = sample_mesh_points(_wall(3.0), 0.05, seed=8)
    assert not np.any(depth_from_points(pts, _pose(), K, W, H, far=2.5))
    assert not np.any(depth_from_points(pts, _pose(yaw=np.pi), K, W, H))  # looking away
    assert np.all(depth_from_points(pts, _pose(), K, W, H, near=2.0)[2:-2, 2:-2] > 0)


def test_camera_pose_world_forward_camera():
    T_WC = _pose(p=(1.0, 2.0, 3.0), pitch=np.radians(30.0))  # nose 30 deg down
    s, c = 0.5, np.sqrt(3) / 2
    np.testing.assert_allclose(T_WC[:3, 2], [c, 0, -s], atol=1e-12)  # optical axis
    np.testing.assert_allclose(T_WC[:3, 1], [-s, 0, -c], atol=1e-12)  # image down
    np.testing.assert_allclose(T_WC[:3, 0], [0, -1, 0], atol=1e-12)  # image right = body right
    np.testing.assert_allclose(T_WC[:3, 3], [1, 2, 3])
    np.testing.assert_allclose(T_WC[3], [0, 0, 0, 1])


def test_camera_pose_world_euroc_cam0():
    # EuRoC's cam0 looks along the body's +z (its IMU frame S: x up, z forward)
    q = quat.from_euler(0.0, 0.0, np.pi / 2)  # body yawed 90 deg about world z
    p = np.array([0.5, -1.0, 1.2])
    T_WC = camera_pose_world(q, p, EUROC_CAM0_T_BS)
    axis_B = EUROC_CAM0_T_BS[:3, 2]
    np.testing.assert_allclose(T_WC[:3, 2], [-axis_B[1], axis_B[0], axis_B[2]], atol=1e-12)
    np.testing.assert_allclose(T_WC[:3, 3], p + [0.064676986768, -0.0216401454975, 0.00981073058949], atol=1e-12)
    np.testing.assert_allclose(T_WC[:3, :3] @ T_WC[:3, :3].T, np.eye(3), atol=1e-9)
    # batched poses
    Ts = camera_pose_world(np.stack([q, q]), np.stack([p, p]), EUROC_CAM0_T_BS)
    np.testing.assert_allclose(Ts, np.stack([T_WC, T_WC]))


def test_euroc_sized_image_of_a_room_corner():
    # floor + wall seen by EuRoC's cam0 intrinsics at 752 x 480, camera 1 m up looking at the wall
    pts = sample_mesh_points(trimesh.util.concatenate([_box(-1, 5, -4, 4, -0.02, 0.0), _wall(3.0)]), 0.03, seed=9)
    T_WC = _pose(pitch=np.radians(10.0))
    d = depth_from_points(pts, T_WC, EUROC_CAM0_K, 752, 480)
    assert d.shape == (480, 752) and np.mean(d > 0) > 0.99
    back = depth_to_points(d, EUROC_CAM0_K, T_WC)
    dist = np.minimum(np.abs(back[:, 2]), np.abs(back[:, 0] - 3.0))
    assert np.percentile(dist, 99) < 0.03


@pytest.mark.parametrize(
    "kwargs, where",
    [
        (dict(points=np.empty((0, 3))), "point cloud"),
        (dict(points=np.full((3, 3), np.nan)), "point cloud"),
        (dict(points=np.zeros((3, 4))), "point cloud"),
        (dict(T_WC=np.eye(3)), "T_WC"),
        (dict(K=np.zeros((3, 3))), "K"),
        (dict(width=0), "image size"),
    ],
)
def test_bad_input_raises(kwargs, where):
    args = dict(points=np.zeros((3, 3)) + [2.0, 0, 0], T_WC=_pose(), K=K, width=W, height=H)
    args.update(kwargs)
    with pytest.raises(InputError) as e:
        depth_from_points(args.pop("points"), args.pop("T_WC"), args.pop("K"), args.pop("width"), args.pop("height"))
    assert e.value.where == where


def test_depth_to_points_inverts_a_pixel():
    T_WC = _pose(p=(0.0, 0.0, 1.0))
    d = np.zeros((H, W), np.float32)
    d[10, 100] = 2.0
    p = depth_to_points(d, K, T_WC)
    # pixel (row 10, col 100): x_C = (100 - 63.5) / 100 * 2, y_C = (10 - 63.5) / 100 * 2, z_C = 2
    np.testing.assert_allclose(p, [[2.0, -0.73, 1.0 + 1.07]], atol=1e-9)


def test_normals_of_a_plane_and_none_at_an_edge():
    rng = np.random.default_rng(0)
    floor = np.c_[rng.uniform(0, 1, (2000, 2)), np.zeros(2000)]
    n = estimate_normals(floor)
    np.testing.assert_allclose(np.abs(n[:, 2]), 1.0, atol=1e-6)
    # two perpendicular planes: points on the edge have no single plane, those far from it do
    wall = np.c_[np.zeros(2000), rng.uniform(0, 1, 2000), rng.uniform(0, 1, 2000)]
    n = estimate_normals(np.r_[floor, wall])
    on_edge = np.r_[floor[:, 0], wall[:, 2]] < 0.005
    far = np.r_[floor[:, 0], wall[:, 2]] > 0.1
    assert np.mean(np.all(n[on_edge] == 0, axis=1)) > 0.8
    assert np.all(np.abs(n[far]).max(axis=1) > 0.999)
    assert not estimate_normals(floor[:2]).any()  # too few points for a plane


@pytest.mark.parametrize("height", [0.03, 0.08, 0.2])
def test_floor_seen_from_a_few_centimetres(height):
    """A 3 cm scan of the floor seen by a camera ``height`` over it, pitched 20 deg down with EuRoC cam0's
    field of view at 32 px: one point's splat spans up to half the image; drawn on its surface's plane
    every pixel still reads the floor's depth (the projection evaluate uses on ground-effect frames)."""
    floor = trimesh.Trimesh(np.array([[-2.0, -2, 0], [3, -2, 0], [3, 2, 0], [-2, 2, 0]]), [[0, 1, 2], [0, 2, 3]],
                            process=False)
    pts = sample_mesh_points(floor, 0.03, seed=2)
    Kc = intrinsics_matrix(30.6, 30.5, 15.5, 15.5)
    T_WC = _pose(p=(0.0, 0.0, height), pitch=np.radians(20.0))
    d = depth_from_points(pts, T_WC, Kc, 32, 32)
    # analytic: the ray of each pixel (z-depth 1) meets the plane z = 0 at z-depth height / (its drop)
    rays = depth_to_points(np.ones((32, 32), np.float32), Kc, T_WC) - T_WC[:3, 3]
    truth = np.where(rays[:, 2] < 0, height / np.maximum(-rays[:, 2], 1e-12), 0.0)
    hit = T_WC[:3, 3] + truth[:, None] * rays
    on_scan = (np.abs(hit[:, 0] - 0.5) < 2.4) & (np.abs(hit[:, 1]) < 1.9)  # off the scan's edges
    truth = truth.reshape(32, 32)
    # beyond the near plane, and where a pixel spans less than 10 % of depth: where the floor is seen
    # more obliquely a pixel has no one depth and its points' nearest wins (the module's stated limit)
    spread = np.full_like(truth, np.inf)
    spread[1:-1] = np.abs(truth[2:] - truth[:-2]) / np.maximum(2 * truth[1:-1], 1e-12)
    seen = (truth > 0.05) & (spread < 0.1) & on_scan.reshape(32, 32)
    assert seen.sum() > 200
    assert np.all(d[seen] > 0)
    rel = np.abs(d[seen] / truth[seen] - 1)
    assert np.median(rel) < 0.025 and np.percentile(rel, 95) < 0.06
    # the same scan drawn at one depth per splat (no normals): the near floor hides the rest
    flat = depth_from_points(PreparedCloud(pts.astype(np.float32), np.full(len(pts), 0.03, np.float32)), T_WC, Kc,
                             32, 32)
    if height < 0.1:
        assert np.median(np.abs(flat[seen] / truth[seen] - 1)) > 0.1
