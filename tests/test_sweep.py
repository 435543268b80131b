"""The Table 1 sweep and `uavturb compare`, on a temporary MLflow store.

The fast tests replace the training function by a stand-in that logs a run with known metric
values (the sweep's own logic -- configs, reuse of pre-training, nesting, tags, resuming -- is
what they check); the slow test trains for real on tiny synthetic data.
"""

from __future__ import annotations

import csv
import io
import signal
from pathlib import Path

import mlflow
import numpy as np
import pytest

from uavturb.errors import InputError, Interrupted
from uavturb.runs import sweep as sweep_mod
from uavturb.runs.table1 import compare
from uavturb.runs.sweep import sweep
from uavturb.runs.config import DEFAULT_SPEC, load_spec
from uavturb.runs.store import tracking_uri

ROWS = [r.name for r in load_spec(DEFAULT_SPEC).rows]


@pytest.fixture(scope="module")
def shared_store(module_mlflow_store):
    """One MLflow store for the module; tests use their own experiments."""
    return module_mlflow_store


@pytest.fixture
def store(shared_store, request):
    """(tracking URI, an experiment name of this test's own)."""
    return shared_store, request.node.name.replace("[", "-").replace("]", "")


def known_rmse(row: str, seed: int) -> tuple[float, float]:
    """The stand-in's test metrics: distinct per row and seed."""
    k = ROWS.index(row)
    return 0.1 * (k + 1) + 0.01 * seed, 1e-4 * (k + 1) * (1 + seed)


class FakeTrain:
    """Stands in for uavturb.runs.train.train: one FINISHED MLflow run with the given tags."""

    def __init__(self, tmp_path: Path, fail_at: int | None = None, kill_at: int | None = None):
        self.calls: list[tuple[object, dict]] = []
        self.resumed: list[str] = []
        self.tmp, self.fail_at, self.kill_at = tmp_path, fail_at, kill_at

    def __call__(self, cfg, tags=None, resume=None):
        self.calls.append((cfg, dict(tags)))
        if self.fail_at is not None and len(self.calls) == self.fail_at:
            raise KeyboardInterrupt
        client = mlflow.MlflowClient(tracking_uri())
        exp = client.get_experiment_by_name(cfg.tracking.experiment)
        if resume is not None:  # as train() does: the same run goes on
            self.resumed.append(resume)
            rid = resume
        else:
            rid = client.create_run(exp.experiment_id, run_name=cfg.tracking.run_name,
                                    tags={**tags, "checkpoint_dir": str(self.tmp / "ckpts")}).info.run_id
        if self.kill_at is not None and len(self.calls) == self.kill_at:  # a signal mid-training: run KILLED
            client.set_terminated(rid, "KILLED")
            raise Interrupted(signal.SIGTERM)
        ckpt = self.tmp / "ckpts" / rid / "best.ckpt"
        ckpt.parent.mkdir(parents=True, exist_ok=True)
        ckpt.write_text(f"{cfg.stage} {rid}")
        client.set_tag(rid, "checkpoint", str(ckpt))
        client.log_artifact(rid, str(ckpt), "checkpoints")  # as train() does
        if cfg.stage == "pretrain":
            metrics = {"test/loss": 1.0}
        else:
            d, fa = known_rmse(tags["ablation"], int(tags["seed"]))
            metrics = {"test/rmse_d": d, "test/rmse_fa": fa}
        for k, v in metrics.items():
            client.log_metric(rid, k, v)
        client.set_terminated(rid, "FINISHED")
        return {"stage": cfg.stage, "metrics": metrics, "checkpoint": str(ckpt), "run_id": rid, "data_hash": "x"}


def _children(store, parent: str) -> list:
    client = mlflow.MlflowClient(store[0])
    exp = client.get_experiment_by_name(store[1])
    return client.search_runs([exp.experiment_id], f"tags.`mlflow.parentRunId` = '{parent}'", max_results=1000)


