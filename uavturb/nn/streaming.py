"""The streaming height model that ``uavturb export`` traces: one depth frame and the rotor speeds
in, height and ``f_a`` out, the GRU state carried by the caller (onboard use)."""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from uavturb.nn.height import phi_alpha_beta

INPUT_NAMES = ("depth", "rotor_speeds", "state")


OUTPUT_NAMES = ("height", "f_a", "state_out")


def gru_step(x: torch.Tensor, h: torch.Tensor, w_ih: torch.Tensor, w_hh: torch.Tensor, b_ih: torch.Tensor,
             b_hh: torch.Tensor) -> torch.Tensor:
    """One step of one GRU layer, PyTorch's equations (gates ordered r, z, n).

    Parameters
    ----------
    x : (B, I) input; h : (B, S) previous state; w_ih : (3S, I); w_hh : (3S, S); b_ih, b_hh : (3S,)

    Returns
    -------
    (B, S) new state ``(1 - z) n + z h``.
    """
    gi = F.linear(x, w_ih, b_ih)
    gh = F.linear(h, w_hh, b_hh)
    i_r, i_z, i_n = gi.chunk(3, dim=1)
    h_r, h_z, h_n = gh.chunk(3, dim=1)
    r = torch.sigmoid(i_r + h_r)
    z = torch.sigmoid(i_z + h_z)
    n = torch.tanh(i_n + r * h_n)
    return (1.0 - z) * n + z * h


class StreamingHeightModel(nn.Module):
    """One frame in, height and ``f_a`` out, the recurrent state carried by the caller.

    Parameters
    ----------
    module : a trained :class:`~uavturb.systems.HeightModule` (its encoder and head are
        shared, not copied)
    alpha : float, optional
        N m^2/(rad/s)^2, ground-effect law (default: the module's)
    beta : float, optional
        m^2 (default: the module's)

    Shapes
    ------
    forward: ``depth (B, 1, H, W)`` [m], ``rotor_speeds (B, N)`` [rad/s], ``state`` (see
    :attr:`state_shape`) -> ``height (B,)`` [m], ``f_a (B,)`` [N], ``new_state``.
    """

    def __init__(self, module: nn.Module, alpha: float | None = None, beta: float | None = None):
        super().__init__()
        hp = module.hparams
        self.encoder = module.encoder
        self.mlp = module.head.mlp
        self.use_gru = module.head.gru is not None
        if self.use_gru:
            gru = module.head.gru
            self.layers, self.hidden = gru.num_layers, gru.hidden_size
            self.gru_weights = nn.ParameterList()
            for k in range(gru.num_layers):
                for name in ("weight_ih", "weight_hh", "bias_ih", "bias_hh"):
                    self.gru_weights.append(getattr(gru, f"{name}_l{k}"))
        else:
            self.layers, self.hidden = 1, 1
        self.register_buffer("alpha", torch.tensor(float(hp.alpha if alpha is None else alpha)))
        self.register_buffer("beta", torch.tensor(float(hp.beta if beta is None else beta)))

    def state_shape(self, batch: int = 1) -> tuple[int, int, int]:
        """``(L, B, S)``: GRU layers and hidden size, or the dummy ``(1, B, 1)`` without GRU."""
        return (self.layers, batch, self.hidden)

    def initial_state(self, batch: int = 1) -> torch.Tensor:
        """Zeros: the state at the start of a flight."""
        return torch.zeros(self.state_shape(batch))

    def forward(self, depth: torch.Tensor, rotor_speeds: torch.Tensor,
                state: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        x = self.encoder(depth)
        if self.use_gru:
            new = []
            for k in range(self.layers):
                w_ih, w_hh, b_ih, b_hh = (self.gru_weights[4 * k + j] for j in range(4))
                x = gru_step(x, state[k], w_ih, w_hh, b_ih, b_hh)
                new.append(x)
            new_state = torch.stack(new)
        else:
            new_state = state.clone()
        d = F.softplus(self.mlp(x).squeeze(-1))
        fa = phi_alpha_beta(d, (rotor_speeds * rotor_speeds).sum(-1), self.alpha, self.beta)
        return d, fa, new_state

