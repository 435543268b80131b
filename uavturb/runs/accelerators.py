"""Which device a training config runs on, checked before anything starts.

:func:`check_trainer_device` turns what Lightning would otherwise report deep inside
``Trainer(...)`` (after data was prepared and an MLflow run opened), or silently change, into
one line naming the key:

- ``trainer.accelerator=gpu`` (or ``cuda``) where torch sees no CUDA device;
- more GPUs in ``trainer.devices`` than the machine has, or a device id it lacks;
- fp16 precision (``16-mixed``, ``16-true``) on the CPU, which Lightning would quietly run
  as ``bf16-mixed``;
- bf16 precision on a GPU without bf16 (before compute capability 8.0: V100, T4).

:func:`uses_cuda` says whether a config trains on a CUDA device (DataLoader pinned memory
follows it, :func:`pin_memory`).
"""

from __future__ import annotations

import os
from typing import Any

import torch

from uavturb.errors import InputError

#: ``trainer.accelerator`` values that mean a CUDA GPU
CUDA_ACCELERATORS = ("gpu", "cuda")
#: ``trainer.precision`` values in fp16, which has no CPU autocast in Lightning
FP16_PRECISIONS = ("16-mixed", "16-true", "16")
#: ``trainer.precision`` values in bf16
BF16_PRECISIONS = ("bf16-mixed", "bf16-true", "bf16")


def cuda_device_count() -> int:
    """CUDA devices torch sees (0 on a build without CUDA or where ``CUDA_VISIBLE_DEVICES`` hides them)."""
    return int(torch.cuda.device_count()) if torch.cuda.is_available() else 0


def no_cuda_reason() -> str:
    """Why torch sees no CUDA device, in words (torch build, ``CUDA_VISIBLE_DEVICES``)."""
    build = f"torch {torch.__version__}, " + ("built without CUDA" if torch.version.cuda is None
                                              else f"CUDA {torch.version.cuda}")
    visible = os.environ.get("CUDA_VISIBLE_DEVICES")
    return build + (f", CUDA_VISIBLE_DEVICES={visible!r}" if visible is not None else "")


def uses_cuda(trainer: Any) -> bool:
    """Whether ``trainer`` (the ``trainer`` node of a training config) trains on a CUDA device."""
    accelerator = str(trainer.accelerator).lower()
    if accelerator in CUDA_ACCELERATORS:
        return True
    return accelerator == "auto" and cuda_device_count() > 0


def pin_memory(cfg: Any) -> bool:
    """DataLoader ``pin_memory`` of a training config: ``data.pin_memory`` where set, else whether it
    trains on a CUDA device (pinned host memory only helps copies to a GPU)."""
    return bool(cfg.data.pin_memory) if cfg.data.pin_memory is not None else uses_cuda(cfg.trainer)


def _devices_asked(devices: str) -> tuple[int, int] | None:
    """(number of GPUs, highest id + 1) a ``trainer.devices`` value asks for; None for auto / all."""
    devices = str(devices).strip()
    if devices in ("auto", "-1"):
        return None
    if devices.isdigit():
        return int(devices), int(devices)
    ids = [int(i) for i in devices.split(",") if i.strip()]
    return len(ids), max(ids) + 1


def check_trainer_device(trainer: Any) -> None:
    """Refuse a device or precision this machine cannot give (see the module docstring).

    Parameters
    ----------
    trainer : the ``trainer`` node of a validated training config.

    Raises
    ------
    InputError : naming ``trainer.accelerator``, ``trainer.devices`` or ``trainer.precision``.
    """
    accelerator, precision = str(trainer.accelerator).lower(), str(trainer.precision)
    if accelerator in CUDA_ACCELERATORS:
        n = cuda_device_count()
        if n == 0:
            raise InputError("trainer.accelerator", f"{accelerator} asked but no CUDA device is seen "
                                                    f"({no_cuda_reason()}); use trainer=cpu here, or a CUDA machine")
        asked = _devices_asked(trainer.devices)
        if asked is not None and asked[1] > n:
            raise InputError("trainer.devices", f"{trainer.devices!r} asks for GPU(s) this machine lacks: it has {n} "
                                                f"(ids 0-{n - 1})")
    on_cuda = uses_cuda(trainer)
    if precision in FP16_PRECISIONS and accelerator in ("cpu", "auto") and not on_cuda:
        raise InputError("trainer.precision", f"{precision}: fp16 needs a CUDA device; on the CPU use bf16-mixed "
                                              "(or 32-true)")
    if precision in BF16_PRECISIONS and on_cuda:
        if not torch.cuda.is_bf16_supported():
            raise InputError("trainer.precision", f"{precision}: this GPU ({torch.cuda.get_device_name(0)}) has no "
                                                  "bf16 (compute capability < 8.0); use 16-mixed or 32-true")