def test_sweep_runs_rows_times_seeds_reusing_pretraining(tmp_path, store, monkeypatch):
    fake = FakeTrain(tmp_path)
    monkeypatch.setattr(sweep_mod, "train", fake)
    res = sweep(DEFAULT_SPEC, profile="quick", seeds=2, experiment=store[1])

    # one pre-training run per variant and seed, one height run per row and seed
    stages = [(cfg.stage, t.get("pretrain") or t["ablation"], t["seed"]) for cfg, t in fake.calls]
    assert sorted(s for s in stages if s[0] == "pretrain") == [("pretrain", v, s) for v in ("depth", "normals")
                                                                  for s in ("0", "1")]
    assert sorted((r, s) for st, r, s in stages if st == "height") == sorted((r, str(s)) for r in ROWS for s in (0, 1))
    # each row's encoder comes from the same seed's pre-training of its variant
    runs = {r.info.run_id: r for r in _children(store, res["parent_run_id"])}
    ckpt = {(r.data.tags["pretrain"], r.data.tags["seed"]): r.data.tags["checkpoint"] for r in runs.values()
            if "pretrain" in r.data.tags}
    assert len(set(ckpt.values())) == 4
    for cfg, t in fake.calls:
        if cfg.stage == "height":
            assert cfg.trainer.seed == int(t["seed"]) and cfg.tracking.experiment == store[1]
            variant = t["ablation"].split("/")[0]
            expected = None if variant == "none" else ckpt[(variant, t["seed"])]
            assert cfg.model.encoder_ckpt == expected, t
            assert cfg.model.lr_head == 1e-3 and cfg.trainer.max_epochs == 10  # the quick profile

    # the store: a nested height child per row and seed with tags and final metrics, 4 pre-training children
    height = [r for r in runs.values() if "ablation" in r.data.tags]
    assert len(ROWS) == 7 and len(height) == 2 * len(ROWS) and len(runs) == 2 * len(ROWS) + 4
    for r in height:
        d, fa = known_rmse(r.data.tags["ablation"], int(r.data.tags["seed"]))
        assert r.data.metrics["test/rmse_d"] == pytest.approx(d) and r.data.metrics["test/rmse_fa"] == pytest.approx(fa)
    parent = mlflow.MlflowClient(store[0]).get_run(res["parent_run_id"])
    # the profile, under its tag's old name
    assert parent.info.status == "FINISHED" and parent.data.tags["preset"] == "quick"
    artifacts = {a.path for a in mlflow.MlflowClient(store[0]).list_artifacts(parent.info.run_id)}
    assert {"table1.md", "table1.csv", "sweep.yaml"} <= artifacts
    # Table 1 is the parent's description; its means stay off the metrics (the run table compares children)
    assert parent.data.metrics == {}
    note = parent.data.tags["mlflow.note.content"]
    mean_d = np.mean([known_rmse("normals/finetune", s)[0] for s in (0, 1)])
    assert any(line.startswith("| normals | finetune |") and f"{mean_d:.3f}" in line for line in note.splitlines())
    # each height run names the pre-training run its encoder comes from
    pre_run = {(r.data.tags["pretrain"], r.data.tags["seed"]): r.info.run_id for r in runs.values()
               if "pretrain" in r.data.tags}
    for r in height:
        variant = r.data.tags["ablation"].split("/")[0]
        assert r.data.tags.get("pretrain_run_id") == pre_run.get((variant, r.data.tags["seed"]))
        assert r.data.tags["mlflow.note.content"].startswith(f"Table 1 row `{r.data.tags['ablation']}`")
    assert res["table"].splitlines()[3].split()[:2] == ["none", "no-GRU"]


def test_interrupted_sweep_resumes_without_redoing_finished_runs(tmp_path, store, monkeypatch):
    first = FakeTrain(tmp_path, fail_at=7)  # 2 pre-trainings, 4 rows done, interrupted in the 5th row
    monkeypatch.setattr(sweep_mod, "train", first)
    with pytest.raises(KeyboardInterrupt):
        sweep(DEFAULT_SPEC, profile="quick", seeds=1, experiment=store[1])
    client = mlflow.MlflowClient(store[0])
    exp = client.get_experiment_by_name(store[1])
    (parent,) = client.search_runs([exp.experiment_id], "tags.sweep = 'ablation'")
    assert parent.info.status == "KILLED" and len(_children(store, parent.info.run_id)) == 6

    # the pre-training checkpoint's local file is gone: the resumed sweep takes it from MLflow
    (normals,) = [r for r in _children(store, parent.info.run_id) if r.data.tags.get("pretrain") == "normals"]
    Path(normals.data.tags["checkpoint"]).unlink()

    second = FakeTrain(tmp_path)
    monkeypatch.setattr(sweep_mod, "train", second)
    res = sweep(DEFAULT_SPEC, profile="quick", seeds=1, experiment=store[1])
    assert res["parent_run_id"] == parent.info.run_id and res["resumed"]
    assert [t["ablation"] for _, t in second.calls] == ROWS[4:]  # nothing finished is trained again
    assert sum(r["reused"] for r in res["runs"]) == 4
    # the remaining normals rows got the pre-training checkpoint of the interrupted sweep, downloaded
    (ckpt,) = {cfg.model.encoder_ckpt for cfg, t in second.calls if t["ablation"].startswith("normals/")}
    assert Path(ckpt).read_text() == f"pretrain {normals.info.run_id}" and ckpt != normals.data.tags["checkpoint"]
    assert len(_children(store, parent.info.run_id)) == 2 + len(ROWS)

    # a third call does nothing at all; a second seed adds only that seed's runs
    third = FakeTrain(tmp_path)
    monkeypatch.setattr(sweep_mod, "train", third)
    sweep(DEFAULT_SPEC, profile="quick", seeds=1, experiment=store[1])
    assert third.calls == []
    sweep(DEFAULT_SPEC, profile="quick", seeds=2, experiment=store[1])
    assert len(third.calls) == 2 + len(ROWS) and {t["seed"] for _, t in third.calls} == {"1"}
    assert len(_children(store, parent.info.run_id)) == 2 * (2 + len(ROWS))


