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
    d, filled = SurfaceIndex(pts, cell=CELL, footprint=0.0).d_down_filled(q)
    assert filled[0] and d[0] == pytest.approx(1.2, abs=1e-3)  # its own column is empty: the floor's plane
    d, filled = SurfaceIndex(pts, cell=CELL).d_down_filled(q)
    assert not filled[0] and d[0] == pytest.approx(1.2, abs=1e-3)
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


def _grid(spacing: float, half: float = 2.0, z=lambda x, y: 0.0 * x) -> np.ndarray:
    """A floor given as a grid of points ``spacing`` [m] apart over [-half, half]^2, at heights ``z(x, y)``."""
    x, y = np.meshgrid(np.arange(-half, half + 1e-9, spacing), np.arange(-half, half + 1e-9, spacing))
    return np.c_[x.ravel(), y.ravel(), z(x, y).ravel()]


@pytest.mark.parametrize("spacing", [0.2, 0.5])
def test_a_floor_given_as_a_sparse_grid_answers_every_position_over_it(spacing):
    idx = SurfaceIndex(_grid(spacing), cell=CELL)
    rng = np.random.default_rng(20)
    pos = np.column_stack([rng.uniform(-1.9, 1.9, 500), rng.uniform(-1.9, 1.9, 500), rng.uniform(0.02, 1.0, 500)])
    d, filled = idx.d_down_filled(pos)
    np.testing.assert_allclose(d, pos[:, 2], atol=1e-9)
    assert filled.mean() > 0.4  # many footprints are empty: these heights are the plane's
    np.testing.assert_allclose(idx.floor[0], 0.0, atol=1e-12)
    assert np.isinf(idx.d_down([3.0, 0.0, 0.5])) and np.isinf(idx.d_down([0.0, 0.0, -0.1]))  # beyond it, under it


def test_a_gently_sloping_floor_and_a_sparse_room_scan_read_their_floor():
    sloped = SurfaceIndex(_grid(0.3, z=lambda x, y: 0.5 + 0.02 * x - 0.01 * y), cell=CELL)
    np.testing.assert_allclose(sloped.floor[0], [0.5, 0.02, -0.01], atol=1e-3)  # through the columns' centres
    assert sloped.d_down([1.05, 1.05, 1.0]) == pytest.approx(1.0 - 0.5105, abs=1e-3)
    # a room scan 15 cm apart: its ceiling is the lowest surface of as many columns as its floor
    ceiling = _grid(0.15) + [0.07, 0.07, 2.5]
    room = SurfaceIndex(np.r_[_grid(0.15), ceiling], cell=CELL)
    np.testing.assert_allclose(room.floor[0], 0.0, atol=1e-12)
    assert room.d_down([0.03, 0.03, 1.0]) == pytest.approx(1.0)
    # lowest surfaces on no one plane (a heap): no floor
    heap = np.random.default_rng(21).uniform([-1, -1, 0], [1, 1, 1], (2000, 3))
    assert SurfaceIndex(heap, cell=CELL).floor is None


def test_a_tilted_scan_is_levelled_about_the_flight_s_centre():
    level = SurfaceIndex(_grid(0.1, z=lambda x, y: 0.002 * x), cell=CELL)  # 0.1 degrees: a built floor
    assert level.tilt([[0.0, 0.0, 1.0], [1.0, 0.0, 1.0]]) is None
    tilted = SurfaceIndex(_grid(0.1, z=lambda x, y: np.tan(np.radians(1.0)) * x), cell=CELL)
    flight = np.array([[0.5, 0.0, 0.3], [1.5, 0.0, 0.3], [1.0, 0.5, 0.3]])
    up, slope = tilted.tilt(flight)
    assert slope == pytest.approx(1.0, abs=0.01)
    np.testing.assert_allclose(up, np.tan(np.radians(1.0)) * (flight[:, 0] - 1.0), atol=2e-4)
    # the levelled scan's heights: the tilted one's where its floor lies that much higher, as flat as the flight
    d = tilted.d_down(flight + np.c_[np.zeros((3, 2)), up])
    np.testing.assert_allclose(d, d[2], atol=1e-3)


def _noisy(points: np.ndarray, sigma: float, seed: int) -> np.ndarray:
    """A scanner's reading of ``points``: each height off by Gaussian noise of ``sigma`` [m]."""
    return points + np.c_[np.zeros((len(points), 2)), np.random.default_rng(seed).normal(0.0, sigma, len(points))]


