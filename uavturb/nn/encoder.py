"""Depth encoder ``Enc(D_t) -> e_t`` (paper, "Network architectures").

Six convolutions (kernel 7, then 3), output channels ``(16, 32, 64, 64, 32, 4)``, each
followed by batch normalisation and ReLU, then an MLP with one hidden ReLU layer to a
50-d embedding.

Choices the paper leaves open (ours):

- **Strides** ``(2, 2, 2, 2, 2, 1)`` with "same" padding (``k // 2``): a 128x128 image
  becomes a 4x4x4 map, i.e. 64 features.
- **Size-agnostic**: an adaptive average pooling to ``pool_size`` (4x4) sits between the
  last convolution and the MLP, so any input size gives ``4 * 4 * 4 = 64`` features (for
  128x128 inputs the pooling is the identity).
- **MLP hidden width** 128.
- **Input normalisation** inside the network: depth in metres is clamped to
  ``[0, max_depth]`` (10 m) and divided by ``max_depth``; no-data pixels (0, NaN, inf)
  become 0.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch import nn

PAPER_CHANNELS = (16, 32, 64, 64, 32, 4)
PAPER_KERNELS = (7, 3, 3, 3, 3, 3)
DEFAULT_STRIDES = (2, 2, 2, 2, 2, 1)


def normalise_depth(depth: torch.Tensor, max_depth: float) -> torch.Tensor:
    """Depth [m] to ``[0, 1]``: no-data (0, NaN, inf, negative) to 0, far values clamped."""
    d = torch.nan_to_num(depth, nan=0.0, posinf=0.0, neginf=0.0)
    return d.clamp(0.0, max_depth) / max_depth


class DepthEncoder(nn.Module):
    """Convolutional depth encoder.

    Parameters
    ----------
    embed_dim : int
        Size of the embedding ``e_t`` (paper: 50).
    channels : sequence of int
        Output channels of the convolutions (paper: 16, 32, 64, 64, 32, 4).
    kernels : sequence of int
        Kernel sizes (paper: 7 then 3).
    strides : sequence of int
        Strides (not in the paper; ours: 2 on the first five).
    pool_size : int
        Side of the adaptive pooling before the MLP.
    hidden : int
        Width of the MLP's hidden layer.
    max_depth : float
        m, depth clamp used for normalisation.

    Shapes
    ------
    forward: ``(B, 1, H, W)`` depth [m] -> ``(B, embed_dim)``.
    """

    def __init__(self, embed_dim: int = 50, channels: Sequence[int] = PAPER_CHANNELS,
                 kernels: Sequence[int] = PAPER_KERNELS, strides: Sequence[int] = DEFAULT_STRIDES,
                 pool_size: int = 4, hidden: int = 128, max_depth: float = 10.0):
        super().__init__()
        if not (len(channels) == len(kernels) == len(strides)):
            raise ValueError("channels, kernels and strides must have the same length")
        self.embed_dim = embed_dim
        self.max_depth = float(max_depth)
        layers: list[nn.Module] = []
        c_in = 1
        for c, k, s in zip(channels, kernels, strides):
            layers += [nn.Conv2d(c_in, c, k, stride=s, padding=k // 2, bias=False), nn.BatchNorm2d(c),
                       nn.ReLU(inplace=True)]
            c_in = c
        self.convs = nn.Sequential(*layers)
        self.pool = nn.AdaptiveAvgPool2d(pool_size)
        self.n_features = c_in * pool_size * pool_size
        self.mlp = nn.Sequential(nn.Linear(self.n_features, hidden), nn.ReLU(inplace=True),
                                 nn.Linear(hidden, embed_dim))

    def forward(self, depth: torch.Tensor) -> torch.Tensor:
        """Embed depth images.

        Parameters
        ----------
        depth : (B, 1, H, W) depth [m], 0 where no data.

        Returns
        -------
        (B, embed_dim) embeddings.
        """
        x = normalise_depth(depth, self.max_depth)
        for layer in self.convs:
            x = _on_one_pixel(layer, x) if isinstance(layer, nn.Conv2d) else layer(x)
        return self.mlp(self.pool(x).flatten(1))


def _on_one_pixel(conv: nn.Conv2d, x: torch.Tensor) -> torch.Tensor:
    """``conv(x)``; on a 1x1 map a strided convolution runs with stride 1, which gives the same 1x1 output
    (only the kernel's centre tap meets the pixel). oneDNN's bfloat16 weight gradient of a stride-2
    convolution over a 1x1 map is NaN a quarter of the time on CPUs with AMX (torch 2.13): images of 16 px
    reach it at the fifth convolution."""
    if x.shape[-2:] == (1, 1) and conv.stride != (1, 1) and conv.padding == (conv.kernel_size[0] // 2,
                                                                              conv.kernel_size[1] // 2):
        return nn.functional.conv2d(x, conv.weight, conv.bias, stride=1, padding=conv.padding,
                                    dilation=conv.dilation, groups=conv.groups)
    return conv(x)
