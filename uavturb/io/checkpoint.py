"""Model checkpoints (Lightning ``.ckpt`` files) read without running code they may carry.

A checkpoint is a pickle: loading it with ``weights_only=False`` runs whatever a poisoned file
asks for. Every checkpoint uavturb loads goes through ``weights_only=True``, given explicitly so
that torch's ``TORCH_FORCE_NO_WEIGHTS_ONLY_LOAD`` cannot turn it off; :func:`read_checkpoint`
checks a file that way before anything else happens (a run's status changes, a module is built).
"""

from __future__ import annotations

import pickle
import re
from pathlib import Path
from typing import Any

import torch

from uavturb.errors import InputError


def read_checkpoint(path: str | Path) -> dict[str, Any]:
    """The content of the checkpoint ``path`` (tensors and plain data only, on the CPU).

    Raises
    ------
    InputError : ``path`` is missing, is not a checkpoint, or holds Python objects other than
        tensors and plain data (it is refused: loading it could run code).
    """
    path = Path(path)
    if not path.is_file():
        raise InputError(path, "checkpoint not found")
    try:
        ckpt = torch.load(path, map_location="cpu", weights_only=True)
    except pickle.UnpicklingError as e:
        found = re.search(r"Unsupported global: GLOBAL ([\w.]{1,120})", str(e))  # torch's refusal names it
        if found is None:
            raise InputError(path, "cannot be read as a checkpoint (UnpicklingError)") from None
        raise InputError(path, f"refused: the checkpoint holds Python objects ({found.group(1)}) other than "
                               "tensors and plain data, and loading them could run code it carries") from None
    except Exception as e:  # noqa: BLE001 - any unreadable file is bad input
        raise InputError(path, f"cannot be read as a checkpoint ({type(e).__name__})") from None
    if not isinstance(ckpt, dict):
        raise InputError(path, f"is not a Lightning checkpoint (it holds a {type(ckpt).__name__}, not a mapping)")
    return ckpt