def test_a_sweep_rerun_resumes_its_interrupted_child_in_place(tmp_path, store, monkeypatch):
    first = FakeTrain(tmp_path, kill_at=4)  # 2 pre-trainings, 1 row done, a signal in the 2nd row
    monkeypatch.setattr(sweep_mod, "train", first)
    with pytest.raises(Interrupted) as e:
        sweep(DEFAULT_SPEC, profile="quick", seeds=1, experiment=store[1])
    client = mlflow.MlflowClient(store[0])
    (parent,) = client.search_runs([client.get_experiment_by_name(store[1]).experiment_id], "tags.sweep = 'ablation'")
    assert parent.info.status == "KILLED" and "run the same command again" in e.value.message()
    (killed,) = [r for r in _children(store, parent.info.run_id) if r.info.status == "KILLED"]
    assert killed.data.tags["ablation"] == ROWS[1]

    second = FakeTrain(tmp_path)
    monkeypatch.setattr(sweep_mod, "train", second)
    res = sweep(DEFAULT_SPEC, profile="quick", seeds=1, experiment=store[1])
    assert second.resumed == [killed.info.run_id]  # continued, not trained again beside it
    assert [t["ablation"] for _, t in second.calls] == ROWS[1:]
    kids = _children(store, res["parent_run_id"])
    assert len(kids) == 2 + len(ROWS) and {r.info.status for r in kids} == {"FINISHED"}
    assert client.get_run(res["parent_run_id"]).info.status == "FINISHED"


def _log(client, exp_id, parent, row, seed, d, fa, status="FINISHED"):
    run = client.create_run(exp_id, tags={"mlflow.parentRunId": parent, "ablation": row, "seed": str(seed)})
    client.log_metric(run.info.run_id, "test/rmse_d", d)
    client.log_metric(run.info.run_id, "test/rmse_fa", fa)
    client.set_terminated(run.info.run_id, status)


