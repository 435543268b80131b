"""Thin training entry point: ``train(cfg) -> dict``.

Stages (``cfg.stage``):

- ``pretrain`` -- :class:`~uavturb.systems.TranscoderModule` on ``cfg.data.pairs_root``
  (depth -> normals, or depth -> depth: ``cfg.model.pretraining``).
- ``height`` -- :class:`~uavturb.systems.HeightModule` on the shards of ``cfg.data.root``;
  with ``model.pretraining != none`` the encoder comes from ``model.encoder_ckpt`` and is
  frozen, then fine-tuned from ``model.unfreeze_at_epoch`` (``model.finetune=true``) by
  :class:`~uavturb.systems.FreezeThenFinetune`.

Both stages keep the best checkpoint on the validation monitor (``val/loss`` resp.
``val/rmse_d``), then test it. Tracking: one MLflow run (Lightning's ``MLFlowLogger``, store
from :func:`uavturb.experiments.tracking.tracking_uri`) holding the resolved config (flattened as
params and as ``config.yaml``), tags ``mlflow.source.git.commit``, ``data_hash`` and ``stage``, the
dataset as the run's input (name and digest), and the metrics.

Metric names keep like with like in MLflow's run table (:class:`StageMetricsLogger`): height runs
log ``train/loss``, ``val/rmse_d`` [m], ``test/rmse_fa`` [N] ... and every ``*rmse_fa`` also as
``*rmse_fa_1e-4N`` in the unit of the paper's Table 1 (N values of ~5e-4 read 0.001 in a
three-decimal column); pre-training runs log theirs under ``pretrain/`` (``pretrain/test/loss``:
the transcoder loss, not a height loss).

Checkpoints: the best one is kept locally at
``<trainer.default_root_dir>/checkpoints/<run_id>/best-<epoch>.ckpt`` (``<run_id>`` the MLflow
run id; a time stamp when tracking is off), logged to the run as the artifact
``checkpoints/best.ckpt`` (:data:`CHECKPOINT_ARTIFACT`), and its local path (relative to the
working folder where it lies under it) is the run's tag ``checkpoint``. Height runs also log
the figure ``plots/test_heights.png`` (predicted vs true height over test trajectories,
:mod:`uavturb.experiments.plots`).

Output: on a terminal Lightning's progress bar; otherwise (a log file) one line per epoch on
stderr (:func:`epoch_lines`). Lightning's notices (accelerator, tips) are left out.
"""

from __future__ import annotations

import logging
import time
from pathlib import Path
from typing import Any

from omegaconf import DictConfig, OmegaConf

from uavturb.errors import InputError
from uavturb.experiments.config import TrainConfig, to_flat_dict, validate

#: MLflow artifact path of a run's best checkpoint (the local file: tag ``checkpoint``)
CHECKPOINT_ARTIFACT = "checkpoints/best.ckpt"
#: RMSE(f_a) is logged in N and, under this suffix, in the 1e-4 N of the paper's Table 1
FA_SCALED_SUFFIX, FA_SCALE = "_1e-4N", 1e4


def quiet_lightning() -> None:
    """Lightning's per-run notices (accelerator, tips, checkpoint restores) and a torch deprecation off."""
    import warnings

    import lightning  # noqa: F401 - sets its loggers' levels on import; override them after

    for name in ("lightning.pytorch", "lightning.fabric", "lightning"):
        logging.getLogger(name).setLevel(logging.WARNING)
    warnings.filterwarnings("ignore", message=r".*isinstance\(treespec, LeafSpec\).*")


def stage_metric_names(stage: str, metrics: dict[str, float]) -> dict[str, float]:
    """Metric names as logged to MLflow (see the module docstring): ``pretrain/`` prefix, scaled f_a."""
    out: dict[str, float] = {}
    for k, v in metrics.items():
        if stage == "pretrain" and k not in ("epoch", "step"):
            k = f"pretrain/{k}"
        out[k] = v
        if k.endswith("rmse_fa"):
            out[k + FA_SCALED_SUFFIX] = v * FA_SCALE
    return out


def _limit(x: float) -> int | float:
    """Lightning's convention: a float <= 1 is a fraction, an int a number of batches."""
    return int(x) if x > 1.0 else float(x)


def _devices(x: str) -> int | str | list[int]:
    x = str(x).strip()
    if x.isdigit():
        return int(x)
    if "," in x:
        return [int(i) for i in x.split(",") if i.strip()]
    return x


