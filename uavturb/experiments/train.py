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
:mod:`uavturb.experiments.plots`). ``last.ckpt`` beside it holds the latest epoch (tag
``checkpoint_dir``: the folder).

Interruptions and resuming: the run is FINISHED when training and testing complete, KILLED when
a signal stops it (:class:`uavturb.errors.Interrupted`), FAILED on an error; its tags ``host``,
``pid`` and ``pid_start`` let any later command mark it FAILED if its process dies without
closing it (SIGKILL). ``train(cfg, resume=RUN_ID)`` (``uavturb train --resume RUN_ID``) continues
such a run in the same MLflow run from its ``last.ckpt``, as Lightning's ``ckpt_path`` does.
Bad config values and bad data fail before any run is opened, and so does a device this machine
lacks (``trainer.accelerator=gpu`` without a CUDA device, fp16 on the CPU:
:mod:`uavturb.experiments.accelerators`).

Devices: DataLoader memory is pinned when training on a CUDA device (``data.pin_memory``
decides otherwise); ``trainer.cudnn_benchmark`` and ``trainer.matmul_precision`` are
Lightning's ``benchmark`` and torch's float32 matmul precision (TF32 with ``high``).
Checkpoints hold float32 weights under mixed precision and load on the CPU wherever they were
trained (``map_location="cpu"`` in evaluate and export).

Output: on a terminal Lightning's progress bar; otherwise (a log file) one line per epoch on
stderr (:func:`epoch_lines`). Lightning's notices (accelerator, tips) are left out.
"""

from __future__ import annotations

import json
import logging
import time
from pathlib import Path
from typing import Any

from omegaconf import DictConfig, OmegaConf

from uavturb.data.datamodules import dataset_camera
from uavturb.errors import InputError
from uavturb.experiments.accelerators import check_trainer_device
from uavturb.experiments.config import TrainConfig, to_flat_dict, validate
from uavturb.experiments.tracking import CAMERA_TAG

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


def trainer_kwargs(t: DictConfig) -> dict[str, Any]:
    """Lightning ``Trainer`` arguments of the ``trainer`` node of a config (device, precision, lengths);
    callbacks, logger and progress are the caller's. ``uavturb bench gpu`` builds its trainers with them."""
    return dict(max_epochs=t.max_epochs, max_steps=t.max_steps, accelerator=t.accelerator,
                devices=_devices(t.devices), strategy=t.strategy, num_nodes=t.num_nodes, precision=t.precision,
                limit_train_batches=_limit(t.limit_train_batches), limit_val_batches=_limit(t.limit_val_batches),
                limit_test_batches=_limit(t.limit_test_batches), log_every_n_steps=t.log_every_n_steps,
                default_root_dir=t.default_root_dir, deterministic=t.deterministic, benchmark=t.cudnn_benchmark)


def set_torch_flags(t: DictConfig) -> None:
    """Process-wide torch settings of the ``trainer`` node: CPU threads and the float32 matmul precision."""
    import torch

    if t.num_threads > 0:
        torch.set_num_threads(t.num_threads)
    torch.set_float32_matmul_precision(t.matmul_precision)


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


def _resolve_ground_effect_law(cfg: DictConfig, data_root: Path) -> None:
    """Fill ``model.alpha`` and ``model.beta`` left unset: the law the training data's ``f_a`` was
    made with (:func:`uavturb.data.datamodules.ground_effect_law`), else the paper's quadrotor's.
    The run then logs the values it trained with (the law-weighted loss and ``f_a`` metrics use them)."""
    from uavturb.data.datamodules import ground_effect_law
    from uavturb.physics.effects import ALPHA_PAPER, BETA_PAPER

    m = cfg.model
    if (m.alpha is None) != (m.beta is None):
        raise InputError("model.alpha", "set model.alpha and model.beta together, or neither (the data's law)")
    if m.alpha is None:
        law = ground_effect_law(data_root) if cfg.stage == "height" else None
        m.alpha, m.beta = law if law is not None else (ALPHA_PAPER, BETA_PAPER)


