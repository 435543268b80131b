"""The GPU path, as far as a machine without one can check it: device and precision choices refused in
one line before anything starts, pinned memory only for a CUDA device, bf16 mixed precision trained
on the CPU and reloaded and exported with the parity check, a checkpoint written on a GPU (storages
tagged cuda:0) reloaded on the CPU, and ``uavturb bench gpu`` (refused without CUDA; its figures with
``--device cpu``)."""

from __future__ import annotations

import contextlib
import math

import pytest
import torch

from uavturb.cli import main
from uavturb.errors import InputError
from uavturb.runs import accelerators
from uavturb.runs.config import load_config

no_cuda = pytest.mark.skipif(torch.cuda.is_available(), reason="checks the refusal on a machine without CUDA")


def _tiny(tmp_path, *extra):
    return [f"data.root={tmp_path / 'sim'}", f"data.pairs_root={tmp_path / 'pre'}", "data.image_size=16",
            "data.window=4", "data.batch_size=8", "data.num_workers=0", "data.synthetic.enabled=true",
            "data.synthetic.n_scenes=3", "data.synthetic.trajs_per_scene=1", "data.synthetic.T=24",
            "data.synthetic.pairs=24", f"trainer.default_root_dir={tmp_path / 'runs'}",
            "trainer.enable_progress_bar=false", "model=none_gru", "tracking.experiment=test", *extra]


