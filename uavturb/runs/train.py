"""Training one stage: ``train(cfg) -> dict`` builds it, fits, tests the best checkpoint and logs.

Stages (``cfg.stage``):

- ``pretrain`` -- :class:`~uavturb.systems.TranscoderModule` on ``cfg.data.pairs_root``
  (depth -> normals, or depth -> depth: ``cfg.model.pretraining``).
- ``height`` -- :class:`~uavturb.systems.HeightModule` on the shards of ``cfg.data.root``;
  with ``model.pretraining != none`` the encoder comes from ``model.encoder_ckpt`` and is
  frozen, then fine-tuned from ``model.unfreeze_at_epoch`` (``model.finetune=true``) by
  :class:`~uavturb.systems.FreezeThenFinetune`.

Both stages keep the best checkpoint on the validation monitor (``val/loss`` resp.
``val/rmse_d``), then test it. Tracking: one MLflow run (Lightning's ``MLFlowLogger``, store
from :func:`uavturb.runs.store.tracking_uri`) holding the resolved config (flattened as
params and as ``config.yaml``), tags ``mlflow.source.git.commit``, ``data_hash`` and ``stage``, the
dataset as the run's input (name and digest), and the metrics.

Metric names and units: :data:`uavturb.runs.store.METRICS`, logged by
:class:`uavturb.runs.trainer.StageMetricsLogger`. Where the pieces live: the stage's module, data,
callbacks and ``Trainer`` arguments in :mod:`uavturb.runs.trainer`, its dataset (synthetic data
written where configured) in :mod:`uavturb.runs.training_data`, the resume policy in
:mod:`uavturb.runs.resume`, every MLflow call in :mod:`uavturb.runs.store`.

Checkpoints: the best one is kept locally at
``<trainer.default_root_dir>/checkpoints/<run_id>/best-<epoch>.ckpt`` (``<run_id>`` the MLflow
run id; a time stamp when tracking is off), logged to the run as the artifact
``checkpoints/best.ckpt`` (:data:`uavturb.runs.store.CHECKPOINT_ARTIFACT`), and its local path (relative to the
working folder where it lies under it) is the run's tag ``checkpoint``. Height runs also log
the figure ``plots/test_heights.png`` (predicted vs true height over test trajectories,
:mod:`uavturb.evaluation.test_heights`). ``last.ckpt`` beside it holds the latest epoch (tag
``checkpoint_dir``: the folder); both callbacks, and why ``last.ckpt`` is saved after the best checkpoint:
:mod:`uavturb.runs.checkpoints`.

Interruptions and resuming: the run is FINISHED when training and testing complete, KILLED when
a signal stops it (:class:`uavturb.errors.Interrupted`), FAILED on an error; its tags ``host``,
``pid`` and ``pid_start`` let any later command mark it FAILED if its process dies without
closing it (SIGKILL). ``train(cfg, resume=RUN_ID)`` (``uavturb train --resume RUN_ID``) continues
such a run in the same MLflow run from its ``last.ckpt``, as Lightning's ``ckpt_path`` does.
Bad config values and bad data fail before any run is opened, and so does a device this machine
lacks (``trainer.accelerator=gpu`` without a CUDA device, fp16 on the CPU:
:mod:`uavturb.runs.accelerators`).

Devices: DataLoader memory is pinned when training on a CUDA device (``data.pin_memory``
decides otherwise); ``trainer.cudnn_benchmark`` and ``trainer.matmul_precision`` are
Lightning's ``benchmark`` and torch's float32 matmul precision (TF32 with ``high``).
Checkpoints hold float32 weights under mixed precision and load on the CPU wherever they were
trained (``map_location="cpu"`` in evaluate and export).
"""

from __future__ import annotations

import importlib.util
import json
import sys
import time
from pathlib import Path
from typing import Any

import lightning as L
import matplotlib.pyplot as plt
from lightning.pytorch.callbacks import EarlyStopping, ModelCheckpoint
from lightning.pytorch.utilities import rank_zero_only
from omegaconf import DictConfig, OmegaConf

