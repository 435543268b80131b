"""Plain-torch networks of the learning pipeline (paper, "Network architectures").

- :class:`DepthEncoder` -- depth image to a 50-d embedding ``e_t``.
- :class:`Decoder` -- embedding back to normals (3 channels) or depth (1 channel), for pre-training.
- :class:`HeightHead` -- GRU memory plus MLP, embeddings to heights ``d_t``.
- :func:`phi_alpha_beta` -- the ground-effect law in torch, heights to ``f_a``;
  :func:`phi_alpha_beta_slope` its slope in height (what a height error costs in ``f_a``).
"""

from __future__ import annotations

from uavturb.nn.decoder import Decoder
from uavturb.nn.encoder import DepthEncoder
from uavturb.nn.height import HeightHead, phi_alpha_beta, phi_alpha_beta_slope

__all__ = ["DepthEncoder", "Decoder", "HeightHead", "phi_alpha_beta", "phi_alpha_beta_slope"]
