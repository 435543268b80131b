"""A run's checkpoints (runs/checkpoints.py): ``last.ckpt`` is the last epoch whatever the monitored metric did, it
names the best checkpoint of its own epoch, and a run resumed from a ``last.ckpt`` naming a best file that is gone
(written before that order was fixed, or a process stopped between the two saves) tests a best file that exists.
"""

from __future__ import annotations

import os
import signal

import lightning as L
import pytest
import torch
from lightning.pytorch.callbacks import ModelCheckpoint
from lightning.pytorch.demos.boring_classes import BoringModel

from uavturb.errors import Interrupted, raise_on_signals
from uavturb.runs.checkpoints import LatestCheckpoint, epoch_checkpoints
from uavturb.runs.resume import LAST_CHECKPOINT


class _Scripted(BoringModel):
    """A model whose validation loss at epoch ``e`` is ``losses[e]``."""

    def __init__(self, losses):
        super().__init__()
        self.losses = losses

    def validation_step(self, batch, batch_idx):
        self.log("val/loss", float(self.losses[self.current_epoch]), on_epoch=True)


def _trainer(callbacks, max_epochs=3):
    return L.Trainer(max_epochs=max_epochs, limit_train_batches=2, limit_val_batches=1, limit_test_batches=1,
                     logger=False, enable_progress_bar=False, enable_model_summary=False, callbacks=callbacks)


def _fit(callbacks, losses=(0.0, 1.0, 2.0), max_epochs=3, ckpt_path=None):
    trainer = _trainer(callbacks, max_epochs)
    trainer.fit(_Scripted(losses), ckpt_path=ckpt_path, weights_only=True)
    return trainer


def _load(path):
    return torch.load(path, map_location="cpu", weights_only=False)


def _best_state(ckpt):
    (state,) = [v for k, v in ckpt["callbacks"].items() if "'monitor': 'val/loss'" in k]
    return state


def _files(folder):
    return sorted(p.name for p in folder.iterdir())


def test_last_checkpoint_is_the_last_epoch_when_validation_does_not_improve(tmp_path):
    best = ModelCheckpoint(dirpath=tmp_path / "run", filename="best-{epoch}", monitor="val/loss", mode="min",
                           save_top_k=1, auto_insert_metric_name=False)
    _fit([best, LatestCheckpoint(tmp_path / "run")])
    assert _files(tmp_path / "run") == ["best-0.ckpt", LAST_CHECKPOINT]
    assert _load(tmp_path / "run" / LAST_CHECKPOINT)["epoch"] == 2
    # Lightning's own save_last, as the run had it: last.ckpt stays at the last improvement
    stale = ModelCheckpoint(dirpath=tmp_path / "old", filename="best-{epoch}", monitor="val/loss", mode="min",
                            save_top_k=1, save_last=True, auto_insert_metric_name=False)
    _fit([stale])
    assert _load(tmp_path / "old" / LAST_CHECKPOINT)["epoch"] == 0


def test_last_checkpoint_names_the_best_file_of_its_own_epoch(tmp_path):
    folder = tmp_path / "run"
    _fit(list(epoch_checkpoints(folder, "val/loss")), losses=(3.0, 2.0, 1.0))
    assert _files(folder) == ["best-2.ckpt", LAST_CHECKPOINT]
    last = _load(folder / LAST_CHECKPOINT)
    state = _best_state(last)
    assert last["epoch"] == 2 and state["best_model_path"] == str(folder.resolve() / "best-2.ckpt")
    assert list(state["best_k_models"]) == [str(folder.resolve() / "best-2.ckpt")]
    assert float(state["best_model_score"]) == 1.0


def _stale_run(folder):
    """A run checkpointed as before the fix (``last.ckpt`` saved before the best), stopped after epoch 1 improved:
    ``last.ckpt`` (epoch 1) names ``best-0.ckpt``, which the best callback deleted right after saving it."""
    latest = LatestCheckpoint(folder)
    best = ModelCheckpoint(dirpath=folder, filename="best-{epoch}", monitor="val/loss", mode="min", save_top_k=1,
                           auto_insert_metric_name=False)
    _fit([latest, best], losses=(1.0, 0.5), max_epochs=2)
    last = _load(folder / LAST_CHECKPOINT)
    assert last["epoch"] == 1 and _best_state(last)["best_model_path"] == str(folder.resolve() / "best-0.ckpt")
    assert _files(folder) == ["best-1.ckpt", LAST_CHECKPOINT]