def test_exact_cloud_is_answered_point_by_point(index):
    assert index.scan_noise_m == 0.0 and index.surface_gap_m is None


def _scanned_room(spacing: float, seed: int) -> np.ndarray:
    """What a scanner sees of a room: the floor's top (z = 0) over [-2, 2]^2, a crate's top (0.75) and sides over
    x in [0.5, 1.5], y in [-0.5, 0.5], a ceiling's underside (2.5) over x in [-2, 0]."""
    floor = _box(-2, 2, -2, 2, -0.02, 0.0)
    crate = _box(0.5, 1.5, -0.5, 0.5, 0.0, 0.75)
    ceiling = _box(-2, 0, -2, 2, 2.5, 2.55)
    pts = sample_mesh_points(trimesh.util.concatenate([floor, crate, ceiling]), spacing, seed)
    return pts[(pts[:, 2] >= 0.0) & (pts[:, 2] <= 2.5)]


@pytest.mark.parametrize("spacing, tolerance", [(0.005, 0.001), (0.02, 0.003)])  # 100 and 6 points a 5 cm column
def test_noisy_scan_reads_surfaces_at_their_median(spacing, tolerance):
    # 5 mm of noise: the highest point of a column lies 1-2 cm over the floor (10-20 % of a 10 cm height)
    pts = _noisy(_scanned_room(spacing, seed=7), 0.005, seed=8)
    idx = SurfaceIndex(pts, cell=CELL)
    assert idx.scan_noise_m == pytest.approx(0.005, rel=0.15)
    rng = np.random.default_rng(9)
    over_floor = np.column_stack([rng.uniform(-1.9, -0.1, 300), rng.uniform(-1.9, 1.9, 300), np.full(300, 0.1)])
    over_crate = np.column_stack([rng.uniform(0.75, 1.25, 100), rng.uniform(-0.25, 0.25, 100), np.full(100, 0.85)])
    under_ceiling = np.column_stack([rng.uniform(-1.9, -0.1, 100), rng.uniform(-1.9, 1.9, 100), np.full(100, 2.0)])
    assert abs(np.mean(idx.d_down(over_floor)) - 0.1) < tolerance
    assert abs(np.mean(idx.d_down(over_crate)) - 0.1) < tolerance
    assert abs(np.mean(idx.d_up(under_ceiling)) - 0.5) < tolerance
    assert np.max(np.abs(idx.d_down(over_floor) - 0.1)) < 3 * tolerance


def test_noisy_scan_keeps_walls_and_legs_as_points():
    rng = np.random.default_rng(10)
    floor = np.column_stack([rng.uniform(-1, 1, 200_000), rng.uniform(-1, 1, 200_000), np.zeros(200_000)])
    wall = np.column_stack([np.full(40_000, 0.5), rng.uniform(-1, 1, 40_000), rng.uniform(0.0, 2.0, 40_000)])
    leg = np.column_stack([-0.5 + rng.uniform(-0.01, 0.01, 2000), rng.uniform(-0.01, 0.01, 2000),
                           rng.uniform(0.0, 0.7, 2000)])
    idx = SurfaceIndex(_noisy(np.r_[floor, wall, leg], 0.005, seed=11), cell=CELL)
    assert idx.surface_gap_m is not None
    # beside the wall and the leg, within the footprint: their points below the query, as in an exact scan
    assert idx.d_down([0.47, 0.0, 0.3]) < 0.02
    assert idx.d_down([-0.5, 0.0, 0.3]) < 0.02
    # a block away from both: the floor's median
    assert idx.d_down([0.0, 0.5, 0.3]) == pytest.approx(0.3, abs=0.002)


def test_inside_a_noisy_floor_layer_the_floor_is_below_and_nothing_above():
    rng = np.random.default_rng(12)
    floor = np.column_stack([rng.uniform(-1, 1, 400_000), rng.uniform(-1, 1, 400_000), np.zeros(400_000)])
    idx = SurfaceIndex(_noisy(floor, 0.02, seed=13), cell=CELL)  # 2 cm of noise
    assert idx.scan_noise_m == pytest.approx(0.02, rel=0.15)
    assert idx.d_down([0.0, 0.0, 0.01]) == pytest.approx(0.01, abs=0.005)  # a landed rotor plane 1 cm up
    assert idx.d_down([0.0, 0.0, -0.005]) == 0.0
    assert np.isinf(idx.d_up([0.0, 0.0, 0.01]))  # the floor's upper tail is not a ceiling


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
