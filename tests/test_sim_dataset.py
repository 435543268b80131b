"""Training shards from simulated flights: determinism, resume after a kill, shards + merge,
statistics and what every sample holds (known answers from the scene)."""

from __future__ import annotations

import json
import os

import numpy as np
import pytest

from uavturb.errors import InputError
from uavturb.io import shards
from uavturb.io.vehicle_file import named_vehicle
from uavturb.physics.ground_effect import phi
from uavturb.scene.procedural import generate_scene
from uavturb.scene.queries import height_below, inside_obstacle
from uavturb.sim.dataset import generation, trajectory_arrays
from uavturb.sim.dataset.presets import get_preset
from uavturb.sim.dataset.assignment import plan_tasks, scene_splits

#: three scenes (one per split), one 1-second trajectory each, 24 x 24 px, geometric controller
SMALL = dict(max_seconds=1.0, width=24, height=24, controller="geometric")


def _arrays(root):
    m = shards.read_manifest(root)
    out = {}
    for split in shards.SPLITS:
        for folder in m.folders(split):
            tr = shards.read_trajectory(folder, mmap=False)
            out[folder.name] = {n: getattr(tr, n) for n in shards.ARRAYS}
    return m, out


def _assert_same(a, b):
    assert a.keys() == b.keys()
    for name in a:
        for arr in a[name]:
            np.testing.assert_array_equal(a[name][arr], b[name][arr], err_msg=f"{name}/{arr}")


@pytest.fixture(scope="module")
def full(tmp_path_factory):
    root = tmp_path_factory.mktemp("full")
    generation.generate_sim("tiny", root, seed=0, progress=False, **SMALL)
    return root


def test_samples_hold_known_answers(full):
    m, arrays = _arrays(full)
    assert m.counts["train"]["trajectories"] == m.counts["val"]["trajectories"] == 1
    assert m.image_size == (24, 24)
    quad = named_vehicle("quad")
    body = json.loads((full / "manifest.json").read_text())
    low = oov = n = 0
    for split in shards.SPLITS:
        for folder in m.folders(split):
            tr = shards.read_trajectory(folder)
            scene = generate_scene(tr.meta["scene_seed"])
            p = np.asarray(tr.state[:, :3])
            assert len(tr) == 21 and np.allclose(np.diff(tr.t), 0.05)  # 1 s at 20 Hz
            np.testing.assert_allclose(tr.d, height_below(scene, p), rtol=1e-6)
            S = (np.asarray(tr.rotor_speeds, float) ** 2).sum(1)
            np.testing.assert_allclose(tr.fa, phi(np.asarray(tr.d, float), quad.thrust_coefficient * S, 2.0,
                                                  quad.rotor_radius), rtol=1e-5)
            assert not inside_obstacle(scene, p).any()
            assert tr.meta["split"] == split and tr.meta["controller"] == "geometric"
            np.testing.assert_allclose(np.linalg.norm(tr.state[:, 3:7], axis=1), 1.0, atol=1e-9)
            # the centre pixel's depth is the distance along the optical axis to the mesh
            from uavturb.sim.core.render import camera_pose

            T = camera_pose(p[5], tr.state[5, 3:7], 20.0)
            loc, _, _ = scene.mesh.ray.intersects_location(T[None, :3, 3], T[None, :3, 2])
            z = np.min((loc - T[:3, 3]) @ T[:3, 2])
            c = np.asarray(tr.depth[5])
            np.testing.assert_allclose(c[11:13, 11:13].mean(), z, rtol=0.03)
            low += int((tr.d < 0.5).sum())
            oov += tr.meta["stats"]["out_of_view"]
            n += len(tr)
    st = body["statistics"]
    assert st["samples"] == n == sum(c["frames"] for c in m.counts.values())
    assert st["share_d_below_0.5m"] == pytest.approx(low / n)
    assert st["share_below_out_of_view"] == pytest.approx(oov / n)
    assert st["samples_inside_obstacles"] == 0 and body["complete"] is True
    assert body["config_hash"] == shards.config_hash(body["config"]) and body["config"]["seed"] == 0
    assert set(body["throughput"]["this_run"]["worker_seconds"]) == {"control", "physics", "render", "other"}


