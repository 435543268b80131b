"""Procedural scenes: determinism, layout validity, splits, geometric queries, loading."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
import trimesh
from scipy import ndimage

from uavturb.errors import InputError
from uavturb.scene import indoor, procedural, queries

SEEDS = range(30)


@pytest.fixture(scope="module")
def many():
    return [procedural.generate_scene(s) for s in SEEDS]


def _table_scene():
    for seed in range(200):
        sc = procedural.generate_scene(seed)
        for f in sc.furniture:
            if f.kind == "table":
                return sc, f
    raise AssertionError("no table in 200 scenes")


def _free_points(sc, n=400, seed=0, z=(0.3, 2.0), margin=0.2):
    rng = np.random.default_rng(seed)
    lo, hi = sc.bounds
    p = rng.uniform([lo[0], lo[1], z[0]], [hi[0], hi[1], z[1]], (n, 3))
    return p[~queries.inside_obstacle(sc, p, margin=margin)]


def test_same_seed_same_vertices_and_different_seeds_differ():
    a, b = procedural.generate_scene(11), procedural.generate_scene(11)
    assert np.array_equal(a.mesh.vertices, b.mesh.vertices)
    assert np.array_equal(a.mesh.faces, b.mesh.faces)
    c = procedural.generate_scene(12)
    assert a.mesh.vertices.shape != c.mesh.vertices.shape or not np.allclose(a.mesh.vertices, c.mesh.vertices)
    assert procedural.generate_scene(11, "office").kind == "office"


def test_scenes_vary(many):
    assert {len(s.rooms) for s in many} >= {2, 3, 4, 5, 6}
    assert {s.kind for s in many} == {"apartment", "office"}
    assert len({len(s.mesh.faces) for s in many}) >= 20
    assert len({round(float(s.bounds[1, 0] * s.bounds[1, 1]), 1) for s in many}) >= 25
    kinds = {f.kind for s in many for f in s.furniture}
    assert kinds == {"table", "desk", "bed", "sofa", "shelf", "counter", "box"}


def test_rooms_floor_ceiling_doors(many):
    for sc in many:
        assert 2 <= len(sc.rooms) <= 6
        assert 2.4 <= sc.ceiling_height <= 3.0
        floors = sc.boxes[sc.box_kinds == "floor"]
        ceilings = sc.boxes[sc.box_kinds == "ceiling"]
        assert len(floors) == len(sc.rooms) and np.all(floors[:, 1, 2] == 0.0)
        assert np.allclose(ceilings[:, 0, 2], sc.ceiling_height)
        # the floor covers every room: straight down from 1 m over free points is 1 m or a surface
        p = _free_points(sc, z=(1.0, 1.0), margin=0.0)
        assert len(p) > 20
        below, above = queries.height_below(sc, p), queries.height_above(sc, p)
        assert np.all(below <= 1.0 + 1e-12) and np.any(below == 1.0)
        assert np.all(above <= sc.ceiling_height - 1.0 + 1e-12)
        assert np.isclose(above.max(), sc.ceiling_height - 1.0)
        # doors: sizes, and they connect all rooms
        assert len(sc.doors) >= len(sc.rooms) - 1
        for d in sc.doors:
            assert 0.9 <= d.width <= 1.2 and 2.0 <= d.height <= 2.1
            assert np.isclose(d.hi[d.axis] - d.lo[d.axis], d.width)
        seen, stack = {0}, [0]
        while stack:
            k = stack.pop()
            for d in sc.doors:
                if k in d.rooms:
                    m = d.rooms[1] if d.rooms[0] == k else d.rooms[0]
                    if m not in seen:
                        seen.add(m)
                        stack.append(m)
        assert seen == set(range(len(sc.rooms)))


def test_furniture_no_overlap_inside_rooms_clear_of_doors(many):
    n_pieces = 0
    for sc in many:
        for f in sc.furniture:
            r = sc.rooms[f.room].rect
            assert f.lo[0] >= r[0] - 1e-9 and f.hi[0] <= r[2] + 1e-9
            assert f.lo[1] >= r[1] - 1e-9 and f.hi[1] <= r[3] + 1e-9
            assert f.lo[2] == 0.0 and f.hi[2] < sc.ceiling_height
            for d in sc.doors:  # nothing beside a door (0.1 m) or in front of it (0.8 m)
                grow = np.full(2, 0.8)
                grow[d.axis] = 0.1
                lo, hi = d.lo[:2] - grow, d.hi[:2] + grow
                assert not (np.all(f.lo[:2] < hi) and np.all(f.hi[:2] > lo)), (sc.seed, f.kind)
            n_pieces += 1
        for f, g in itertools.combinations(sc.furniture, 2):
            assert not (np.all(f.lo[:2] < g.hi[:2]) and np.all(f.hi[:2] > g.lo[:2])), (sc.seed, f.kind, g.kind)
    assert n_pieces > 200


def test_furniture_heights():
    tops = {}
    for seed in range(60):
        for f in procedural.generate_scene(seed).furniture:
            tops.setdefault(f.kind, []).append(f.surface)
            if f.kind == "shelf":
                assert 1.5 <= f.top <= 2.0
    assert all(0.72 <= t <= 0.78 for t in tops["table"])
    assert all(0.45 <= t <= 0.6 for t in tops["bed"])
    assert all(0.86 <= t <= 0.92 for t in tops["counter"])
    assert all(0.2 <= t <= 0.6 for t in tops["box"])


def test_split_scenes():
    sp = procedural.split_scenes()
    assert [len(sp[k]) for k in ("train", "val", "test")] == [43, 9, 16]
    allk = sp["train"] + sp["val"] + sp["test"]
    assert sorted(allk) == list(range(68))
    assert sp == procedural.split_scenes()
    assert sp != procedural.split_scenes(seed=1)
    with pytest.raises(InputError):
        procedural.split_scenes(68, 40, 9, 16)


def test_heights_over_floor_and_table():
    sc, t = _table_scene()
    c = t.centre
    top_slab = t.parts[0]
    p = np.array([[c[0], c[1], 1.0], [c[0], c[1], 0.3]])
    below = queries.height_below(sc, p)
    above = queries.height_above(sc, p)
    assert np.isclose(below[0], 1.0 - t.top)
    assert np.isclose(below[1], 0.3)  # free space under the table, legs at the corners
    assert np.isclose(above[1], top_slab[0, 2] - 0.3)
    assert np.isclose(above[0], sc.ceiling_height - 1.0)
    # over the floor at 1 m
    q = _free_points(sc, z=(1.0, 1.0), margin=0.0)
    b = queries.height_below(sc, q)
    assert np.any(b == 1.0)
    # the mesh ray caster agrees with the boxes
    pts = _free_points(sc, n=300)
    assert np.allclose(queries.height_below(sc.mesh, pts), queries.height_below(sc, pts), atol=1e-9)
    assert np.allclose(queries.height_above(sc.mesh, pts), queries.height_above(sc, pts), atol=1e-9)
    with pytest.raises(InputError):
        queries.height_below(sc, np.zeros((3, 2)))


def test_inside_obstacle():
    sc, t = _table_scene()
    c, top = t.centre, t.top
    tt = t.parts[0, 1, 2] - t.parts[0, 0, 2]
    pts = np.array([
        [c[0], c[1], top - tt / 2],  # inside the table top
        [c[0], c[1], 0.3],  # under the table
        [c[0], c[1], top + 0.1],  # 10 cm over it
        [-5.0, -5.0, 1.0],  # outside the building
        [c[0], c[1], -0.01],  # under the floor
    ])
    hit = queries.inside_obstacle(sc, pts)
    assert hit.tolist() == [True, False, False, True, True]
    assert queries.inside_obstacle(sc, pts[2:3], margin=0.15)[0]
    wall = sc.boxes[sc.box_kinds == "wall"][0]
    assert queries.inside_obstacle(sc, ((wall[0] + wall[1]) / 2)[None])[0]
    free = _free_points(sc, margin=0.3)
    assert not queries.inside_obstacle(sc, free).any()
    assert queries.inside_obstacle(sc, free, margin=0.0).sum() == 0


def test_free_space_grid_navigable(many):
    for sc in many:
        occ, origin, res = sc.free_space_grid(1.0, resolution=0.1, margin=0.3, height_band=0.3)
        assert res == 0.1 and occ.dtype == bool
        labels, n = ndimage.label(~occ)
        assert n >= 1
        sizes = np.bincount(labels.ravel())[1:]
        main = 1 + int(np.argmax(sizes))
        for room in sc.rooms:  # every room reaches the same free component (through its doors)
            i0, j0 = np.ceil((room.rect[:2] - origin) / res).astype(int)
            i1, j1 = np.floor((room.rect[2:] - origin) / res).astype(int)
            assert np.any(labels[i0 : i1 + 1, j0 : j1 + 1] == main), (sc.seed, room.kind)
        # free cells are clear of obstacles by the margin (horizontally and, with the band, vertically)
        ij = np.argwhere(~occ)
        xyz = np.c_[origin + ij * res, np.full(len(ij), 1.0)]
        assert not queries.inside_obstacle(sc, xyz, margin=0.29).any()


def test_free_space_grid_from_mesh_matches_boxes():
    sc = procedural.generate_scene(7)
    ext = indoor.Scene(mesh=sc.mesh, seed=None, kind="external", bounds=sc.bounds)
    ob, o1, _ = sc.free_space_grid(1.0, 0.1, 0.3)
    om, o2, _ = ext.free_space_grid(1.0, 0.1, 0.3)
    assert np.allclose(o1, o2) and ob.shape == om.shape
    assert (ob == om).mean() > 0.95


def test_load_scene_mesh_round_trip(tmp_path):
    sc = procedural.generate_scene(4)
    for ext in ("ply", "obj"):
        path = tmp_path / f"scene.{ext}"
        sc.mesh.export(path)
        loaded = indoor.load_scene_mesh(path)
        assert loaded.kind == "external" and loaded.furniture == [] and loaded.seed is None
        assert np.allclose(loaded.bounds, sc.bounds, atol=1e-5)
        assert np.isclose(loaded.mesh.area, sc.mesh.area, rtol=1e-5)
        pts = _free_points(sc, n=100)
        assert np.allclose(queries.height_below(loaded, pts), queries.height_below(sc, pts), atol=1e-5)
        assert np.allclose(queries.height_above(loaded, pts), queries.height_above(sc, pts), atol=1e-5)
    # y-up file (Habitat/Matterport convention)
    yup = sc.mesh.copy()
    yup.apply_transform(trimesh.transformations.rotation_matrix(-np.pi / 2, [1, 0, 0]))
    yup.export(tmp_path / "yup.ply")
    loaded = indoor.load_scene_mesh(tmp_path / "yup.ply", up_axis="y")
    assert np.allclose(loaded.bounds, sc.bounds, atol=1e-5)
    # several geometries are concatenated
    multi = trimesh.Scene([trimesh.creation.box((1, 1, 1)), trimesh.creation.box((2, 2, 2))])
    multi.export(tmp_path / "multi.glb")
    assert len(indoor.load_scene_mesh(tmp_path / "multi.glb").mesh.faces) == 24


def test_load_scene_mesh_errors(tmp_path):
    missing = tmp_path / "nope.glb"
    with pytest.raises(InputError, match="nope.glb"):
        indoor.load_scene_mesh(missing)
    bad = tmp_path / "bad.ply"
    bad.write_bytes(b"this is not a mesh")
    with pytest.raises(InputError, match="bad.ply"):
        indoor.load_scene_mesh(bad)
    (tmp_path / "ok.ply").write_bytes(b"")
    with pytest.raises(InputError):
        indoor.load_scene_mesh(tmp_path / "ok.ply", up_axis="x")
    with pytest.raises(InputError):
        procedural.generate_scene(0, "castle")
