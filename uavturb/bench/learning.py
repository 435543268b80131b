"""``uavturb bench train`` and ``uavturb bench infer``: figures of the learning pipeline.

- **train**: training throughput of :class:`~uavturb.systems.HeightModule` (windows/s and
  frames/s) on synthetic shards (:func:`uavturb.data.synthetic.make_synthetic_dataset`),
  and the *input overhead*: the ratio of the median step time (fetch + forward + backward +
  Adam) when batches come from the real
  :class:`~uavturb.data.datamodules.ShardWindowsDataModule` DataLoader (memory maps, worker
  processes) to the median step time on the very same batches already in memory, measured
  in alternating blocks of 5 steps. 1.0 means the model never waits for data; the target is
  under 1.10. On a machine shared with other jobs, step times scatter by tens of percent:
  read the ratio together with the time spent waiting for the next batch, printed too.
- **infer**: the exported streaming model (:mod:`uavturb.commands.export`) at 128 x 128 on **one CPU
  thread**: per-frame latency (batch 1, state carried; target <= 1 ms, the camera at 20 Hz
  leaves 50 ms) for the ``torch.export`` program and for ONNX Runtime, and batched throughput.
  Latency does not depend on the weights, so a freshly initialised model of the paper's
  architecture is exported unless a folder of ``uavturb export`` is given.
"""

from __future__ import annotations

import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import onnxruntime as ort
import torch
import torch.nn.functional as F

from uavturb.commands.export import ONNX_FILE, PT2_FILE, export_streaming
from uavturb.data.datamodules import ShardWindowsDataModule
from uavturb.data.synthetic import make_synthetic_dataset
from uavturb.nn.streaming import StreamingHeightModel
from uavturb.progress import progress_bar
from uavturb.systems import HeightModule


def _row(name: str, value: float, unit: str = "") -> None:
    print(f"{name:<58}{value:>12.4g}  {unit}")


