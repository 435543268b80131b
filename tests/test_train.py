"""The training entry point end to end on tiny synthetic data, with a temporary MLflow store."""

from __future__ import annotations

import json
from pathlib import Path

import mlflow
import numpy as np
import pytest
import torch
from omegaconf import OmegaConf

from uavturb.cli import main
from uavturb.data import synthetic
from uavturb.data.datamodules import ground_effect_law
from uavturb.errors import InputError
from uavturb.evaluation.test_heights import plot_test_heights, predict_last_frames
from uavturb.io import shards
from uavturb.physics.effects import ALPHA_PAPER, BETA_PAPER
from uavturb.physics.vehicle import HEXAROTOR
from uavturb.runs.config import CONF_DIR, allowed_keys, load_config
from uavturb.runs.store import EXPERIMENT_KIND, NOTE_TAG
from uavturb.runs.train import train
from uavturb.runs.training_data import resolve_ground_effect_law
from uavturb.scene.camera import forward_camera
from uavturb.sim.dataset import generation
from uavturb.systems import HeightModule


@pytest.fixture
def store(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # MLflow artifacts land in ./mlruns
    uri = f"sqlite:///{tmp_path / 'mlflow.db'}"
    monkeypatch.setenv("MLFLOW_TRACKING_URI", uri)
    return uri


def _overrides(tmp_path, *extra):
    return [f"data.root={tmp_path / 'sim'}", f"data.pairs_root={tmp_path / 'pre'}", "data.image_size=16",
            "data.window=4", "data.batch_size=8", "data.num_workers=0", "data.synthetic.enabled=true",
            "data.synthetic.n_scenes=3", "data.synthetic.trajs_per_scene=2", "data.synthetic.T=32",
            "data.synthetic.pairs=48", f"trainer.default_root_dir={tmp_path / 'runs'}", "trainer.accelerator=cpu",
            "trainer.enable_progress_bar=false", "trainer.log_every_n_steps=1", "trainer.limit_train_batches=1.0",
            "trainer.limit_val_batches=1.0", "trainer.limit_test_batches=1.0", "tracking.experiment=test", *extra]


def test_tiny_height_training_learns_and_logs(tmp_path, store):
    cfg = load_config(_overrides(tmp_path, "trainer.max_epochs=4", "model.lr_head=3e-3", "model.lr_encoder=3e-3"),
                      experiment="smoke")
    assert cfg.model.pretraining == "none"
    out = train(cfg)
    assert out["stage"] == "height" and out["checkpoint"].endswith(".ckpt")
    for key in ("val/rmse_d", "val/rmse_fa", "test/rmse_d", "test/rmse_fa"):
        assert np.isfinite(out["metrics"][key]), key

    client = mlflow.MlflowClient(store)
    run = client.get_run(out["run_id"])
    assert run.data.metrics["test/rmse_d"] == pytest.approx(out["metrics"]["test/rmse_d"], rel=1e-6)
    assert run.data.tags["data_hash"] == out["data_hash"] == shards.dataset_hash(tmp_path / "sim")
    assert len(run.data.tags["mlflow.source.git.commit"]) == 40  # MLflow's Version column
    assert run.data.tags[NOTE_TAG].startswith("Height model: pre-training none, GRU")
    (ds,) = run.inputs.dataset_inputs  # MLflow's Dataset column: the shards with their digest
    assert ds.dataset.digest == out["data_hash"] and ds.tags[0].value == "training"
    assert client.get_experiment(run.info.experiment_id).tags["mlflow.experimentKind"] == EXPERIMENT_KIND
    # f_a also in the paper's 1e-4 N, so that a three-decimal column shows it
    assert run.data.metrics["test/rmse_fa_1e-4N"] == pytest.approx(1e4 * run.data.metrics["test/rmse_fa"])
    assert run.data.params["model.use_gru"] == "True" and run.data.params["data.window"] == "4"
    # alpha, beta unset: the synthetic data's law (the paper's quadrotor, mu = 2), logged as numbers
    assert float(run.data.params["model.beta"]) == pytest.approx(BETA_PAPER, rel=1e-9)
    assert float(run.data.params["model.alpha"]) == pytest.approx(ALPHA_PAPER, rel=1e-9)
    assert "config.yaml" in [a.path for a in client.list_artifacts(out["run_id"])]
    assert [a.path for a in client.list_artifacts(out["run_id"], "checkpoints")] == ["checkpoints/best.ckpt"]
    assert [a.path for a in client.list_artifacts(out["run_id"], "plots")] == ["plots/test_heights.png"]
    assert (Path.cwd() / run.data.tags["checkpoint"]).resolve() == Path(out["checkpoint"]).resolve()
    losses = [m.value for m in client.get_metric_history(out["run_id"], "train/loss_step")]
    assert len(losses) >= 8
    assert np.mean(losses[-3:]) < np.mean(losses[:3])  # the loss went down

    # the checkpoint alone rebuilds the model, with the camera of its training data (the run names it too)
    module = HeightModule.load_from_checkpoint(out["checkpoint"])
    expected = forward_camera(16, 16, synthetic.YFOV_DEG, synthetic.PITCH_DEG, frame_dt=synthetic.DT).record()
    assert module.camera_model().record() == expected == json.loads(run.data.tags["camera"])
    module2 = HeightModule.load_from_checkpoint(out["checkpoint"])
    x = torch.rand(2, 4, 1, 16, 16) * 3
    module.eval(), module2.eval()
    with torch.no_grad():
        torch.testing.assert_close(module(x)[0], module2(x)[0], rtol=0, atol=0)
    state = torch.load(out["checkpoint"], map_location="cpu", weights_only=True)["state_dict"]
    torch.testing.assert_close(module.state_dict()["head.mlp.0.weight"], state["head.mlp.0.weight"])


def test_ground_effect_law_of_the_training_data(tmp_path):
    """``model.alpha, beta`` default to the law the shards were made with: the simulator's hexarotor with
    mu = 2 gives beta = 2 * 0.1^2 / 16 and alpha = k_T beta; a folder without shards gives None."""
    generation.generate_sim("tiny", tmp_path / "hex", seed=0, progress=False, vehicle="hex", width=16, height=16,
                         controller="geometric", trajectories=3)
    alpha, beta = ground_effect_law(tmp_path / "hex")
    assert beta == pytest.approx(2.0 * 0.1**2 / 16, rel=1e-12)
    assert alpha == pytest.approx(HEXAROTOR.thrust_coefficient * beta, rel=1e-12)
    assert ground_effect_law(tmp_path / "nothing") is None
    with pytest.raises(InputError, match="model.alpha"):
        resolve_ground_effect_law(load_config(["model.alpha=1e-9"]), tmp_path / "hex")


def test_pretrain_then_finetune_height(tmp_path, store):
    pre = train(load_config(_overrides(tmp_path, "trainer.max_epochs=1"), experiment="smoke_pretrain"))
    assert pre["stage"] == "pretrain" and "test/loss" in pre["metrics"] and "val/angle_deg" in pre["metrics"]
    logged = mlflow.MlflowClient(store).get_run(pre["run_id"]).data.metrics
    # in MLflow the transcoder's losses stand apart from the height runs' test/loss [m^2]
    assert logged["pretrain/test/loss"] == pytest.approx(pre["metrics"]["test/loss"], rel=1e-6)
    assert not [k for k in logged if k.startswith(("test/", "val/", "train/"))]
    out = train(load_config(_overrides(tmp_path, "model=normals_finetune", f"model.encoder_ckpt={pre['checkpoint']}",
                                       "model.unfreeze_at_epoch=1", "trainer.max_epochs=2", "model.lr_head=1e-3"),
                            experiment="smoke"))
    module = HeightModule.load_from_checkpoint(out["checkpoint"])
    assert module.hparams.pretrained_from == pre["checkpoint"] and module.hparams.encoder_ckpt is None


def test_optional_system_metrics(tmp_path, store, monkeypatch):
    """tracking.system_metrics=true: MLflow's system/* metrics on the run, or one line naming the key without psutil
    (psutil may come with Ray: once a test has imported ray, its vendored copy is importable)."""
    import importlib.util

    # a sampling interval far longer than the run: the sample taken at the end must still be there
    monkeypatch.setenv("MLFLOW_SYSTEM_METRICS_SAMPLING_INTERVAL", "1000")

    cfg = load_config(_overrides(tmp_path, "trainer.max_epochs=1", "tracking.system_metrics=true"), experiment="smoke")
    if importlib.util.find_spec("psutil") is None:
        with pytest.raises(InputError) as e:
            train(cfg)
        assert e.value.where == "tracking.system_metrics" and "psutil" in e.value.problem
    else:
        out = train(cfg)
        metrics = mlflow.MlflowClient(store).get_run(out["run_id"]).data.metrics
        assert any(k.startswith("system/") for k in metrics)


def test_height_stage_needs_encoder_checkpoint(tmp_path, store):
    cfg = load_config(_overrides(tmp_path, "model=normals_finetune", "tracking.enabled=false"))
    with pytest.raises(InputError) as e:
        train(cfg)
    assert e.value.where == "model.encoder_ckpt"


@pytest.mark.parametrize("override, key", [
    ("model.use_gr=false", "model.use_gr"),
    ("trainer.max_epoch=3", "trainer.max_epoch"),
    ("dta.root=x", "dta"),
    ("trainer.max_epochs=many", "trainer.max_epochs"),
    ("model.pretraining=imagenet", "model.pretraining"),
])
def test_config_typo_names_the_key(override, key):
    with pytest.raises(InputError) as e:
        load_config([override])
    assert e.value.where == key
    if "unknown key" in e.value.problem:
        parent = key.rsplit(".", 1)[0] if "." in key else ""
        assert all(k in e.value.problem for k in allowed_keys(parent))


def test_config_groups_and_experiments():
    cfg = load_config(["model=none_nogru", "trainer=gpu", "model.lr_head=0.01"])
    assert cfg.model.pretraining == "none" and cfg.model.use_gru is False and cfg.model.lr_head == 0.01
    assert cfg.trainer.accelerator == "gpu"
    smoke = load_config(experiment="smoke")
    assert smoke.data.synthetic.enabled and smoke.trainer.accelerator == "cpu"
    assert load_config(["experiment=pretrain_normals"]).stage == "pretrain"
    paper = load_config()
    for group in ("model", "trainer", "data"):  # every choice of every group resolves and validates
        for choice in sorted(p.stem for p in (CONF_DIR / group).glob("*.yaml")):
            assert load_config([f"{group}={choice}"])[group] is not None
    with pytest.raises(InputError, match="choices"):
        load_config(["model=nonsense"])
    with pytest.raises(InputError, match="choices"):
        load_config(experiment="nonsense")
    OmegaConf.to_yaml(paper)


def test_group_file_typo_names_file_and_key(tmp_path):
    import shutil

    conf = tmp_path / "conf"
    shutil.copytree(CONF_DIR, conf)
    (conf / "model" / "broken.yaml").write_text("use_gruu: true\n")
    with pytest.raises(InputError) as e:
        load_config(["model=broken"], conf_dir=conf)
    assert e.value.where == "model.use_gruu" and "broken.yaml" in e.value.problem


def test_cli_train_typo_is_one_line_naming_the_key(capsys):
    assert main(["train", "model.use_gr=false", "--experiment", "smoke"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "model.use_gr" in err and "use_gru" in err  # names the key and the allowed ones


def test_predict_last_frames_matches_the_windows_the_metrics_score(tmp_path):
    m = synthetic.make_synthetic_dataset(tmp_path / "ds", n_scenes=3, trajs_per_scene=1, T=9, size=8)
    module = HeightModule(encoder_hidden=16)
    module.eval()
    tr = shards.read_trajectory(m.folders("test")[0])
    d = predict_last_frames(module, tr.depth, window=4, batch=2)
    assert np.isnan(d[:3]).all() and np.isfinite(d[3:]).all()
    with torch.no_grad():
        want = module(torch.from_numpy(np.array(tr.depth[2:6])).unsqueeze(0).unsqueeze(2))[0][0, -1]
    assert d[5] == pytest.approx(float(want), abs=1e-6)
    png = plot_test_heights(module, m.folders("test"), 4, tmp_path / "p" / "h.png")
    assert png.stat().st_size > 1000


def test_ddp_with_two_cpu_processes(tmp_path):
    """The same command scales out: DDP over 2 CPU processes (Lightning's subprocess launcher
    re-runs the command line), one MLflow run from rank 0, one checkpoint folder, test metrics."""
    import json
    import os
    import subprocess
    import sys

    env = {**os.environ, "MLFLOW_TRACKING_URI": f"sqlite:///{tmp_path / 'mlflow.db'}", "PYTHONUNBUFFERED": "1"}
    cmd = [sys.executable, "-m", "uavturb.cli", "train", "--experiment", "smoke", *_overrides(tmp_path),
           "trainer.strategy=ddp", "trainer.devices=2", "trainer.num_nodes=1", "trainer.max_epochs=2",
           "trainer.num_threads=1"]
    proc = subprocess.run(cmd, cwd=tmp_path, env=env, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-3000:]
    lines = [l for l in proc.stdout.splitlines() if l.startswith("{")]
    assert len(lines) == 1, proc.stdout  # rank 1 prints nothing
    out = json.loads(lines[0])
    assert out["run_id"] and out["checkpoint"].endswith(".ckpt")
    client = mlflow.MlflowClient(env["MLFLOW_TRACKING_URI"])
    exp = client.get_experiment_by_name("test")
    runs = client.search_runs([exp.experiment_id])
    assert len(runs) == 1 and np.isfinite(runs[0].data.metrics["test/rmse_d"])
    assert runs[0].data.tags["world_size"] == "2"
    assert len(list((tmp_path / "runs" / "checkpoints").iterdir())) == 1
    HeightModule.load_from_checkpoint(out["checkpoint"])
