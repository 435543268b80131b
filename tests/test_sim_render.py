"""Headless rendering: depth against analytic geometry, normals, camera poses."""

from __future__ import annotations

import os

os.environ.setdefault("PYOPENGL_PLATFORM", "egl")

import numpy as np  # noqa: E402
import pytest  # noqa: E402

from uavturb.errors import InputError  # noqa: E402
from uavturb.physics import quaternion as quat  # noqa: E402
from uavturb.scene import boxes, procedural  # noqa: E402
from uavturb.sim.core import render as R  # noqa: E402


def _pixel_rays(K, H, W):
    """Camera-frame rays ``(H, W, 3)`` with unit z through pixel centres."""
    v, u = np.mgrid[0:H, 0:W]
    return np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones((H, W))], axis=-1)


def test_camera_pose_convention():
    T = R.camera_pose([1.0, 2.0, 3.0], [1, 0, 0, 0], 0.0)
    assert np.allclose(T[:3, 2], [1, 0, 0])  # optical axis = body +x
    assert np.allclose(T[:3, 0], [0, -1, 0])  # image right = body -y
    assert np.allclose(T[:3, 1], [0, 0, -1])  # image down = body -z
    assert np.allclose(T[:3, 3], [1, 2, 3])
    T = R.camera_pose([0, 0, 0], [1, 0, 0, 0], 90.0)
    assert np.allclose(T[:3, 2], [0, 0, -1])  # pitched down 90 deg: looks at the floor
    q = quat.from_euler(0.0, 0.0, np.pi / 2)  # yawed left: forward is world +y
    T = R.camera_pose([0, 0, 1], q, 30.0, offset=[0.1, 0.0, -0.05])
    assert np.allclose(T[:3, 2], [0, np.cos(np.pi / 6), -np.sin(np.pi / 6)])
    assert np.allclose(T[:3, 3], [0, 0.1, 0.95])
    assert np.allclose(T[:3, :3].T @ T[:3, :3], np.eye(3)) and np.isclose(np.linalg.det(T[:3, :3]), 1.0)


def test_depth_of_wall_in_front():
    wall = boxes.boxes_to_mesh(np.array([[[5.0, -20.0, -20.0], [6.0, 20.0, 20.0]]]))
    with R.SceneRenderer(wall, 128, 128, yfov_deg=70.0) as r:
        T = R.camera_pose([3.0, 0.0, 1.0], [1, 0, 0, 0], 0.0)
        d = r.depth(T)
        assert d.shape == (128, 128) and d.dtype == np.float32
        assert abs(d[64, 64] - 2.0) < 1e-4
        assert np.allclose(d, 2.0, atol=1e-4)  # z-depth, not range
        n = r.normals(T)
        assert np.allclose(n, [0.0, 0.0, -1.0], atol=1e-6)  # facing the camera
        # looking away: nothing within zfar
        assert np.all(r.depth(R.camera_pose([3.0, 0.0, 1.0], quat.from_euler(0, 0, np.pi), 0.0)) == 0.0)


def test_floor_depth_and_normals_match_analytic():
    floor = boxes.boxes_to_mesh(np.array([[[-60.0, -60.0, -1.0], [60.0, 60.0, 0.0]]]))
    with R.SceneRenderer(floor, 128, 96, yfov_deg=60.0, zfar=20.0) as r:
        h = 1.5
        q = quat.from_euler(0.15, 0.0, 0.4)  # a roll makes left/right and up/down matter
        T = R.camera_pose([0.3, -0.2, h], q, 35.0)
        depth, normals = r.depth_and_normals(T)
        rays_W = _pixel_rays(r.K, 96, 128) @ T[:3, :3].T
        with np.errstate(divide="ignore"):
            s = -h / rays_W[..., 2]
        z_depth = np.where((s > 0) & (s <= 20.0), s, 0.0)  # rays have unit z_C: s is the z-depth
        hit = z_depth > 0
        edge = np.abs(z_depth - 20.0) < 0.5  # the far-plane cut may go either way there
        assert np.array_equal((depth > 0)[~edge], hit[~edge])
        assert hit.sum() > 5000
        both = hit & (depth > 0)
        assert np.allclose(depth[both], z_depth[both], rtol=1e-3)
        assert np.max(np.abs(depth[both] - z_depth[both]) / z_depth[both]) < 2e-4
        expected = T[:3, :3].T @ np.array([0.0, 0.0, 1.0])  # world +z in the camera frame
        assert np.abs(normals[both] - expected).max() < 1e-3
        assert np.all(normals[~(depth > 0)] == 0.0)


