"""Pre-training pairs: rendered from training scenes (deterministic, resumable) and read from IRS."""

from __future__ import annotations

import json

import numpy as np
import pytest

from uavturb.errors import InputError
from uavturb.io import shards
from uavturb.sim.dataset import assignment, pretraining_pairs
from uavturb.sim.dataset.presets import get_preset


def _normals_of_depth(depth, f):
    n, ok = pretraining_pairs._depth_normals(depth.astype(float), f)
    return n, ok


@pytest.fixture(scope="module")
def pairs(tmp_path_factory):
    root = tmp_path_factory.mktemp("pairs")
    pretraining_pairs.generate_normals("tiny", root, seed=0, progress=False)
    return root


def test_pairs_are_consistent_and_from_training_scenes(pairs):
    depth, normals, meta = shards.read_pairs(pairs, mmap=False)
    p = get_preset("tiny")
    assert depth.shape == (24, 32, 32) and normals.shape == (24, 32, 32, 3) and meta["count"] == 24
    assert meta["scenes"] == assignment.scene_splits(p)["train"] and meta["split"] == "train"
    assert meta["config_hash"] == shards.config_hash(meta["config"])
    hit = depth > 0
    np.testing.assert_allclose(np.linalg.norm(normals[hit], axis=-1), 1.0, atol=1e-5)
    assert (normals[~hit] == 0).all()
    f = (32 / 2) / np.tan(np.deg2rad(p.yfov_deg) / 2)
    agree = []
    for m in range(len(depth)):
        n, ok = _normals_of_depth(depth[m], f)
        agree.append(np.sum(n[ok] * normals[m, 1:-1, 1:-1][ok], axis=-1))
    assert np.median(np.concatenate(agree)) > 0.99  # normals are the depth map's surface, facing the camera
    assert not (pairs / pretraining_pairs.CHUNKS_DIR).exists()


def test_interrupted_pairs_resume_identical(pairs, tmp_path):
    root = tmp_path / "p"

    def kill(c):
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        pretraining_pairs.generate_normals("tiny", root, seed=0, progress=False, on_chunk=kill)
    assert sorted(p.name for p in (root / pretraining_pairs.CHUNKS_DIR).iterdir()) == ["chunk_00000", "config.json"]
    assert not (root / shards.PAIRS_DIR).exists()
    pretraining_pairs.generate_normals("tiny", root, seed=0, progress=False)
    a, b = shards.read_pairs(pairs, mmap=False), shards.read_pairs(root, mmap=False)
    np.testing.assert_array_equal(a[0], b[0])
    np.testing.assert_array_equal(a[1], b[1])
    # finished pairs are kept as they are; another config is refused
    stamp = (root / shards.PAIRS_DIR / "depth.npy").stat().st_mtime_ns
    pretraining_pairs.generate_normals("tiny", root, seed=0, progress=False)
    assert (root / shards.PAIRS_DIR / "depth.npy").stat().st_mtime_ns == stamp
    with pytest.raises(InputError, match="another config"):
        pretraining_pairs.generate_normals("tiny", root, seed=1, progress=False)


# --- IRS ------------------------------------------------------------------------------------------

W, H = 96, 54  # a 1/10-scale IRS frame (IRS: 960 x 540)
F = pretraining_pairs.IRS_FOCAL_PX * W / pretraining_pairs.IRS_WIDTH_PX  # px
N_TRUE = np.array([0.2, -0.5, -0.84]) / np.linalg.norm([0.2, -0.5, -0.84])  # plane normal, optical frame


def _plane_depth(offset):
    u = (np.arange(W) - (W - 1) / 2) / F
    v = (np.arange(H) - (H - 1) / 2) / F
    rays = np.concatenate([np.stack(np.meshgrid(u, v), axis=-1), np.ones((H, W, 1))], axis=-1)
    return -offset / (rays @ N_TRUE)  # z-depth of the plane n . X + offset = 0


def _write_exr(path, channels):
    import OpenEXR

    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    OpenEXR.File(header, channels).write(str(path))


def _fake_irs(root):
    """Two IRS scenes of one plane each; IRS stores normals in its own axes (here x, -y, -z)."""
    for k, (cat, scene, offset) in enumerate([("Home", "ArchVizInterior03Data", 2.0), ("Office", "Mall01", 3.0)]):
        folder = root / cat / scene
        folder.mkdir(parents=True)
        depth = _plane_depth(offset)
        disp = (F * pretraining_pairs.IRS_BASELINE_M / depth).astype(np.float32)
        n_irs = np.broadcast_to(N_TRUE * [1.0, -1.0, -1.0], (H, W, 3)).astype(np.float32)
        for i in range(2):
            _write_exr(folder / f"d_{i + 1}.exr", {"Y": disp})
            _write_exr(folder / f"n_{i + 1}.exr", {"RGB": np.ascontiguousarray(n_irs)})
            (folder / f"l_{i + 1}.png").write_bytes(b"")
        _write_exr(folder / "d_9.exr", {"Y": disp})  # no normal map beside it: skipped
    return root


def test_irs_reader_known_plane(tmp_path):
    pytest.importorskip("OpenEXR")
    root = _fake_irs(tmp_path / "IRS")
    got = list(pretraining_pairs.read_irs(root, size=18))
    assert [g[2].name for g in got] == ["d_1.exr", "d_2.exr", "d_1.exr", "d_2.exr"]
    for (depth, normals, dfile), offset in zip(got, (2.0, 2.0, 3.0, 3.0)):
        full = _plane_depth(offset)
        s = H  # centre square crop, nearest neighbour to 18 px: every third pixel from 1
        ref = full[:, (W - s) // 2:(W - s) // 2 + s][1::3, 1::3]
        np.testing.assert_allclose(depth, ref, rtol=1e-5)
        np.testing.assert_allclose(normals.reshape(-1, 3), np.broadcast_to(N_TRUE, (18 * 18, 3)), atol=1e-5)
    meta = pretraining_pairs.import_irs(root, tmp_path / "out", size=18, chunk=3, progress=False)
    d, n, m = shards.read_pairs(tmp_path / "out")
    assert m["count"] == meta["count"] == 4 and m["source"] == "IRS" and d.shape == (4, 18, 18)
    np.testing.assert_array_equal(d[2], got[2][0])
    with pytest.raises(InputError, match="no IRS pairs"):
        pretraining_pairs.irs_pairs(tmp_path / "out")
    (root / "Home" / "ArchVizInterior03Data" / "n_1.exr").write_bytes(b"not an exr")
    with pytest.raises(InputError) as e:
        list(pretraining_pairs.read_irs(root, size=18))
    assert e.value.where.endswith("n_1.exr")
    assert json.loads((tmp_path / "out" / "pairs" / "meta.json").read_text())["count"] == 4
