"""``uavturb bench gpu``: the training pipeline on a CUDA device at the paper's image size, float32
and bf16 side by side.

Both stages are trained as ``uavturb train`` trains them -- the config groups ``trainer=gpu``
and ``data=shards_gpu`` (``--device cpu``: ``trainer=cpu``), the modules and memory-mapped
DataLoaders that :func:`uavturb.runs.trainer.build_stage` builds, Lightning's ``Trainer``
with :func:`~uavturb.runs.train.trainer_kwargs` -- on synthetic box rooms
(:mod:`uavturb.data.synthetic`) written as shards and pairs to a temporary folder:

- **height**: the encoder + GRU (``model=none_gru``: the encoder trains, as when fine-tuned),
  windows of ``data.window`` frames;
- **pretrain**: the depth -> normals transcoder on pairs.

Each (stage, precision) trains ``epochs`` epochs of ``steps`` batches without validation; the
first epoch is warm-up (worker start, cuDNN autotuning) and left out. A callback times each
epoch (the device synchronised at its ends) and the gaps between one batch's end and the next
one's start: the **DataLoader share** is that waiting (fetch from the workers, pinned copy to
the device) over the epoch's time. Peak GPU memory is ``torch.cuda.max_memory_allocated``.

Projections: the paper's data (358,828 frames over 68 scenes, 43 of them training; 22,705
pre-training pairs, 10 % held out) at the measured rates give an epoch time per stage, and 500
pre-training epochs take ``500 x`` the pre-training epoch. On a CUDA machine the same
pre-training and height steps are also timed on the CPU with ``cpu_threads`` torch threads
(2: this project's CPU machines) and no workers, for the comparison. ``--device cpu`` runs the
whole measurement on the CPU at a small size (the CPU reference is then its own float32 row).
"""

from __future__ import annotations

import os
import resource
import sys
import tempfile
import time
import warnings
from pathlib import Path
from typing import Any

import lightning as L
import numpy as np
import torch
from lightning.pytorch.callbacks import Callback

from uavturb.data.synthetic import make_synthetic_dataset, make_synthetic_pairs
from uavturb.errors import InputError
from uavturb.io import shards
from uavturb.runs.accelerators import check_trainer_device, cuda_device_count, no_cuda_reason
from uavturb.runs.config import PRECISIONS as ALLOWED
from uavturb.runs.config import load_config
from uavturb.runs.trainer import build_stage, quiet_lightning, set_torch_flags, trainer_kwargs

PAPER_FRAMES = 358_828          # paper: "531 trajectories along 68 scenes and a total of 358,828 samples"
PAPER_TRAIN_SHARE = 43 / 68     # 43 training scenes of 68 (frames assumed spread evenly over scenes)
PAPER_PAIRS = 22_705            # paper: pre-training on "22,705 images of the IRS dataset"
PAPER_PRETRAIN_EPOCHS = 500
PRECISIONS = ("32-true", "bf16-mixed")
STAGES = ("height", "pretrain")
#: defaults per device: image side [px], timed steps per epoch, DataLoader workers (None: the config's)
DEVICE_DEFAULTS = {"cuda": {"size": 128, "steps": 100, "workers": None},
                   "cpu": {"size": 32, "steps": 4, "workers": 0}}


def _synchronize(on_cuda: bool) -> None:
    if on_cuda:
        torch.cuda.synchronize()


def _clock(on_cuda: bool):
    """A Lightning callback timing epochs and the waits for batches (module docstring)."""
    class Clock(Callback):
        def __init__(self):
            self.epochs: list[dict[str, float]] = []

        def on_train_epoch_start(self, trainer, pl_module):
            _synchronize(on_cuda)
            self.t0 = self.t_prev = time.perf_counter()
            self.wait, self.steps, self.samples = 0.0, 0, 0

        def on_train_batch_start(self, trainer, pl_module, batch, batch_idx):
            self.wait += time.perf_counter() - self.t_prev

        def on_train_batch_end(self, trainer, pl_module, outputs, batch, batch_idx):
            self.steps += 1
            self.samples += int(batch["depth"].shape[0])
            self.t_prev = time.perf_counter()

        def on_train_epoch_end(self, trainer, pl_module):
            _synchronize(on_cuda)
            self.epochs.append({"time": time.perf_counter() - self.t0, "wait": self.wait, "steps": self.steps,
                                "samples": self.samples})

    return Clock()