def _build(cfg: DictConfig):
    """(module, datamodule, callbacks, monitor) of the configured stage."""
    from uavturb.data.datamodules import PairsDataModule, ShardWindowsDataModule
    from uavturb.experiments.accelerators import pin_memory
    from uavturb.systems import FreezeThenFinetune, HeightModule, TranscoderModule

    m, d = cfg.model, cfg.data
    if cfg.stage == "pretrain":
        if m.pretraining == "none":
            raise InputError("model.pretraining", "stage pretrain needs normals or depth, not none")
        module = TranscoderModule(target=m.pretraining, lr=m.lr_pretrain, lam=m.lam, embed_dim=m.embed_dim,
                                  encoder_hidden=m.encoder_hidden, max_depth=m.max_depth)
        dm = PairsDataModule(d.pairs_root, target=m.pretraining, batch_size=d.batch_size, num_workers=d.num_workers,
                             val_fraction=d.val_fraction, seed=cfg.trainer.seed, pin_memory=pin_memory(cfg))
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
    camera = dataset_camera(d.root)  # the model carries the camera of its training images
    module = HeightModule(use_gru=m.use_gru, embed_dim=m.embed_dim, encoder_hidden=m.encoder_hidden,
                          gru_hidden=m.gru_hidden, gru_layers=m.gru_layers, mlp_hidden=m.mlp_hidden,
                          max_depth=m.max_depth, lr_head=m.lr_head, lr_encoder=m.lr_encoder, alpha=m.alpha,
                          beta=m.beta, loss_frames=m.loss_frames, encoder_ckpt=encoder_ckpt,
                          loss=m.loss, law_weight_ref=m.law_weight_ref,
                          camera=None if camera is None else camera.record())
    dm = ShardWindowsDataModule(d.root, window=d.window, stride=d.stride, eval_stride=d.eval_stride,
                                batch_size=d.batch_size, num_workers=d.num_workers, image_size=d.image_size,
                                seed=cfg.trainer.seed,  # seeds differ in batch order too, not only in init
                                pin_memory=pin_memory(cfg))
    return module, dm, callbacks, "val/rmse_d"


def build_stage(cfg: DictConfig, data_root: Path):
    """(module, datamodule, callbacks, monitor) of the configured stage on ``data_root``, the ground-effect
    law resolved first (as :func:`train` does; ``uavturb bench gpu`` trains what this builds)."""
    _resolve_ground_effect_law(cfg, data_root)
    return _build(cfg)


#: keys a resumed run may change (how long and where it trains, not what it learns); any other
#: difference from the run's own config is refused
RESUMABLE_KEYS = ("trainer.max_epochs", "trainer.max_steps", "trainer.num_threads", "trainer.enable_progress_bar",
                  "trainer.accelerator", "trainer.devices", "trainer.strategy", "trainer.num_nodes",
                  "trainer.cudnn_benchmark", "data.num_workers", "data.pin_memory", "model.encoder_ckpt")
#: name of the checkpoint of the latest epoch, in the run's checkpoint folder (tag ``checkpoint_dir``)
LAST_CHECKPOINT = "last.ckpt"


def _run_name(cfg: DictConfig) -> str:
    return cfg.tracking.run_name or f"{cfg.stage}-{cfg.model.pretraining}-{'gru' if cfg.model.use_gru else 'nogru'}"


def _is_rank_zero() -> bool:
    from lightning.pytorch.utilities import rank_zero_only

    return getattr(rank_zero_only, "rank", 0) == 0


def _resumable_run(client, run_id: str):
    """The run ``run_id`` if it is a training run that may be resumed now; InputError otherwise."""
    from mlflow.exceptions import MlflowException

    from uavturb.experiments.tracking import process_alive, tracking_uri

    try:
        run = client.get_run(run_id)
    except MlflowException:
        raise InputError("--resume", f"no run '{run_id}' in the MLflow store {tracking_uri()}") from None
    tags = run.data.tags
    if "stage" not in tags or "checkpoint_dir" not in tags:
        raise InputError("--resume", f"run {run_id} is not a uavturb training run (no tags stage, checkpoint_dir)")
    alive = process_alive(tags)
    if run.info.status == "RUNNING" and alive is not False:  # False: its process is gone (stale)
        where = f"pid {tags.get('pid', '?')} on {tags.get('host', '?')}"
        state = "still runs" if alive else "is RUNNING on another host"
        raise InputError("--resume", f"run {run_id} {state} ({where}); stop it first or wait for it")
    return run