def bench_train(root: str | Path | None = None, *, size: int = 64, window: int = 8, batch_size: int = 16,
                workers: tuple[int, ...] = (2, 0), steps: int = 40,
                use_gru: bool = True) -> dict[int, dict[str, float]]:
    """Training samples/s and the input-overhead ratio (see the module docstring).

    Parameters
    ----------
    root : shard dataset (default: a synthetic one in a temporary folder, removed after)
    size : image side [px] of the synthetic dataset
    window, batch_size : as ``data.*`` of the training config
    workers : DataLoader worker counts to measure (the config's default is 2)
    steps : timed optimiser steps per measurement (after one untimed block of 5)
    use_gru : model variant

    Returns
    -------
    ``{num_workers: figures}``, the printed figures.
    """

    tmp = None
    if root is None:
        tmp = tempfile.TemporaryDirectory(prefix="uavturb-bench-")
        root = Path(tmp.name) / "sim"
        n_frames = (steps + 7) * batch_size + 8 * window
        T = 64
        n_traj = max(3, -(-n_frames // (T - window + 1)) + 2)
        t0 = time.perf_counter()
        make_synthetic_dataset(root, n_scenes=max(3, n_traj // 2 + 1), trajs_per_scene=2, T=T, size=size, seed=0)
        print(f"synthetic shards: {size}x{size} px, made in {time.perf_counter() - t0:.1f} s", file=sys.stderr)
    try:
        return {nw: _bench_train_once(root, size, window, batch_size, nw, steps, use_gru) for nw in workers}
    finally:
        if tmp is not None:
            tmp.cleanup()


def _bench_train_once(root, size: int, window: int, batch_size: int, num_workers: int, steps: int,
                      use_gru: bool) -> dict[str, float]:
    dm = ShardWindowsDataModule(str(root), window=window, batch_size=batch_size, num_workers=num_workers)
    dm.setup("fit")
    torch.manual_seed(0)
    module = HeightModule(use_gru=use_gru, lr_head=1e-4, lr_encoder=1e-4)
    module.train()
    opt = torch.optim.Adam(module.parameters(), lr=1e-4)

    def step(batch) -> None:
        opt.zero_grad(set_to_none=True)
        d_hat, _ = module(batch["depth"])
        F.mse_loss(d_hat, batch["d"]).backward()
        opt.step()

    # Blocks of 5 steps, alternating: the real DataLoader (memory maps, workers; the batches
    # are kept), then the very same batches from memory. Alternating blocks cancel slow
    # drifts of the machine's load; the first block of each kind is warm-up.
    block = max(1, min(5, steps))
    n_blocks = 1 + -(-steps // block)
    it = iter(dm.train_dataloader())
    t_load: list[float] = []
    t_mem: list[float] = []
    t_fetch: list[float] = []
    bs = batch_size
    bar = progress_bar(n_blocks, f"bench train ({num_workers} workers), blocks of 5 steps DataLoader + 5 from memory",
                       "blocks")
    for blk in range(n_blocks):
        batches = []
        for _ in range(block):
            t0 = time.perf_counter()
            try:
                b = next(it)
            except StopIteration:
                it = iter(dm.train_dataloader())
                b = next(it)
            t1 = time.perf_counter()
            step(b)
            if blk > 0:
                t_load.append(time.perf_counter() - t0)
                t_fetch.append(t1 - t0)
            batches.append(b)
        for b in batches:
            t0 = time.perf_counter()
            step(b)
            if blk > 0:
                t_mem.append(time.perf_counter() - t0)
        bs = int(batches[-1]["depth"].shape[0])
        bar.update(1)
    bar.close()
    del it
    # medians: robust to the scheduling hiccups of a shared machine
    loader, memory, wait = (float(np.median(x)) for x in (t_load, t_mem, t_fetch))
    out = {"windows_per_s": bs / loader, "frames_per_s": bs * window / loader, "step_ms_dataloader": 1e3 * loader,
           "step_ms_memory": 1e3 * memory, "input_overhead_ratio": loader / memory, "wait_ms": 1e3 * wait}
    print(f"HeightModule ({'GRU' if use_gru else 'no GRU'}), {size}x{size} px, window {window}, batch {batch_size}, "
          f"{num_workers} DataLoader workers, {len(t_load)} timed steps, torch threads {torch.get_num_threads()}, "
          f"{os.cpu_count()} cores")
    _row("training throughput (windows/s)", out["windows_per_s"], "windows/s")
    _row("training throughput (frames/s)", out["frames_per_s"], "frames/s")
    _row("step time, real DataLoader (ms, median)", out["step_ms_dataloader"], "ms")
    _row("  of which waiting for the next batch (ms)", out["wait_ms"], "ms")
    _row("step time, same batches from memory (ms, median)", out["step_ms_memory"], "ms")
    _row("input overhead: DataLoader / memory (target < 1.10)", out["input_overhead_ratio"], "x")
    return out


def _latency(fn, n: int, warmup: int = 10) -> np.ndarray:
    for _ in range(warmup):
        fn()
    ts = np.empty(n)
    for k in range(n):
        t0 = time.perf_counter()
        fn()
        ts[k] = time.perf_counter() - t0
    return ts


def bench_infer(model_dir: str | Path | None = None, *, size: int = 128, frames: int = 300, batch: int = 64,
                use_gru: bool = True) -> dict[str, float]:
    """Per-frame latency on one CPU thread and batched throughput of the exported model.

    Parameters
    ----------
    model_dir : a folder written by ``uavturb export`` (default: export a fresh model of the
        paper's architecture at ``size`` px into a temporary folder)
    size : image side [px] when exporting a fresh model
    frames : timed frames for the latency
    batch : batch size of the throughput figure
    use_gru : variant of the fresh model

    Returns
    -------
    dict of the printed figures.
    """
    tmp = None
    if model_dir is None:
        tmp = tempfile.TemporaryDirectory(prefix="uavturb-bench-")
        model_dir = Path(tmp.name)
        torch.manual_seed(0)
        t0 = time.perf_counter()
        export_streaming(StreamingHeightModel(HeightModule(use_gru=use_gru).eval()).eval(), (size, size), 6,
                         model_dir)
        print(f"exported a fresh {size}x{size} model in {time.perf_counter() - t0:.1f} s", file=sys.stderr)
    threads = torch.get_num_threads()
    try:
        torch.set_num_threads(1)
        lat, thr, (H, W, N, L, S) = _time_exported(Path(model_dir), frames, batch)
    finally:
        torch.set_num_threads(threads)
        if tmp is not None:
            tmp.cleanup()
    out = {}
    print(f"exported streaming model {H}x{W} px, {N} rotors, state {L}x{S}; one CPU thread "
          f"({os.cpu_count()} cores on this machine)")
    for name, label in (("onnx", "ONNX Runtime"), ("pt2", "torch.export (.pt2)")):
        med, p90 = 1e3 * np.median(lat[name]), 1e3 * np.percentile(lat[name], 90)
        out[f"{name}_latency_ms"], out[f"{name}_latency_p90_ms"], out[f"{name}_batch_fps"] = med, p90, thr[name]
        _row(f"{label}: per-frame latency, batch 1, median (target <= 1 ms)", med, "ms")
        _row(f"{label}: per-frame latency, batch 1, 90th percentile", p90, "ms")
        _row(f"{label}: batched throughput, batch {batch}", thr[name], "frames/s")
    return out


def _time_exported(model_dir: Path, frames: int, batch: int
                   ) -> tuple[dict[str, np.ndarray], dict[str, float], tuple[int, int, int, int, int]]:
    """(per-frame latencies [s] of batch 1 with the state carried over, throughputs [frames/s] of ``batch``,
    the model's (H, W, rotors, GRU layers, state size)) of ``model.onnx`` (ONNX Runtime) and ``model.pt2``
    in ``model_dir``, on the threads torch and ONNX Runtime are given (one)."""
    program = torch.export.load(str(model_dir / PT2_FILE)).module()
    opts = ort.SessionOptions()
    opts.intra_op_num_threads, opts.inter_op_num_threads = 1, 1
    opts.execution_mode = ort.ExecutionMode.ORT_SEQUENTIAL
    sess = ort.InferenceSession(str(model_dir / ONNX_FILE), opts, providers=["CPUExecutionProvider"])
    shapes = {i.name: i.shape for i in sess.get_inputs()}
    H, W = shapes["depth"][2], shapes["depth"][3]
    N = shapes["rotor_speeds"][1]
    L, S = shapes["state"][0], shapes["state"][2]
    rng = np.random.default_rng(0)

    def inputs(B: int):
        return (rng.uniform(0.3, 6.0, (B, 1, H, W)).astype(np.float32),
                np.full((B, N), 500.0, np.float32), np.zeros((L, B, S), np.float32))

    d1, r1, s1 = inputs(1)
    feeds = {"depth": d1, "rotor_speeds": r1, "state": s1}
    state = {"onnx": s1, "pt2": torch.from_numpy(s1)}

    def onnx_step():
        feeds["state"] = state["onnx"]
        state["onnx"] = sess.run(None, feeds)[2]

    td, tr = torch.from_numpy(d1), torch.from_numpy(r1)

    def pt2_step():
        with torch.inference_mode():
            state["pt2"] = program(td, tr, state["pt2"])[2]

    lat = {"onnx": _latency(onnx_step, frames), "pt2": _latency(pt2_step, frames // 3)}
    dB, rB, sB = inputs(batch)
    fB = {"depth": dB, "rotor_speeds": rB, "state": sB}
    tB = (torch.from_numpy(dB), torch.from_numpy(rB), torch.from_numpy(sB))

    def onnx_batch():
        sess.run(None, fB)

    def pt2_batch():
        with torch.inference_mode():
            program(*tB)

    thr = {"onnx": batch / np.median(_latency(onnx_batch, 10, 2)),
           "pt2": batch / np.median(_latency(pt2_batch, 5, 1))}
    return lat, thr, (H, W, N, L, S)