def _make_data(root: Path, size: int, train_samples: int, window: int) -> tuple[Path, Path]:
    """(shards folder, pairs root) of synthetic box rooms with at least ``train_samples`` training windows
    (stride 1) and pairs; pairs beyond 256 repeat the first ones (the content does not change the speed)."""

    t0 = time.perf_counter()
    T = max(2 * window, 64 if size <= 32 else 128)
    n_train_scenes = 5  # scene_splits(7): 5 train, 1 val, 1 test
    per_scene = max(1, -(-train_samples // (n_train_scenes * (T - window + 1))))
    make_synthetic_dataset(root / "sim", n_scenes=7, trajs_per_scene=per_scene, T=T, size=size, seed=0)
    n_pairs = int(np.ceil(train_samples / 0.9)) + 2
    unique = make_synthetic_pairs(root / "unique", M=min(n_pairs, 256), size=size, seed=0)
    depth, normals, meta = shards.read_pairs(unique, mmap=False)
    reps = -(-n_pairs // len(depth))
    shards.write_pairs(root / "pairs", np.tile(depth, (reps, 1, 1))[:n_pairs],
                       np.tile(normals, (reps, 1, 1, 1))[:n_pairs], {"generator": "bench gpu (tiled)"})
    print(f"synthetic data: {size}x{size} px, {7 * per_scene} trajectories of {T} frames, {n_pairs} pairs, "
          f"made in {time.perf_counter() - t0:.1f} s", file=sys.stderr)
    return root / "sim", root / "pairs"


def _config(stage: str, device: str, precision: str, data: tuple[Path, Path], size: int, batch_size: int,
            workers: int | None, steps: int, epochs: int, runs: Path):
    groups = ["trainer=gpu", "data=shards_gpu"] if device == "cuda" else ["trainer=cpu", "data=shards"]
    overrides = [*groups, "model=none_gru", f"stage={stage}", "model.pretraining=" + ("normals" if stage == "pretrain"
                                                                                       else "none"),
                 f"data.root={data[0]}", f"data.pairs_root={data[1]}", f"data.image_size={size}",
                 f"data.batch_size={batch_size}", f"trainer.precision={precision}", f"trainer.max_epochs={epochs}",
                 f"trainer.limit_train_batches={steps}", "trainer.enable_progress_bar=false",
                 f"trainer.default_root_dir={runs}", "tracking.enabled=false", "model.lr_head=1e-4",
                 "model.lr_encoder=1e-4"]
    if workers is not None:
        overrides.append(f"data.num_workers={workers}")
    return load_config(overrides)


def measure_stage(cfg, data_root: Path, on_cuda: bool) -> dict[str, float]:
    """Train ``cfg``'s stage as configured and time it (module docstring).

    Returns
    -------
    ``samples_per_s`` (windows or pairs), ``frames_per_s`` (height: frames through the encoder), ``step_ms``,
    ``dataloader_share`` [0-1], ``epoch_s`` (an epoch of the timed steps), ``peak_memory_mb`` (GPU:
    allocated by torch; CPU: the process's peak resident memory so far).
    """
    quiet_lightning()
    set_torch_flags(cfg.trainer)
    L.seed_everything(cfg.trainer.seed, workers=True, verbose=False)
    module, dm, callbacks, _ = build_stage(cfg, data_root)
    clock = _clock(on_cuda)
    kwargs = {**trainer_kwargs(cfg.trainer), "limit_val_batches": 0, "num_sanity_val_steps": 0}
    trainer = L.Trainer(**kwargs, callbacks=[*callbacks, clock], logger=False, enable_checkpointing=False,
                        enable_progress_bar=False, enable_model_summary=False)
    if on_cuda:
        torch.cuda.reset_peak_memory_stats()
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=r".*(does not have many workers|number of training batches).*")
        trainer.fit(module, datamodule=dm)
    timed = clock.epochs[1:] or clock.epochs  # the first epoch warms up
    t, wait = sum(e["time"] for e in timed), sum(e["wait"] for e in timed)
    samples, steps = sum(e["samples"] for e in timed), sum(e["steps"] for e in timed)
    memory = (torch.cuda.max_memory_allocated() / 2**20 if on_cuda
              else resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024)  # Linux: KiB
    out = {"samples_per_s": samples / t, "step_ms": 1e3 * t / steps, "dataloader_share": wait / t,
           "epoch_s": float(np.median([e["time"] for e in timed])), "peak_memory_mb": memory}
    if cfg.stage == "height":
        out["frames_per_s"] = samples * cfg.data.window / t
    return out


def _paper_epoch_s(stage: str, samples_per_s: float) -> float:
    """Seconds of one training epoch over the paper's data at ``samples_per_s`` (windows at stride 1 ~ frames)."""
    n = PAPER_FRAMES * PAPER_TRAIN_SHARE if stage == "height" else PAPER_PAIRS * 0.9
    return n / samples_per_s


def _cpu_reference(data: tuple[Path, Path], size: int, batch_size: int, steps: int, threads: int,
                   runs: Path) -> dict[str, dict[str, float]]:
    """Float32 figures of both stages on the CPU with ``threads`` torch threads and no workers."""
    before = torch.get_num_threads()
    try:
        out = {}
        for stage in STAGES:
            cfg = _config(stage, "cpu", "32-true", data, size, batch_size, 0, steps, 2, runs)
            cfg.trainer.num_threads = threads
            out[stage] = measure_stage(cfg, data[0] if stage == "height" else data[1], False)
        return out
    finally:
        torch.set_num_threads(before)


def _device_line(device: str) -> str:
    where = torch.cuda.get_device_name(0) if device == "cuda" else f"CPU, {torch.get_num_threads()} torch threads"
    return f"{where}; torch {torch.__version__}, Lightning {L.__version__}, {os.cpu_count()} cores"


def bench_gpu(device: str = "cuda", *, size: int | None = None, batch_size: int = 16, workers: int | None = None,
              steps: int | None = None, epochs: int = 3, precisions: tuple[str, ...] = PRECISIONS,
              cpu_threads: int = 2, cpu_steps: int = 6) -> dict[str, Any]:
    """Measure and print the training figures of both stages per precision (module docstring).

    Parameters
    ----------
    device : ``cuda`` (refused in one line where torch sees no CUDA device) or ``cpu``.
    size : image side [px] (default 128 on CUDA, 32 on the CPU).
    batch_size : windows or pairs per batch (the configs' 16).
    workers : DataLoader workers (default: ``data=shards_gpu``'s on CUDA, 0 on the CPU).
    steps : timed batches per epoch (>= 2; default 100 on CUDA, 4 on the CPU).
    epochs : epochs per measurement, the first one warm-up (>= 2).
    precisions : ``trainer.precision`` values to compare.
    cpu_threads, cpu_steps : the CPU reference on a CUDA machine (threads, batches per epoch).

    Returns
    -------
    ``{"device": str, "figures": {(stage, precision): figures}, "cpu": {stage: figures}, "skipped":
    {precision: reason}}``; figures: those of :func:`measure_stage`, ``paper_epoch_s``, ``speedup_vs_cpu``
    and (pretrain) ``paper_500_epochs_h``.

    Raises
    ------
    InputError : ``device`` is cuda and no CUDA device is seen, or a size, count or precision is bad.
    """

    size, steps, workers = _settings(device, size, steps, workers, epochs, batch_size, cpu_threads, precisions)
    on_cuda = device == "cuda"
    out: dict[str, Any] = {"device": _device_line(device), "figures": {}, "cpu": {}, "skipped": {}}
    with tempfile.TemporaryDirectory(prefix="uavturb-bench-gpu-") as tmp:
        data = _make_data(Path(tmp), size, steps * batch_size, 8)
        for precision in precisions:
            for stage in STAGES:
                cfg = _config(stage, device, precision, data, size, batch_size, workers, steps, epochs,
                              Path(tmp) / "runs")
                try:
                    check_trainer_device(cfg.trainer)
                except InputError as e:  # e.g. bf16 on a V100: the other precisions are still measured
                    out["skipped"][precision] = e.problem
                    break
                print(f"bench gpu: {stage}, {precision} ...", file=sys.stderr, flush=True)
                out["figures"][(stage, precision)] = measure_stage(cfg, data[0] if stage == "height" else data[1],
                                                                   on_cuda)
        if on_cuda:
            print(f"bench gpu: CPU reference, {cpu_threads} threads ...", file=sys.stderr, flush=True)
            out["cpu"] = _cpu_reference(data, size, batch_size, cpu_steps, cpu_threads, Path(tmp) / "runs-cpu")
        else:  # the float32 row (else the first precision measured) is the reference
            measured = list(dict.fromkeys(p for _, p in out["figures"]))
            ref = "32-true" if "32-true" in measured else next(iter(measured), None)
            out["cpu"] = {s: f for (s, p), f in out["figures"].items() if p == ref}
    _add_projections(out)
    _print(out, size, batch_size, workers, cpu_threads, on_cuda)
    return out


def _settings(device: str, size: int | None, steps: int | None, workers: int | None, epochs: int, batch_size: int,
              cpu_threads: int, precisions: tuple[str, ...]) -> tuple[int, int, int | None]:
    """(size, steps, workers) of :func:`bench_gpu`, the device's defaults filled in; InputError naming the
    option that is bad, or ``--device`` where no CUDA device is seen."""

    if device not in DEVICE_DEFAULTS:
        raise InputError("--device", f"{device!r}: choose cuda or cpu")
    if device == "cuda" and cuda_device_count() == 0:
        raise InputError("--device", f"no CUDA device is seen ({no_cuda_reason()}); run this on a CUDA machine, "
                                     "or add --device cpu for the same measurement, small, on the CPU")
    size = size or DEVICE_DEFAULTS[device]["size"]
    steps = steps or DEVICE_DEFAULTS[device]["steps"]
    workers = workers if workers is not None else DEVICE_DEFAULTS[device]["workers"]
    for name, value, low in (("--size", size, 8), ("--steps", steps, 2), ("--epochs", epochs, 2),
                             ("--batch-size", batch_size, 1), ("--cpu-threads", cpu_threads, 1),
                             ("--workers", 0 if workers is None else workers, 0)):
        if value < low:
            raise InputError(name, f"{value} is too small; at least {low}")
    bad = [p for p in precisions if p not in ALLOWED]
    if bad or not precisions:
        raise InputError("--precision", f"{bad[0] if bad else ''!r}: one of {', '.join(ALLOWED)}")
    return size, steps, workers


def _add_projections(out: dict[str, Any]) -> None:
    """``paper_epoch_s``, ``speedup_vs_cpu`` and (pretrain) ``paper_500_epochs_h`` into every figures dict."""
    for stage, f in [*((s, f) for (s, _), f in out["figures"].items()), *out["cpu"].items()]:
        f["paper_epoch_s"] = _paper_epoch_s(stage, f["samples_per_s"])
        f["speedup_vs_cpu"] = f["samples_per_s"] / out["cpu"][stage]["samples_per_s"]
        if stage == "pretrain":
            f["paper_500_epochs_h"] = PAPER_PRETRAIN_EPOCHS * f["paper_epoch_s"] / 3600


#: (key, label, unit) of the printed rows
ROWS = (("samples_per_s", "training throughput (windows or pairs /s)", "1/s"),
        ("frames_per_s", "frames through the encoder /s", "1/s"),
        ("step_ms", "step time (ms)", "ms"),
        ("dataloader_share", "DataLoader share of the epoch (waiting for batches)", "-"),
        ("epoch_s", "epoch of the timed steps (s)", "s"),
        ("peak_memory_mb", "peak memory (MB; GPU: torch allocated, CPU: process RSS)", "MB"),
        ("paper_epoch_s", "projected epoch on the paper's data (s)", "s"),
        ("paper_500_epochs_h", "projected 500 pre-training epochs (h)", "h"),
        ("speedup_vs_cpu", "speed-up over the CPU reference", "x"))


def _print(out: dict[str, Any], size: int, batch_size: int, workers: int | None, cpu_threads: int,
           on_cuda: bool) -> None:
    """The figures as a table: one column per precision (and the CPU reference on CUDA), one block per stage."""
    precisions = list(dict.fromkeys(p for _, p in out["figures"]))
    columns = [(p, lambda stage, p=p: out["figures"].get((stage, p), {})) for p in precisions]
    if on_cuda:
        columns.append((f"CPU {cpu_threads} thr", lambda stage: out["cpu"].get(stage, {})))
    print(f"{out['device']}; {size}x{size} px, batch {batch_size}, window 8, DataLoader workers "
          f"{'as data=shards_gpu' if workers is None else workers}"
          + (f"; CPU reference: 32-true, {cpu_threads} torch threads, 0 workers" if on_cuda else ""))
    for stage in STAGES:
        name = "height: encoder + GRU (windows)" if stage == "height" else "pretrain: transcoder (pairs)"
        print(f"{name:<62}" + "".join(f"{c:>14}" for c, _ in columns))
        for key, label, _ in ROWS:
            vals = [get(stage).get(key) for _, get in columns]
            if any(v is not None for v in vals):
                print(f"  {label:<60}" + "".join(f"{v:>14.4g}" if v is not None else f"{'-':>14}" for v in vals))
    for precision, why in out["skipped"].items():
        print(f"skipped {precision}: {why}")