def run_config(run_id: str) -> DictConfig:
    """The resolved config a training run logged (its ``config.yaml`` artifact), validated."""
    import tempfile

    from uavturb.experiments.tracking import client

    c = client()
    _resumable_run(c, run_id)
    with tempfile.TemporaryDirectory() as tmp:
        try:
            path = c.download_artifacts(run_id, "config.yaml", tmp)
        except Exception:  # noqa: BLE001 - MlflowException or OSError: the artifact is gone
            raise InputError("--resume", f"run {run_id} has no readable config.yaml artifact") from None
        from uavturb.io.yaml_mapping import read_yaml_mapping

        return validate(OmegaConf.create(read_yaml_mapping(path)))  # within the YAML bounds: runs can be shared


def resume_config(run_id: str, overrides: list[str] | None = None, experiment: str | None = None) -> DictConfig:
    """The config of ``uavturb train --resume RUN_ID [overrides]``.

    With only :data:`RESUMABLE_KEYS` overrides (e.g. ``trainer.max_epochs=50``) and no
    ``--experiment``: the run's own config with those changes. Otherwise the config is composed
    as for a new run (repeating the run's command line); :func:`train` then refuses it if it
    differs from the run's in any other key.
    """
    from uavturb.experiments.config import load_config

    overrides = list(overrides or [])
    if experiment is None and all(o.split("=", 1)[0] in RESUMABLE_KEYS for o in overrides):
        base = run_config(run_id)
        return validate(OmegaConf.merge(base, OmegaConf.from_dotlist(overrides)))
    return load_config(overrides, experiment=experiment)


def _config_changes(cfg: DictConfig, run) -> dict[str, tuple[str, str]]:
    """``{key: (run's value, new value)}`` where ``cfg`` differs from a run's logged params; InputError
    where a key outside :data:`RESUMABLE_KEYS` differs."""
    changes = {}
    for key, value in to_flat_dict(cfg).items():
        new, old = str("null" if value is None else value)[:250], run.data.params.get(key)
        if old is None or old == new:
            continue
        if key not in RESUMABLE_KEYS:
            raise InputError("--resume", f"{key} is {new!r} here but {old!r} in run {run.info.run_id}; a resumed run "
                             f"keeps its config except {', '.join(RESUMABLE_KEYS)} (or start a new run)")
        changes[key] = (old, new)
    return changes


def _open_run(cfg: DictConfig, data_root: Path, data_hash: str, ckpt_root: Path, tags: dict[str, str] | None,
              resume: str | None) -> tuple[Any, str, Path | None]:
    """Open (or, with ``resume``, re-open) the MLflow run: (client, run id, last checkpoint or None).

    A new run gets the resolved config (params and ``config.yaml``), the dataset as its input
    (name, digest), a description, the tags ``mlflow.source.git.commit``, ``data_hash``, ``stage``,
    ``checkpoint_dir`` and :func:`uavturb.experiments.tracking.process_tags`.
    A resumed one is marked RUNNING by this process, keeps its params, and records what changed
    in the tags ``resumed`` (how many times) and ``resume_changes``.
    """
    from mlflow.entities import Param

    from uavturb.experiments.tracking import (NOTE_TAG, claim_run, client, experiment_id, log_dataset, project_path,
                                              run_tags)

    c = client()
    if resume is not None:
        run = _resumable_run(c, resume)
        changes = _config_changes(cfg, run)
        claim_run(c, resume)
        c.set_tag(resume, "resumed", str(int(run.data.tags.get("resumed", "0")) + 1))
        if changes:
            c.set_tag(resume, "resume_changes", ", ".join(f"{k} {a} -> {b}" for k, (a, b) in changes.items()))
        last = Path(run.data.tags["checkpoint_dir"]) / LAST_CHECKPOINT
        return c, resume, last if last.is_file() else None
    exp_id = experiment_id(c, cfg.tracking.experiment)
    run = c.create_run(exp_id, run_name=_run_name(cfg),
                       tags=run_tags({"data_hash": data_hash, "stage": cfg.stage,
                                      NOTE_TAG: _describe(cfg, data_root, data_hash), **(tags or {})}))
    run_id = run.info.run_id
    try:
        c.set_tag(run_id, "checkpoint_dir", str((ckpt_root / run_id).resolve()))
        flat = {k: str("null" if v is None else v)[:250] for k, v in to_flat_dict(cfg).items()}
        if cfg.model.encoder_ckpt:
            flat["model.encoder_ckpt"] = project_path(cfg.model.encoder_ckpt)
        params = [Param(k, v) for k, v in flat.items()]
        for i in range(0, len(params), 100):
            c.log_batch(run_id, params=params[i:i + 100])
        c.log_text(run_id, OmegaConf.to_yaml(cfg, resolve=True), "config.yaml")
        if data_root.is_dir():
            log_dataset(c, run_id, data_root, data_hash, "pretraining" if cfg.stage == "pretrain" else "training")
    except BaseException as e:
        from uavturb.errors import Interrupted
        from uavturb.experiments.tracking import close_run

        status = close_run(c, run_id, e)
        if isinstance(e, Interrupted):  # stopped while the run was being opened: nothing trained yet
            e.notes.append(f"run {run_id} marked {status}; continue it with `uavturb train --resume {run_id}`")
        raise
    return c, run_id, None


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


