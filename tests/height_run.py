"""Test support: a tiny trained HeightModule, saved as a Lightning checkpoint and logged as an
MLflow run the way ``uavturb.runs.train`` logs one (params ``data.root``, ``trainer.default_root_dir``)."""

from __future__ import annotations

import json
import os
from pathlib import Path

import lightning as L
import mlflow
import torch

from uavturb.data import synthetic
from uavturb.data.datamodules import ShardWindowsDataModule, dataset_camera
from uavturb.io import shards
from uavturb.runs.store import CAMERA_TAG
from uavturb.systems import HeightModule


def tiny_dataset(root: Path, size: int = 16, T: int = 24, pitch_deg: float = synthetic.PITCH_DEG) -> Path:
    if not (root / shards.MANIFEST).is_file():
        synthetic.make_synthetic_dataset(root, n_scenes=3, trajs_per_scene=1, T=T, size=size, seed=0,
                                         pitch_deg=pitch_deg)
    return root


def tiny_height_run(tmp_path: Path, *, use_gru: bool = True, keep: str = "folder", steps: int = 6,
                    size: int = 16, camera: bool = True, pitch_deg: float = synthetic.PITCH_DEG
                    ) -> tuple[str, Path, Path, HeightModule]:
    """Train a tiny HeightModule a few steps on synthetic shards; log a run.

    ``keep`` says where the run keeps its checkpoint: ``folder`` (``<root>/checkpoints/<run>/``,
    as ``uavturb.runs.train``), ``artifact`` (a ``.ckpt`` artifact) or ``tag`` (a ``checkpoint`` tag).
    ``camera``: the module and the run carry the data's camera, as ``uavturb.runs.train`` makes them
    (False: neither does, as a model trained before models kept their camera); ``pitch_deg`` [deg]:
    the synthetic data's camera pitch.

    Returns ``(run_id, checkpoint, data_root, module in eval mode)``.
    """
    data = tiny_dataset(tmp_path / "sim", size=size, pitch_deg=pitch_deg)
    torch.manual_seed(0)
    record = dataset_camera(data).record() if camera else None
    module = HeightModule(use_gru=use_gru, lr_head=3e-3, lr_encoder=3e-3, camera=record)
    dm = ShardWindowsDataModule(str(data), window=4, batch_size=8, num_workers=0)
    trainer = L.Trainer(max_steps=steps, accelerator="cpu", logger=False, enable_checkpointing=False,
                        enable_progress_bar=False, enable_model_summary=False, limit_val_batches=0)
    trainer.fit(module, datamodule=dm)
    mlflow.set_tracking_uri(os.environ.get("MLFLOW_TRACKING_URI", "sqlite:///mlflow.db"))
    mlflow.set_experiment("test")
    runs = tmp_path / "runs"
    with mlflow.start_run(run_name="height-none-" + ("gru" if use_gru else "nogru")) as run:
        rid = run.info.run_id
        mlflow.log_params({"data.root": str(data), "trainer.default_root_dir": str(runs), "data.image_size": size,
                           "model.use_gru": use_gru})
        if record is not None:
            mlflow.set_tag(CAMERA_TAG, json.dumps(record))
        folder = runs / "checkpoints" / rid if keep == "folder" else tmp_path / "elsewhere"
        folder.mkdir(parents=True, exist_ok=True)
        ckpt = folder / "best-0.ckpt"
        trainer.save_checkpoint(ckpt)
        if keep == "artifact":
            mlflow.log_artifact(str(ckpt), artifact_path="checkpoints")
            ckpt.unlink()
        elif keep == "tag":
            mlflow.set_tag("checkpoint", str(ckpt))
    module.eval()
    return rid, ckpt, data, module