def test_interrupted_run_resumes_to_identical_arrays(full, tmp_path):
    root = tmp_path / "killed"

    def kill(meta):
        raise KeyboardInterrupt("killed")

    with pytest.raises(KeyboardInterrupt):
        generation.generate_sim("tiny", root, seed=0, progress=False, on_trajectory=kill, **SMALL)
    done = sorted(p.name for p in root.iterdir())
    assert done == ["traj_00000"]  # one finished shard, no manifest yet
    first = root / "traj_00000" / "depth.npy"
    stamp = os.stat(first).st_mtime_ns
    # a half-written shard of the next trajectory, as a kill mid-write leaves it
    junk = root / ".traj_00001.abc.tmp"
    junk.mkdir()
    (junk / "depth.npy").write_bytes(b"half")
    generation.generate_sim("tiny", root, seed=0, progress=False, **SMALL)
    assert os.stat(first).st_mtime_ns == stamp  # finished shards are never rewritten
    assert not junk.exists()
    _assert_same(_arrays(full)[1], _arrays(root)[1])
    assert json.loads((root / "manifest.json").read_text())["throughput"]["this_run"]["trajectories"] == 2


def test_same_seed_same_arrays_any_workers_other_seed_differs(full, tmp_path):
    generation.generate_sim("tiny", tmp_path / "w2", seed=0, workers=2, progress=False, **SMALL)
    _assert_same(_arrays(full)[1], _arrays(tmp_path / "w2")[1])
    m = generation.generate_sim("tiny", tmp_path / "s1", seed=1, progress=False, shard="1/3", **SMALL)
    other = shards.read_trajectory(m.root / "traj_00000")
    assert not np.array_equal(other.state, shards.read_trajectory(full / "traj_00000").state)


def test_shards_then_merge_equal_the_full_run(full, tmp_path):
    for k in (1, 2):
        generation.generate_sim("tiny", tmp_path / f"s{k}", seed=0, shard=f"{k}/2", progress=False, **SMALL)
    part = json.loads((tmp_path / "s1" / "manifest.json").read_text())
    assert part["shard"] == "1/2" and part["complete"] is False and part["statistics"]["trajectories"] == 2
    merged = generation.merge_datasets([tmp_path / "s1", tmp_path / "s2"], tmp_path / "merged")
    mf, af = _arrays(full)
    assert merged.splits == mf.splits and merged.counts == mf.counts and merged.config_hash == mf.config_hash
    _assert_same(af, _arrays(tmp_path / "merged")[1])
    a, b = (json.loads((r / "manifest.json").read_text()) for r in (full, tmp_path / "merged"))
    assert a["statistics"] == b["statistics"] and b["complete"] is True
    # merging into one of the shard folders works too
    generation.merge_datasets([tmp_path / "s1", tmp_path / "s2"], tmp_path / "s1")
    assert shards.read_manifest(tmp_path / "s1").splits == mf.splits


def test_bad_inputs_fail_naming_the_key(full, tmp_path):
    with pytest.raises(InputError, match="unknown preset"):
        generation.generate_sim("huge", tmp_path / "x", progress=False)
    with pytest.raises(InputError, match="--shard"):
        generation.generate_sim("tiny", tmp_path / "x", shard="0/2", progress=False)
    with pytest.raises(InputError, match="preset tiny: widht: unknown key \\(did you mean 'width'\\?\\)"):
        generation.generate_sim("tiny", tmp_path / "x", widht=3, progress=False)
    with pytest.raises(InputError, match="plan.bogus"):
        get_preset("tiny", plan={"bogus": 1})
    with pytest.raises(InputError, match="n_train"):
        get_preset("tiny", n_train=2)
    # a folder of another config is refused, and nothing is written into it
    before = sorted(p.name for p in full.iterdir())
    with pytest.raises(InputError, match="another config"):
        generation.generate_sim("tiny", full, seed=5, progress=False, **SMALL)
    assert sorted(p.name for p in full.iterdir()) == before
    s = tmp_path / "other"
    generation.generate_sim("tiny", s, seed=3, shard="1/3", progress=False, **SMALL)
    with pytest.raises(InputError, match="config hash"):
        generation.merge_datasets([full, s], tmp_path / "m")


def test_paper_preset_matches_the_paper():
    p = get_preset("paper")
    tasks = plan_tasks(p, 0)
    splits = scene_splits(p)
    assert len(tasks) == 531 and p.n_scenes == 68 and [len(splits[s]) for s in shards.SPLITS] == [43, 9, 16]
    assert {t.split for t in tasks if t.scene in splits["val"]} == {"val"}
    counts = np.bincount([t.scene for t in tasks])
    assert counts.min() == 7 and counts.max() == 8
    assert get_preset("paper").pairs == 22705
    assert plan_tasks(p, 0) == tasks and plan_tasks(p, 1) != tasks