def test_compare_means_and_stds_from_logged_runs(tmp_path, store):
    client = mlflow.MlflowClient(store[0])
    exp_id = client.create_experiment(store[1])
    old = client.create_run(exp_id, tags={"sweep": "ablation", "sweep_hash": "a"}).info.run_id
    _log(client, exp_id, old, "none/GRU", 0, 9.0, 9.0)  # an older sweep: not in the table
    parent = client.create_run(exp_id, tags={"sweep": "ablation", "sweep_hash": "b"}).info.run_id
    values = {"normals/finetune": [(0.30, 6e-4), (0.32, 7e-4), (0.34, 5e-4)],
              "none/no-GRU": [(0.50, 4e-3), (0.40, 3e-3)],
              "depth/frozen": [(0.25, 2e-4)]}
    for row, vals in values.items():
        for seed, (d, fa) in enumerate(vals):
            _log(client, exp_id, parent, row, seed, d, fa)
    _log(client, exp_id, parent, "none/no-GRU", 2, 100.0, 100.0, status="FAILED")  # unfinished: left out

    res = compare(experiment=store[1], out=tmp_path / "tables")
    assert res["parent_run_id"] == parent
    assert [r["row"] for r in res["rows"]] == ["none/no-GRU", "depth/frozen", "normals/finetune"]  # paper's order
    for r in res["rows"]:
        d, fa = np.array(values[r["row"]]).T
        assert r["n"] == len(d)
        assert r["rmse_d_mean"] == pytest.approx(d.mean()) and r["rmse_fa_mean"] == pytest.approx(fa.mean())
        if len(d) > 1:
            assert r["rmse_d_std"] == pytest.approx(d.std(ddof=1)) and r["rmse_fa_std"] == pytest.approx(fa.std(ddof=1))
        else:
            assert np.isnan(r["rmse_d_std"])
    assert res["rows"][2]["paper_rmse_d"] == 0.3184
    # one number of decimals per column (3 significant digits of its smallest value); f_a in 1e-4 N
    assert "0.320 ± 0.020" in res["table"] and "6.00 ± 1.00" in res["table"]
    frozen = next(line for line in res["table"].splitlines() if line.startswith("depth"))
    assert frozen.split()[2:5] == ["1", "0.250", "2.00"] and "±" not in frozen and "-" not in frozen.split()[3:5]
    rows = list(csv.DictReader(io.StringIO(Path(res["csv"]).read_text())))
    assert [r["row"] for r in rows] == [r["row"] for r in res["rows"]]
    assert float(rows[0]["rmse_d_mean"]) == pytest.approx(0.45) and rows[0]["seeds"] == "0;1"
    md = Path(res["markdown"]).read_text()
    assert md.count("\n| ") == 4 and "| normals | finetune | 3 | 0.320 ± 0.020 | 6.00 ± 1.00 | 0.3184 | 6.357 |" in md
    assert sorted(p.name for p in (tmp_path / "tables").iterdir()) == ["table1.csv", "table1.md"]
    # the tables are replaced only with overwrite (checked before any query)
    (tmp_path / "tables" / "table1.md").write_text("my edits")
    with pytest.raises(InputError, match=r"table1.md: already exists \(use --overwrite to replace it\)"):
        compare(experiment=store[1], out=tmp_path / "tables")
    assert (tmp_path / "tables" / "table1.md").read_text() == "my edits"
    assert compare(experiment=store[1], out=tmp_path / "tables", overwrite=True)["markdown"] == res["markdown"]
    assert (tmp_path / "tables" / "table1.md").read_text() == md

    # an explicit parent; a missing experiment names it
    assert compare(experiment=store[1], parent_run_id=old, out=None)["rows"][0]["rmse_d_mean"] == 9.0
    with pytest.raises(InputError, match="nope"):
        compare(experiment="nope", out=None)


def test_sweep_typos_fail_before_anything_runs(tmp_path, store, monkeypatch):
    fake = FakeTrain(tmp_path)
    monkeypatch.setattr(sweep_mod, "train", fake)
    with pytest.raises(InputError) as e:
        sweep(DEFAULT_SPEC, overrides=["model.use_gr=false"], experiment=store[1])
    assert e.value.where == "model.use_gr"
    with pytest.raises(InputError, match="choices: quick, paper"):
        sweep(DEFAULT_SPEC, profile="fast")
    bad = tmp_path / "bad.yaml"
    bad.write_text(DEFAULT_SPEC.read_text().replace("profiles:", "profilez:"))
    with pytest.raises(InputError) as e:
        sweep(bad)
    assert "profilez" in e.value.where and str(bad) in e.value.where
    bad.write_text(DEFAULT_SPEC.read_text().replace("model: none_gru", "model: none_gruu"))
    with pytest.raises(InputError, match="none_gruu"):
        sweep(bad)
    assert fake.calls == [] and mlflow.MlflowClient(store[0]).get_experiment_by_name(store[1]) is None


