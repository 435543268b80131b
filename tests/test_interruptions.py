"""Interrupted work tells the truth: exit status, one line, MLflow run states, resuming, and a store
that concurrent first use cannot break (config values checked before anything starts: test_config.py).

The signal tests run the real command line in a subprocess with its own MLflow store in tmp.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import mlflow
import pytest

import uavturb
from uavturb.cli import main
from uavturb.errors import Interrupted, raise_on_signals, signals_deferred

REPO = Path(uavturb.__file__).resolve().parents[1]


def _env(uri: str) -> dict[str, str]:
    return {**os.environ, "MLFLOW_TRACKING_URI": uri, "PYTHONUNBUFFERED": "1",
            "PYTHONPATH": os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")])}


def _tiny(tmp_path: Path, *extra: str) -> list[str]:
    return ["--experiment", "smoke", f"data.root={tmp_path / 'sim'}", "data.image_size=16", "data.window=4",
            "data.batch_size=8", "data.synthetic.n_scenes=3", "data.synthetic.trajs_per_scene=2",
            "data.synthetic.T=32", f"trainer.default_root_dir={tmp_path / 'runs'}", "trainer.enable_progress_bar=false",
            "trainer.limit_train_batches=4", "trainer.limit_val_batches=1", "trainer.limit_test_batches=1",
            "tracking.experiment=sig", *extra]


def _wait_for(predicate, proc: subprocess.Popen, timeout: float = 300.0, what: str = ""):
    t0 = time.time()
    while time.time() - t0 < timeout:
        value = predicate()
        if value:
            return value
        if proc.poll() is not None:
            raise AssertionError(f"process ended ({proc.returncode}) before {what}: {proc.stderr.read()[-3000:]}")
        time.sleep(0.5)
    proc.kill()
    raise AssertionError(f"timed out waiting for {what}")


def _last_line(stderr: str) -> str:
    return [line for line in stderr.splitlines() if line.strip()][-1]


def _runs(uri: str, experiment: str) -> list:
    from uavturb.runs.mutex import store_lock

    with store_lock(uri):  # the store may be being created by the command under test
        client = mlflow.MlflowClient(uri)
        client.search_experiments(max_results=1)
    exp = client.get_experiment_by_name(experiment)
    return client.search_runs([exp.experiment_id]) if exp else []


# --- SIGTERM, then --resume --------------------------------------------------------------------


def _train_until(tmp_path: Path, uri: str, sig: int, *, after_epoch: bool):
    """Start a tiny training, send ``sig`` once its run exists (or once it saved ``last.ckpt``); returns
    (process, stderr, run id, last.ckpt or None)."""
    cmd = [sys.executable, "-m", "uavturb.cli", "train", *_tiny(tmp_path, "trainer.max_epochs=200")]
    proc = subprocess.Popen(cmd, cwd=tmp_path, env=_env(uri), stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True)
    folder = tmp_path / "runs" / "checkpoints"
    if after_epoch:
        last = _wait_for(lambda: next(iter(folder.glob("*/last.ckpt")), None) if folder.is_dir() else None, proc,
                         what="last.ckpt")
    else:
        last = None
        _wait_for(lambda: (tmp_path / "mlflow.db").is_file() and _runs(uri, "sig"), proc, what="a run")
    proc.send_signal(sig)
    _, err = proc.communicate(timeout=120)
    (run,) = _runs(uri, "sig")
    return proc, err, run, last


def test_sigterm_stops_training_in_one_line_and_the_run_is_killed(tmp_path):
    uri = f"sqlite:///{tmp_path / 'mlflow.db'}"
    proc, err, run, _ = _train_until(tmp_path, uri, signal.SIGTERM, after_epoch=False)
    run_id = run.info.run_id
    assert proc.returncode == 128 + signal.SIGTERM, err[-3000:]
    assert "Traceback" not in err
    assert _last_line(err) == (f"uavturb train: interrupted by SIGTERM; run {run_id} marked KILLED; continue it "
                               f"with `uavturb train --resume {run_id}`")
    assert run.info.status == "KILLED" and run.data.tags["pid"] == str(proc.pid)


@pytest.mark.slow
def test_sigint_then_resume_continues_the_same_run_at_the_next_epoch(tmp_path, monkeypatch, capsys):
    import torch

    uri = f"sqlite:///{tmp_path / 'mlflow.db'}"
    proc, err, run, last = _train_until(tmp_path, uri, signal.SIGINT, after_epoch=True)
    run_id = run.info.run_id
    assert proc.returncode == 130 and run.info.status == "KILLED", err[-3000:]
    assert _last_line(err).startswith("uavturb train: interrupted by SIGINT; run ")
    assert run.data.tags["checkpoint_dir"] == str(last.parent.resolve()) and last.parent.name == run_id

    epoch = torch.load(last, map_location="cpu", weights_only=False)["epoch"]  # the last epoch saved
    res = subprocess.run([sys.executable, "-m", "uavturb.cli", "train", "--resume", run_id,
                          f"trainer.max_epochs={epoch + 3}"], cwd=tmp_path, env=_env(uri), capture_output=True,
                         text=True, timeout=600)
    assert res.returncode == 0, res.stderr[-3000:]
    out = json.loads([line for line in res.stdout.splitlines() if line.startswith("{")][0])
    assert out["run_id"] == run_id and out["start_epoch"] == epoch + 1
    assert f"resuming run {run_id} from {last.resolve()}" in res.stderr
    (run,) = _runs(uri, "sig")  # no second run
    assert run.info.status == "FINISHED" and run.data.tags["resumed"] == "1"
    assert run.data.tags["resume_changes"] == f"trainer.max_epochs 200 -> {epoch + 3}"
    steps = [m.step for m in mlflow.MlflowClient(uri).get_metric_history(run_id, "train/loss_epoch")]
    assert len(steps) == len(set(steps)) and len(steps) >= epoch + 2  # no epoch trained twice, none lost after it


def test_resume_refuses_a_changed_config_before_any_work(tmp_path, monkeypatch, capsys):
    from uavturb.runs import store
    from uavturb.runs.config import load_config, to_flat_dict

    uri = f"sqlite:///{tmp_path / 'mlflow.db'}"
    monkeypatch.setenv("MLFLOW_TRACKING_URI", uri)
    c = store.client()
    rid = c.create_run(store.experiment_id(c, "sig"), tags={"stage": "height", "checkpoint_dir": "x"}).info.run_id
    for k, v in to_flat_dict(load_config(_tiny(tmp_path)[2:], experiment="smoke")).items():
        c.log_param(rid, k, str("null" if v is None else v))
    c.set_terminated(rid, "KILLED")
    assert main(["train", "--resume", rid, *_tiny(tmp_path), "model.lr_head=0.5"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and err.startswith("uavturb train: error: --resume: model.lr_head is '0.5' here")
    assert not (tmp_path / "sim").exists()  # refused before any data was made
    assert main(["train", "--resume", "0" * 32]) == 2
    assert "no run '00000000000000000000000000000000'" in capsys.readouterr().err


@pytest.mark.slow
def test_sigint_on_a_sweep_exits_130_in_one_line_parent_and_child_killed(tmp_path):
    uri = f"sqlite:///{tmp_path / 'mlflow.db'}"
    overrides = [f"data.root={tmp_path / 'sim'}", f"data.pairs_root={tmp_path / 'pre'}", "data.image_size=16",
                 "data.window=4", "data.synthetic.n_scenes=3", "data.synthetic.trajs_per_scene=1",
                 "data.synthetic.T=16", "data.synthetic.pairs=32", f"trainer.default_root_dir={tmp_path / 'runs'}",
                 "trainer.max_epochs=200"]
    cmd = [sys.executable, "-m", "uavturb.cli", "sweep", str(REPO / "sweeps" / "ablation.yaml"), "--preset", "quick",
           "--seeds", "1", "--mlflow-experiment", "sw", *overrides]
    proc = subprocess.Popen(cmd, cwd=tmp_path, env=_env(uri), stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True)
    _wait_for(lambda: ((tmp_path / "runs" / "checkpoints").is_dir()
                       and any((tmp_path / "runs" / "checkpoints").iterdir())),
              proc, what="a child training")
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 130, err[-3000:]
    assert "Traceback" not in err
    line = _last_line(err)
    assert line.startswith("uavturb sweep: interrupted by SIGINT; run ") and "run the same command again" in line
    runs = _runs(uri, "sw")
    assert {r.info.status for r in runs} == {"KILLED"} and len(runs) == 2  # parent and its first child


# --- SIGKILL: the next command that opens the store marks the run ------------------------------


_OPEN_A_RUN = """
import time
from uavturb.runs.store import client, experiment_id, run_tags
c = client()
run = c.create_run(experiment_id(c, "k"), tags=run_tags())
print(run.info.run_id, flush=True)
time.sleep(600)
"""


def test_sigkill_leaves_a_run_the_next_store_command_marks_failed(tmp_path, monkeypatch, capsys):
    uri = f"sqlite:///{tmp_path / 'mlflow.db'}"
    proc = subprocess.Popen([sys.executable, "-c", _OPEN_A_RUN], cwd=tmp_path, env=_env(uri), stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    run_id = proc.stdout.readline().strip()
    assert run_id, proc.stderr.read()
    proc.kill()
    proc.wait(timeout=30)
    client = mlflow.MlflowClient(uri)
    assert client.get_run(run_id).info.status == "RUNNING"

    monkeypatch.setenv("MLFLOW_TRACKING_URI", uri)
    # any command that opens the store; this one finds no table
    assert main(["compare", "--mlflow-experiment", "k"]) == 2
    run = client.get_run(run_id)
    assert run.info.status == "FAILED"
    assert run.data.tags["stale"].startswith(f"process {proc.pid} on ")


def test_stale_marking_leaves_live_and_foreign_runs_alone(tmp_path, monkeypatch):
    from uavturb.runs import store
    from uavturb.runs.processes import process_tags

    monkeypatch.setenv("MLFLOW_TRACKING_URI", f"sqlite:///{tmp_path / 'mlflow.db'}")
    c = store.client()
    exp = store.experiment_id(c, "stale")
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True)
    mine = c.create_run(exp, tags=process_tags()).info.run_id
    other_host = c.create_run(exp, tags={**process_tags(), "host": "elsewhere"}).info.run_id
    gone = c.create_run(exp, tags={**process_tags(), "pid": dead.stdout.strip()}).info.run_id
    reused = c.create_run(exp, tags={**process_tags(), "pid_start": "1"}).info.run_id  # pid reused since
    untagged = c.create_run(exp).info.run_id
    assert sorted(store.mark_stale_runs(c)) == sorted([gone, reused])
    status = {r: c.get_run(r).info.status for r in (mine, other_host, gone, reused, untagged)}
    assert status == {mine: "RUNNING", other_host: "RUNNING", gone: "FAILED", reused: "FAILED", untagged: "RUNNING"}


# --- generate sim ------------------------------------------------------------------------------


def _alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state != "Z"  # a zombie has ended; only its reaping is left


def _children(pid: int) -> list[int]:
    out = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            if int(stat.read_text().rsplit(")", 1)[1].split()[1]) == pid:
                out.append(int(stat.parent.name))
        except (OSError, ValueError, IndexError):
            pass
    return out


@pytest.mark.skipif(not Path("/proc").is_dir(), reason="reads /proc")
def test_sigterm_on_generate_sim_stops_workers_and_leaves_no_temporary_folder(tmp_path):
    out = tmp_path / "sim"
    proc = subprocess.Popen([sys.executable, "-m", "uavturb.cli", "generate", "sim", "--preset", "quick", "--workers",
                             "2", "--out", str(out)], cwd=tmp_path, env=_env(f"sqlite:///{tmp_path / 'm.db'}"),
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    kids = _wait_for(lambda: (lambda k: k if len(k) >= 2 else None)(_children(proc.pid)), proc, what="workers")
    time.sleep(3.0)  # the workers are rendering (quick: 16 trajectories, well over 3 s of work)
    kids = _children(proc.pid)
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 128 + signal.SIGTERM, err[-3000:]
    assert "Traceback" not in err and "BrokenPipe" not in err
    assert _last_line(err).endswith("uavturb generate: interrupted by SIGTERM")
    t0 = time.time()
    while any(_alive(k) for k in kids) and time.time() - t0 < 10:
        time.sleep(0.2)
    assert not [k for k in kids if _alive(k)], "orphaned workers"
    leftovers = [p.name for p in tmp_path.rglob(".*") if p.name.endswith(".tmp")]
    assert leftovers == []
    assert not out.exists() or not [p for p in out.iterdir() if p.name.startswith(".")]


# --- concurrent first use of a store ------------------------------------------------------------

_OPEN = "from uavturb.runs.store import client; client(); print('ok')"


def _open_together(tmp_path: Path, n_procs: int) -> list[subprocess.CompletedProcess]:
    uri = f"sqlite:///{tmp_path / 'mlflow.db'}"
    procs = [subprocess.Popen([sys.executable, "-c", _OPEN], cwd=tmp_path, env=_env(uri), stdout=subprocess.PIPE,
                              stderr=subprocess.PIPE, text=True) for _ in range(n_procs)]
    return [p.communicate(timeout=300) for p in procs]


def _check_fresh_store_opened(tmp_path: Path, tries: int) -> None:
    for i in range(tries):
        folder = tmp_path / f"try{i}"
        folder.mkdir()
        for out, err in _open_together(folder, 2):
            assert out.strip() == "ok", err[-2000:]
        mlflow.MlflowClient(f"sqlite:///{folder / 'mlflow.db'}").search_experiments()  # usable afterwards


def test_two_processes_create_a_fresh_store_at_once(tmp_path):
    _check_fresh_store_opened(tmp_path, tries=1)


@pytest.mark.slow
def test_two_processes_create_a_fresh_store_at_once_five_times(tmp_path):
    _check_fresh_store_opened(tmp_path, tries=5)


def test_a_broken_store_is_one_line_with_what_to_do(tmp_path, monkeypatch, capsys):
    db = tmp_path / "mlflow.db"
    db.write_bytes(b"this is not a database" * 100)
    monkeypatch.setenv("MLFLOW_TRACKING_URI", f"sqlite:///{db}")
    assert main(["compare", "--mlflow-experiment", "x"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and err.startswith(f"uavturb compare: error: MLflow store sqlite:///{db} ")
    assert "mlflow db upgrade" in err


def test_an_interrupted_migration_names_the_table_to_drop():
    from uavturb.runs.store import _store_problem

    e = Exception("(sqlite3.OperationalError) table _alembic_tmp_experiments already exists\n[SQL: ...]")
    msg = str(_store_problem("sqlite:///x/mlflow.db", e))
    assert "DROP TABLE _alembic_tmp_experiments" in msg and "mlflow db upgrade sqlite:///x/mlflow.db" in msg
    assert "\n" not in msg


def test_a_signal_during_a_store_write_waits_for_the_write_to_end():
    """SIGTERM while a run-store write is under way (an SQLite transaction, cut short, leaves the database
    locked for the write that marks the run KILLED): the write ends first, then Interrupted is raised."""
    done = []
    with pytest.raises(Interrupted) as caught:
        with raise_on_signals():
            with signals_deferred():
                os.kill(os.getpid(), signal.SIGTERM)
                time.sleep(0.05)  # the handler has run by now, and raised nothing here
                done.append("write finished")
    assert done == ["write finished"] and caught.value.signum == signal.SIGTERM


@pytest.mark.parametrize("opening", ["start", "reopen"])
def test_a_signal_while_a_run_is_opened_ends_it_killed_with_the_hint(tmp_path, monkeypatch, opening):
    """SIGTERM while ``start_run`` writes the new run (or ``reopen_run`` claims one): held until the writes end,
    then raised where the run's id is known, so that the run ends KILLED and the one line says how to continue
    it (raised after the return, the caller had no id: "interrupted by SIGTERM" alone, a flaky test under load)."""
    import mlflow

    from uavturb.runs import store

    monkeypatch.setenv("MLFLOW_TRACKING_URI", f"sqlite:///{tmp_path / 'mlflow.db'}")
    c = store.client()
    old = c.create_run(store.experiment_id(c, "sig"), tags=store.run_tags({})).info.run_id
    c.set_terminated(old, "KILLED")
    real, sent = mlflow.MlflowClient.set_tag, []

    def signalled(self, *args, **kwargs):  # one signal arrives in the middle of the writes (a second ends the process)
        if not sent:
            sent.append(os.kill(os.getpid(), signal.SIGTERM))
            time.sleep(0.05)
        return real(self, *args, **kwargs)

    monkeypatch.setattr(mlflow.MlflowClient, "log_text", lambda self, *a, **k: signalled(self, a[0], "x", "y"))
    monkeypatch.setattr(mlflow.MlflowClient, "set_tag", signalled)
    with pytest.raises(Interrupted) as caught:
        with raise_on_signals():
            if opening == "start":
                store.start_run("sig", "run", {}, texts={"a.txt": "a"})
            else:
                store.reopen_run(old, {"resumed": "1"})
    monkeypatch.setattr(mlflow.MlflowClient, "set_tag", real)
    (run,) = [r for r in store.client().search_runs([store.experiment_id(c, "sig")]) if r.info.run_id != old] \
        if opening == "start" else [store.client().get_run(old)]
    assert run.info.status == "KILLED"
    assert caught.value.message() == (f"interrupted by SIGTERM; run {run.info.run_id} marked KILLED; continue it with "
                                      f"`uavturb train --resume {run.info.run_id}`")