def _prepare_data(cfg: DictConfig) -> Path:
    """The dataset folder of this stage, generated when ``data.synthetic.enabled`` and missing."""
    from uavturb.data import synthetic
    from uavturb.io import shards

    syn = cfg.data.synthetic
    size = cfg.data.image_size or 32
    if cfg.stage == "pretrain":
        root = Path(cfg.data.pairs_root)
        if syn.enabled and not (root / shards.PAIRS_DIR / "meta.json").is_file():
            synthetic.make_synthetic_pairs(root, M=syn.pairs, size=size, seed=syn.seed)
        return root / shards.PAIRS_DIR if (root / shards.PAIRS_DIR).is_dir() else root
    root = Path(cfg.data.root)
    if syn.enabled and not (root / shards.MANIFEST).is_file():
        synthetic.make_synthetic_dataset(root, n_scenes=syn.n_scenes, trajs_per_scene=syn.trajs_per_scene, T=syn.T,
                                      size=size, seed=syn.seed)
    return root


def _build(cfg: DictConfig):
    """(module, datamodule, callbacks, monitor) of the configured stage."""
    from uavturb.data.datamodules import PairsDataModule, ShardWindowsDataModule
    from uavturb.systems import FreezeThenFinetune, HeightModule, TranscoderModule

    m, d = cfg.model, cfg.data
    if cfg.stage == "pretrain":
        if m.pretraining == "none":
            raise InputError("model.pretraining", "stage pretrain needs normals or depth, not none")
        module = TranscoderModule(target=m.pretraining, lr=m.lr_pretrain, lam=m.lam, embed_dim=m.embed_dim,
                                  encoder_hidden=m.encoder_hidden, max_depth=m.max_depth)
        dm = PairsDataModule(d.pairs_root, target=m.pretraining, batch_size=d.batch_size, num_workers=d.num_workers,
                             val_fraction=d.val_fraction, seed=cfg.trainer.seed)
        return module, dm, [], "val/loss"
    callbacks = []
    encoder_ckpt = None
    if m.pretraining != "none":
        if not m.encoder_ckpt:
            raise InputError("model.encoder_ckpt", f"needed with model.pretraining={m.pretraining} (a checkpoint of "
                             "stage pretrain); or choose model.pretraining=none")
        encoder_ckpt = str(m.encoder_ckpt)
        callbacks.append(FreezeThenFinetune(unfreeze_at_epoch=m.unfreeze_at_epoch if m.finetune else -1,
                                            lr=m.lr_encoder))
    module = HeightModule(use_gru=m.use_gru, embed_dim=m.embed_dim, encoder_hidden=m.encoder_hidden,
                          gru_hidden=m.gru_hidden, gru_layers=m.gru_layers, mlp_hidden=m.mlp_hidden,
                          max_depth=m.max_depth, lr_head=m.lr_head, lr_encoder=m.lr_encoder, alpha=m.alpha,
                          beta=m.beta, loss_frames=m.loss_frames, encoder_ckpt=encoder_ckpt)
    dm = ShardWindowsDataModule(d.root, window=d.window, stride=d.stride, eval_stride=d.eval_stride,
                                batch_size=d.batch_size, num_workers=d.num_workers, image_size=d.image_size,
                                seed=cfg.trainer.seed)  # seeds differ in batch order too, not only in init
    return module, dm, callbacks, "val/rmse_d"


def _describe(cfg: DictConfig, data_root: Path, data_hash: str) -> str:
    """The run's description (MLflow's ``mlflow.note.content``, Markdown)."""
    from uavturb.experiments.tracking import project_path

    m = cfg.model
    if cfg.stage == "pretrain":
        what = f"Pre-training: depth encoder, depth → {m.pretraining} transcoder"
    else:
        what = (f"Height model: pre-training {m.pretraining}, {'GRU' if m.use_gru else 'no GRU'}"
                + ("" if m.pretraining == "none" else f", {'fine-tuned' if m.finetune else 'frozen'} encoder"))
    return (f"{what}. Data `{project_path(data_root)}` (digest `{data_hash}`), {cfg.trainer.max_epochs} epochs, "
            f"seed {cfg.trainer.seed}.")