from uavturb.errors import InputError
from uavturb.evaluation.test_heights import figure_test_heights
from uavturb.io.shards import dataset_hash
from uavturb.runs import store
from uavturb.runs.accelerators import check_trainer_device
from uavturb.runs.checkpoints import epoch_checkpoints
from uavturb.runs.config import TrainConfig, to_flat_dict, validate
from uavturb.runs.resume import LAST_CHECKPOINT, check_resume, config_changes, last_checkpoint, resumable_run
from uavturb.runs.trainer import (
    FirstEpoch,
    StageMetricsLogger,
    build,
    progress_callbacks,
    quiet_lightning,
    set_torch_flags,
    trainer_kwargs,
)
from uavturb.runs.training_data import prepare_data, resolve_ground_effect_law


def _run_name(cfg: DictConfig) -> str:
    return cfg.tracking.run_name or f"{cfg.stage}-{cfg.model.pretraining}-{'gru' if cfg.model.use_gru else 'nogru'}"


def _is_rank_zero() -> bool:
    return getattr(rank_zero_only, "rank", 0) == 0


def _checked(cfg: DictConfig | TrainConfig | dict, resume: str | None) -> DictConfig:
    """The config validated, and everything that can be refused before any work refused: psutil for
    ``tracking.system_metrics``, a device this machine lacks, a run that cannot be resumed."""
    cfg = validate(cfg)
    if cfg.tracking.enabled and cfg.tracking.system_metrics and importlib.util.find_spec("psutil") is None:
        raise InputError("tracking.system_metrics", "needs psutil: pip install 'uavturb[system-metrics]'")
    check_trainer_device(cfg.trainer)  # gpu without a CUDA device, fp16 on the CPU: one line, nothing started
    quiet_lightning()
    if resume is not None and not cfg.tracking.enabled:
        raise InputError("--resume", "needs tracking.enabled=true (the run lives in MLflow)")
    if resume is not None and _is_rank_zero():
        check_resume(cfg, resume)
    return cfg


def _describe(cfg: DictConfig, data_root: Path, data_hash: str) -> str:
    """The run's description (MLflow's ``mlflow.note.content``, Markdown)."""
    m = cfg.model
    if cfg.stage == "pretrain":
        what = f"Pre-training: depth encoder, depth → {m.pretraining} transcoder"
    else:
        what = (f"Height model: pre-training {m.pretraining}, {'GRU' if m.use_gru else 'no GRU'}"
                + ("" if m.pretraining == "none" else f", {'fine-tuned' if m.finetune else 'frozen'} encoder"))
    return (f"{what}. Data `{store.project_path(data_root)}` (digest `{data_hash}`), {cfg.trainer.max_epochs} "
            f"epochs, seed {cfg.trainer.seed}.")


def _open_run(cfg: DictConfig, data_root: Path, data_hash: str, tags: dict[str, str] | None,
              resume: str | None) -> tuple[str, Path | None]:
    """Open (or, with ``resume``, re-open) the MLflow run: (run id, last checkpoint or None).

    A new run gets the resolved config (params and ``config.yaml``), the dataset as its input
    (name, digest), a description, the tags ``mlflow.source.git.commit``, ``data_hash``, ``stage``
    and :func:`uavturb.runs.store.process_tags`. A resumed one is marked RUNNING by this process,
    keeps its params, and records what changed in the tags ``resumed`` (how many times) and
    ``resume_changes``.
    """
    if resume is not None:
        run = resumable_run(resume)
        changes = config_changes(cfg, run)
        store.reopen_run(resume, {"resumed": str(int(run.data.tags.get("resumed", "0")) + 1)})
        if changes:
            store.set_tags(resume, {"resume_changes": ", ".join(f"{k} {a} -> {b}" for k, (a, b) in changes.items())})
        last = last_checkpoint(run)
        return resume, last if last.is_file() else None
    params = {k: str("null" if v is None else v)[:250] for k, v in to_flat_dict(cfg).items()}
    if cfg.model.encoder_ckpt:
        params["model.encoder_ckpt"] = store.project_path(cfg.model.encoder_ckpt)
    dataset = (data_root, data_hash, "pretraining" if cfg.stage == "pretrain" else "training")
    run_id = store.start_run(cfg.tracking.experiment, _run_name(cfg),
                             {"data_hash": data_hash, "stage": cfg.stage,
                              store.NOTE_TAG: _describe(cfg, data_root, data_hash), **(tags or {})},
                             params=params, texts={"config.yaml": OmegaConf.to_yaml(cfg, resolve=True)},
                             dataset=dataset if data_root.is_dir() else None)
    return run_id, None