def _logger(cfg: DictConfig, run_id: str | None):
    """Lightning's MLFlowLogger writing into run ``run_id`` (None on DDP ranks other than 0)."""
    if not cfg.tracking.enabled:
        return None
    from lightning.pytorch.loggers import MLFlowLogger

    from uavturb.experiments.tracking import tracking_uri

    class StageMetricsLogger(MLFlowLogger):
        """MLFlowLogger that logs the stage's metric names (:func:`stage_metric_names`)."""

        def log_metrics(self, metrics, step=None):
            super().log_metrics(stage_metric_names(cfg.stage, dict(metrics)), step)

    return StageMetricsLogger(experiment_name=cfg.tracking.experiment, run_name=_run_name(cfg),
                              tracking_uri=tracking_uri(), run_id=run_id, log_model=False)


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


def _finish_system_metrics(monitor) -> None:
    """Stop MLflow's monitor; a run it logged nothing for (shorter than its sampling interval, or
    its thread gave up on a busy store) gets one sample taken now, so the run shows its system
    metrics whatever its length."""
    logged = monitor._logging_step > 0  # MLflow's monitor has no public count of what it logged
    monitor.finish()
    if not logged:
        monitor.collect_metrics()
        monitor.publish_metrics(monitor.aggregate_metrics())
        monitor.mlflow_logger.flush()


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


class _FirstEpoch:
    """Remembers the epoch training starts at (0, or where a resumed run continues)."""

    def __init__(self):
        from lightning.pytorch.callbacks import Callback

        outer = self

        class _Cb(Callback):
            def on_train_epoch_start(self, trainer, pl_module):
                if outer.epoch is None:
                    outer.epoch = int(trainer.current_epoch)

        self.epoch: int | None = None
        self.callback = _Cb()


