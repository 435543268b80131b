"""Pre-training of the depth encoder as a transcoder (paper, eq. L2).

    L2 = lam ||N - N*||^2 + sum_c ||grad N_c - grad N*_c||^2

``grad`` is kornia's normalised Sobel :func:`kornia.filters.spatial_gradient` (x and y).
Norms are squared norms per pixel (over channels, resp. over the two gradient components),
averaged over pixels and batch, so ``lam`` (paper: 10,000) does not depend on image size.
For the Depth->Depth baseline the target is the input depth, compared on the encoder's
normalised scale (``clamp(D, 0, max_depth) / max_depth``).
"""

from __future__ import annotations

import lightning as L
import torch
from kornia.filters import spatial_gradient
from torchmetrics import MeanMetric

from uavturb.nn.decoder import TARGETS, Decoder
from uavturb.nn.encoder import DepthEncoder, normalise_depth


def transcoding_loss(pred: torch.Tensor, target: torch.Tensor, lam: float = 10000.0) -> torch.Tensor:
    """The paper's transcoding loss.

    Parameters
    ----------
    pred, target : (B, C, H, W) images (C = 3 normals, or 1 normalised depth).
    lam : weight of the pixel term.

    Returns
    -------
    Scalar loss; 0 iff ``pred == target`` up to a constant per channel that the gradient term
    cannot see -- the pixel term catches that.
    """
    pixel = ((pred - target) ** 2).sum(1).mean()
    grad = ((spatial_gradient(pred) - spatial_gradient(target)) ** 2).sum((1, 2)).mean()
    return lam * pixel + grad


class TranscoderModule(L.LightningModule):
    """Depth encoder + decoder trained on (depth, normals) or (depth, depth) pairs.

    Parameters
    ----------
    target : "normals" | "depth"
    lr : Adam learning rate (paper: 1e-3).
    lam : pixel-term weight (paper: 10,000).
    embed_dim : embedding size (paper: 50).
    encoder_hidden : width of the encoder's MLP hidden layer.
    max_depth : m, depth normalisation clamp.

    Logged: ``train/loss``, ``val/loss``, ``test/loss``; for normals also ``{val,test}/angle_deg``
    (mean angle between predicted and true normals, degrees).
    """

    def __init__(self, target: str = "normals", lr: float = 1e-3, lam: float = 10000.0, embed_dim: int = 50,
                 encoder_hidden: int = 128, max_depth: float = 10.0):
        super().__init__()
        if target not in TARGETS:
            raise ValueError(f"target must be one of {TARGETS}, not {target!r}")
        self.save_hyperparameters(logger=False)  # train() logs the resolved config once
        self.encoder = DepthEncoder(embed_dim=embed_dim, hidden=encoder_hidden, max_depth=max_depth)
        self.decoder = Decoder(target=target, embed_dim=embed_dim, hidden=encoder_hidden)
        self.angle = torch.nn.ModuleDict({s: MeanMetric() for s in ("val", "test")})

    def forward(self, depth: torch.Tensor) -> torch.Tensor:
        """(B, 1, H, W) depth [m] -> (B, 3, H, W) unit normals or (B, 1, H, W) normalised depth."""
        return self.decoder(self.encoder(depth), size=tuple(depth.shape[-2:]))

    def _target(self, batch: dict[str, torch.Tensor]) -> torch.Tensor:
        if self.hparams.target == "depth":
            return normalise_depth(batch["target"], self.hparams.max_depth)
        return batch["target"]

    def _step(self, batch: dict[str, torch.Tensor], stage: str) -> torch.Tensor:
        pred, target = self(batch["depth"]), self._target(batch)
        loss = transcoding_loss(pred, target, self.hparams.lam)
        bs = pred.shape[0]
        self.log(f"{stage}/loss", loss, prog_bar=True, on_step=stage == "train", on_epoch=True, batch_size=bs,
                 sync_dist=stage != "train")  # mean over DDP ranks
        if stage != "train" and self.hparams.target == "normals":
            valid = target.norm(dim=1) > 0.5
            cos = (pred * target).sum(1).clamp(-1.0, 1.0)
            self.angle[stage].update(torch.rad2deg(torch.acos(cos[valid])))
            self.log(f"{stage}/angle_deg", self.angle[stage], on_epoch=True, batch_size=bs)
        return loss

    def training_step(self, batch, batch_idx):
        return self._step(batch, "train")

    def validation_step(self, batch, batch_idx):
        self._step(batch, "val")

    def test_step(self, batch, batch_idx):
        self._step(batch, "test")

    def configure_optimizers(self):
        return torch.optim.Adam(self.parameters(), lr=self.hparams.lr)
