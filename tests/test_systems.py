"""LightningModules and the freeze-then-fine-tune callback."""

from __future__ import annotations

import lightning as L
import pytest
import torch

from uavturb.errors import InputError
from uavturb.systems import (
    FreezeThenFinetune,
    HeightModule,
    TranscoderModule,
    transcoding_loss,
)


def _unit(x):
    return torch.nn.functional.normalize(x, dim=1)


def test_transcoding_loss_zero_iff_perfect():
    torch.manual_seed(0)
    n = _unit(torch.randn(2, 3, 16, 16))
    assert transcoding_loss(n, n.clone(), lam=1e4).item() == 0.0
    other = _unit(n + 0.1 * torch.randn_like(n))
    assert transcoding_loss(other, n, lam=1e4).item() > 0
    # a constant shift hides from the gradient term but not from the pixel term
    assert transcoding_loss(n + 0.01, n, lam=0.0).item() == pytest.approx(0.0, abs=1e-10)
    assert transcoding_loss(n + 0.01, n, lam=1.0).item() > 0
    # the gradient term alone sees edges
    smooth = torch.zeros(1, 1, 8, 8)
    edge = smooth.clone()
    edge[..., 4:] = 1.0
    assert transcoding_loss(edge, smooth, lam=0.0).item() > 0


@pytest.mark.parametrize("target", ["normals", "depth"])
def test_transcoder_forward_and_step(target):
    module = TranscoderModule(target=target)
    depth = torch.rand(2, 1, 32, 32) * 5
    out = module(depth)
    assert out.shape == (2, 3 if target == "normals" else 1, 32, 32)
    y = _unit(torch.randn(2, 3, 32, 32)) if target == "normals" else depth
    loss = module.training_step({"depth": depth, "target": y}, 0)
    assert loss.ndim == 0 and loss.item() > 0


def _batch(B=2, T=5, size=16):
    return {"depth": torch.rand(B, T, 1, size, size) * 3, "d": torch.rand(B, T) + 0.1,
            "fa": torch.rand(B, T) * 1e-4, "sum_omega2": torch.full((B, T), 9e4)}


class _Loader(torch.utils.data.Dataset):
    def __init__(self, n=4):
        self.items = [{k: v[0] for k, v in _batch(B=1).items()} for _ in range(n)]

    def __len__(self):
        return len(self.items)

    def __getitem__(self, i):
        return self.items[i]


def _trainer(tmp_path, **kw):
    return L.Trainer(default_root_dir=tmp_path, accelerator="cpu", devices=1, logger=False, enable_progress_bar=False,
                     enable_model_summary=False, enable_checkpointing=False, **kw)


@pytest.mark.parametrize("use_gru", [True, False])
def test_height_module_checkpoint_round_trip(tmp_path, use_gru):
    module = HeightModule(use_gru=use_gru, lr_head=1e-3, lr_encoder=1e-3)
    dl = torch.utils.data.DataLoader(_Loader(), batch_size=2)
    trainer = _trainer(tmp_path, max_steps=2)
    trainer.fit(module, train_dataloaders=dl)
    path = tmp_path / "m.ckpt"
    trainer.save_checkpoint(path)
    again = HeightModule.load_from_checkpoint(path)
    assert again.hparams.use_gru == use_gru and again.hparams.lr_head == 1e-3
    x = _batch()["depth"]
    module.eval()
    again.eval()
    with torch.no_grad():
        torch.testing.assert_close(again(x)[0], module(x)[0], rtol=0, atol=0)


def test_height_module_loads_pretrained_encoder(tmp_path):
    pre = TranscoderModule(target="normals")
    trainer = _trainer(tmp_path, max_steps=0)
    trainer.strategy.connect(pre)
    trainer.save_checkpoint(tmp_path / "pre.ckpt")
    module = HeightModule(encoder_ckpt=str(tmp_path / "pre.ckpt"))
    for (k, a), (_, b) in zip(module.encoder.state_dict().items(), pre.encoder.state_dict().items()):
        torch.testing.assert_close(a, b, msg=k)
    assert module.hparams.encoder_ckpt is None and module.hparams.pretrained_from.endswith("pre.ckpt")
    with pytest.raises(InputError, match="not found"):
        HeightModule(encoder_ckpt=str(tmp_path / "missing.ckpt"))
    torch.save({"state_dict": {"head.x": torch.zeros(1)}}, tmp_path / "bad.ckpt")
    with pytest.raises(InputError, match="encoder"):
        HeightModule(encoder_ckpt=str(tmp_path / "bad.ckpt"))