def test_generated_scene_depth_matches_ray_casting_and_normals_axis_aligned():
    sc = procedural.generate_scene(3)
    poses = R.random_poses(sc, 4, seed=1, pitch_deg=25.0)
    rng = np.random.default_rng(0)
    with R.SceneRenderer(sc, 96, 72, yfov_deg=80.0) as r:
        rays = _pixel_rays(r.K, 72, 96)
        for T in poses:
            depth, n_C = r.depth_and_normals(T)
            assert np.array_equal(depth, r.depth(T))
            hit = depth > 0
            assert hit.mean() > 0.99  # closed rooms: every ray hits something
            # world normals of a box scene are axis-aligned and face the camera
            n_W = n_C[hit] @ T[:3, :3].T
            assert np.allclose(np.abs(n_W).max(axis=1), 1.0, atol=1e-3)
            assert np.all(np.sum(n_C[hit] * rays[hit], axis=1) < 0)
            # depth at random pixels = range of a trimesh ray cast times the ray's z_C
            ij = np.argwhere(hit)[rng.choice(hit.sum(), 40, replace=False)]
            d_C = rays[ij[:, 0], ij[:, 1]]
            d_W = d_C @ T[:3, :3].T
            locs, idx, _ = sc.mesh.ray.intersects_location(
                np.repeat(T[None, :3, 3], len(ij), axis=0), d_W / np.linalg.norm(d_W, axis=1, keepdims=True),
                multiple_hits=False)
            rng_ = np.full(len(ij), np.nan)
            rng_[idx] = np.linalg.norm(locs - T[:3, 3], axis=1)
            z = rng_ / np.linalg.norm(d_C, axis=1)
            ok = np.isfinite(z)
            # a pixel whose centre ray grazes an edge may differ; nearly all agree to 1 mm
            agree = np.abs(depth[ij[ok, 0], ij[ok, 1]] - z[ok]) < 1e-3
            assert agree.mean() > 0.9


def test_rgb_and_lifecycle():
    sc = procedural.generate_scene(5)
    T = R.random_poses(sc, 1, seed=2)[0]
    r = R.SceneRenderer(sc, 64, 48, rgb=True)
    img = r.rgb(T)
    assert img.shape == (48, 64, 3) and img.dtype == np.uint8 and img.std() > 5
    d = r.depth(T)
    assert d.shape == (48, 64) and (d > 0).all()
    with pytest.raises(InputError):
        r.depth(np.eye(3))
    r.close()
    r.close()
    with pytest.raises(InputError):
        r.depth(T)
    with R.SceneRenderer(sc.mesh, 32, 32) as r2:
        with pytest.raises(InputError, match="rgb=True"):
            r2.rgb(T)
    with pytest.raises(InputError):
        R.SceneRenderer(sc, 32, 32, znear=1.0, zfar=0.5)


def test_surfaces_are_two_sided():
    """A camera inside a closed box sees its inside in both passes (scanned meshes have no outside)."""
    box = boxes.boxes_to_mesh(np.array([[[-1.0, -3.0, -3.0], [1.5, 3.0, 3.0]]]))
    with R.SceneRenderer(box, 64, 64, yfov_deg=60.0) as r:
        T = R.camera_pose([0.0, 0.0, 0.0], [1, 0, 0, 0], 0.0)
        d, n = r.depth_and_normals(T)
        assert np.allclose(r.depth(T), 1.5, atol=1e-4) and np.allclose(d, 1.5, atol=1e-4)
        assert np.allclose(n, [0.0, 0.0, -1.0], atol=1e-6)
