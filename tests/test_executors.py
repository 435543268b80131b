"""Sweeps on Ray (``--executor ray``) against the sequential executor, failures and retries,
a real ``mlflow server`` over HTTP, and ``generate sim`` on Ray.

One small local Ray (2 CPUs, no dashboard) serves the module and is shut down at its end.
Ray workers are other processes: the stand-in training below is shipped to them by value
(cloudpickle), and it is told which runs to fail through a plan file in the run folder.
"""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import time
import urllib.request
from pathlib import Path

import mlflow
import numpy as np
import pytest

from uavturb.errors import InputError
from uavturb.runs import executors
from uavturb.runs import sweep as sweep_mod
from uavturb.runs.executors import absolute_tracking_uri, task_resources
from uavturb.runs.sweep import sweep
from uavturb.runs.config import DEFAULT_SPEC, load_spec
from uavturb.runs.store import tracking_uri

ray = pytest.importorskip("ray")

ROWS = [r.name for r in load_spec(DEFAULT_SPEC).rows]
#: the tiny real-training settings of tests/test_sweep.py's slow test (plus 1 epoch less)
TINY = ["data.image_size=16", "data.window=4", "data.synthetic.n_scenes=3", "data.synthetic.trajs_per_scene=1",
        "data.synthetic.T=16", "data.synthetic.pairs=32", "trainer.max_epochs=2", "model.unfreeze_at_epoch=1"]


@pytest.fixture(scope="module")
def ray_local(module_mlflow_store):
    """A small local Ray for the module (the executors use it as it is and leave it running)."""
    ray.cloudpickle.register_pickle_by_value(sys.modules[__name__])  # fake_train travels to the workers
    ray.init(num_cpus=2, include_dashboard=False, logging_level="ERROR", object_store_memory=100 * 2**20)
    yield module_mlflow_store
    ray.shutdown()


@pytest.fixture
def experiment(request):
    return request.node.name.replace("[", "-").replace("]", "")


def fake_train(cfg, tags=None):
    """Stands in for train(): a FINISHED run with known metrics; fails as ``<root>/plan.json`` says.

    ``plan.json``: ``{label: n}`` -- the run labelled ``label`` fails its first ``n`` attempts
    (-1: every attempt), after opening its MLflow run (as a crash mid-training leaves it: RUNNING).
    """
    root = Path(cfg.trainer.default_root_dir)
    client = mlflow.MlflowClient(tracking_uri())
    exp = client.get_experiment_by_name(cfg.tracking.experiment)
    run = client.create_run(exp.experiment_id, run_name=cfg.tracking.run_name, tags=tags)
    rid = run.info.run_id
    plan = json.loads((root / "plan.json").read_text()) if (root / "plan.json").is_file() else {}
    label = cfg.tracking.run_name
    attempts = root / "attempts"
    attempts.mkdir(parents=True, exist_ok=True)
    n = len(list(attempts.glob(f"{label.replace('/', '_')}.*")))
    (attempts / f"{label.replace('/', '_')}.{n}").write_text(f"{os.getpid()}")
    if label in plan and (plan[label] < 0 or n < plan[label]):
        raise RuntimeError(f"injected failure of {label}, attempt {n + 1}")
    ckpt = root / "ckpts" / rid / "best.ckpt"
    ckpt.parent.mkdir(parents=True)
    ckpt.write_text(f"{cfg.stage} {rid} {cfg.model.encoder_ckpt}")
    client.set_tag(rid, "checkpoint", str(ckpt))
    if cfg.stage == "pretrain":
        metrics = {"test/loss": 1.0}
    else:
        k, seed = ROWS.index(tags["ablation"]), int(tags["seed"])
        metrics = {"test/rmse_d": 0.1 * (k + 1) + 0.01 * seed, "test/rmse_fa": 1e-4 * (k + 1)}
    for key, v in metrics.items():
        client.log_metric(rid, key, v)
    client.set_terminated(rid, "FINISHED")
    return {"stage": cfg.stage, "metrics": metrics, "checkpoint": str(ckpt), "run_id": rid, "data_hash": "x"}


def _children(parent: str, experiment: str, uri: str | None = None) -> list:
    client = mlflow.MlflowClient(uri or tracking_uri())
    exp = client.get_experiment_by_name(experiment)
    return client.search_runs([exp.experiment_id], f"tags.`mlflow.parentRunId` = '{parent}'", max_results=1000)


def _key(run) -> tuple[str, str]:
    t = run.data.tags
    return (t.get("ablation") or f"pretrain {t['pretrain']}", t["seed"])


def _attempts(root: Path, label: str) -> int:
    return len(list((root / "attempts").glob(f"{label.replace('/', '_')}.*")))