def train(cfg: DictConfig | TrainConfig | dict, tags: dict[str, str] | None = None,
          resume: str | None = None) -> dict[str, Any]:
    """Train one stage as configured, test its best checkpoint, and return the results.

    Parameters
    ----------
    cfg : a config from :func:`uavturb.runs.config.load_config` (or anything that merges into
        :class:`uavturb.runs.config.TrainConfig`; validated again here).
    tags : extra MLflow tags of the run (e.g. ``mlflow.parentRunId`` to nest it in a sweep).
    resume : id of an interrupted (KILLED, FAILED) or finished run to continue in the same MLflow
        run from its ``last.ckpt`` (epoch, optimizer, callbacks), as Lightning's ``ckpt_path`` does;
        without a ``last.ckpt`` (stopped in its first epoch) it starts over in that run. ``cfg``
        may differ from the run's config only in :data:`uavturb.runs.resume.RESUMABLE_KEYS`.

    Returns
    -------
    dict with ``stage``, ``metrics`` (``{"val/rmse_d": ..., "test/rmse_d": ..., ...}``,
    floats), ``checkpoint`` (path of the best checkpoint, str), ``run_id`` (MLflow run id or
    None), ``data_hash``, ``start_epoch`` (first epoch trained here; > 0 when resumed).

    Raises
    ------
    InputError : bad config or data (before any run is opened), or a run that cannot be resumed.
    uavturb.errors.Interrupted : SIGTERM or SIGINT (the command line's handlers); the run is then
        KILLED and the error's notes say how to resume it.
    """
    cfg = _checked(cfg, resume)
    t = cfg.trainer
    set_torch_flags(t)
    L.seed_everything(t.seed, workers=True, verbose=False)
    data_root = prepare_data(cfg)
    resolve_ground_effect_law(cfg, data_root)
    data_hash = dataset_hash(data_root) if data_root.is_dir() else "missing"
    module, dm, callbacks, monitor = build(cfg)
    dm.setup("fit")  # bad data fails here, before a run is opened
    if module.hparams.get("camera") is not None:  # the run names the model's camera too (tag camera, JSON)
        tags = {**(tags or {}), store.CAMERA_TAG: json.dumps(module.hparams["camera"])}
    ckpt_root = Path(t.default_root_dir) / "checkpoints"
    run_id, last = None, None
    if cfg.tracking.enabled and _is_rank_zero():
        run_id, last = _open_run(cfg, data_root, data_hash, tags, resume)
    elif resume is not None:  # DDP ranks > 0: rank 0's run, found by the same command line's --resume
        last = ckpt_root / resume / LAST_CHECKPOINT
        last = last if last.is_file() else None
    try:
        if run_id is not None and resume is None:
            store.set_tags(run_id, {"checkpoint_dir": str((ckpt_root / run_id).resolve())})
        out = _fit_and_test(cfg, module, dm, callbacks, monitor, run_id, last, ckpt_root, resume)
    except BaseException as e:
        if run_id is not None:
            store.finish_run(run_id, e, resume_hint=True)
        raise
    return {**out, "data_hash": data_hash}


def _logger(cfg: DictConfig, run_id: str | None) -> StageMetricsLogger | None:
    """Lightning's MLFlowLogger writing into run ``run_id`` (None on DDP ranks other than 0)."""
    if not cfg.tracking.enabled:
        return None
    return StageMetricsLogger(cfg.stage, experiment_name=cfg.tracking.experiment, run_name=_run_name(cfg),
                              tracking_uri=store.tracking_uri(), run_id=run_id, log_model=False)


