"""Height prediction ``d_t = Pred(GRU(e_t, h_{t-1}))`` and the ground-effect law in torch.

Paper: "The prediction network is a 2-layer GRU with hidden state of size 50, followed by a
2-layers MLP. The final output is a single scalar that represents the height." Ours: the
MLP is ``Linear(50, 50) - ReLU - Linear(50, 1)`` and a softplus keeps the height positive.
The no-GRU ablation (Table 1, "x GRU") applies the same MLP to each frame's embedding.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from uavturb.physics.ground_effect import CLIP_FORCE_N


class HeightHead(nn.Module):
    """GRU memory + MLP, embeddings to positive heights.

    Parameters
    ----------
    embed_dim : int
        Size of the input embeddings (50).
    hidden : int
        GRU hidden size (50).
    num_layers : int
        GRU layers (2).
    mlp_hidden : int
        Width of the MLP's hidden layer.
    use_gru : bool
        False: the ablation without memory (the MLP reads each embedding alone).

    Shapes
    ------
    forward: ``e_seq (B, T, embed_dim)``, ``h0 (num_layers, B, hidden)`` or None ->
    ``d (B, T)`` heights [m] and ``h_T (num_layers, B, hidden)`` (None without GRU).
    Feeding a sequence in pieces, passing each returned state on, gives the same heights
    as feeding it whole (streaming use on board).
    """

    def __init__(self, embed_dim: int = 50, hidden: int = 50, num_layers: int = 2, mlp_hidden: int = 50,
                 use_gru: bool = True):
        super().__init__()
        self.use_gru = use_gru
        self.gru = nn.GRU(embed_dim, hidden, num_layers=num_layers, batch_first=True) if use_gru else None
        width = hidden if use_gru else embed_dim
        self.mlp = nn.Sequential(nn.Linear(width, mlp_hidden), nn.ReLU(inplace=True), nn.Linear(mlp_hidden, 1))

    def forward(self, e_seq: torch.Tensor, h0: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor | None]:
        """Heights for a sequence of embeddings.

        Parameters
        ----------
        e_seq : (B, T, embed_dim)
        h0 : (num_layers, B, hidden) or None (zeros); ignored without GRU.

        Returns
        -------
        d : (B, T) heights [m], positive.
        h_T : (num_layers, B, hidden) last GRU state, or None without GRU.
        """
        if self.gru is not None:
            x, h_T = self.gru(e_seq, h0)
        else:
            x, h_T = e_seq, None
        # the MLP in its weights' dtype even under mixed precision: bf16 would round heights to
        # 2^-8 relative (8 mm at 2 m) in the loss and the metrics
        with torch.autocast(x.device.type, enabled=False):
            d = F.softplus(self.mlp(x.to(self.mlp[0].weight.dtype)).squeeze(-1))
        return d, h_T


def phi_alpha_beta(d: torch.Tensor, sum_omega2: torch.Tensor, alpha: float, beta: float) -> torch.Tensor:
    """Ground-effect force ``alpha sum(Omega^2) / (d^2 - beta)`` [N], clipped like the paper.

    Same law and clip as :func:`uavturb.physics.ground_effect.phi_alpha_beta`:
    :data:`~uavturb.physics.ground_effect.CLIP_FORCE_N` where ``d^2 <= beta``, 0 where ``d``
    is infinite. Differentiable in ``d`` away from the clip (the clipped branch has zero
    gradient and never produces NaN gradients).

    Parameters
    ----------
    d : (...) heights over the surface below [m].
    sum_omega2 : (...) ``sum_i Omega_i^2`` [rad^2/s^2], broadcastable with ``d``.
    alpha : float
        ``k_T beta`` [N m^2/(rad/s)^2].
    beta : float
        ``mu r^2 / 16`` [m^2].

    Returns
    -------
    (...) force [N], dtype of ``d``.
    """
    d2 = d * d
    clipped = d2 <= beta
    far = torch.isinf(d2)
    safe = torch.where(clipped | far, torch.ones_like(d2), d2 - beta)
    f = alpha * sum_omega2.to(d.dtype) / safe
    f = torch.where(clipped, torch.full_like(f, CLIP_FORCE_N), f)
    return torch.where(far, torch.zeros_like(f), f)


def phi_alpha_beta_slope(d: torch.Tensor, sum_omega2: torch.Tensor, alpha: float, beta: float) -> torch.Tensor:
    """``d phi / d d`` [N/m] of :func:`phi_alpha_beta`: ``-2 alpha sum(Omega^2) d / (d^2 - beta)^2``.

    What a height error costs in ``f_a``: to first order ``f_a(d_hat) - f_a(d) = slope * (d_hat - d)``.
    The paper's clip applies here as in :func:`phi_alpha_beta`: where ``d^2 <= beta`` the clipped law
    is constant, so its slope is 0; so it is where ``d`` is infinite (no surface below).

    Parameters
    ----------
    d : (...) heights over the surface below [m].
    sum_omega2 : (...) ``sum_i Omega_i^2`` [rad^2/s^2], broadcastable with ``d``.
    alpha : float
        N m^2/(rad/s)^2.
    beta : float
        m^2.

    Returns
    -------
    (...) slope [N/m] (negative: the force falls with height), dtype of ``d``.
    """
    d2 = d * d
    dead = (d2 <= beta) | torch.isinf(d2)
    safe = torch.where(dead, torch.ones_like(d2), d2 - beta)
    slope = -2.0 * alpha * sum_omega2.to(d.dtype) * torch.where(dead, torch.zeros_like(d), d) / (safe * safe)
    return torch.where(dead, torch.zeros_like(slope), slope)
