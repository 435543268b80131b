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
  ``state``; outputs ``height``, ``f_a``, ``state_out``; the dynamic batch axis is named
  ``batch``; units, ``(alpha, beta)`` and the source run in the model's metadata properties);
- ``export.json`` -- shapes, ``(alpha, beta)``, the run and checkpoint it came from, and the
  check below.

The check: on real sequences from the run's dataset (shard trajectories, test split first),
the exported program and the ONNX model are stepped frame by frame with the state carried,
and compared with the Lightning module run on the whole sequence; the largest absolute
difference (heights, f_a, final state) must not exceed ``tolerance`` (1e-5).

MLflow: the ONNX model is logged to the run as ``streaming_model`` with a signature that states
every shape (the state is ``(L, batch, S)``: batch on axis 1), an input example, and metadata
(units, ``alpha``, ``beta``, the run), and registered as :data:`REGISTERED_MODEL`; the alias
:data:`uavturb.runs.store.BEST_ALIAS` follows the version whose run has the lowest ``test/rmse_d``. Exporting the
same checkpoint with the same law again logs and registers nothing new.
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
from uavturb.io import shards
from uavturb.io.checkpoint import read_checkpoint
from uavturb.io.publish import check_output_folder, publish_folder
from uavturb.nn.height import phi_alpha_beta
from uavturb.nn.streaming import INPUT_NAMES, OUTPUT_NAMES, StreamingHeightModel
from uavturb.runs import store
from uavturb.scene.camera import CameraModel, camera_from_record
from uavturb.systems import HeightModule

PT2_FILE, ONNX_FILE, META_FILE = "model.pt2", "model.onnx", "export.json"
TOLERANCE = 1e-5
#: name of the logged model in its run, and in MLflow's model registry
MODEL_NAME, REGISTERED_MODEL = "streaming_model", "uavturb-height"
UNITS = {"depth": "m (z-depth, 0 = no data)", "rotor_speeds": "rad/s", "height": "m", "f_a": "N (vertical, world +z)",
         "state": "GRU hidden state (layers, batch, hidden); zeros at the start of a flight"}






def load_height_module(run_id: str | None = None, checkpoint: str | Path | None = None):
    """A :class:`~uavturb.systems.HeightModule` in eval mode, float32 on the CPU, from a run or a file
    (a checkpoint written on a GPU, or in bf16, loads the same)."""
    path = Path(checkpoint) if checkpoint is not None else store.run_checkpoint(run_id)
    read_checkpoint(path)  # one line for a missing, unreadable or poisoned file
    try:  # weights_only given explicitly: TORCH_FORCE_NO_WEIGHTS_ONLY_LOAD cannot turn it off
        module = HeightModule.load_from_checkpoint(str(path), map_location="cpu", weights_only=True)
    except InputError:
        raise
    except Exception as e:  # noqa: BLE001 - any unreadable checkpoint is bad input
        raise InputError(path, f"not a HeightModule checkpoint ({type(e).__name__}: {str(e)[:200]})") from None
    return module.float().eval()  # float32 on the CPU, whatever device and precision it was trained with


def model_camera(module, run: Any = None, checkpoint: str | Path | None = None) -> CameraModel:
    """The camera a height model was trained through: its checkpoint's hyperparameter ``camera``,
    else its run's tag :data:`~uavturb.runs.store.CAMERA_TAG`. Never guessed.

    Raises
    ------
    InputError : naming the checkpoint (or run) that carries no camera, or a malformed one.
    """
    where = str(checkpoint) if checkpoint is not None else f"run {run.info.run_id}" if run is not None else "model"
    record = module.hparams.get("camera")
    if record is None and run is not None and run.data.tags.get(store.CAMERA_TAG):
        try:
            record = json.loads(run.data.tags[store.CAMERA_TAG])
        except json.JSONDecodeError:
            raise InputError(f"run {run.info.run_id}", f"tag {store.CAMERA_TAG!r} is not JSON") from None
    if record is None:
        raise InputError(where, "the model carries no camera (image size, intrinsics, mount): trained before "
                                "models kept their camera, or on data whose manifest names none; train it again")
    return camera_from_record(record, where)


# --- real sequences to check against -----------------------------------------------------


@dataclass
class CheckSequence:
    """Consecutive frames of one trajectory: ``depth (T, H, W)`` [m], ``rotor_speeds (T, N)`` [rad/s]."""

    name: str
    depth: np.ndarray
    rotor_speeds: np.ndarray


def shard_sequences(root: str | Path, n: int = 2, length: int = 32) -> list[CheckSequence]:
    """Up to ``n`` sequences of ``length`` frames from a shard dataset (test split first)."""
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