def test_cli_compare_without_store_is_one_line(tmp_path, store, capsys):
    from uavturb.cli import main

    assert main(["compare", "--mlflow-experiment", "nothing-here"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "nothing-here" in err
    # the old spelling still works, with one deprecation line
    assert main(["compare", "--experiment", "nothing-here"]) == 2
    old = capsys.readouterr().err.splitlines()
    assert old[0] == "uavturb compare: --experiment is deprecated, use --mlflow-experiment" and old[1] == err.strip()


@pytest.mark.slow
def test_quick_sweep_trains_for_real_and_resumes(tmp_path, store):
    over = [f"data.root={tmp_path / 'sim'}", f"data.pairs_root={tmp_path / 'pre'}", "data.image_size=16",
            "data.window=4", "data.synthetic.n_scenes=3", "data.synthetic.trajs_per_scene=1", "data.synthetic.T=16",
            "data.synthetic.pairs=32", f"trainer.default_root_dir={tmp_path / 'runs'}", "trainer.max_epochs=2",
            "model.unfreeze_at_epoch=1"]
    res = sweep(DEFAULT_SPEC, profile="quick", seeds=1, overrides=over, experiment=store[1])
    assert sorted(r["row"] for r in res["runs"]) == sorted(ROWS) and not any(r["reused"] for r in res["runs"])
    kids = _children(store, res["parent_run_id"])
    n_runs = len(ROWS) + len(load_spec(DEFAULT_SPEC).pretraining)  # every row, and each pre-training variant once
    assert len(kids) == n_runs == 9
    for r in kids:
        if "ablation" in r.data.tags:
            assert np.isfinite(r.data.metrics["test/rmse_d"]) and np.isfinite(r.data.metrics["test/rmse_fa"])
            assert Path(r.data.tags["checkpoint"]).is_file()
            assert "checkpoints/best.ckpt" in [a.path for a in mlflow.MlflowClient(store[0]).list_artifacts(
                r.info.run_id, "checkpoints")]
    again = sweep(DEFAULT_SPEC, profile="quick", seeds=1, overrides=over, experiment=store[1])
    assert all(r["reused"] for r in again["runs"]) and len(_children(store, res["parent_run_id"])) == n_runs
    assert compare(experiment=store[1], out=None)["rows"][0]["n"] == 1


def test_cli_sweep_typo_is_one_line_naming_the_key(tmp_path, store, capsys, monkeypatch):
    from uavturb.cli import main

    fake = FakeTrain(tmp_path)
    monkeypatch.setattr(sweep_mod, "train", fake)
    assert main(["sweep", str(DEFAULT_SPEC), "--mlflow-experiment", store[1], "trainer.max_epoch=3"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "trainer.max_epoch:" in err and "max_epochs" in err and fake.calls == []


def test_two_identical_sweeps_started_together_train_each_child_once(tmp_path, store, monkeypatch):
    """The second sweep finds the first one's parent and waits for the child it is training
    (a lock per child), then reuses it: nothing is trained twice."""
    import threading
    import time

    fake = FakeTrain(tmp_path)

    def slow(cfg, tags=None):
        time.sleep(0.3)  # both sweeps reach the same child while it trains
        return fake(cfg, tags)

    monkeypatch.setattr(sweep_mod, "train", slow)
    results, errors = [], []

    def one():
        try:
            results.append(sweep(DEFAULT_SPEC, profile="quick", seeds=1, experiment=store[1]))
        except BaseException as e:  # noqa: BLE001 - reported below
            errors.append(e)

    threads = [threading.Thread(target=one) for _ in range(2)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(timeout=300)
    assert not errors, errors
    assert results[0]["parent_run_id"] == results[1]["parent_run_id"]
    trained = [(t.get("pretrain") or t["ablation"], t["seed"]) for _, t in fake.calls]
    assert len(trained) == len(set(trained)) == 2 + len(ROWS)  # every child once
    assert len(_children(store, results[0]["parent_run_id"])) == 2 + len(ROWS)


def test_a_sweep_on_changed_training_data_is_not_resumed(tmp_path, store, monkeypatch):
    """The same sweep command on the same data folder resumes its parent and reuses every finished run; once
    the folder's content changes (data generated again, another build), a new parent trains every row again
    instead of computing Table 1 from models of other data."""
    data = tmp_path / "sim"
    data.mkdir()
    np.save(data / "depth.npy", np.zeros((4, 8, 8), np.float32))
    fake = FakeTrain(tmp_path)
    monkeypatch.setattr(sweep_mod, "train", fake)
    args = dict(profile="quick", seeds=1, experiment=store[1], overrides=[f"data.root={data}"])
    first = sweep(DEFAULT_SPEC, **args)
    n = len(fake.calls)
    again = sweep(DEFAULT_SPEC, **args)
    assert again["resumed"] and again["parent_run_id"] == first["parent_run_id"] and len(fake.calls) == n
    np.save(data / "depth.npy", np.ones((4, 8, 8), np.float32))
    changed = sweep(DEFAULT_SPEC, **args)
    assert not changed["resumed"] and changed["parent_run_id"] != first["parent_run_id"]
    assert len([c for c, _ in fake.calls[n:] if c.stage == "height"]) == len(ROWS)
    parent = mlflow.MlflowClient(store[0]).get_run(changed["parent_run_id"])
    assert parent.data.tags[sweep_mod.DATA_TAG] and parent.data.tags[sweep_mod.DATA_TAG] != \
        mlflow.MlflowClient(store[0]).get_run(first["parent_run_id"]).data.tags[sweep_mod.DATA_TAG]