def train(cfg: DictConfig | TrainConfig | dict, tags: dict[str, str] | None = None,
          resume: str | None = None) -> dict[str, Any]:
    """Train one stage as configured, test its best checkpoint, and return the results.

    Parameters
    ----------
    cfg : a config from :func:`uavturb.config.load_config` (or anything that merges into
        :class:`uavturb.config.TrainConfig`; validated again here).
    tags : extra MLflow tags of the run (e.g. ``mlflow.parentRunId`` to nest it in a sweep).
    resume : id of an interrupted (KILLED, FAILED) or finished run to continue in the same MLflow
        run from its ``last.ckpt`` (epoch, optimizer, callbacks), as Lightning's ``ckpt_path`` does;
        without a ``last.ckpt`` (stopped in its first epoch) it starts over in that run. ``cfg``
        may differ from the run's config only in :data:`RESUMABLE_KEYS`.

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
    import lightning as L

    from uavturb.io.shards import dataset_hash

    cfg = validate(cfg)
    _check_system_metrics(cfg)
    check_trainer_device(cfg.trainer)  # gpu without a CUDA device, fp16 on the CPU: one line, nothing started
    quiet_lightning()
    if resume is not None and not cfg.tracking.enabled:
        raise InputError("--resume", "needs tracking.enabled=true (the run lives in MLflow)")
    if resume is not None and _is_rank_zero():  # a run that cannot be resumed fails before any work
        from uavturb.experiments.tracking import client
        from uavturb.io.checkpoint import read_checkpoint

        run = _resumable_run(client(), resume)
        _config_changes(cfg, run)
        last = Path(run.data.tags["checkpoint_dir"]) / LAST_CHECKPOINT
        if last.is_file():  # a poisoned or broken checkpoint is refused before the run is touched
            read_checkpoint(last)
    t = cfg.trainer
    set_torch_flags(t)
    L.seed_everything(t.seed, workers=True, verbose=False)
    data_root = _prepare_data(cfg)
    _resolve_ground_effect_law(cfg, data_root)
    data_hash = dataset_hash(data_root) if data_root.is_dir() else "missing"
    module, dm, callbacks, monitor = _build(cfg)
    dm.setup("fit")  # bad data fails here, before a run is opened
    if module.hparams.get("camera") is not None:  # the run names the model's camera too (tag camera, JSON)
        tags = {**(tags or {}), CAMERA_TAG: json.dumps(module.hparams["camera"])}
    ckpt_root = Path(t.default_root_dir) / "checkpoints"
    client, run_id, last = None, None, None
    if cfg.tracking.enabled and _is_rank_zero():
        client, run_id, last = _open_run(cfg, data_root, data_hash, ckpt_root, tags, resume)
    elif resume is not None:  # DDP ranks > 0: rank 0's run, found by the same command line's --resume
        last = ckpt_root / resume / LAST_CHECKPOINT
        last = last if last.is_file() else None
    try:
        return _fit_and_test(cfg, module, dm, callbacks, monitor, client, run_id, last, ckpt_root, resume, data_hash)
    except BaseException as e:
        if client is not None:
            from uavturb.errors import Interrupted
            from uavturb.experiments.tracking import close_run

            status = close_run(client, run_id, e)
            if isinstance(e, Interrupted):
                e.notes.append(f"run {run_id} marked {status}; continue it with `uavturb train --resume {run_id}`")
        raise


def _fit_and_test(cfg, module, dm, callbacks, monitor, client, run_id, last, ckpt_root, resume, data_hash
                  ) -> dict[str, Any]:
    """Fit (from ``last`` when resuming), test the best checkpoint, log it; the run is closed FINISHED."""
    import sys

    import lightning as L
    from lightning.pytorch.callbacks import EarlyStopping, ModelCheckpoint

    t = cfg.trainer
    logger = _logger(cfg, run_id)
    # Under DDP only rank 0 has an MLflow run; ModelCheckpoint broadcasts rank 0's folder to the others.
    run_tag = run_id or resume or time.strftime("%Y%m%d-%H%M%S")
    checkpoint = ModelCheckpoint(dirpath=ckpt_root / run_tag, filename="best-{epoch}", monitor=monitor, mode="min",
                                 save_top_k=1, save_last=True, auto_insert_metric_name=False)
    first = _FirstEpoch()
    callbacks = [*callbacks, checkpoint, first.callback]
    if t.early_stopping_patience > 0:
        callbacks.append(EarlyStopping(monitor=monitor, mode="min", patience=t.early_stopping_patience))
    progress_bar, progress_lines = _progress_callbacks(t)
    callbacks.extend(progress_lines)
    trainer = L.Trainer(**trainer_kwargs(t), enable_progress_bar=progress_bar, callbacks=callbacks,
                        logger=logger if logger is not None else False, enable_model_summary=False)
    if resume is not None and trainer.is_global_zero:
        print(f"resuming run {resume} " + (f"from {last}" if last else f"from the start (no {LAST_CHECKPOINT} yet)"),
              file=sys.stderr, flush=True)
    system = _system_metrics(cfg, logger) if logger is not None and trainer.is_global_zero else None
    try:
        trainer.fit(module, datamodule=dm, ckpt_path=str(last) if last else None, weights_only=True)
    finally:
        if system is not None:
            _finish_system_metrics(system)
    metrics = {k: float(v) for k, v in trainer.callback_metrics.items()}
    best = checkpoint.best_model_path or None
    tested = trainer.test(module, datamodule=dm, ckpt_path=best if best else None, verbose=False, weights_only=True)
    for row in tested:
        metrics.update({k: float(v) for k, v in row.items()})
    metrics.update({k + FA_SCALED_SUFFIX: v * FA_SCALE for k, v in list(metrics.items()) if k.endswith("rmse_fa")})
    if client is not None and trainer.is_global_zero:
        from uavturb.experiments.tracking import close_run

        logger.experiment.set_tag(logger.run_id, "world_size", str(trainer.world_size))
        _log_checkpoint(logger, best)
        if cfg.stage == "height":
            _log_height_plot(logger, module, dm, cfg.data.window)
        close_run(client, run_id)
    return {"stage": cfg.stage, "metrics": metrics, "checkpoint": best, "run_id": run_id,
            "global_rank": trainer.global_rank, "data_hash": data_hash,
            "start_epoch": first.epoch if first.epoch is not None else int(trainer.current_epoch)}