def name_batch_axis(path: Path, properties: dict[str, str] | None = None) -> None:
    """Name the ONNX model's dynamic batch axis ``batch`` (the exporter writes a symbol such as ``s12``)
    and store ``properties`` as its metadata properties."""
    import onnx

    m = onnx.load(str(path))
    symbol = m.graph.input[0].type.tensor_type.shape.dim[0].dim_param
    if symbol:
        for value in [*m.graph.input, *m.graph.output, *m.graph.value_info]:
            for dim in value.type.tensor_type.shape.dim:
                if dim.dim_param == symbol:
                    dim.dim_param = "batch"
    if properties:
        onnx.helper.set_model_props(m, {k: str(v) for k, v in properties.items()})
    onnx.save(m, str(path))


def export_streaming(model: StreamingHeightModel, image_size: tuple[int, int], n_rotors: int, folder: Path,
                     properties: dict[str, str] | None = None) -> None:
    """Write ``model.pt2`` and ``model.onnx`` of ``model`` into ``folder`` (dynamic batch);
    ``properties``: the ONNX model's metadata."""
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
    name_batch_axis(folder / ONNX_FILE, properties)


def signature(model: StreamingHeightModel, image_size: tuple[int, int], n_rotors: int):
    """The MLflow signature with every shape: batch is axis 0 of the frames, axis 1 of the state."""
    H, W = image_size
    state = (model.layers, -1, model.hidden)
    return store.tensor_signature(
        inputs=[((-1, 1, H, W), "depth"), ((-1, n_rotors), "rotor_speeds"), (state, "state")],
        outputs=[((-1,), "height"), ((-1,), "f_a"), (state, "state_out")])


def _log_to_mlflow(run_id: str, folder: Path, meta: dict[str, Any], example: dict[str, np.ndarray], sig,
                   registered_name: str | None) -> dict[str, Any]:
    """Log the ONNX model (signature, input example, metadata) and register it; reuse an identical export.

    Returns ``{"model_uri", "registered_version", "reused"}``.
    """
    key = store.input_key(checkpoint_sha256=meta["checkpoint_sha256"], alpha=meta["alpha"], beta=meta["beta"],
                          registered_name=registered_name)
    metadata = {k: meta[k] for k in ("units", "alpha", "beta", "use_gru", "inputs", "outputs", "max_abs_diff")}
    metadata["run_id"] = run_id
    return store.log_onnx_model(run_id, folder / ONNX_FILE, name=MODEL_NAME, key=key, signature=sig,
                                input_example=example, metadata=metadata,
                                artifacts=[folder / PT2_FILE, folder / META_FILE], artifact_path="export",
                                metrics={store.EXPORT_DIFF: meta["max_abs_diff"]},
                                tags={"export": store.project_path(meta["out"])}, registered_name=registered_name)


def run_and_output(run_id: str | None, checkpoint: str | Path | None, out: Path, overwrite: bool,
                   hint: str = "") -> Any:
    """Check an output folder and a model source before any work; returns the MLflow run (or None).

    Raises
    ------
    InputError : ``out`` exists and ``overwrite`` is false, its parent folder is missing, or
        neither a run id nor a checkpoint is given (or the run is unknown).
    """
    check_output_folder(out, overwrite=overwrite, hint=hint)
    run = store.get_run(run_id) if run_id is not None else None
    if run is None and checkpoint is None:
        raise InputError("--run", "a run id (or a checkpoint) is needed")
    return run