@pytest.mark.parametrize("override, hint", [
    ("trainer.precision=bf16mixed", "(did you mean 'bf16-mixed'?)"),
    ("trainer.precision=16_mixed", "(did you mean '16-mixed'?)"),
    ("trainer.accelerator=GPU", "(did you mean 'gpu'?)"),
    ("trainer.accelerator=cdua", "(did you mean 'cuda'?)"),
    ("trainer.matmul_precision=hihg", "(did you mean 'high'?)"),
])
def test_device_and_precision_typos_fail_in_one_line_with_the_likely_choice(tmp_path, monkeypatch, capsys,
                                                                              override, hint):
    monkeypatch.setenv("MLFLOW_TRACKING_URI", f"sqlite:///{tmp_path / 'mlflow.db'}")
    assert main(["train", *_tiny(tmp_path), override]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and err.endswith(hint)
    assert err.startswith(f"uavturb train: error: {override.split('=')[0]}: ") and "is not allowed" in err
    assert not (tmp_path / "mlflow.db").exists() and not (tmp_path / "sim").exists()


def test_a_value_far_from_every_choice_gets_no_guess():
    with pytest.raises(InputError) as e:
        load_config(["trainer.precision=quantum"])
    assert "did you mean" not in e.value.problem and "bf16-mixed" in e.value.problem


@no_cuda
@pytest.mark.parametrize("override", ["trainer=gpu", "trainer.accelerator=cuda", "trainer=ddp"])
def test_gpu_without_a_cuda_device_is_refused_before_any_run(tmp_path, monkeypatch, capsys, override):
    monkeypatch.setenv("MLFLOW_TRACKING_URI", f"sqlite:///{tmp_path / 'mlflow.db'}")
    assert main(["train", *_tiny(tmp_path), override]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1
    assert err.startswith("uavturb train: error: trainer.accelerator: ") and "no CUDA device is seen" in err
    assert f"torch {torch.__version__}" in err and "trainer=cpu" in err
    assert not (tmp_path / "mlflow.db").exists() and not (tmp_path / "sim").exists()  # no run, no data


@no_cuda
def test_the_sweeps_gpu_preset_is_refused_before_its_parent_run(tmp_path, monkeypatch, capsys):
    import mlflow

    uri = f"sqlite:///{tmp_path / 'mlflow.db'}"
    monkeypatch.setenv("MLFLOW_TRACKING_URI", uri)
    assert main(["sweep", "ablation", "--preset", "gpu", "--mlflow-experiment", "never-made"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and err.startswith("uavturb sweep: error: trainer.accelerator: gpu asked")
    if (tmp_path / "mlflow.db").exists():
        assert mlflow.MlflowClient(uri).get_experiment_by_name("never-made") is None


def test_gpu_counts_fp16_on_the_cpu_and_bf16_on_old_gpus_are_refused(monkeypatch):
    gpu = load_config(["trainer=gpu", "trainer.devices=2"]).trainer
    monkeypatch.setattr(accelerators, "cuda_device_count", lambda: 1)
    with pytest.raises(InputError) as e:
        accelerators.check_trainer_device(gpu)
    assert e.value.where == "trainer.devices" and "it has 1 (ids 0-0)" in e.value.problem
    with pytest.raises(InputError, match="lacks"):
        accelerators.check_trainer_device(load_config(["trainer=gpu", "trainer.devices=0,3"]).trainer)
    monkeypatch.setattr(torch.cuda, "is_bf16_supported", lambda *a, **k: False)
    monkeypatch.setattr(torch.cuda, "get_device_name", lambda *a, **k: "Tesla V100")
    with pytest.raises(InputError) as e:
        accelerators.check_trainer_device(load_config(["trainer=gpu"]).trainer)  # bf16-mixed
    assert e.value.where == "trainer.precision" and "Tesla V100" in e.value.problem and "16-mixed" in e.value.problem
    accelerators.check_trainer_device(load_config(["trainer=gpu", "trainer.precision=16-mixed"]).trainer)
    accelerators.check_trainer_device(load_config(["trainer=gpu", "trainer.precision=32-true"]).trainer)

    monkeypatch.setattr(accelerators, "cuda_device_count", lambda: 0)
    for precision in ("16-mixed", "16-true"):
        for accelerator in ("cpu", "auto"):
            with pytest.raises(InputError) as e:
                accelerators.check_trainer_device(load_config([f"trainer.accelerator={accelerator}",
                                                               f"trainer.precision={precision}"]).trainer)
            assert e.value.where == "trainer.precision" and "bf16-mixed" in e.value.problem
    accelerators.check_trainer_device(load_config(["trainer=cpu", "trainer.precision=bf16-mixed"]).trainer)


def test_pinned_memory_follows_the_device_unless_set(monkeypatch):
    monkeypatch.setattr(accelerators, "cuda_device_count", lambda: 0)
    assert accelerators.pin_memory(load_config(["trainer=gpu", "data=shards_gpu"])) is True
    assert accelerators.pin_memory(load_config(["trainer=gpu"])) is True
    assert accelerators.pin_memory(load_config(["trainer=cpu"])) is False
    assert accelerators.pin_memory(load_config(["trainer=default"])) is False  # auto, no CUDA: the CPU
    assert accelerators.pin_memory(load_config(["trainer=cpu", "data.pin_memory=true"])) is True
    assert accelerators.pin_memory(load_config(["trainer=gpu", "data.pin_memory=false"])) is False
    monkeypatch.setattr(accelerators, "cuda_device_count", lambda: 2)
    assert accelerators.pin_memory(load_config(["trainer=default"])) is True  # auto picks the GPU


def test_the_gpu_groups_say_what_they_set():
    cfg = load_config(["trainer=gpu", "data=shards_gpu"])
    t, d = cfg.trainer, cfg.data
    assert (t.accelerator, t.devices, t.precision, t.cudnn_benchmark) == ("gpu", "1", "bf16-mixed", True)
    assert (d.image_size, d.window, d.batch_size, d.pin_memory) == (128, 8, 16, True) and d.num_workers >= 2
    from uavturb.runs.trainer import trainer_kwargs

    kw = trainer_kwargs(t)
    assert (kw["accelerator"], kw["devices"], kw["precision"], kw["benchmark"]) == ("gpu", 1, "bf16-mixed", True)


@contextlib.contextmanager
def _storages_tagged_cuda():
    """torch.save writes every storage's location as ``cuda:0``, as on a GPU (on this CPU machine)."""
    entry = (0, lambda storage: "cuda:0", lambda storage, location: None)
    torch.serialization._package_registry.insert(0, entry)
    try:
        yield
    finally:
        torch.serialization._package_registry.remove(entry)


def test_bf16_mixed_training_on_the_cpu_reloads_and_exports_like_float32(tmp_path):
    import numpy as np

    from uavturb.commands.export import export, load_height_module
    from uavturb.runs.train import train

    cfg = load_config(_tiny(tmp_path, "trainer=cpu", "trainer.precision=bf16-mixed", "trainer.max_epochs=2",
                            "trainer.limit_train_batches=4", "tracking.enabled=false", "model.lr_head=3e-3",
                            "model.lr_encoder=3e-3"))
    out = train(cfg)
    for key in ("val/rmse_d", "test/rmse_d", "test/rmse_fa"):
        assert math.isfinite(out["metrics"][key]) and out["metrics"][key] > 0, key
    ckpt = torch.load(out["checkpoint"], map_location="cpu", weights_only=False)
    weights = [v for k, v in ckpt["state_dict"].items() if v.is_floating_point()]
    assert weights and all(v.dtype == torch.float32 for v in weights)  # mixed precision keeps float32 weights

    # the same checkpoint as a GPU writes it: plain torch.load fails on this machine, the loader does not
    gpu_ckpt = tmp_path / "gpu-trained.ckpt"
    with _storages_tagged_cuda():
        torch.save(ckpt, gpu_ckpt)
    if not torch.cuda.is_available():
        with pytest.raises(RuntimeError, match="CUDA"):
            torch.load(gpu_ckpt, weights_only=False)
    module = load_height_module(checkpoint=gpu_ckpt)
    assert next(module.parameters()).device.type == "cpu"
    assert all(p.dtype == torch.float32 for p in module.parameters())
    reference = load_height_module(checkpoint=out["checkpoint"])
    x = torch.rand(2, 5, 1, 16, 16) * 4
    with torch.no_grad():
        assert torch.equal(module(x)[0], reference(x)[0])
        with torch.autocast("cpu", dtype=torch.bfloat16):  # heights leave the head in float32 under autocast
            d_bf16, _ = module(x)
    assert d_bf16.dtype == torch.float32 and np.allclose(d_bf16, reference(x)[0].detach(), atol=0.1)

    res = export(None, tmp_path / "exported", checkpoint=gpu_ckpt, data=tmp_path / "sim", n_sequences=1, length=12,
                 log=False, verbose=False)
    assert res["max_abs_diff"] <= 1e-5 and res["image_size"] == (16, 16)

    # the DataLoaders train() builds pin memory as the config says (the CPU: no)
    from uavturb.runs.trainer import build_stage

    for extra, pinned in (([], False), (["data.pin_memory=true"], True)):
        _, dm, _, _ = build_stage(load_config(_tiny(tmp_path, "trainer=cpu", *extra)), tmp_path / "sim")
        dm.setup("fit")
        assert dm.train_dataloader().pin_memory is pinned and dm.test_dataloader().pin_memory is pinned


def test_a_gpu_written_pretraining_checkpoint_initialises_an_encoder_on_the_cpu(tmp_path):
    from uavturb.systems import HeightModule, TranscoderModule
    from uavturb.systems.height import load_encoder_state

    torch.manual_seed(0)
    transcoder = TranscoderModule()
    path = tmp_path / "pretrain-gpu.ckpt"
    with _storages_tagged_cuda():
        torch.save({"state_dict": transcoder.state_dict()}, path)
    state = load_encoder_state(path)
    assert all(v.device.type == "cpu" for v in state.values())
    module = HeightModule(encoder_ckpt=str(path))
    for k, v in transcoder.encoder.state_dict().items():
        assert torch.equal(module.encoder.state_dict()[k], v), k


@no_cuda
def test_bench_gpu_without_cuda_is_one_line(capsys):
    assert main(["bench", "gpu"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and err.startswith("uavturb bench: error: --device: no CUDA device is seen")
    assert "--device cpu" in err
    assert main(["bench", "physics", "--device", "cpu"]) == 2
    assert capsys.readouterr().err.strip() == "uavturb bench: error: --device: only with TARGET gpu"


def test_bench_gpu_on_the_cpu_prints_every_figure_for_both_precisions(capsys):
    from uavturb.bench.gpu import PAPER_PRETRAIN_EPOCHS, PRECISIONS, STAGES, bench_gpu

    res = bench_gpu("cpu", size=16, batch_size=4, steps=2, epochs=2)
    assert set(res["figures"]) == {(s, p) for s in STAGES for p in PRECISIONS} and not res["skipped"]
    for (stage, precision), f in res["figures"].items():
        keys = {"samples_per_s", "step_ms", "dataloader_share", "epoch_s", "peak_memory_mb", "paper_epoch_s",
                "speedup_vs_cpu"} | ({"frames_per_s"} if stage == "height" else {"paper_500_epochs_h"})
        assert set(f) == keys, (stage, precision)
        assert all(math.isfinite(v) and v > 0 for k, v in f.items() if k != "dataloader_share")
        assert 0 <= f["dataloader_share"] < 1
        # the figures agree with one another: 2 steps of 4 samples per timed epoch
        assert f["samples_per_s"] == pytest.approx(4 / (f["step_ms"] / 1e3))
        if stage == "height":
            assert f["frames_per_s"] == pytest.approx(8 * f["samples_per_s"])
        else:
            assert f["paper_500_epochs_h"] == pytest.approx(PAPER_PRETRAIN_EPOCHS * f["paper_epoch_s"] / 3600)
    assert res["cpu"]["pretrain"] is res["figures"][("pretrain", "32-true")]  # the CPU reference is itself
    assert res["figures"][("height", "32-true")]["speedup_vs_cpu"] == pytest.approx(1.0)
    out = capsys.readouterr().out
    assert "32-true" in out and "bf16-mixed" in out and "projected 500 pre-training epochs (h)" in out
    with pytest.raises(InputError, match="--steps"):
        bench_gpu("cpu", steps=1)
    with pytest.raises(InputError, match="--precision"):
        bench_gpu("cpu", precisions=("bf16mixed",))
