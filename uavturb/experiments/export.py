"""``uavturb export``: a trained height model as a streaming model for on-board use.

The streaming model (:class:`StreamingHeightModel`) runs one camera frame at a time::

    (depth (B, 1, H, W) [m], rotor_speeds (B, N) [rad/s], state (L, B, S))
        -> (height (B,) [m], f_a (B,) [N], new_state (L, B, S))

``height`` is the network's ``d_t``, ``f_a = alpha sum_i Omega_i^2 / (d_t^2 - beta)`` the
ground-effect law of :func:`uavturb.nn.height.phi_alpha_beta` (vertical force, world ``+z``)
with the module's ``(alpha, beta)`` unless others are given (e.g. identified on the target
vehicle by ``uavturb evaluate``). With a GRU, ``state`` is the GRU's hidden state
(``L = gru_layers``, ``S = gru_hidden``; zeros at the start of a flight); without a GRU
(Table 1's "x GRU" ablation) the state is a dummy ``(1, B, 1)`` tensor passed through
unchanged, so both variants have the same interface.

The GRU is unrolled one step by hand (:func:`gru_step`, PyTorch's ``nn.GRU`` equations and
weights), which keeps both exporters on plain matrix products.

Output folder (written under a temporary name and renamed when complete):

- ``model.pt2`` -- :func:`torch.export.save` of the exported program (load it with
  :func:`torch.export.load`, call ``.module()``);
- ``model.onnx`` -- the same graph for ONNX Runtime (inputs ``depth``, ``rotor_speeds``,
  ``state``; outputs ``height``, ``f_a``, ``state_out``; the batch dimension is dynamic);
- ``export.json`` -- shapes, ``(alpha, beta)``, the run and checkpoint it came from, and the
  check below.

The check: on real sequences from the run's dataset (shard trajectories, test split first),
the exported program and the ONNX model are stepped frame by frame with the state carried,
and compared with the Lightning module run on the whole sequence; the largest absolute
difference (heights, f_a, final state) must not exceed ``tolerance`` (1e-5).
"""

from __future__ import annotations

import json
import logging
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn

from uavturb.errors import InputError
from uavturb.experiments.tracking import client as _client
from uavturb.io.publish import check_output_folder, publish_folder
from uavturb.nn.height import phi_alpha_beta
from uavturb.nn.streaming import INPUT_NAMES, OUTPUT_NAMES, StreamingHeightModel

PT2_FILE, ONNX_FILE, META_FILE = "model.pt2", "model.onnx", "export.json"
TOLERANCE = 1e-5






# --- where a run's checkpoint is ---------------------------------------------------------


def get_run(run_id: str):
    """The MLflow run ``run_id`` of the configured store; InputError naming ``--run`` if absent."""
    from mlflow.exceptions import MlflowException

    from uavturb.experiments.tracking import tracking_uri

    try:
        return _client().get_run(run_id)
    except MlflowException:
        raise InputError("--run", f"no run '{run_id}' in the MLflow store {tracking_uri()}") from None


def _artifact_ckpts(client, run_id: str, path: str | None = None, depth: int = 0) -> list[str]:
    out = []
    for a in client.list_artifacts(run_id, path):
        if a.is_dir and depth < 4:
            out += _artifact_ckpts(client, run_id, a.path, depth + 1)
        elif a.path.endswith(".ckpt"):
            out.append(a.path)
    return out


def run_checkpoint(run_id: str) -> Path:
    """The checkpoint of an MLflow training run, wherever the run keeps it.

    Looked up in order: a ``checkpoint`` tag or param holding a path that exists; a
    ``*.ckpt`` artifact of the run (downloaded; ``best*`` preferred); the folder
    :func:`uavturb.train.train` writes to, ``<trainer.default_root_dir>/checkpoints/<run_id>/``.

    Raises
    ------
    InputError : no such run, or no checkpoint found (naming where it looked).
    """
    run = get_run(run_id)
    for value in (run.data.tags.get("checkpoint"), run.data.params.get("checkpoint")):
        if value and Path(value).is_file():
            return Path(value)
    client = _client()
    arts = _artifact_ckpts(client, run_id)
    if arts:
        arts.sort(key=lambda p: (not Path(p).name.startswith("best"), p))
        import tempfile

        dst = Path(tempfile.mkdtemp(prefix="uavturb-ckpt-"))
        return Path(client.download_artifacts(run_id, arts[0], str(dst)))
    root = Path(run.data.params.get("trainer.default_root_dir", "runs"))
    folder = root / "checkpoints" / run_id
    found = sorted(folder.glob("*.ckpt"), key=lambda p: (not p.name.startswith("best"), -p.stat().st_mtime))
    if found:
        return found[0]
    raise InputError("--run", f"run {run_id} has no checkpoint (no 'checkpoint' tag, no .ckpt artifact, "
                              f"nothing in {folder})")


