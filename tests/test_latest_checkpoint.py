"""``last.ckpt`` is the last epoch whatever the monitored metric did (runs/train.py ``_latest_checkpoint``): a run
stopped after an epoch that did not improve resumes from that epoch, not from the last improvement."""

from __future__ import annotations

import lightning as L
import torch
from lightning.pytorch.callbacks import ModelCheckpoint
from lightning.pytorch.demos.boring_classes import BoringModel

from uavturb.runs.resume import LAST_CHECKPOINT
from uavturb.runs.train import _latest_checkpoint


class _Worsening(BoringModel):
    """A model whose validation loss grows every epoch: the first epoch stays the best."""

    def validation_step(self, batch, batch_idx):
        self.log("val/loss", float(self.current_epoch), on_epoch=True)


def _fit(callbacks):
    trainer = L.Trainer(max_epochs=3, limit_train_batches=2, limit_val_batches=1, logger=False,
                        enable_progress_bar=False, enable_model_summary=False, callbacks=callbacks)
    trainer.fit(_Worsening())


def test_last_checkpoint_is_the_last_epoch_when_validation_does_not_improve(tmp_path):
    best = ModelCheckpoint(dirpath=tmp_path / "run", filename="best-{epoch}", monitor="val/loss", mode="min",
                           save_top_k=1, auto_insert_metric_name=False)
    _fit([_latest_checkpoint(tmp_path / "run"), best])
    assert sorted(p.name for p in (tmp_path / "run").iterdir()) == ["best-0.ckpt", LAST_CHECKPOINT]
    assert torch.load(tmp_path / "run" / LAST_CHECKPOINT, map_location="cpu", weights_only=False)["epoch"] == 2
    # Lightning's own save_last, as the run had it: last.ckpt stays at the last improvement
    stale = ModelCheckpoint(dirpath=tmp_path / "old", filename="best-{epoch}", monitor="val/loss", mode="min",
                            save_top_k=1, save_last=True, auto_insert_metric_name=False)
    _fit([stale])
    assert torch.load(tmp_path / "old" / LAST_CHECKPOINT, map_location="cpu", weights_only=False)["epoch"] == 0
