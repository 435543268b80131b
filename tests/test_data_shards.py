"""The simulator-shard contract: round trips, atomic writes, manifest validation, DataModules."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from uavturb.data import synthetic
from uavturb.data.datamodules import (
    PairsDataModule,
    ShardWindowsDataModule,
    ShardWindowsDataset,
)
from uavturb.errors import InputError
from uavturb.io import shards
from uavturb.physics.ground_effect import phi


def _arrays(T=5, H=4, W=6, N=4, normals=True):
    rng = np.random.default_rng(0)
    a = {"depth": rng.uniform(0, 5, (T, H, W)), "rotor_speeds": rng.uniform(100, 200, (T, N)),
         "state": rng.normal(size=(T, 13)), "d": rng.uniform(0.1, 2, T), "fa": rng.uniform(0, 1e-3, T),
         "t": np.arange(T) * 0.05}
    if normals:
        n = rng.normal(size=(T, H, W, 3))
        a["normals"] = n / np.linalg.norm(n, axis=-1, keepdims=True)
    return a


META = {"scene_id": "s0", "split": "train", "trajectory_id": 0, "vehicle": "quad", "k_T": 5.45e-6, "mu": 2.0,
        "rotor_radius": 0.01}


def test_trajectory_round_trip(tmp_path):
    a = _arrays()
    folder = shards.write_trajectory(tmp_path / "traj_00000", a, {**META, "extra": 1})
    for mmap in (True, False):
        tr = shards.read_trajectory(folder, mmap=mmap)
        assert len(tr) == 5 and tr.meta["extra"] == 1
        for name, (dtype, _) in {**shards.ARRAYS, **shards.OPTIONAL_ARRAYS}.items():
            got = getattr(tr, name)
            assert got.dtype == dtype
            np.testing.assert_array_equal(got, a[name].astype(dtype))
    assert isinstance(shards.read_trajectory(folder).depth, np.memmap)
    assert not any(p.name.startswith(".") for p in tmp_path.iterdir())


def test_normals_optional(tmp_path):
    shards.write_trajectory(tmp_path / "t", _arrays(normals=False), META)
    assert shards.read_trajectory(tmp_path / "t").normals is None


def test_half_written_shard_never_appears(tmp_path, monkeypatch):
    real_save = np.save
    calls = []

    def failing_save(path, arr, *args, **kw):
        calls.append(path)
        if len(calls) == 3:
            assert not (tmp_path / "traj_00001").exists()  # mid-write: not under its final name
            raise OSError("disk full")
        return real_save(path, arr, *args, **kw)

    monkeypatch.setattr(np, "save", failing_save)
    with pytest.raises(OSError):
        shards.write_trajectory(tmp_path / "traj_00001", _arrays(), META)
    assert list(tmp_path.iterdir()) == []  # neither the final name nor the temporary folder


def test_existing_trajectory_needs_overwrite(tmp_path):
    shards.write_trajectory(tmp_path / "t", _arrays(), META)
    with pytest.raises(InputError, match="already exists"):
        shards.write_trajectory(tmp_path / "t", _arrays(), META)
    a = _arrays()
    a["d"] = a["d"] + 1
    shards.write_trajectory(tmp_path / "t", a, META, overwrite=True)
    np.testing.assert_allclose(shards.read_trajectory(tmp_path / "t").d, a["d"].astype(np.float32))
    assert [p.name for p in tmp_path.iterdir()] == ["t"]


@pytest.mark.parametrize("change, match", [
    (lambda a, m: a.pop("fa"), "missing array"),
    (lambda a, m: a.update(state=np.zeros((5, 12))), "state"),
    (lambda a, m: a.update(d=np.zeros(4)), "frames"),
    (lambda a, m: a.update(bogus=np.zeros(5)), "unknown array"),
    (lambda a, m: m.pop("k_T"), "k_T"),
    (lambda a, m: m.update(split="training"), "split"),
])
def test_write_rejects_bad_shards(tmp_path, change, match):
    a, m = _arrays(), dict(META)
    change(a, m)
    with pytest.raises(InputError, match=match):
        shards.write_trajectory(tmp_path / "t", a, m)
    assert not (tmp_path / "t").exists()


def test_read_names_bad_file(tmp_path):
    shards.write_trajectory(tmp_path / "t", _arrays(), META)
    (tmp_path / "t" / "fa.npy").unlink()
    with pytest.raises(InputError) as e:
        shards.read_trajectory(tmp_path / "t")
    assert e.value.where.endswith("fa.npy")


def test_manifest_round_trip_and_validation(tmp_path):
    for i, (scene, split) in enumerate([("a", "train"), ("a", "train"), ("b", "val"), ("c", "test")]):
        shards.write_trajectory(tmp_path / f"traj_{i:05d}", _arrays(T=5 + i), {**META, "scene_id": scene,
                                                                               "split": split})
    splits = {"train": ["traj_00000", "traj_00001"], "val": ["traj_00002"], "test": ["traj_00003"]}
    shards.write_manifest(tmp_path, splits, {"seed": 1})
    m = shards.read_manifest(tmp_path)
    assert m.splits == splits and m.image_size == (4, 6)
    assert m.counts["train"] == {"trajectories": 2, "frames": 11, "scenes": 1}
    assert m.config_hash == shards.config_hash({"seed": 1})
    # a scene in two splits
    with pytest.raises(InputError, match="scene 'a'"):
        shards.write_manifest(tmp_path, {"train": ["traj_00000"], "val": ["traj_00001"], "test": []}, {})
    # broken manifests name the file and the key
    body = json.loads((tmp_path / "manifest.json").read_text())
    for key, value in [("splits", {"train": []}), ("image_size", [4]), ("version", 99)]:
        bad = {**body, key: value}
        (tmp_path / "manifest.json").write_text(json.dumps(bad))
        with pytest.raises(InputError) as e:
            shards.read_manifest(tmp_path)
        assert e.value.where.endswith("manifest.json") and key in e.value.problem
    (tmp_path / "manifest.json").write_text(json.dumps({k: v for k, v in body.items() if k != "counts"}))
    with pytest.raises(InputError, match="counts"):
        shards.read_manifest(tmp_path)


def test_synthetic_dataset_is_consistent(tmp_path):
    m = synthetic.make_synthetic_dataset(tmp_path, n_scenes=3, trajs_per_scene=2, T=40, size=16, seed=3,
                                      with_normals=True)
    assert all(len(m.splits[s]) == 2 for s in shards.SPLITS)
    scenes = {s: {shards.read_trajectory(f).meta["scene_id"] for f in m.folders(s)} for s in shards.SPLITS}
    assert not (scenes["train"] & scenes["val"]) and not (scenes["train"] & scenes["test"])
    tr = shards.read_trajectory(m.folders("train")[0])
    assert tr.depth.shape == (40, 16, 16) and tr.normals.shape == (40, 16, 16, 3)
    S = (tr.rotor_speeds.astype(float) ** 2).sum(1)
    np.testing.assert_allclose(tr.fa, phi(tr.d, 5.45e-6 * S, 2.0, 0.01), rtol=1e-5)
    assert (tr.d > 0).all() and np.allclose(tr.state[:, 2] >= tr.d - 1e-4, True)
    # same seed, same dataset
    m2 = synthetic.make_synthetic_dataset(tmp_path / "again", n_scenes=3, trajs_per_scene=2, T=40, size=16, seed=3,
                                       with_normals=True)
    np.testing.assert_array_equal(shards.read_trajectory(m2.folders("train")[0]).depth, tr.depth)


def test_synthetic_pairs_normals_match_depth(tmp_path):
    synthetic.make_synthetic_pairs(tmp_path, M=8, size=48, seed=1)
    depth, normals, meta = shards.read_pairs(tmp_path, mmap=False)
    assert depth.shape == (8, 48, 48) and normals.shape == (8, 48, 48, 3) and meta["count"] == 8
    rays = synthetic.pixel_rays(48)
    for m in range(8):
        P = rays * depth[m].astype(float)[..., None]
        n = np.cross(P[1:-1, 2:] - P[1:-1, :-2], P[2:, 1:-1] - P[:-2, 1:-1])
        n /= np.linalg.norm(n, axis=-1, keepdims=True)
        g = normals[m, 1:-1, 1:-1].astype(float)
        assert np.median(np.abs((n * g).sum(-1))) > 0.99  # normals agree with the depth's surface
        assert ((g * P[1:-1, 1:-1]).sum(-1) < 0).mean() > 0.99  # and face the camera


def test_window_datamodule(tmp_path):
    synthetic.make_synthetic_dataset(tmp_path, n_scenes=3, trajs_per_scene=1, T=20, size=16, seed=0)
    dm = ShardWindowsDataModule(str(tmp_path), window=6, stride=2, eval_stride=1, batch_size=4, num_workers=0)
    dm.setup("fit")
    assert len(dm.sets["train"]) == len(range(0, 15, 2)) and len(dm.sets["val"]) == 15
    assert dm.sets["train"].index[:2] == [(0, 0), (0, 2)]
    b = next(iter(dm.train_dataloader()))
    assert b["depth"].shape == (4, 6, 1, 16, 16) and b["depth"].dtype == torch.float32
    assert b["d"].shape == b["fa"].shape == b["sum_omega2"].shape == (4, 6)
    with pytest.raises(InputError, match="image_size"):
        ShardWindowsDataModule(str(tmp_path), window=6, image_size=32).setup("fit")


def test_window_dataset_opens_maps_once_and_pickles_light(tmp_path):
    import pickle

    m = synthetic.make_synthetic_dataset(tmp_path, n_scenes=3, trajs_per_scene=1, T=12, size=8)
    ds = ShardWindowsDataset(m.folders("train"), window=4)
    ds[0]
    first = ds._trajs
    ds[3]
    assert ds._trajs is first  # opened once per process, not per sample
    clone = pickle.loads(pickle.dumps(ds))
    assert clone._trajs is None and len(clone) == len(ds)
    torch.testing.assert_close(clone[2]["d"], ds[2]["d"])


def test_window_datamodule_with_workers(tmp_path):
    synthetic.make_synthetic_dataset(tmp_path, n_scenes=3, trajs_per_scene=1, T=12, size=8)
    dm = ShardWindowsDataModule(str(tmp_path), window=4, batch_size=3, num_workers=2)
    dm.setup("fit")
    n = sum(b["d"].shape[0] for b in dm.train_dataloader())
    assert n == len(dm.sets["train"])


@pytest.mark.parametrize("target, channels", [("normals", 3), ("depth", 1)])
def test_pairs_datamodule(tmp_path, target, channels):
    synthetic.make_synthetic_pairs(tmp_path, M=20, size=16)
    dm = PairsDataModule(str(tmp_path), target=target, batch_size=5, val_fraction=0.2)
    dm.setup("fit")
    assert len(dm.train_set) == 16 and len(dm.val_set) == 4
    assert not set(dm.train_set.indices) & set(dm.val_set.indices)
    b = next(iter(dm.train_dataloader()))
    assert b["depth"].shape == (5, 1, 16, 16) and b["target"].shape == (5, channels, 16, 16)


def test_update_manifest_and_dataset_hash(tmp_path):
    m = synthetic.make_synthetic_dataset(tmp_path / "ds", n_scenes=3, trajs_per_scene=1, T=6, size=8)
    h = shards.dataset_hash(tmp_path / "ds")
    assert h == shards.dataset_hash(tmp_path / "ds") and len(h) == 16
    up = shards.update_manifest(tmp_path / "ds", complete=True, statistics={"frames": 18})
    assert up.extra == {"complete": True, "statistics": {"frames": 18}} and up.splits == m.splits
    with pytest.raises(InputError, match="splits"):
        shards.update_manifest(tmp_path / "ds", splits={})
    h2 = shards.dataset_hash(tmp_path / "ds")
    assert h2 != h  # the manifest changed
    (tmp_path / "ds" / ".traj_00009.x.tmp").mkdir()  # an interrupted writer's leftovers do not count
    np.save(tmp_path / "ds" / ".traj_00009.x.tmp" / "d.npy", np.zeros(3))
    assert shards.dataset_hash(tmp_path / "ds") == h2
    folder = m.folders("test")[0]
    a = {n: np.array(getattr(shards.read_trajectory(folder, mmap=False), n)) for n in shards.ARRAYS}
    a["d"][0] += 0.5
    meta = {k: v for k, v in shards.read_meta(folder).items() if k not in shards.WRITER_META}
    shards.write_trajectory(folder, a, meta, overwrite=True)
    assert shards.dataset_hash(tmp_path / "ds") != h2  # one value in one array changed


def test_synthetic_heights_see_the_boxes(tmp_path):
    """Known answers of the analytic scene: depth of the floor straight ahead, box tops under the body."""
    from uavturb.data.synthetic import camera_rotation, pixel_rays, render
    from uavturb.scene.layouts import box_room
    from uavturb.scene.queries import surface_below

    room = box_room((8.0, 8.0), 3.0, [(-1.0, 1.0, -1.0, 1.0, 0.5)])
    np.testing.assert_allclose(surface_below(room, np.array([[0.0, 0.0], [2.0, 0.0]])), [0.5, 0.0])
    # camera 1 m above the floor, looking straight down (pitch 90 deg) over the floor at x = 2.5
    rays = pixel_rays(5, 70.0)
    depth, normals = render(room, np.array([[2.5, 0.0, 1.0]]), camera_rotation(np.zeros(1), 90.0), rays)
    assert depth[0, 2, 2] == pytest.approx(1.0)  # centre pixel: the floor, 1 m along the optical axis
    np.testing.assert_allclose(normals[0, 2, 2], [0.0, 0.0, -1.0], atol=1e-12)  # towards the camera
    # over the box: its top 0.5 m below
    depth, _ = render(room, np.array([[0.0, 0.0, 1.0]]), camera_rotation(np.zeros(1), 90.0), rays)
    assert depth[0, 2, 2] == pytest.approx(0.5)
    # looking level along +x from x = 2.5: the wall at x = 4, 1.5 m ahead
    depth, _ = render(room, np.array([[2.5, 0.0, 1.0]]), camera_rotation(np.zeros(1), 0.0), rays)
    assert depth[0, 2, 2] == pytest.approx(1.5)


def test_written_files_have_ordinary_permissions(tmp_path):
    """Atomic writes go through private temporary entries; the results are not left private."""
    import os
    import stat

    folder = shards.write_trajectory(tmp_path / "t", _arrays(), META)
    shards.write_manifest(tmp_path, {"train": ["t"], "val": [], "test": []}, {})
    mask = os.umask(0)
    os.umask(mask)
    assert stat.S_IMODE(folder.stat().st_mode) == 0o777 & ~mask
    assert stat.S_IMODE((tmp_path / "manifest.json").stat().st_mode) == 0o666 & ~mask
