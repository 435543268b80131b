"""A training run's two checkpoint callbacks: ``best-<epoch>.ckpt`` (the best epoch on the validation monitor)
and ``last.ckpt`` (the latest epoch), kept in the run's checkpoint folder so that ``uavturb train --resume``
finds them consistent.

- Order: the best checkpoint is saved before ``last.ckpt`` (:func:`epoch_checkpoints`), so that ``last.ckpt``
  records the best checkpoint as of its own epoch. Saved the other way round, ``last.ckpt`` of an epoch that
  improved named the best file of the epoch before, which the best callback deleted right after; a run resumed
  from it, whose later epochs did not beat that older score, tested a file that no longer existed
  (``FileNotFoundError: Checkpoint file not found: .../best-0.ckpt``, "a file: FileNotFoundError" on the command
  line; the flaky SIGINT-then-resume test).
- Signals: each callback's end-of-epoch saving (writing one file, deleting the one it replaces, and the state
  recorded with them) is whole: a SIGTERM or SIGINT that arrives during it takes effect when it ends
  (:func:`uavturb.errors.signals_deferred`), as for the run store's writes.
- Resuming: :class:`BestCheckpoint` checks the state it restores against the folder. Where the checkpoint
  resumed from names best files that are gone (a run checkpointed before the order above was fixed, a process
  killed between the two saves, a file deleted by hand), it takes the state of the best checkpoint in the folder
  that loads, as that file recorded it, or starts afresh where none does.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

from lightning.pytorch.callbacks import ModelCheckpoint

from uavturb.errors import InputError, signals_deferred
from uavturb.io.checkpoint import read_checkpoint
from uavturb.runs.resume import LAST_CHECKPOINT

#: the best checkpoint's file name pattern (Lightning's ``filename``; ``.ckpt`` added)
BEST_FILENAME = "best-{epoch}"
#: a best checkpoint's file name, with Lightning's version suffix where a name was taken (``best-3-v1.ckpt``)
BEST_FILE = re.compile(r"best-(\d+)(?:-v\d+)?\.ckpt")


class _WholeSaves(ModelCheckpoint):
    """Lightning's ``ModelCheckpoint`` whose end-of-epoch saving a signal does not cut (held until it ends), under
    Lightning's own state key (a checkpoint written by a plain ``ModelCheckpoint`` restores into it, and back)."""

    @property
    def state_key(self) -> str:
        key = super().state_key
        return ModelCheckpoint.__qualname__ + key[len(type(self).__qualname__):]

    def on_train_epoch_end(self, trainer: Any, pl_module: Any) -> None:
        with signals_deferred():
            super().on_train_epoch_end(trainer, pl_module)

    def on_validation_end(self, trainer: Any, pl_module: Any) -> None:
        with signals_deferred():
            super().on_validation_end(trainer, pl_module)


class LatestCheckpoint(_WholeSaves):
    """Writes ``last.ckpt`` (:data:`~uavturb.runs.resume.LAST_CHECKPOINT`) at every epoch's end, whatever the
    monitored metric did. Lightning's ``save_last`` writes it only where the best checkpoint was saved too: after an
    epoch that did not improve, a run stopped by a signal resumed from the last improvement, trained the epochs
    after it again and logged their metrics a second time (validation loss 0.0342 at epoch 4, 0.0351 at epoch 5,
    ``last.ckpt`` left at epoch 4).

    Parameters
    ----------
    dirpath : the run's checkpoint folder
    """

    def __init__(self, dirpath: str | Path):
        super().__init__(dirpath=dirpath, filename=Path(LAST_CHECKPOINT).stem, monitor=None, save_top_k=1,
                         enable_version_counter=False)


class BestCheckpoint(_WholeSaves):
    """Keeps ``best-<epoch>.ckpt``, the epoch with the lowest ``monitor``, and restores only a state whose files
    exist (see the module docstring).

    Parameters
    ----------
    dirpath : the run's checkpoint folder
    monitor : the validation metric to minimise (``val/rmse_d``, ``val/loss``)
    """

    def __init__(self, dirpath: str | Path, monitor: str):
        super().__init__(dirpath=dirpath, filename=BEST_FILENAME, monitor=monitor, mode="min", save_top_k=1,
                         auto_insert_metric_name=False)

    def load_state_dict(self, state_dict: dict[str, Any]) -> None:
        """Lightning's restore of ``state_dict`` where the files it names exist; otherwise the state that the
        best checkpoint in the folder recorded of itself, or none (the callback starts afresh)."""
        if _files_exist(state_dict):
            super().load_state_dict(state_dict)
            return
        own = self._recorded_on_disk()
        if own is not None:
            super().load_state_dict(own)

    def _recorded_on_disk(self) -> dict[str, Any] | None:
        """This callback's state as recorded in the best checkpoint of its folder that loads and names itself
        (lowest score; the latest epoch among equals), or None."""
        found = []
        for path in Path(self.dirpath).glob("best-*.ckpt") if self.dirpath else []:
            match = BEST_FILE.fullmatch(path.name)
            if match is None:
                continue
            try:
                states = read_checkpoint(path).get("callbacks")
            except InputError:  # unreadable (or refused): not a checkpoint to continue from
                continue
            state = states.get(self.state_key) if isinstance(states, dict) else None
            if (isinstance(state, dict) and _same_file(state.get("best_model_path"), path)
                    and state.get("best_model_score") is not None):
                found.append((float(state["best_model_score"]), -int(match.group(1)), str(path), state))
        if not found:
            return None
        return {**min(found, key=lambda f: f[:3])[3], "dirpath": self.dirpath}


def _same_file(recorded: Any, path: Path) -> bool:
    """Whether ``recorded`` (a path a ModelCheckpoint state holds) is the file ``path``."""
    return isinstance(recorded, str) and bool(recorded) and Path(recorded).resolve() == path.resolve()


def _files_exist(state: dict[str, Any]) -> bool:
    """Whether every checkpoint file a ModelCheckpoint state names (best, top k) is there."""
    named = [state.get("best_model_path"), *(state.get("best_k_models") or {})]
    return all(Path(p).is_file() for p in named if p)


def epoch_checkpoints(dirpath: str | Path, monitor: str) -> tuple[BestCheckpoint, LatestCheckpoint]:
    """The run's checkpoint callbacks in the order Lightning must call them: the best first, then ``last.ckpt``
    (which then records the best checkpoint of its own epoch)."""
    return BestCheckpoint(dirpath, monitor), LatestCheckpoint(dirpath)