@pytest.mark.parametrize("pitch, depth_scale, expected", [(90.0, 1.0, False), (90.0, 0.5, True), (0.0, 1.0, True)])
def test_below_out_of_view_known_answers(pitch, depth_scale, expected):
    d = np.array([0.8])
    state = np.zeros((1, 13))
    state[0, :3] = [1.0, 2.0, 0.8]
    state[0, 3] = 1.0
    f = 16.0
    K = np.array([[f, 0, 15.5], [0, f, 15.5], [0, 0, 1]])
    depth = np.full((1, 32, 32), 0.8 * depth_scale, np.float32)  # camera looking down sees the floor at 0.8 m
    assert trajectory_arrays.below_out_of_view(state, d, depth, K, pitch)[0] == expected


@pytest.mark.slow
def test_quick_preset_statistics(tmp_path):
    """The issue's thresholds on the quick preset (run with -m slow; about a minute on 2 cores)."""
    generation.generate_sim("quick", tmp_path / "q", workers=2, seed=0, progress=False)
    st = json.loads((tmp_path / "q" / "manifest.json").read_text())["statistics"]
    assert st["share_d_below_0.5m"] >= 0.15
    assert st["share_below_out_of_view"] >= 0.05
    assert st["samples_inside_obstacles"] == 0


@pytest.mark.slow
def test_sigkill_mid_run_then_rerun_gives_the_same_arrays(full, tmp_path):
    """A real kill (SIGKILL of the generating process) instead of an exception."""
    import signal
    import subprocess
    import sys
    import time

    root = tmp_path / "k"
    code = ("from uavturb.sim.dataset import generation; "
            f"generation.generate_sim('tiny', {str(root)!r}, seed=0, progress=False, **{SMALL!r})")
    proc = subprocess.Popen([sys.executable, "-c", code])
    deadline = time.time() + 120
    while not (root / "traj_00000").exists() and time.time() < deadline and proc.poll() is None:
        time.sleep(0.01)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    assert not (root / "manifest.json").exists()
    generation.generate_sim("tiny", root, seed=0, progress=False, **SMALL)
    _assert_same(_arrays(full)[1], _arrays(root)[1])


def test_optional_normals_and_rgb_ride_in_the_same_shard(full, tmp_path):
    m = generation.generate_sim("tiny", tmp_path / "nr", seed=0, shard="1/3", progress=False,
                             **{**SMALL, "normals": True, "rgb": True})
    tr = shards.read_trajectory(m.root / "traj_00000")
    ref = shards.read_trajectory(full / "traj_00000")
    np.testing.assert_array_equal(tr.depth, ref.depth)  # the extras change nothing else
    assert tr.normals.shape == (21, 24, 24, 3)
    hit = np.asarray(tr.depth) > 0
    np.testing.assert_allclose(np.linalg.norm(tr.normals[hit], axis=-1), 1.0, atol=1e-5)
    rgb = np.load(m.root / "traj_00000" / "rgb.npy")
    assert rgb.dtype == np.uint8 and rgb.shape == (21, 24, 24, 3) and rgb.std() > 0
    assert tr.meta["extra_arrays"]["rgb"]["shape"] == [21, 24, 24, 3]
    assert sorted(p.name for p in (tmp_path / "nr").iterdir()) == ["manifest.json", "traj_00000"]


def test_mpc_and_geometric_flyers_fly_the_same_plan(full, tmp_path):
    m = generation.generate_sim("tiny", tmp_path / "mpc", seed=0, shard="1/3", progress=False,
                             **{**SMALL, "controller": "mpc"})
    mpc = shards.read_trajectory(m.root / "traj_00000")
    geo = shards.read_trajectory(full / "traj_00000")
    assert mpc.meta["controller"] == "mpc" and len(mpc) == len(geo)
    np.testing.assert_allclose(mpc.t, geo.t)
    # both track one reference: positions within 2 cm, hover rotor speeds within 5 %
    assert np.abs(mpc.state[:, :3] - geo.state[:, :3]).max() < 0.02
    np.testing.assert_allclose(np.asarray(mpc.rotor_speeds).mean(), np.asarray(geo.rotor_speeds).mean(), rtol=0.05)
