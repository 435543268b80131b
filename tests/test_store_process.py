"""Logging a run from a second process (uavturb.runs.store_process): the same run as logged in-process,
nothing written when it is never asked, one clear error when the store cannot be opened."""

from __future__ import annotations

import mlflow
import pytest

from uavturb.runs import store
from uavturb.runs.store import StoreError
from uavturb.runs.store_process import StoreProcess


@pytest.fixture
def report_folder(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("MLFLOW_TRACKING_URI", f"sqlite:///{tmp_path / 'mlflow.db'}")
    (tmp_path / "report").mkdir()
    (tmp_path / "report" / "report.md").write_text("# report\n")
    return tmp_path / "report"


def test_the_second_process_logs_the_run_the_caller_would_have(report_folder, tmp_path):
    args = dict(run_name="gap a,b", params={"recordings": ["a", "b"], "seed": 0}, tags={"effects": "wind"},
                artifacts=report_folder)
    with StoreProcess() as proc:
        rid = proc.log_run("uavturb-gap", metrics={"gap/final_heldout_rmse_N": 0.08, "gap/nan": float("nan")},
                           **args)
    # the same inputs logged in this process find that run (same key: same params, name and experiment)
    again = store.log_run("uavturb-gap", metrics={"gap/final_heldout_rmse_N": 0.07}, **args)
    assert again == rid
    client = mlflow.MlflowClient(f"sqlite:///{tmp_path / 'mlflow.db'}")
    run = client.get_run(rid)
    assert run.data.params == {"recordings": "['a', 'b']", "seed": "0"}
    assert run.data.tags["effects"] == "wind" and run.info.status == "FINISHED"
    assert "gap/nan" not in run.data.metrics
    assert [a.path for a in client.list_artifacts(rid)] == ["report.md"]


def test_a_process_never_asked_writes_nothing(report_folder, tmp_path):
    proc = StoreProcess()
    proc.close()
    assert proc._proc.wait(timeout=120) == 0
    assert not (tmp_path / "mlflow.db").exists()


def test_a_store_that_cannot_be_opened_is_one_line(report_folder, tmp_path, monkeypatch):
    (tmp_path / "not_a_folder").write_text("a file")
    monkeypatch.setenv("MLFLOW_TRACKING_URI", f"sqlite:///{tmp_path / 'not_a_folder' / 'mlflow.db'}")
    with StoreProcess() as proc, pytest.raises(StoreError) as e:
        proc.log_run("uavturb-gap", run_name="gap a", params={}, metrics={}, artifacts=report_folder)
    assert "\n" not in str(e.value) and "not_a_folder" in str(e.value)


def test_without_a_second_process_the_run_is_logged_in_this_one(report_folder, tmp_path, monkeypatch):
    def no_process(*args, **kwargs):
        raise OSError("no more processes")

    monkeypatch.setattr("uavturb.runs.store_process.subprocess.Popen", no_process)
    with StoreProcess() as proc:
        rid = proc.log_run("uavturb-gap", run_name="gap c", params={"seed": 1}, metrics={"m": 2.0},
                           artifacts=report_folder)
    run = mlflow.MlflowClient(f"sqlite:///{tmp_path / 'mlflow.db'}").get_run(rid)
    assert run.data.metrics["m"] == 2.0 and run.info.status == "FINISHED"