def _trainer(cfg: DictConfig, logger: Any, callbacks: list, checkpoints: tuple[ModelCheckpoint, ...], monitor: str,
             first: FirstEpoch) -> L.Trainer:
    """Lightning's Trainer of the config with the checkpoint (in the order given: the best, then ``last.ckpt``),
    early stopping and progress callbacks."""
    t = cfg.trainer
    callbacks = [*callbacks, *checkpoints, first]
    if t.early_stopping_patience > 0:
        callbacks.append(EarlyStopping(monitor=monitor, mode="min", patience=t.early_stopping_patience))
    progress_bar, progress_lines = progress_callbacks(t)
    return L.Trainer(**trainer_kwargs(t), enable_progress_bar=progress_bar, callbacks=[*callbacks, *progress_lines],
                     logger=logger if logger is not None else False, enable_model_summary=False)


def _fit(cfg: DictConfig, trainer: L.Trainer, module: Any, dm: Any, logger: Any, last: Path | None) -> None:
    """``trainer.fit`` (from ``last`` when resuming), MLflow's system metrics around it when configured."""
    monitor = None
    if logger is not None and trainer.is_global_zero and cfg.tracking.system_metrics:
        monitor = store.start_system_metrics(logger.run_id)
    try:
        trainer.fit(module, datamodule=dm, ckpt_path=str(last) if last else None, weights_only=True)
    finally:
        if monitor is not None:
            store.finish_system_metrics(monitor, logger.run_id)


def _fit_and_test(cfg, module, dm, callbacks, monitor, run_id, last, ckpt_root, resume) -> dict[str, Any]:
    """Fit (from ``last`` when resuming), test the best checkpoint, log it; the run is closed FINISHED."""
    logger = _logger(cfg, run_id)
    # Under DDP only rank 0 has an MLflow run; ModelCheckpoint broadcasts rank 0's folder to the others.
    run_tag = run_id or resume or time.strftime("%Y%m%d-%H%M%S")
    checkpoint, latest = epoch_checkpoints(ckpt_root / run_tag, monitor)
    first = FirstEpoch()
    trainer = _trainer(cfg, logger, callbacks, (checkpoint, latest), monitor, first)
    if resume is not None and trainer.is_global_zero:
        print(f"resuming run {resume} " + (f"from {last}" if last else f"from the start (no {LAST_CHECKPOINT} yet)"),
              file=sys.stderr, flush=True)
    _fit(cfg, trainer, module, dm, logger, last)
    metrics = {k: float(v) for k, v in trainer.callback_metrics.items()}
    best = checkpoint.best_model_path or None
    for row in trainer.test(module, datamodule=dm, ckpt_path=best if best else None, verbose=False,
                            weights_only=True):
        metrics.update({k: float(v) for k, v in row.items()})
    if run_id is not None and trainer.is_global_zero:
        _log_results(cfg, run_id, trainer.world_size, best, module, dm)
    return {"stage": cfg.stage, "metrics": store.with_scaled_fa(metrics), "checkpoint": best, "run_id": run_id,
            "global_rank": trainer.global_rank,
            "start_epoch": first.epoch if first.epoch is not None else int(trainer.current_epoch)}


def _log_results(cfg: DictConfig, run_id: str, world_size: int, best: str | None, module: Any, dm: Any) -> None:
    """The world size, the best checkpoint and (height runs) the figure of predicted vs true heights
    over the first test trajectories (``plots/test_heights.png``) into the run, which ends FINISHED."""
    store.set_tags(run_id, {"world_size": str(world_size)})
    store.log_checkpoint(run_id, best)
    if cfg.stage == "height":
        fig = figure_test_heights(module, dm.sets["test"].folders, cfg.data.window)
        store.log_figure(run_id, fig, "plots/test_heights.png")
        plt.close(fig)
    store.finish_run(run_id)