def _logger(cfg: DictConfig, data_root: Path, data_hash: str, tags: dict[str, str] | None = None):
    """Lightning's MLFlowLogger with the resolved config, commit and dataset logged once."""
    if not cfg.tracking.enabled:
        return None
    from lightning.pytorch.loggers import MLFlowLogger

    from uavturb.experiments import tracking

    class StageMetricsLogger(MLFlowLogger):
        """MLFlowLogger that logs the stage's metric names (:func:`stage_metric_names`)."""

        def log_metrics(self, metrics, step=None):
            super().log_metrics(stage_metric_names(cfg.stage, dict(metrics)), step)

    tracking.quiet_mlflow()
    tracking.ensure_experiment(cfg.tracking.experiment)
    run_name = cfg.tracking.run_name or f"{cfg.stage}-{cfg.model.pretraining}-{'gru' if cfg.model.use_gru else 'nogru'}"
    logger = StageMetricsLogger(experiment_name=cfg.tracking.experiment, run_name=run_name,
                                tracking_uri=tracking.tracking_uri(),
                                tags={**tracking.source_tags(), "data_hash": data_hash, "stage": cfg.stage,
                                      tracking.NOTE_TAG: _describe(cfg, data_root, data_hash), **(tags or {})},
                                log_model=False)
    params = {k: ("null" if v is None else v) for k, v in to_flat_dict(cfg).items()}
    if cfg.model.encoder_ckpt:
        params["model.encoder_ckpt"] = tracking.project_path(cfg.model.encoder_ckpt)
    logger.log_hyperparams(params)
    logger.experiment.log_text(logger.run_id, OmegaConf.to_yaml(cfg, resolve=True), "config.yaml")
    if data_root.is_dir():
        tracking.log_dataset(logger.experiment, logger.run_id, data_root, data_hash,
                             "pretraining" if cfg.stage == "pretrain" else "training")
    return logger


def epoch_lines(max_epochs: int):
    """A Lightning callback printing one line per epoch to stderr: progress that reads well in a log file."""
    import sys

    from lightning.pytorch.callbacks import Callback

    class EpochLines(Callback):
        def __init__(self):
            self.t0 = time.perf_counter()

        def on_train_epoch_end(self, trainer, pl_module):
            if not trainer.is_global_zero:
                return
            m = trainer.callback_metrics
            shown = "  ".join(f"{k.removesuffix('_epoch')} {float(m[k]):.4g}" for k in sorted(m)
                              if k == "train/loss_epoch" or k.startswith("val/"))
            print(f"epoch {trainer.current_epoch + 1}/{max_epochs} ({time.perf_counter() - self.t0:.0f} s): {shown}",
                  file=sys.stderr, flush=True)

    return EpochLines()


def _progress_callbacks(t) -> tuple[bool, list]:
    """(enable Lightning's bar, extra callbacks): the bar on a terminal, :func:`epoch_lines` in a file."""
    import sys

    if not t.enable_progress_bar:
        return False, []
    if sys.stderr.isatty():
        return True, []
    return False, [epoch_lines(t.max_epochs)]


def _check_system_metrics(cfg: DictConfig) -> None:
    """``tracking.system_metrics`` needs psutil: fail before anything is logged."""
    import importlib.util

    if cfg.tracking.enabled and cfg.tracking.system_metrics and importlib.util.find_spec("psutil") is None:
        raise InputError("tracking.system_metrics", "needs psutil: pip install 'uavturb[system-metrics]'")


def _system_metrics(cfg: DictConfig, logger):
    """MLflow's system-metrics monitor on the run (``tracking.system_metrics``), started; or None."""
    if logger is None or not cfg.tracking.system_metrics:
        return None
    from mlflow.system_metrics.system_metrics_monitor import SystemMetricsMonitor

    from uavturb.experiments.tracking import tracking_uri

    monitor = SystemMetricsMonitor(logger.run_id, tracking_uri=tracking_uri())
    monitor.start()
    return monitor


def _log_checkpoint(logger, best: str | None) -> None:
    """The best checkpoint as artifact :data:`CHECKPOINT_ARTIFACT`; its local path as tag ``checkpoint``."""
    import shutil
    import tempfile

    from uavturb.experiments.tracking import project_path

    if not best:
        return
    folder, name = CHECKPOINT_ARTIFACT.rsplit("/", 1)
    client = logger.experiment
    client.set_tag(logger.run_id, "checkpoint", project_path(best))
    with tempfile.TemporaryDirectory() as tmp:
        shutil.copyfile(best, Path(tmp) / name)
        client.log_artifact(logger.run_id, str(Path(tmp) / name), folder)