def load_height_module(run_id: str | None = None, checkpoint: str | Path | None = None):
    """A :class:`~uavturb.systems.HeightModule` in eval mode on the CPU, from a run or a file."""
    from uavturb.systems import HeightModule

    path = Path(checkpoint) if checkpoint is not None else run_checkpoint(run_id)
    if not path.is_file():
        raise InputError(path, "checkpoint not found")
    try:
        module = HeightModule.load_from_checkpoint(str(path), map_location="cpu")
    except InputError:
        raise
    except Exception as e:  # noqa: BLE001 - any unreadable checkpoint is bad input
        raise InputError(path, f"not a HeightModule checkpoint ({type(e).__name__}: {str(e)[:200]})") from None
    return module.eval()


# --- real sequences to check against -----------------------------------------------------


@dataclass
class CheckSequence:
    """Consecutive frames of one trajectory: ``depth (T, H, W)`` [m], ``rotor_speeds (T, N)`` [rad/s]."""

    name: str
    depth: np.ndarray
    rotor_speeds: np.ndarray


def shard_sequences(root: str | Path, n: int = 2, length: int = 32) -> list[CheckSequence]:
    """Up to ``n`` sequences of ``length`` frames from a shard dataset (test split first)."""
    from uavturb.io import shards

    root = Path(root)
    if not (root / shards.MANIFEST).is_file():
        raise InputError(root / shards.MANIFEST, "dataset manifest not found: the export is checked on real "
                                                  "sequences of the run's dataset (pass --data DIR)")
    manifest = shards.read_manifest(root)
    out: list[CheckSequence] = []
    for split in ("test", "val", "train"):
        for folder in manifest.folders(split):
            tr = shards.read_trajectory(folder)
            T = min(length, len(tr))
            out.append(CheckSequence(Path(folder).name, np.array(tr.depth[:T], np.float32),
                                np.array(tr.rotor_speeds[:T], np.float32)))
            if len(out) >= n:
                return out
    if not out:
        raise InputError(root, "dataset holds no trajectories")
    return out


def run_data_root(run) -> Path | None:
    root = run.data.params.get("data.root")
    return Path(root) if root else None


# --- checks -------------------------------------------------------------------------------


