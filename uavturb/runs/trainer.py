"""Lightning wiring of a training config: the stage's module, data and callbacks, the ``Trainer``'s
arguments, the metric names MLflow receives, and the progress shown.

Metric names keep like with like in MLflow's run table (:class:`StageMetricsLogger`): height runs
log ``train/loss``, ``val/rmse_d`` [m], ``test/rmse_fa`` [N] ... and every ``*rmse_fa`` also as
``*rmse_fa_1e-4N`` in the unit of the paper's Table 1 (:data:`uavturb.runs.store.METRICS`);
pre-training runs log theirs under ``pretrain/`` (``pretrain/test/loss``: the transcoder loss,
not a height loss).

Output: on a terminal Lightning's progress bar; otherwise (a log file) one line per epoch on
stderr (:class:`EpochLines`). Lightning's notices (accelerator, tips) are left out.
"""

from __future__ import annotations

import logging
import sys
import time
import warnings
from pathlib import Path
from typing import Any

import lightning  # noqa: F401 - sets its loggers' levels on import; quiet_lightning overrides them after
import torch
from lightning.pytorch.callbacks import Callback
from lightning.pytorch.loggers import MLFlowLogger
from omegaconf import DictConfig

from uavturb.data.datamodules import PairsDataModule, ShardWindowsDataModule, dataset_camera
from uavturb.errors import InputError
from uavturb.runs import store
from uavturb.runs.accelerators import pin_memory
from uavturb.runs.training_data import resolve_ground_effect_law
from uavturb.systems import FreezeThenFinetune, HeightModule, TranscoderModule


def quiet_lightning() -> None:
    """Lightning's per-run notices (accelerator, tips, checkpoint restores) and a torch deprecation off."""
    for name in ("lightning.pytorch", "lightning.fabric", "lightning"):
        logging.getLogger(name).setLevel(logging.WARNING)
    warnings.filterwarnings("ignore", message=r".*isinstance\(treespec, LeafSpec\).*")


def stage_metric_names(stage: str, metrics: dict[str, float]) -> dict[str, float]:
    """Metric names as logged to MLflow (see the module docstring): ``pretrain/`` prefix, scaled f_a."""
    named = {(f"pretrain/{k}" if stage == "pretrain" and k not in ("epoch", "step") else k): v
             for k, v in metrics.items()}
    return store.with_scaled_fa(named)


class StageMetricsLogger(MLFlowLogger):
    """Lightning's MLFlowLogger that logs the stage's metric names (:func:`stage_metric_names`), each of its
    writes whole: a SIGTERM or SIGINT that arrives during one takes effect when it ends
    (:func:`uavturb.runs.store.whole_write`, as for the store's own writes). Cut short, an SQLite
    transaction left the database locked, and the write that then marks the run ended failed ("database is
    locked": the run FAILED with an internal error instead of KILLED, seen under load)."""

    def __init__(self, stage: str, **kwargs: Any):
        super().__init__(**kwargs)
        self.stage = stage

    @store.whole_write
    def log_metrics(self, metrics, step=None):
        super().log_metrics(stage_metric_names(self.stage, dict(metrics)), step)

    @store.whole_write
    def log_hyperparams(self, params):
        super().log_hyperparams(params)

    @store.whole_write
    def finalize(self, status: str = "success") -> None:
        super().finalize(status)


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
    if t.num_threads > 0:
        torch.set_num_threads(t.num_threads)
    torch.set_float32_matmul_precision(t.matmul_precision)


def _pretraining(cfg: DictConfig):
    """(module, datamodule, callbacks, monitor) of stage ``pretrain``: depth -> normals or depth."""
    m, d = cfg.model, cfg.data
    if m.pretraining == "none":
        raise InputError("model.pretraining", "stage pretrain needs normals or depth, not none")
    module = TranscoderModule(target=m.pretraining, lr=m.lr_pretrain, lam=m.lam, embed_dim=m.embed_dim,
                              encoder_hidden=m.encoder_hidden, max_depth=m.max_depth)
    dm = PairsDataModule(d.pairs_root, target=m.pretraining, batch_size=d.batch_size, num_workers=d.num_workers,
                         val_fraction=d.val_fraction, seed=cfg.trainer.seed, pin_memory=pin_memory(cfg))
    return module, dm, [], store.PRETRAIN_MONITOR


def build(cfg: DictConfig):
    """(module, datamodule, callbacks, monitor) of the configured stage."""
    if cfg.stage == "pretrain":
        return _pretraining(cfg)
    m, d = cfg.model, cfg.data
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
    return module, dm, callbacks, store.HEIGHT_MONITOR


def build_stage(cfg: DictConfig, data_root: Path):
    """(module, datamodule, callbacks, monitor) of the configured stage on ``data_root``, the ground-effect
    law resolved first (as :func:`uavturb.runs.train.train` does; ``uavturb bench gpu`` trains what this builds)."""
    resolve_ground_effect_law(cfg, data_root)
    return build(cfg)


class EpochLines(Callback):
    """One line per epoch on stderr (the training loss and the validation metrics): progress that
    reads well in a log file."""

    def __init__(self, max_epochs: int):
        self.max_epochs = max_epochs
        self.t0 = time.perf_counter()

    def on_train_epoch_end(self, trainer, pl_module):
        if not trainer.is_global_zero:
            return
        m = trainer.callback_metrics
        shown = "  ".join(f"{k.removesuffix('_epoch')} {float(m[k]):.4g}" for k in sorted(m)
                          if k == "train/loss_epoch" or k.startswith("val/"))
        print(f"epoch {trainer.current_epoch + 1}/{self.max_epochs} ({time.perf_counter() - self.t0:.0f} s): {shown}",
              file=sys.stderr, flush=True)


class FirstEpoch(Callback):
    """Remembers the epoch training starts at (0, or where a resumed run continues): :attr:`epoch`."""

    def __init__(self):
        self.epoch: int | None = None

    def on_train_epoch_start(self, trainer, pl_module):
        if self.epoch is None:
            self.epoch = int(trainer.current_epoch)


def progress_callbacks(t: DictConfig) -> tuple[bool, list]:
    """(enable Lightning's bar, extra callbacks): the bar on a terminal, :class:`EpochLines` in a file."""
    if not t.enable_progress_bar:
        return False, []
    if sys.stderr.isatty():
        return True, []
    return False, [EpochLines(t.max_epochs)]