def test_a_resumed_run_whose_last_checkpoint_names_a_deleted_best_file_tests_the_one_there(tmp_path):
    folder = tmp_path / "run"
    _stale_run(folder)
    best, latest = epoch_checkpoints(folder, "val/loss")
    trainer = _fit([best, latest], losses=(1.0, 0.5, 2.0, 2.0), max_epochs=4, ckpt_path=folder / LAST_CHECKPOINT)
    # the epochs after it (2.0) did not beat best-1 (0.5): best-1 stays the best; it had been best-0, gone
    assert best.best_model_path == str(folder.resolve() / "best-1.ckpt") and float(best.best_model_score) == 0.5
    assert list(best.best_k_models) == [best.best_model_path]
    assert _files(folder) == ["best-1.ckpt", LAST_CHECKPOINT]
    assert trainer.test(ckpt_path=best.best_model_path, weights_only=True, verbose=False) == [{}]  # it loads


def test_a_resumed_run_with_no_loadable_best_file_starts_its_best_afresh(tmp_path):
    folder = tmp_path / "run"
    _stale_run(folder)
    (folder / "best-1.ckpt").write_bytes(b"cut short")  # unreadable: not a checkpoint to continue from
    best, latest = epoch_checkpoints(folder, "val/loss")
    _fit([best, latest], losses=(1.0, 0.5, 2.0, 3.0), max_epochs=4, ckpt_path=folder / LAST_CHECKPOINT)
    assert best.best_model_path == str(folder.resolve() / "best-2.ckpt") and float(best.best_model_score) == 2.0
    assert _load(folder / LAST_CHECKPOINT)["epoch"] == 3


def test_a_signal_during_the_best_save_ends_the_save_and_the_run_resumes_from_what_it_left(tmp_path, monkeypatch):
    """SIGINT while ``best-1.ckpt`` is written: the write (and the removal of ``best-0.ckpt`` it replaces) ends,
    then Interrupted is raised, before ``last.ckpt`` of epoch 1; the resumed run retrains epoch 1 and keeps best-1."""
    folder = tmp_path / "run"
    best, latest = epoch_checkpoints(folder, "val/loss")
    real, sent = L.Trainer.save_checkpoint, []

    def signalled(self, filepath, *args, **kwargs):
        if str(filepath).endswith("best-1.ckpt") and not sent:
            sent.append(os.kill(os.getpid(), signal.SIGINT))
        return real(self, filepath, *args, **kwargs)

    monkeypatch.setattr(L.Trainer, "save_checkpoint", signalled)
    with pytest.raises(Interrupted) as caught:
        with raise_on_signals():
            _fit([best, latest], losses=(1.0, 0.5, 2.0), max_epochs=3)
    assert caught.value.signum == signal.SIGINT and sent
    assert _files(folder) == ["best-1.ckpt", LAST_CHECKPOINT]
    assert _best_state(_load(folder / "best-1.ckpt"))["best_model_path"] == str(folder.resolve() / "best-1.ckpt")
    last = _load(folder / LAST_CHECKPOINT)
    assert last["epoch"] == 0 and _best_state(last)["best_model_path"] == str(folder.resolve() / "best-0.ckpt")
    monkeypatch.setattr(L.Trainer, "save_checkpoint", real)
    best, latest = epoch_checkpoints(folder, "val/loss")
    _fit([best, latest], losses=(1.0, 0.75, 2.0), max_epochs=3, ckpt_path=folder / LAST_CHECKPOINT)
    # epoch 1 trained again (0.75 this time) did not beat the best-1 it had saved (0.5)
    assert best.best_model_path == str(folder.resolve() / "best-1.ckpt") and float(best.best_model_score) == 0.5
    assert _load(folder / LAST_CHECKPOINT)["epoch"] == 2
