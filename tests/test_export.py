"""``uavturb export``: the streaming model as .pt2 and ONNX, equal to the Lightning module,
loadable in a clean process, logged to MLflow with its signature."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest
import torch
from height_run import tiny_dataset, tiny_height_run

from uavturb.commands.export import REGISTERED_MODEL, export
from uavturb.errors import InputError
from uavturb.io import shards
from uavturb.nn.height import phi_alpha_beta
from uavturb.nn.streaming import StreamingHeightModel, gru_step
from uavturb.runs.store import run_checkpoint
from uavturb.scene.camera import forward_camera
from uavturb.systems import HeightModule


@pytest.fixture(scope="module")
def store(module_mlflow_store):
    return module_mlflow_store


CLEAN_SCRIPT = r"""
import json, sys
import numpy as np, torch, onnxruntime as ort
folder, inputs, outputs = sys.argv[1:4]
x = np.load(inputs)
prog = torch.export.load(f"{folder}/model.pt2").module()
sess = ort.InferenceSession(f"{folder}/model.onnx", providers=["CPUExecutionProvider"])
res = {}
for name in ("pt2", "onnx", "pt2_reset"):
    state = x["state0"]
    d_all, fa_all = [], []
    for t in range(len(x["depth"])):
        if name == "pt2_reset":
            state = x["state0"]  # forget the memory every frame
        args = (x["depth"][t][None, None], x["rotors"][t][None], state)
        if name == "onnx":
            d, fa, state = sess.run(None, dict(zip(("depth", "rotor_speeds", "state"), args)))
        else:
            with torch.no_grad():
                d, fa, state = (v.numpy() for v in prog(*(torch.from_numpy(np.ascontiguousarray(a)) for a in args)))
        d_all.append(d[0]); fa_all.append(fa[0])
    res[f"{name}_d"], res[f"{name}_fa"], res[f"{name}_state"] = np.array(d_all), np.array(fa_all), state