def _log_height_plot(logger, module, dm, window: int) -> None:
    """Predicted vs true height over the first test trajectories, as the figure ``plots/test_heights.png``."""
    import matplotlib.pyplot as plt

    from uavturb.experiments.plots import figure_test_heights

    fig = figure_test_heights(module, dm.sets["test"].folders, window)
    logger.experiment.log_figure(logger.run_id, fig, "plots/test_heights.png")
    plt.close(fig)


def train(cfg: DictConfig | TrainConfig | dict, tags: dict[str, str] | None = None) -> dict[str, Any]:
    """Train one stage as configured, test its best checkpoint, and return the results.

    Parameters
    ----------
    cfg : a config from :func:`uavturb.config.load_config` (or anything that merges into
        :class:`uavturb.config.TrainConfig`; validated again here).
    tags : extra MLflow tags of the run (e.g. ``mlflow.parentRunId`` to nest it in a sweep).

    Returns
    -------
    dict with ``stage``, ``metrics`` (``{"val/rmse_d": ..., "test/rmse_d": ..., ...}``,
    floats), ``checkpoint`` (path of the best checkpoint, str), ``run_id`` (MLflow run id or
    None), ``data_hash``.

    Raises
    ------
    InputError : bad config or data.
    """
    import lightning as L
    from lightning.pytorch.callbacks import EarlyStopping, ModelCheckpoint

    from uavturb.io.shards import dataset_hash

    cfg = validate(cfg)
    _check_system_metrics(cfg)
    quiet_lightning()
    t = cfg.trainer
    if t.num_threads > 0:
        import torch

        torch.set_num_threads(t.num_threads)
    L.seed_everything(t.seed, workers=True, verbose=False)
    data_root = _prepare_data(cfg)
    data_hash = dataset_hash(data_root) if data_root.is_dir() else "missing"
    module, dm, callbacks, monitor = _build(cfg)
    logger = _logger(cfg, data_root, data_hash, tags)
    # Under DDP only rank 0 has an MLflow run; ModelCheckpoint broadcasts rank 0's folder to the others.
    run_id = logger.run_id if logger is not None else None
    run_tag = run_id or time.strftime("%Y%m%d-%H%M%S")
    ckpt_dir = Path(t.default_root_dir) / "checkpoints" / run_tag
    checkpoint = ModelCheckpoint(dirpath=ckpt_dir, filename="best-{epoch}", monitor=monitor, mode="min", save_top_k=1,
                                 auto_insert_metric_name=False)
    callbacks.append(checkpoint)
    if t.early_stopping_patience > 0:
        callbacks.append(EarlyStopping(monitor=monitor, mode="min", patience=t.early_stopping_patience))
    progress_bar, progress_lines = _progress_callbacks(t)
    callbacks.extend(progress_lines)
    trainer = L.Trainer(max_epochs=t.max_epochs, max_steps=t.max_steps, accelerator=t.accelerator,
                        devices=_devices(t.devices), strategy=t.strategy, num_nodes=t.num_nodes,
                        precision=t.precision, limit_train_batches=_limit(t.limit_train_batches),
                        limit_val_batches=_limit(t.limit_val_batches), limit_test_batches=_limit(t.limit_test_batches),
                        log_every_n_steps=t.log_every_n_steps, enable_progress_bar=progress_bar,
                        default_root_dir=t.default_root_dir, deterministic=t.deterministic, callbacks=callbacks,
                        logger=logger if logger is not None else False, enable_model_summary=False)
    system = _system_metrics(cfg, logger) if logger is not None and trainer.is_global_zero else None
    try:
        trainer.fit(module, datamodule=dm)
    finally:
        if system is not None:
            system.finish()
    metrics = {k: float(v) for k, v in trainer.callback_metrics.items()}
    best = checkpoint.best_model_path or None
    tested = trainer.test(module, datamodule=dm, ckpt_path=best if best else None, verbose=False)
    for row in tested:
        metrics.update({k: float(v) for k, v in row.items()})
    metrics.update({k + FA_SCALED_SUFFIX: v * FA_SCALE for k, v in list(metrics.items()) if k.endswith("rmse_fa")})
    if logger is not None and trainer.is_global_zero:
        logger.experiment.set_tag(logger.run_id, "world_size", str(trainer.world_size))
        _log_checkpoint(logger, best)
        if cfg.stage == "height":
            _log_height_plot(logger, module, dm, cfg.data.window)
        logger.finalize("success")
    return {"stage": cfg.stage, "metrics": metrics, "checkpoint": best, "run_id": logger.run_id if logger else None,
            "global_rank": trainer.global_rank,
            "data_hash": data_hash}
