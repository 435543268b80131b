"""Tests of uavturb.scene.heights: d_down / d_up on point clouds sampled from boxes."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from uavturb.errors import InputError
from uavturb.scene.heights import SurfaceIndex, sample_mesh_points

CELL = 0.05


def _box(x0, x1, y0, y1, z0, z1) -> trimesh.Trimesh:
    b = trimesh.creation.box(extents=(x1 - x0, y1 - y0, z1 - z0))
    b.apply_translation(((x0 + x1) / 2, (y0 + y1) / 2, (z0 + z1) / 2))
    return b


def _scene(spacing=0.02, seed=0) -> np.ndarray:
    """Floor (top at z = 0) over [-2, 2]^2, a 1 x 1 m table top (top 0.75, underside 0.71)
    over x in [0.5, 1.5], y in [-0.5, 0.5], a ceiling (underside 2.5) over x in [-2, 0] only."""
    floor = _box(-2, 2, -2, 2, -0.02, 0.0)
    table = _box(0.5, 1.5, -0.5, 0.5, 0.71, 0.75)
    ceiling = _box(-2, 0, -2, 2, 2.5, 2.55)
    return sample_mesh_points(trimesh.util.concatenate([floor, table, ceiling]), spacing, seed)


@pytest.fixture(scope="module")
def index() -> SurfaceIndex:
    return SurfaceIndex(_scene(), cell=CELL)


def test_d_down_over_floor_table_and_under_table(index):
    pos = np.array([
        [-1.0, 1.0, 1.0],   # over the floor
        [1.0, 0.0, 1.0],    # over the table top
        [1.0, 0.0, 0.3],    # under the table: the floor counts
        [1.2, 0.3, 0.751],  # just over the table top
    ])
    np.testing.assert_allclose(index.d_down(pos), [1.0, 0.25, 0.3, 0.001], atol=1e-6)


def test_d_up_ceiling_table_underside_and_inf(index):
    pos = np.array([
        [-1.0, 1.0, 1.0],   # under the ceiling (2.5)
        [1.0, 0.0, 0.3],    # under the table: its underside at 0.71
        [1.0, 0.0, 1.0],    # over the table, no ceiling there
        [1.0, 1.5, 1.0],    # over bare floor, no ceiling
    ])
    d = index.d_up(pos)
    np.testing.assert_allclose(d[:2], [1.5, 0.41], atol=1e-3)
    assert np.all(np.isinf(d[2:]))


def test_inf_where_nothing(index):
    pos = np.array([[10.0, 10.0, 1.0], [0.0, 0.0, -1.0], [-2.3, 0.0, 1.0]])
    down, up = index.d_down(pos), index.d_up(pos)
    assert np.all(np.isinf(down))
    assert np.isinf(up[0]) and np.isinf(up[2])
    np.testing.assert_allclose(up[1], 0.98, atol=1e-3)  # the floor slab's underside at -0.02


def test_single_position_and_many_positions_agree(index):
    rng = np.random.default_rng(3)
    pos = np.column_stack([rng.uniform(-2.2, 2.2, 500), rng.uniform(-2.2, 2.2, 500), rng.uniform(-0.5, 3.0, 500)])
    down, up = index.d_down(pos), index.d_up(pos)
    for k in range(0, 500, 50):
        assert index.d_down(pos[k]) == down[k] or (np.isinf(down[k]) and np.isinf(index.d_down(pos[k])))
        assert index.d_up(pos[k]) == up[k] or (np.isinf(up[k]) and np.isinf(index.d_up(pos[k])))


def test_matches_brute_force_over_footprint_columns():
    pts = _scene(spacing=0.04, seed=1)
    idx = SurfaceIndex(pts, cell=CELL)
    rng = np.random.default_rng(4)
    pos = np.column_stack([rng.uniform(-2.1, 2.1, 300), rng.uniform(-2.1, 2.1, 300), rng.uniform(-0.1, 2.7, 300)])
    xy0 = pts[:, :2].min(axis=0)
    col_p = np.floor((pts[:, :2] - xy0) / CELL).astype(int)
    col_q = np.floor((pos[:, :2] - xy0) / CELL).astype(int)
    down, up = idx.d_down(pos), idx.d_up(pos)
    for k in range(len(pos)):
        near = np.all(np.abs(col_p - col_q[k]) <= 1, axis=1)  # default footprint: 3 x 3 columns
        z = pts[near, 2]
        below, above = z[z <= pos[k, 2]], z[z > pos[k, 2]]
        exp_down = pos[k, 2] - below.max() if len(below) else np.inf
        exp_up = above.min() - pos[k, 2] if len(above) else np.inf
        assert down[k] == pytest.approx(exp_down, abs=1e-9)
        assert up[k] == pytest.approx(exp_up, abs=1e-9)


def test_sparse_holey_cloud_still_answers():
    # 3 cm random scan with a 6 cm hole punched right under the query
    pts = sample_mesh_points(_box(-1, 1, -1, 1, -0.02, 0.0), 0.03, seed=2)
    xy0 = pts[:, :2].min(axis=0)
    q = np.array([*(xy0 + (np.floor((0.1 - xy0) / CELL) + 0.5) * CELL), 1.2])  # a column centre
    pts = pts[np.hypot(pts[:, 0] - q[0], pts[:, 1] - q[1]) > 0.06]
    assert np.isinf(SurfaceIndex(pts, cell=CELL, footprint=0.0).d_down(q))  # its own column is empty
    assert SurfaceIndex(pts, cell=CELL).d_down(q) == pytest.approx(1.2, abs=1e-3)
    # and a very sparse cloud (10 cm spacing, random) over a 5 cm grid: most columns empty
    sparse = sample_mesh_points(_box(-1, 1, -1, 1, -0.02, 0.0), 0.10, seed=5)
    rng = np.random.default_rng(6)
    pos = np.column_stack([rng.uniform(-0.8, 0.8, 200), rng.uniform(-0.8, 0.8, 200), np.full(200, 0.5)])
    d = SurfaceIndex(sparse, cell=CELL, footprint=0.15).d_down(pos)
    assert np.mean(np.isfinite(d)) > 0.97
    np.testing.assert_allclose(d[np.isfinite(d)], 0.5, atol=1e-3)


def test_footprint_reaches_a_table_edge(index):
    # 3 cm beside the table's edge (x = 0.5): the default 3 x 3 columns see the table top
    assert index.d_down([0.47, 0.0, 1.0]) == pytest.approx(0.25, abs=1e-3)
    assert SurfaceIndex(_scene(), cell=CELL, footprint=0.0).d_down([0.4, 0.0, 1.0]) == pytest.approx(1.0, abs=1e-3)


@pytest.mark.parametrize(
    "bad, problem",
    [
        (np.empty((0, 3)), "empty"),
        (np.zeros((5, 2)), "shape"),
        (np.array([[0.0, 0.0, np.nan], [1.0, 1.0, 1.0]]), "NaN"),
        ([["a", "b", "c"]], "numeric"),
    ],
)
def test_bad_cloud_raises_input_error(bad, problem):
    with pytest.raises(InputError) as e:
        SurfaceIndex(bad)
    assert e.value.where == "point cloud"
    assert problem in e.value.problem


def test_bad_positions_raise(index):
    with pytest.raises(InputError):
        index.d_down(np.zeros((4, 2)))
    with pytest.raises(InputError):
        index.d_up(np.array([[0.0, np.nan, 1.0]]))
    assert index.d_down(np.empty((0, 3))).shape == (0,)


def test_sample_mesh_points_count_surface_and_seed():
    box = _box(0, 2, 0, 1, 0, 0.5)  # area 2 * (2 + 1 + 0.5) = 7 m^2
    pts = sample_mesh_points(box, 0.05, seed=1)
    assert pts.shape == (int(np.ceil(7 / 0.05**2)), 3)
    lo, hi = np.array([0, 0, 0.0]), np.array([2, 1, 0.5])
    assert np.all(pts >= lo - 1e-9) and np.all(pts <= hi + 1e-9)
    on_face = np.min(np.abs(np.concatenate([pts - lo, hi - pts], axis=1)), axis=1)
    assert np.max(on_face) < 1e-9  # every point lies on a face
    np.testing.assert_array_equal(pts, sample_mesh_points(box, 0.05, seed=1))
    # area-uniform: the top face holds 2/7 of the points
    assert np.mean(np.abs(pts[:, 2] - 0.5) < 1e-9) == pytest.approx(2 / 7, abs=0.02)
    with pytest.raises(InputError):
        sample_mesh_points(box, 0.0)
    with pytest.raises(InputError):
        sample_mesh_points(trimesh.Trimesh(), 0.1)