# ----------------------------------------------------------------------------------------------


def test_task_resources_from_the_config(capsys):
    from uavturb.cli import main
    from uavturb.runs.config import load_config

    cfg = load_config(["trainer=cpu", "trainer.num_threads=3", "data.num_workers=2"])
    assert task_resources(cfg) == {"num_cpus": 5.0, "num_gpus": 0.0}
    cfg = load_config(["trainer=gpu", "trainer.devices=2"])
    assert task_resources(cfg) == {"num_cpus": 3.0, "num_gpus": 2.0}  # data=shards: 2 loader workers
    cfg = load_config(["trainer=gpu", "trainer.devices=0,3,5"])
    assert task_resources(cfg)["num_gpus"] == 3.0
    with pytest.raises(InputError) as e:
        task_resources(load_config(["trainer=gpu", "trainer.devices=auto"]))
    assert e.value.where == "trainer.devices"
    with pytest.raises(InputError, match="num_nodes"):
        task_resources(load_config(["trainer=gpu", "trainer.num_nodes=2"]))
    assert absolute_tracking_uri("sqlite:///x/mlflow.db") == f"sqlite:///{Path('x/mlflow.db').resolve()}"
    assert absolute_tracking_uri("sqlite:////abs/m.db") == "sqlite:////abs/m.db"
    assert absolute_tracking_uri("http://127.0.0.1:5000") == "http://127.0.0.1:5000"
    with pytest.raises(InputError, match="choices: sequential, ray"):
        executors.make_executor("dask")
    with pytest.raises(InputError, match="only with --executor ray"):
        executors.make_executor("sequential", address="auto")
    # a config Ray cannot reserve fails in one line before anything runs (no MLflow experiment either)
    assert main(["sweep", str(DEFAULT_SPEC), "--executor", "ray", "--mlflow-experiment", "never-made",
                 "trainer.accelerator=gpu", "trainer.devices=auto"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("uavturb sweep: error: trainer.devices: 'auto'")
    assert mlflow.MlflowClient(tracking_uri()).get_experiment_by_name("never-made") is None


@pytest.mark.parametrize("executor", ["sequential", "ray"])
def test_a_run_that_fails_once_is_retried_and_finishes(ray_local, tmp_path, experiment, executor, monkeypatch):
    monkeypatch.setattr(sweep_mod, "train", fake_train)
    (tmp_path / "plan.json").write_text(json.dumps({"none/GRU seed 0": 1, "pretrain depth seed 0": 1}))
    over = [f"trainer.default_root_dir={tmp_path}", "data.synthetic.enabled=false"]
    res = sweep(DEFAULT_SPEC, seeds=1, overrides=over, experiment=experiment, executor=executor, max_retries=1)
    kids = _children(res["parent_run_id"], experiment)
    finished = [r for r in kids if r.info.status == "FINISHED"]
    failed = [r for r in kids if r.info.status == "FAILED"]
    assert sorted(_key(r) for r in finished) == sorted([(r, "0") for r in ROWS] + [("pretrain depth", "0"),
                                                                                    ("pretrain normals", "0")])
    assert sorted(_key(r) for r in failed) == [("none/GRU", "0"), ("pretrain depth", "0")]
    assert not [r for r in kids if r.info.status not in ("FINISHED", "FAILED")]  # nothing left RUNNING
    for r in failed:
        assert r.data.tags["error"].startswith("RuntimeError: injected failure of") and "attempt 1" in r.data.tags[
            "error"]
        text = Path(mlflow.MlflowClient(tracking_uri()).download_artifacts(r.info.run_id, "error.txt",
                                                                           str(tmp_path))).read_text()
        assert text.startswith("Traceback") and "injected failure" in text
    assert _attempts(tmp_path, "none/GRU seed 0") == 2 and _attempts(tmp_path, "none/no-GRU seed 0") == 1
    # the depth rows got the retried (finished) pre-training's checkpoint
    (depth,) = [r for r in finished if r.data.tags.get("pretrain") == "depth"]
    for r in res["runs"]:
        if r["row"].startswith("depth/"):
            assert Path(r["checkpoint"]).read_text().endswith(depth.data.tags["checkpoint"])
    assert mlflow.MlflowClient(tracking_uri()).get_run(res["parent_run_id"]).info.status == "FINISHED"
    assert ([r["metrics"]["test/rmse_d"] for r in res["runs"]]
            == pytest.approx([0.1 * (k + 1) for k in range(len(ROWS))]))


@pytest.mark.parametrize("executor", ["sequential", "ray"])
def test_a_run_that_always_fails_ends_failed_and_a_rerun_trains_only_it(ray_local, tmp_path, experiment, executor,
                                                                         monkeypatch, capsys):
    from uavturb.cli import main

    monkeypatch.setattr(sweep_mod, "train", fake_train)
    (tmp_path / "plan.json").write_text(json.dumps({"none/GRU seed 0": -1, "pretrain normals seed 0": -1}))
    over = [f"trainer.default_root_dir={tmp_path}", "data.synthetic.enabled=false"]
    argv = ["sweep", str(DEFAULT_SPEC), "--mlflow-experiment", experiment, "--executor", executor, "--max-retries", "2",
            *over]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert "Traceback" not in "\n".join(err)
    assert err[-1].startswith(f"uavturb sweep: error: 2 of {2 + len(ROWS)} runs failed after 3 attempt(s), 2 skipped "
                              "(their pre-training failed): pretrain normals seed 0, none/GRU seed 0; first error: "
                              "RuntimeError: injected failure of pretrain normals seed 0, attempt 3"), err[-1]
    client = mlflow.MlflowClient(tracking_uri())
    exp = client.get_experiment_by_name(experiment)
    (parent,) = client.search_runs([exp.experiment_id], "tags.sweep = 'ablation'")
    assert parent.info.status == "FAILED"
    kids = _children(parent.info.run_id, experiment)
    assert sorted(_key(r) for r in kids if r.info.status == "FAILED") == [("none/GRU", "0")] * 3 + [
        ("pretrain normals", "0")] * 3
    before = {_key(r): r.info.run_id for r in kids if r.info.status == "FINISHED"}
    assert sorted(before) == sorted([(r, "0") for r in ROWS if not r.startswith(("normals", "none/GRU"))]
                                    + [("pretrain depth", "0")])
    assert not [r for r in kids if r.info.status not in ("FINISHED", "FAILED")]
    assert _attempts(tmp_path, "normals/frozen seed 0") == 0  # skipped: never started

    # fixed: the re-run trains the failed pre-training, its two rows and the failed row, nothing else
    (tmp_path / "plan.json").unlink()
    res = sweep(DEFAULT_SPEC, overrides=over, experiment=experiment, executor=executor)
    assert res["parent_run_id"] == parent.info.run_id and res["resumed"]
    assert sorted(r["row"] for r in res["runs"] if not r["reused"]) == ["none/GRU", "normals/finetune",
                                                                        "normals/frozen"]
    kids = _children(parent.info.run_id, experiment)
    after = {_key(r): r.info.run_id for r in kids if r.info.status == "FINISHED"}
    assert len(after) == 2 + len(ROWS) and all(after[k] == v for k, v in before.items())
    assert _attempts(tmp_path, "depth/frozen seed 0") == 1 and _attempts(tmp_path, "pretrain depth seed 0") == 1
    assert client.get_run(parent.info.run_id).info.status == "FINISHED"


# ----------------------------------------------------------------------------------------------
# a real tracking server


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture
def mlflow_server(tmp_path):
    """``mlflow server`` on 127.0.0.1 (a free port) with a SQLite backend and proxied artifacts."""
    port = _free_port()
    db = tmp_path / "server" / "mlflow.db"
    db.parent.mkdir()
    log = open(tmp_path / "server" / "log.txt", "w")
    proc = subprocess.Popen([sys.executable, "-m", "mlflow", "server", "--backend-store-uri", f"sqlite:///{db}",
                             "--artifacts-destination", str(tmp_path / "server" / "artifacts"), "--host",
                             "127.0.0.1", "--port", str(port), "--workers", "1"],
                            stdout=log, stderr=subprocess.STDOUT, start_new_session=True)
    url = f"http://127.0.0.1:{port}"
    try:
        for _ in range(240):
            try:
                with urllib.request.urlopen(f"{url}/health", timeout=1) as r:
                    if r.status == 200:
                        break
            except OSError:
                assert proc.poll() is None, (tmp_path / "server" / "log.txt").read_text()
                time.sleep(0.5)
        else:
            pytest.fail("mlflow server did not start in 120 s")
        yield url, f"sqlite:///{db}", tmp_path / "server" / "artifacts"
    finally:
        os.killpg(proc.pid, signal.SIGTERM)
        try:
            proc.wait(timeout=20)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
        log.close()


def test_ray_sweep_through_an_mlflow_server_matches_the_sequential_sweep(ray_local, tmp_path, mlflow_server,
                                                                         monkeypatch):
    """Real (tiny) training: sequential into the SQLite file store, Ray through HTTP: same children, same metrics."""
    url, server_db, artifacts = mlflow_server
    over = [f"data.root={tmp_path / 'sim'}", f"data.pairs_root={tmp_path / 'pre'}", *TINY]
    seq = sweep(DEFAULT_SPEC, seeds=1, overrides=[*over, f"trainer.default_root_dir={tmp_path / 'seq'}"],
                experiment="equiv", executor="sequential")
    file_store = tracking_uri()

    monkeypatch.setenv("MLFLOW_TRACKING_URI", url)
    monkeypatch.chdir(tmp_path)  # a file store would appear here (mlflow.db, mlruns/)
    on_ray = sweep(DEFAULT_SPEC, seeds=1, overrides=[*over, f"trainer.default_root_dir={tmp_path / 'ray'}"],
                   experiment="equiv", executor="ray")

    a = {_key(r): r for r in _children(seq["parent_run_id"], "equiv", file_store)}
    b = {_key(r): r for r in _children(on_ray["parent_run_id"], "equiv", url)}
    assert len(b) == 2 + len(ROWS) and a.keys() == b.keys()  # every child once, the same tags
    assert len(_children(on_ray["parent_run_id"], "equiv", url)) == 2 + len(ROWS)
    for k in a:
        assert b[k].info.status == "FINISHED"
        ma, mb = a[k].data.metrics, b[k].data.metrics
        for m in ("test/rmse_d", "test/rmse_fa", "test/loss"):
            if m in ma:
                assert np.isfinite(ma[m]) and mb[m] == pytest.approx(ma[m], rel=1e-4), (k, m, ma[m], mb[m])
    # it went through HTTP: the server's database holds the runs, artifacts went to its destination
    assert not (tmp_path / "mlflow.db").exists() and not (tmp_path / "mlruns").exists()
    direct = {_key(r) for r in _children(on_ray["parent_run_id"], "equiv", server_db)}
    assert direct == set(a)
    assert all(r.info.artifact_uri.startswith("mlflow-artifacts:") for r in b.values())
    assert len(list(artifacts.rglob("best.ckpt"))) == 2 + len(ROWS)
    assert len(_children(seq["parent_run_id"], "equiv", file_store)) == 2 + len(ROWS)  # nothing went to the file store


# ----------------------------------------------------------------------------------------------
# generate sim


def test_generate_sim_on_ray_writes_the_same_arrays(ray_local, tmp_path):
    from uavturb.commands.generate import generate_sim
    from uavturb.io import shards

    from uavturb.cli import main

    small = dict(max_seconds=1.0, width=24, height=24, controller="geometric")
    generate_sim("tiny", tmp_path / "local", seed=0, **small)
    assert main(["generate", "sim", "--preset", "tiny", "--out", str(tmp_path / "ray"), "--executor", "ray",
                 *[a for k, v in small.items() for a in ("--set", f"{k}={v}")]]) == 0
    a, b = shards.read_manifest(tmp_path / "local"), shards.read_manifest(tmp_path / "ray")
    assert a.splits == b.splits and a.config_hash == b.config_hash and sum(len(v) for v in a.splits.values()) == 3
    for split in shards.SPLITS:
        for fa, fb in zip(a.folders(split), b.folders(split)):
            ta, tb = shards.read_trajectory(fa, mmap=False), shards.read_trajectory(fb, mmap=False)
            for name in shards.ARRAYS:
                np.testing.assert_array_equal(getattr(ta, name), getattr(tb, name), err_msg=f"{fa.name}/{name}")
    assert json.loads((tmp_path / "ray" / "manifest.json").read_text())["complete"] is True
    with pytest.raises(InputError, match="only with --executor ray"):
        generate_sim("tiny", tmp_path / "x", address="auto", **small)


@pytest.mark.slow
def test_a_local_ray_instance_listens_on_loopback_only(tmp_path):
    """``--executor ray`` without ``--address``: the local instance's GCS port is bound to 127.0.0.1."""
    code = """
import ray
from uavturb.runs.executors import ray_session
with ray_session(None, num_cpus=1):
    host, port = ray.get_runtime_context().gcs_address.rsplit(":", 1)
    listening = set()
    for table in ("/proc/net/tcp", "/proc/net/tcp6"):
        for row in open(table).read().splitlines()[1:]:
            local, state = row.split()[1], row.split()[3]
            if state == "0A" and int(local.rsplit(":", 1)[1], 16) == int(port):
                listening.add(local.rsplit(":", 1)[0])
    print(host, sorted(listening))
"""
    env = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[1])}
    env.pop("RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER", None)
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300, env=env,
                         cwd=tmp_path)
    assert res.returncode == 0, res.stderr[-2000:]
    host, listening = res.stdout.strip().splitlines()[-1].split(" ", 1)
    assert host == "127.0.0.1"
    assert listening in ("['0100007F']", "['0000000000000000FFFF00000100007F']"), listening  # 127.0.0.1, v4 or v6