def export(run_id: str | None, out: str | Path, *, checkpoint: str | Path | None = None, data: str | Path | None = None,
           alpha: float | None = None, beta: float | None = None, n_sequences: int = 2, length: int = 32,
           tolerance: float = TOLERANCE, overwrite: bool = False, log: bool = True, verbose: bool = True,
           registered_name: str | None = REGISTERED_MODEL) -> dict[str, Any]:
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
    registered_name : register the logged model under this name in MLflow's model registry
        (None: do not register)

    Returns
    -------
    dict: ``out``, ``max_abs_diff`` (worst of both formats), ``max_abs_diff_pt2``,
    ``max_abs_diff_onnx``, ``alpha``, ``beta``, ``checkpoint``, ``image_size``, ``state_shape``,
    ``mlflow`` (``model_uri``, ``registered_version``, ``reused``; None without logging).

    Raises
    ------
    InputError : unknown run, missing checkpoint or data, existing ``out``, or a check above
        ``tolerance`` (nothing is written then).
    """
    out = Path(out)
    if (alpha is None) != (beta is None):
        raise InputError("--alpha/--beta", "give both of the ground-effect law's constants, or neither")
    run = run_and_output(run_id, checkpoint, out, overwrite, hint=" (use --overwrite to replace it)")
    ckpt = Path(checkpoint) if checkpoint is not None else store.run_checkpoint(run_id)
    module = load_height_module(checkpoint=ckpt)
    camera = model_camera(module, run, checkpoint)
    if data is None:
        data = run_data_root(run) if run is not None else None
        if data is None:
            raise InputError("--data", "no dataset to check the export on (the run names no data.root)")
    seqs = shard_sequences(data, n=n_sequences, length=length)
    H, W = seqs[0].depth.shape[1:]
    if (H, W) != (camera.height, camera.width):
        raise InputError(data, f"holds {H}x{W} images but the model's camera ({camera.name}) makes "
                               f"{camera.height}x{camera.width}")
    n_rotors = seqs[0].rotor_speeds.shape[1]
    model = StreamingHeightModel(module, alpha, beta).eval()
    a, b = float(model.alpha), float(model.beta)
    properties = {"units": json.dumps(UNITS), "alpha": repr(a), "beta": repr(b), "run_id": str(run_id),
                  "use_gru": str(model.use_gru), "camera": json.dumps(camera.record())}

    with publish_folder(out, overwrite=overwrite, command="uavturb export") as tmp:
        t0 = time.perf_counter()
        export_streaming(model, (H, W), n_rotors, tmp, properties)
        t_export = time.perf_counter() - t0
        diff_pt2, diff_onnx = _check_exported(tmp, module, model, seqs)
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
        meta = {"run_id": run_id, "checkpoint": str(ckpt), "checkpoint_sha256": _sha256(ckpt), "out": str(out),
                "inputs": {"depth": [-1, 1, int(H), int(W)], "rotor_speeds": [-1, int(n_rotors)],
                           "state": [model.layers, -1, model.hidden]},
                "outputs": {"height": [-1], "f_a": [-1], "state_out": [model.layers, -1, model.hidden]},
                "units": UNITS, "use_gru": model.use_gru, "alpha": a, "beta": b, "max_abs_diff": worst,
                "max_abs_diff_pt2": diff_pt2, "max_abs_diff_onnx": diff_onnx, "tolerance": tolerance,
                "check_sequences": [s.name for s in seqs], "data": str(data), "camera": camera.record()}
        (tmp / META_FILE).write_text(json.dumps(meta, indent=2))
    logged = None
    if log and run_id is not None:
        logged = _log_export(run_id, out, meta, model, seqs[0], registered_name, verbose)
    return {"out": str(out), "max_abs_diff": worst, "max_abs_diff_pt2": diff_pt2, "max_abs_diff_onnx": diff_onnx,
            "alpha": a, "beta": b, "checkpoint": str(ckpt), "image_size": (int(H), int(W)),
            "camera": camera.record(), "state_shape": model.state_shape(1), "mlflow": logged}


def _check_exported(folder: Path, module: Any, model: StreamingHeightModel,
                    seqs: list[CheckSequence]) -> tuple[float, float]:
    """(model.pt2, model.onnx): the largest absolute difference of each, run frame by frame with the state
    carried over, to the Lightning module run on the whole sequence (heights, f_a, final state)."""
    a, b = float(model.alpha), float(model.beta)
    program = torch.export.load(str(folder / PT2_FILE)).module()
    step_pt2, step_onnx = torch_stepper(program), onnx_stepper(folder / ONNX_FILE)
    diff_pt2 = diff_onnx = 0.0
    for seq in seqs:
        ref = reference_outputs(module, seq, a, b)
        s0 = np.zeros(model.state_shape(1), np.float32)
        diff_pt2 = max(diff_pt2, max_abs_diff(ref, step_through(step_pt2, seq, s0)))
        diff_onnx = max(diff_onnx, max_abs_diff(ref, step_through(step_onnx, seq, s0)))
    return diff_pt2, diff_onnx


def _log_export(run_id: str, out: Path, meta: dict[str, Any], model: StreamingHeightModel, seq: CheckSequence,
                registered_name: str | None, verbose: bool) -> dict[str, Any]:
    """:func:`_log_to_mlflow` with two frames of ``seq`` as the input example; says what it logged."""
    H, W = seq.depth.shape[1:]
    example = {"depth": seq.depth[:2, None].astype(np.float32), "rotor_speeds": seq.rotor_speeds[:2],
               "state": np.zeros(model.state_shape(2), np.float32)}
    logged = _log_to_mlflow(run_id, out, meta, example, signature(model, (H, W), seq.rotor_speeds.shape[1]),
                            registered_name)
    if verbose:
        reg = (f", registered as {registered_name} version {logged['registered_version']}"
               if logged["registered_version"] else "")
        print(f"MLflow run {run_id}: model '{MODEL_NAME}' (ONNX, signature, input example){reg}"
              + (" -- the same export was logged before, nothing new" if logged["reused"] else ""))
    return logged


def _sha256(path: Path) -> str:
    import hashlib

    return hashlib.sha256(Path(path).read_bytes()).hexdigest()