# a batch of 3 frames at once (dynamic batch) through both
B = np.repeat(x["depth"][:1, None], 3, 0), np.repeat(x["rotors"][:1], 3, 0), np.repeat(x["state0"], 3, 1)
res["onnx_batch_d"] = sess.run(None, dict(zip(("depth", "rotor_speeds", "state"), B)))[0]
np.savez(outputs, **res)
print(json.dumps({"inputs": [i.name for i in sess.get_inputs()], "outputs": [o.name for o in sess.get_outputs()]}))
"""


@pytest.mark.parametrize("use_gru, keep", [(True, "artifact"),
                                           pytest.param(False, "folder", marks=pytest.mark.slow)])
def test_export_equals_module_in_clean_process(tmp_path, store, use_gru, keep):
    rid, _, data, _ = tiny_height_run(tmp_path, use_gru=use_gru, keep=keep, steps=3)
    import mlflow

    mlflow.MlflowClient(store).log_metric(rid, "test/rmse_d", 0.5 if use_gru else 0.3)  # the registry's "best"
    out = tmp_path / "exported"
    result = export(rid, out, n_sequences=1, length=12, verbose=False)
    assert result["max_abs_diff"] <= 1e-5
    assert sorted(p.name for p in out.iterdir()) == [".uavturb-output.json", "export.json", "model.onnx", "model.pt2"]
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".")] == []  # no temporary folder left
    meta = json.loads((out / "export.json").read_text())
    assert meta["use_gru"] is use_gru and meta["inputs"]["depth"] == [-1, 1, 16, 16]
    # the camera the model was trained through, from its checkpoint: the synthetic data's forward camera
    assert meta["camera"] == forward_camera(16, 16, 70.0, 45.0, frame_dt=0.05).record() == result["camera"]

    # the module exactly as load_from_checkpoint alone rebuilds it
    module = HeightModule.load_from_checkpoint(str(run_checkpoint(rid)), map_location="cpu").eval()
    tr = shards.read_trajectory(shards.read_manifest(data).folders("test")[0])
    T = 20
    depth, rotors = np.array(tr.depth[:T], np.float32), np.array(tr.rotor_speeds[:T], np.float32)
    with torch.no_grad():
        d_ref, h_ref = module(torch.from_numpy(depth)[None, :, None])
    S = (torch.from_numpy(rotors) ** 2).sum(-1)
    fa_ref = phi_alpha_beta(d_ref[0], S, module.hparams.alpha, module.hparams.beta).numpy()
    d_ref = d_ref[0].numpy()
    state0 = np.zeros((2, 1, 50) if use_gru else (1, 1, 1), np.float32)
    np.savez(tmp_path / "in.npz", depth=depth, rotors=rotors, state0=state0)

    proc = subprocess.run([sys.executable, "-c", CLEAN_SCRIPT, str(out), str(tmp_path / "in.npz"),
                           str(tmp_path / "out.npz")], capture_output=True, text=True, timeout=120, cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr[-2000:]
    names = json.loads(proc.stdout.strip().splitlines()[-1])
    assert names == {"inputs": ["depth", "rotor_speeds", "state"], "outputs": ["height", "f_a", "state_out"]}
    got = np.load(tmp_path / "out.npz")
    for fmt in ("pt2", "onnx"):
        np.testing.assert_allclose(got[f"{fmt}_d"], d_ref, rtol=0, atol=1e-5)
        np.testing.assert_allclose(got[f"{fmt}_fa"], fa_ref, rtol=0, atol=1e-5)
    np.testing.assert_allclose(got["pt2_d"], got["onnx_d"], rtol=0, atol=1e-5)
    np.testing.assert_allclose(got["onnx_batch_d"], np.repeat(got["onnx_d"][:1], 3), rtol=0, atol=1e-5)
    if use_gru:
        np.testing.assert_allclose(got["pt2_state"], h_ref.numpy(), rtol=0, atol=1e-5)
        assert np.abs(got["pt2_reset_d"] - d_ref).max() > 1e-4  # the carried state matters
    else:
        np.testing.assert_array_equal(got["pt2_state"], state0)
        np.testing.assert_allclose(got["pt2_reset_d"], d_ref, rtol=0, atol=1e-5)  # memoryless

    # logged to MLflow as a model with its signature
    import mlflow

    info = mlflow.models.get_model_info(f"runs:/{rid}/streaming_model")
    sig = info.signature.to_dict()
    assert [i["name"] for i in json.loads(sig["inputs"])] == ["depth", "rotor_speeds", "state"]
    assert [o["name"] for o in json.loads(sig["outputs"])] == ["height", "f_a", "state_out"]
    client = mlflow.MlflowClient(store)
    assert client.get_run(rid).data.metrics["export/max_abs_diff"] == pytest.approx(result["max_abs_diff"])
    _check_mlflow_model(client, rid, result, out, use_gru, depth, rotors, d_ref)


def _check_mlflow_model(client, rid, result, out, use_gru, depth, rotors, d_ref):
    """The logged model: its shapes, a batch of 3 through pyfunc, registered, metadata; the ONNX axis names."""
    import mlflow
    import onnx

    L, S = (2, 50) if use_gru else (1, 1)
    info = mlflow.models.get_model_info(f"runs:/{rid}/streaming_model")
    shapes = {i["name"]: i["tensor-spec"]["shape"] for i in json.loads(info.signature.to_dict()["inputs"])}
    assert shapes == {"depth": [-1, 1, 16, 16], "rotor_speeds": [-1, rotors.shape[1]], "state": [L, -1, S]}
    assert info.metadata["alpha"] == pytest.approx(result["alpha"]) and info.metadata["run_id"] == rid
    assert info.metadata["units"]["height"] == "m" and info.saved_input_example_info is not None
    version = result["mlflow"]["registered_version"]
    assert version is not None
    model = mlflow.pyfunc.load_model(f"models:/{REGISTERED_MODEL}/{version}")
    batch = {"depth": np.repeat(depth[:1, None], 3, 0), "rotor_speeds": np.repeat(rotors[:1], 3, 0),
             "state": np.zeros((L, 3, S), np.float32)}
    pred = model.predict(batch)  # schema enforcement passes a batch of 3
    np.testing.assert_allclose(pred["height"], np.repeat(d_ref[:1], 3), rtol=0, atol=1e-5)
    assert pred["state_out"].shape == (L, 3, S)
    # alias "best": the version whose run has the lowest test/rmse_d (the GRU run comes first, at 0.5)
    assert client.get_registered_model(REGISTERED_MODEL).aliases["best"] == version
    m = onnx.load(str(out / "model.onnx"))
    assert m.graph.input[0].type.tensor_type.shape.dim[0].dim_param == "batch"
    assert m.graph.input[2].type.tensor_type.shape.dim[1].dim_param == "batch"
    props = {p.key: p.value for p in m.metadata_props}
    assert float(props["beta"]) == pytest.approx(result["beta"]) and props["run_id"] == rid
    # the same export again logs and registers nothing new
    n_versions = len(client.search_model_versions(f"name = '{REGISTERED_MODEL}'"))
    again = export(rid, out, n_sequences=1, length=12, verbose=False, overwrite=True)
    assert again["mlflow"]["reused"] and again["mlflow"]["registered_version"] == version
    assert len(client.search_model_versions(f"name = '{REGISTERED_MODEL}'")) == n_versions
    exp_id = client.get_run(rid).info.experiment_id
    logged = mlflow.search_logged_models(experiment_ids=[exp_id], output_format="list",
                                         filter_string=f"source_run_id = '{rid}'")
    assert len(logged) == 1


def test_streaming_gru_step_is_torch_gru():
    torch.manual_seed(1)
    gru = torch.nn.GRU(5, 7, num_layers=1, batch_first=True)
    x, h = torch.randn(3, 1, 5), torch.randn(1, 3, 7)
    _, h_ref = gru(x, h)
    h_new = gru_step(x[:, 0], h[0], gru.weight_ih_l0, gru.weight_hh_l0, gru.bias_ih_l0, gru.bias_hh_l0)
    torch.testing.assert_close(h_new, h_ref[0], rtol=0, atol=1e-6)


def test_streaming_model_uses_given_law():
    torch.manual_seed(0)
    m = HeightModule(use_gru=False).eval()
    sm = StreamingHeightModel(m, alpha=2e-4, beta=1e-3).eval()
    depth, rotors = torch.rand(2, 1, 16, 16) * 3, torch.full((2, 6), 500.0)
    with torch.no_grad():
        d, fa, s = sm(depth, rotors, sm.initial_state(2))
        d_ref = m(depth[:, None])[0][:, 0]
    torch.testing.assert_close(d, d_ref, rtol=0, atol=1e-6)
    torch.testing.assert_close(fa, 2e-4 * 6 * 500.0**2 / (d**2 - 1e-3), rtol=1e-5, atol=0)
    assert s.shape == (1, 2, 1)


def test_export_bad_inputs(tmp_path, store):
    with pytest.raises(InputError, match="no run 'nope'"):
        export("nope", tmp_path / "x")
    rid, _, _, _ = tiny_height_run(tmp_path, use_gru=False, keep="tag", steps=1)
    (tmp_path / "taken").mkdir()
    (tmp_path / "taken" / "my_notes.txt").write_text("keep")
    with pytest.raises(InputError, match="not written by uavturb"):
        export(rid, tmp_path / "taken", overwrite=True)
    assert (tmp_path / "taken" / "my_notes.txt").read_text() == "keep"
    with pytest.raises(InputError, match="nothing written"):  # a check that cannot pass
        export(rid, tmp_path / "y", tolerance=-1.0, verbose=False, log=False, n_sequences=1, length=4)
    assert not (tmp_path / "y").exists()
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".")] == []
    with pytest.raises(InputError, match="manifest"):
        export(rid, tmp_path / "z", data=tmp_path / "empty", log=False)
    # a dataset of another image size than the model's camera is no check of the export
    other = tiny_dataset(tmp_path / "other", size=12)
    with pytest.raises(InputError, match="holds 12x12 images but the model's camera \\(forward\\) makes 16x16"):
        export(rid, tmp_path / "w", data=other, log=False)
    assert not (tmp_path / "w").exists()