def reference_outputs(module, seq: CheckSequence, alpha: float,
                      beta: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Heights, f_a and final GRU state of the Lightning module run on the whole sequence."""
    depth = torch.from_numpy(seq.depth)[None, :, None]
    with torch.no_grad():
        d, h = module(depth)
        S = (torch.from_numpy(seq.rotor_speeds) ** 2).sum(-1)[None]
        fa = phi_alpha_beta(d, S, alpha, beta)
    state = h.numpy() if h is not None else np.zeros((1, 1, 1), np.float32)
    return d[0].numpy(), fa[0].numpy(), state


def step_through(step, seq: CheckSequence, state0: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Run ``step(depth (1,1,H,W), rotors (1,N), state) -> (d, fa, state)`` (numpy) frame by frame."""
    state = state0
    ds, fas = [], []
    for t in range(len(seq.depth)):
        d, fa, state = step(seq.depth[t][None, None], seq.rotor_speeds[t][None], state)
        ds.append(float(np.asarray(d).ravel()[0]))
        fas.append(float(np.asarray(fa).ravel()[0]))
    return np.array(ds), np.array(fas), np.asarray(state)


def torch_stepper(program: nn.Module):
    def step(depth, rotors, state):
        with torch.no_grad():
            d, fa, s = program(torch.from_numpy(np.ascontiguousarray(depth)),
                               torch.from_numpy(np.ascontiguousarray(rotors)), torch.from_numpy(state))
        return d.numpy(), fa.numpy(), s.numpy()
    return step


def onnx_stepper(path: str | Path, threads: int = 1):
    import onnxruntime as ort

    opts = ort.SessionOptions()
    opts.intra_op_num_threads = threads
    opts.inter_op_num_threads = 1
    sess = ort.InferenceSession(str(path), opts, providers=["CPUExecutionProvider"])

    def step(depth, rotors, state):
        return tuple(sess.run(list(OUTPUT_NAMES), {"depth": np.ascontiguousarray(depth, np.float32),
                                                   "rotor_speeds": np.ascontiguousarray(rotors, np.float32),
                                                   "state": np.ascontiguousarray(state, np.float32)}))
    return step


def max_abs_diff(ref: tuple[np.ndarray, ...], got: tuple[np.ndarray, ...]) -> float:
    return float(max(np.max(np.abs(np.asarray(a, np.float64) - np.asarray(b, np.float64))) for a, b in zip(ref, got)))


# --- the export ---------------------------------------------------------------------------


def export_streaming(model: StreamingHeightModel, image_size: tuple[int, int], n_rotors: int, folder: Path) -> None:
    """Write ``model.pt2`` and ``model.onnx`` of ``model`` into ``folder`` (dynamic batch)."""
    import warnings

    H, W = image_size
    B = 2  # example batch; the batch dimension is exported dynamic
    args = (torch.rand(B, 1, H, W) * 3.0, torch.full((B, n_rotors), 500.0), torch.zeros(model.state_shape(B)))
    batch = torch.export.Dim("batch", min=1, max=4096)
    dyn = {"depth": {0: batch}, "rotor_speeds": {0: batch}, "state": {1: batch}}
    model = model.eval()
    with torch.no_grad():
        ep = torch.export.export(model, args, dynamic_shapes=dyn)
    torch.export.save(ep, str(folder / PT2_FILE))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        logging.getLogger("torch.onnx").setLevel(logging.ERROR)
        import contextlib
        import io

        with contextlib.redirect_stdout(io.StringIO()):
            # the exported program itself: one trace serves both formats
            torch.onnx.export(ep, f=str(folder / ONNX_FILE), input_names=list(INPUT_NAMES),
                              output_names=list(OUTPUT_NAMES), external_data=False, verbose=False)


def _log_to_mlflow(run_id: str, folder: Path, meta: dict[str, Any], sample: dict[str, np.ndarray],
                   outputs: dict[str, np.ndarray]) -> None:
    import warnings

    import mlflow
    import onnx
    from mlflow.models import infer_signature

    from uavturb.experiments.tracking import tracking_uri

    _client()  # opens the store (created safely, stale runs marked) before the fluent API uses it
    mlflow.set_tracking_uri(tracking_uri())
    signature = infer_signature(sample, outputs)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        with mlflow.start_run(run_id=run_id):
            mlflow.onnx.log_model(onnx.load(str(folder / ONNX_FILE)), name="streaming_model", signature=signature)
            mlflow.log_artifact(str(folder / PT2_FILE), artifact_path="export")
            mlflow.log_artifact(str(folder / META_FILE), artifact_path="export")
            mlflow.log_metric("export/max_abs_diff", meta["max_abs_diff"])
            mlflow.set_tag("export", str(Path(meta["out"]).resolve()))


def run_and_output(run_id: str | None, checkpoint: str | Path | None, out: Path, overwrite: bool,
                   hint: str = "") -> Any:
    """Check an output folder and a model source before any work; returns the MLflow run (or None).

    Raises
    ------
    InputError : ``out`` exists and ``overwrite`` is false, its parent folder is missing, or
        neither a run id nor a checkpoint is given (or the run is unknown).
    """
    check_output_folder(out, overwrite=overwrite, hint=hint)
    run = get_run(run_id) if run_id is not None else None
    if run is None and checkpoint is None:
        raise InputError("--run", "a run id (or a checkpoint) is needed")
    return run


def export(run_id: str | None, out: str | Path, *, checkpoint: str | Path | None = None, data: str | Path | None = None,
           alpha: float | None = None, beta: float | None = None, n_sequences: int = 2, length: int = 32,
           tolerance: float = TOLERANCE, overwrite: bool = False, log: bool = True, verbose: bool = True
           ) -> dict[str, Any]:
    """``uavturb export``: the run's model as ``model.pt2`` and ``model.onnx``, checked and logged.

    Parameters
    ----------
    run_id : MLflow run of a height training (its checkpoint and dataset are used)
    out : output folder (created atomically; an existing one needs ``overwrite``)
    checkpoint : use this checkpoint instead of the run's (then ``run_id`` may be None)
    data : shard dataset to take the check's sequences from (default: the run's ``data.root``)
    alpha, beta : ground-effect law of the exported ``f_a`` (default: the module's)
    n_sequences, length : how many real sequences, of how many frames, the check runs on
    tolerance : largest allowed absolute difference to the Lightning module
    overwrite : replace an existing ``out``
    log : log the ONNX model (with its signature), the ``.pt2`` and the check into the run
    verbose : print the check's figures

    Returns
    -------
    dict: ``out``, ``max_abs_diff`` (worst of both formats), ``max_abs_diff_pt2``,
    ``max_abs_diff_onnx``, ``alpha``, ``beta``, ``checkpoint``, ``image_size``, ``state_shape``.

    Raises
    ------
    InputError : unknown run, missing checkpoint or data, existing ``out``, or a check above
        ``tolerance`` (nothing is written then).
    """
    out = Path(out)
    if (alpha is None) != (beta is None):
        raise InputError("--alpha/--beta", "give both of the ground-effect law's constants, or neither")
    run = run_and_output(run_id, checkpoint, out, overwrite, hint=" (use --overwrite to replace it)")
    ckpt = Path(checkpoint) if checkpoint is not None else run_checkpoint(run_id)
    module = load_height_module(checkpoint=ckpt)
    if data is None:
        data = run_data_root(run) if run is not None else None
        if data is None:
            raise InputError("--data", "no dataset to check the export on (the run names no data.root)")
    seqs = shard_sequences(data, n=n_sequences, length=length)
    H, W = seqs[0].depth.shape[1:]
    n_rotors = seqs[0].rotor_speeds.shape[1]
    model = StreamingHeightModel(module, alpha, beta).eval()
    a, b = float(model.alpha), float(model.beta)

    with publish_folder(out, overwrite=overwrite, command="uavturb export") as tmp:
        t0 = time.perf_counter()
        export_streaming(model, (H, W), n_rotors, tmp)
        t_export = time.perf_counter() - t0
        program = torch.export.load(str(tmp / PT2_FILE)).module()
        step_pt2, step_onnx = torch_stepper(program), onnx_stepper(tmp / ONNX_FILE)
        diff_pt2 = diff_onnx = 0.0
        for seq in seqs:
            ref = reference_outputs(module, seq, a, b)
            s0 = np.zeros(model.state_shape(1), np.float32)
            diff_pt2 = max(diff_pt2, max_abs_diff(ref, step_through(step_pt2, seq, s0)))
            diff_onnx = max(diff_onnx, max_abs_diff(ref, step_through(step_onnx, seq, s0)))
        worst = max(diff_pt2, diff_onnx)
        if verbose:
            frames = sum(len(s.depth) for s in seqs)
            print(f"exported in {t_export:.1f} s; checked on {len(seqs)} sequence(s), {frames} frames of {data}, "
                  f"state carried frame to frame")
            print(f"max abs difference to the Lightning module: model.pt2 {diff_pt2:.3g}, model.onnx {diff_onnx:.3g} "
                  f"(heights [m], f_a [N], final state; tolerance {tolerance:g})")
        if not worst <= tolerance:
            raise InputError(out, f"exported model differs from the Lightning module by {worst:.3g} "
                                  f"(> {tolerance:g}); nothing written")
        meta = {"run_id": run_id, "checkpoint": str(ckpt), "out": str(out), "inputs": {
                    "depth": [-1, 1, int(H), int(W)], "rotor_speeds": [-1, int(n_rotors)],
                    "state": [model.layers, -1, model.hidden]},
                "outputs": {"height": [-1], "f_a": [-1], "state_out": [model.layers, -1, model.hidden]},
                "units": {"depth": "m (z-depth, 0 = no data)", "rotor_speeds": "rad/s", "height": "m", "f_a": "N"},
                "use_gru": model.use_gru, "alpha": a, "beta": b, "max_abs_diff": worst,
                "max_abs_diff_pt2": diff_pt2, "max_abs_diff_onnx": diff_onnx, "tolerance": tolerance,
                "check_sequences": [s.name for s in seqs], "data": str(data)}
        (tmp / META_FILE).write_text(json.dumps(meta, indent=2))
    if log and run_id is not None:
        seq = seqs[0]
        sample = {"depth": seq.depth[:1, None].astype(np.float32), "rotor_speeds": seq.rotor_speeds[:1],
                  "state": np.zeros(model.state_shape(1), np.float32)}
        d, fa, s = step_pt2(sample["depth"], sample["rotor_speeds"], sample["state"])
        _log_to_mlflow(run_id, out, meta, sample, {"height": d, "f_a": fa, "state_out": s})
        if verbose:
            print(f"logged to MLflow run {run_id}: model 'streaming_model' (ONNX, with signature), export/model.pt2")
    return {"out": str(out), "max_abs_diff": worst, "max_abs_diff_pt2": diff_pt2, "max_abs_diff_onnx": diff_onnx,
            "alpha": a, "beta": b, "checkpoint": str(ckpt), "image_size": (int(H), int(W)),
            "state_shape": model.state_shape(1)}
