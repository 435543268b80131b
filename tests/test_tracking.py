"""MLflow tracking helpers: a command run again on the same inputs reuses its run; project-relative paths."""

from __future__ import annotations

from pathlib import Path

import mlflow
import pytest

from uavturb.runs import store


def test_log_run_reuses_the_run_of_the_same_inputs(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    uri = f"sqlite:///{tmp_path / 'mlflow.db'}"
    monkeypatch.setenv("MLFLOW_TRACKING_URI", uri)
    (tmp_path / "report").mkdir()
    (tmp_path / "report" / "report.md").write_text("# report\n")
    args = dict(run_name="gap hex_0,hex_1", params={"recordings": ["a", "b"], "seed": 0},
                tags={"effects": "ground_effect"}, artifacts=tmp_path / "report")
    first = store.log_run("uavturb-gap", metrics={"gap/final_heldout_rmse_N": 0.08}, **args)
    again = store.log_run("uavturb-gap", metrics={"gap/final_heldout_rmse_N": 0.07}, **args)
    other = store.log_run("uavturb-gap", metrics={"gap/final_heldout_rmse_N": 0.09},
                             **{**args, "params": {"recordings": ["a"], "seed": 0}})
    client = mlflow.MlflowClient(uri)
    exp = client.get_experiment_by_name("uavturb-gap")
    assert again == first and other != first
    assert sorted(r.info.run_id for r in client.search_runs([exp.experiment_id])) == sorted([first, other])
    run = client.get_run(first)
    assert run.data.metrics["gap/final_heldout_rmse_N"] == 0.07 and run.data.tags["effects"] == "ground_effect"
    assert exp.tags["mlflow.experimentKind"] == store.EXPERIMENT_KIND


def test_project_path(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert store.project_path(tmp_path / "runs" / "best.ckpt") == str(Path("runs") / "best.ckpt")
    assert store.project_path("/elsewhere/x.ckpt") == "/elsewhere/x.ckpt"


def test_a_write_that_collides_with_another_process_is_retried_once_it_exists():
    from mlflow.exceptions import MlflowException

    from uavturb.runs.store import CONFLICT_ATTEMPTS, on_conflict_retry

    calls = []

    def collides_once(key, value):
        calls.append((key, value))
        if len(calls) == 1:
            raise MlflowException("(sqlite3.IntegrityError) UNIQUE constraint failed: experiment_tags.key")
        return value

    assert on_conflict_retry(collides_once, "k", value=3) == 3 and calls == [("k", 3), ("k", 3)]

    def broken():
        calls.append("broken")
        raise MlflowException("no such experiment")

    calls.clear()
    with pytest.raises(MlflowException, match="no such experiment"):
        on_conflict_retry(broken)
    assert calls == ["broken"]  # other errors are not retried

    def always():
        calls.append("always")
        raise MlflowException("UNIQUE constraint failed: datasets.dataset_uuid")

    calls.clear()
    with pytest.raises(MlflowException):
        on_conflict_retry(always)
    assert len(calls) == CONFLICT_ATTEMPTS
