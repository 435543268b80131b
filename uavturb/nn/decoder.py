"""Decoder ``Dec(e_t) -> N_t`` used only for pre-training (paper: "the inverse architecture
(an MLP followed by convolutions) coupled with up-sampling layers").

Ours: an MLP (one hidden ReLU layer) to a ``4 x pool_size x pool_size`` map, then five
stages of bilinear up-sampling + 3x3 convolution + batch norm + ReLU with channels
``(32, 64, 64, 32, 16)`` (the encoder's, reversed), and a final 7x7 convolution to the
output channels. The up-sampling sizes grow geometrically from ``pool_size`` to the
requested output size, so the decoder is size-agnostic like the encoder.

Outputs: ``target="normals"`` gives 3-channel unit vectors (normalised over channels, camera
frame); ``target="depth"`` gives 1 channel in ``[0, 1]`` (sigmoid), i.e. depth divided by
``max_depth`` -- the scale :func:`uavturb.nn.encoder.normalise_depth` uses.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
import torch.nn.functional as F
from torch import nn

TARGETS = ("normals", "depth")


class Decoder(nn.Module):
    """Embedding to a dense image.

    Parameters
    ----------
    target : {"normals", "depth"}
    embed_dim : int
    channels : sequence of int
        Channels of the up-sampling stages.
    base_channels : int
        Channels of the map the MLP produces (the encoder's last: 4).
    pool_size : int
        Side of that map.
    hidden : int
        Width of the MLP's hidden layer.

    Shapes
    ------
    forward: ``(B, embed_dim)`` and ``size=(H, W)`` -> ``(B, 3, H, W)`` unit normals or
    ``(B, 1, H, W)`` normalised depth.
    """

    def __init__(self, target: str = "normals", embed_dim: int = 50, channels: Sequence[int] = (32, 64, 64, 32, 16),
                 base_channels: int = 4, pool_size: int = 4, hidden: int = 128):
        super().__init__()
        if target not in TARGETS:
            raise ValueError(f"target must be one of {TARGETS}, not {target!r}")
        self.target = target
        self.out_channels = 3 if target == "normals" else 1
        self.base_channels, self.pool_size = base_channels, pool_size
        self.mlp = nn.Sequential(nn.Linear(embed_dim, hidden), nn.ReLU(inplace=True),
                                 nn.Linear(hidden, base_channels * pool_size * pool_size), nn.ReLU(inplace=True))
        stages = []
        c_in = base_channels
        for c in channels:
            stages.append(nn.Sequential(nn.Conv2d(c_in, c, 3, padding=1, bias=False), nn.BatchNorm2d(c),
                                        nn.ReLU(inplace=True)))
            c_in = c
        self.stages = nn.ModuleList(stages)
        self.head = nn.Conv2d(c_in, self.out_channels, 7, padding=3)

    def _sizes(self, size: tuple[int, int]) -> list[tuple[int, int]]:
        n = len(self.stages)
        p = self.pool_size
        return [tuple(max(1, round(p * (s / p) ** ((i + 1) / n))) for s in size) for i in range(n)]

    def forward(self, e: torch.Tensor, size: tuple[int, int] = (128, 128)) -> torch.Tensor:
        """Decode embeddings.

        Parameters
        ----------
        e : (B, embed_dim) embeddings.
        size : (H, W) output size in pixels.

        Returns
        -------
        (B, 3, H, W) unit normals, or (B, 1, H, W) depth / max_depth in [0, 1].
        """
        size = (int(size[0]), int(size[1]))
        x = self.mlp(e).view(-1, self.base_channels, self.pool_size, self.pool_size)
        for stage, s in zip(self.stages, self._sizes(size)):
            x = stage(F.interpolate(x, size=s, mode="bilinear", align_corners=False))
        x = self.head(x)
        if self.target == "normals":
            return F.normalize(x, dim=1, eps=1e-6)
        return torch.sigmoid(x)