def test_height_module_metrics_names():
    module = HeightModule()
    logged = {}
    module.log = lambda name, value, **kw: logged.setdefault(name, value)
    module.validation_step(_batch(), 0)
    assert {"val/loss", "val/rmse_d", "val/rmse_fa"} <= set(logged)


def test_law_weighted_loss_known_answer():
    """``law_weighted``: squared errors weighted by ``1 + (phi'/g_ref)^2``, normalised by the weights;
    ``height``: the plain mean; the weights come from the true heights (1 where the law is clipped)."""
    from uavturb.nn import phi_alpha_beta_slope

    alpha, beta = 1.0686e-8, 1.25e-3
    module = HeightModule(alpha=alpha, beta=beta, loss="law_weighted", law_weight_ref=2.0)
    d_true = torch.tensor([[0.02, 0.16, 0.30, 1.20]])
    d_hat = d_true + torch.tensor([[0.05, 0.01, -0.02, 0.10]])
    S = torch.full((1, 4), 6 * 413.0**2)
    g = phi_alpha_beta_slope(d_true, S, alpha, beta)[0]
    w = 1 + (g / 2.0) ** 2
    assert w[0] == 1 and w[1] > 9 and w[3] < 1.001  # clipped; near the floor; far from it
    e2 = torch.tensor([0.05, 0.01, 0.02, 0.10]) ** 2
    torch.testing.assert_close(module.height_loss(d_hat, d_true, S), (w * e2).sum() / w.sum())
    plain = HeightModule(alpha=alpha, beta=beta)
    torch.testing.assert_close(plain.height_loss(d_hat, d_true, S), e2.mean())
    last = HeightModule(alpha=alpha, beta=beta, loss="law_weighted", loss_frames="last")
    torch.testing.assert_close(last.height_loss(d_hat, d_true, S), e2[-1])  # one frame: its own weight cancels
    with pytest.raises(InputError, match="model.loss"):
        HeightModule(loss="fa")
    with pytest.raises(InputError, match="model.law_weight_ref"):
        HeightModule(loss="law_weighted", law_weight_ref=0.0)


def test_config_losses_are_the_modules():
    import dataclasses

    from uavturb.runs.config import ModelConfig
    from uavturb.systems.height import LOSSES

    field = {f.name: f for f in dataclasses.fields(ModelConfig)}["loss"]
    assert tuple(field.metadata["allowed"].choices) == LOSSES


def test_freeze_then_finetune(tmp_path):
    module = HeightModule(lr_head=1e-3, lr_encoder=1e-4)
    enc0 = {k: v.clone() for k, v in module.encoder.state_dict().items()}
    cb = FreezeThenFinetune(unfreeze_at_epoch=1, lr=1e-4)
    dl = torch.utils.data.DataLoader(_Loader(), batch_size=2)
    trainer = _trainer(tmp_path, max_epochs=1, callbacks=[cb])
    trainer.fit(module, train_dataloaders=dl)
    # epoch 0: frozen -- weights and batch-norm statistics untouched, one param group
    for k, v in module.encoder.state_dict().items():
        torch.testing.assert_close(v, enc0[k], msg=k)
    assert len(trainer.optimizers[0].param_groups) == 1 and cb.frozen
    trainer = _trainer(tmp_path, max_epochs=2, callbacks=[FreezeThenFinetune(unfreeze_at_epoch=1, lr=1e-4)])
    trainer.fit(module, train_dataloaders=dl)
    groups = trainer.optimizers[0].param_groups
    assert len(groups) == 2 and groups[1]["lr"] == 1e-4
    assert any(not torch.equal(v, enc0[k]) for k, v in module.encoder.state_dict().items())
