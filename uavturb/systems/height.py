"""Height over ground from depth sequences, and ``f_a`` through the ground-effect law.

    e_t = Enc(D_t);  h_t = GRU(e_t, h_{t-1});  d_t = Pred(h_t);  f_a,t = phi(d_t, Omega_t)

Loss (``loss``):

- ``height`` (the paper's): ``L1 = ||d_t - d*_t||^2``, the mean squared error over the window's
  frames, or over its last frame only (``loss_frames``).
- ``law_weighted`` (ours, beyond the paper): the same squared errors weighted by what they cost
  in ``f_a``, ``w_t = 1 + (phi'(d*_t, Omega_t) / g_ref)^2`` with ``phi'`` the law's slope in height
  at the frame's true height and rotor speeds (:func:`uavturb.nn.height.phi_alpha_beta_slope`,
  the paper's clip applied as in ``f_a``: slope 0 where the law is clipped) and ``g_ref =
  law_weight_ref`` [N/m]; ``L = sum(w e^2) / sum(w)`` over the frames the loss uses, so the
  loss stays in m^2 and its scale (hence the learning rate) is that of ``height``. To first order
  ``phi' e`` is the frame's ``f_a`` error: a frame where a centimetre of height costs
  ``0.01 g_ref`` newtons counts twice as much as one far from any surface, and near the floor
  (the hexarotor at 0.16 m: ``phi' ~ 10 N/m``) about 100 times. Metrics, on the **last frame of each window** (the frame
predicted with ``H`` frames of memory), torchmetrics RMSE: ``{train,val,test}/rmse_d`` [m]
and ``{train,val,test}/rmse_fa`` [N] with ``f_a`` from
:func:`uavturb.nn.height.phi_alpha_beta` at the frame's rotor speeds; plus ``*/loss``.

Defaults follow the paper: head learning rate 1e-6 (Adam), encoder (fine-tuning) learning
rate the same; ``alpha, beta`` of the paper's simulated quadrotor (k_T = 5.45e-6, r = 0.01 m,
mu = 2: ``beta = mu r^2 / 16 = 1.25e-5 m^2``, ``alpha = k_T beta``).
"""

from __future__ import annotations

from pathlib import Path

import lightning as L
import torch
import torch.nn.functional as F
from torchmetrics import MeanSquaredError

from uavturb.errors import InputError
from uavturb.nn.encoder import DepthEncoder
from uavturb.nn.height import HeightHead, phi_alpha_beta, phi_alpha_beta_slope
from uavturb.physics.effects import ALPHA_PAPER, BETA_PAPER
from uavturb.scene.camera import CameraModel, camera_from_record

STAGES = ("train", "val", "test")
LOSSES = ("height", "law_weighted")  # the paper's height loss; ours weighted by the law's slope


def load_encoder_state(path: str | Path) -> dict[str, torch.Tensor]:
    """Encoder weights (``encoder.*`` keys, prefix removed) of a Lightning checkpoint."""
    path = Path(path)
    if not path.is_file():
        raise InputError(path, "encoder checkpoint not found")
    try:
        ckpt = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as e:  # noqa: BLE001 - any unreadable file is bad input
        raise InputError(path, f"cannot read as a checkpoint ({type(e).__name__})") from None
    state = ckpt.get("state_dict", ckpt) if isinstance(ckpt, dict) else {}
    enc = {k[len("encoder."):]: v for k, v in state.items() if k.startswith("encoder.")}
    if not enc:
        raise InputError(path, "holds no 'encoder.*' weights (expected a TranscoderModule checkpoint)")
    return enc


class HeightModule(L.LightningModule):
    """Encoder + (GRU) head predicting height over ground.

    Parameters
    ----------
    use_gru : bool
        False: Table 1's "x GRU" ablation (per-frame MLP).
    embed_dim, encoder_hidden, gru_hidden, gru_layers, mlp_hidden : int
        Architecture (paper: 50, -, 50, 2, -).
    max_depth : float
        m, depth normalisation clamp of the encoder.
    lr_head : float
        Adam learning rate of the head (paper: 1e-6).
    lr_encoder : float
        Learning rate of the encoder when it trains (from scratch, or once unfrozen).
    alpha : float
        N m^2/(rad/s)^2, ground-effect law.
    beta : float
        m^2, ground-effect law.
    loss_frames : "all" | "last"
        Frames of each window the loss uses.
    loss : "height" | "law_weighted"
        The paper's height loss, or ours weighted by the law's sensitivity (module docstring).
    law_weight_ref : float
        N/m, ``g_ref`` of ``law_weighted``.
    encoder_ckpt : str or None
        Pre-training checkpoint to initialise the encoder from. It is read once here; the
        saved hyper-parameters record it as ``pretrained_from`` and set ``encoder_ckpt`` to
        None, so :meth:`load_from_checkpoint` never needs the pre-training file.
    pretrained_from : str or None
        Provenance only (see ``encoder_ckpt``).
    camera : dict or None
        The camera of the training images (:meth:`uavturb.scene.camera.CameraModel.record`:
        name, image size, intrinsics, mount, frame period), kept in the checkpoint so that
        ``evaluate`` and ``export`` see flights through it (:meth:`camera_model`). None: the
        training data named none, and those commands refuse the model.
    """

    def __init__(self, use_gru: bool = True, embed_dim: int = 50, encoder_hidden: int = 128, gru_hidden: int = 50,
                 gru_layers: int = 2, mlp_hidden: int = 50, max_depth: float = 10.0, lr_head: float = 1e-6,
                 lr_encoder: float = 1e-6, alpha: float = ALPHA_PAPER, beta: float = BETA_PAPER,
                 loss_frames: str = "all", encoder_ckpt: str | None = None, pretrained_from: str | None = None,
                 loss: str = "height", law_weight_ref: float = 1.0, camera: dict | None = None):
        super().__init__()
        if loss_frames not in ("all", "last"):
            raise InputError("model.loss_frames", f"must be all or last, not {loss_frames!r}")
        if loss not in LOSSES:
            raise InputError("model.loss", f"must be one of {', '.join(LOSSES)}, not {loss!r}")
        if not law_weight_ref > 0:
            raise InputError("model.law_weight_ref", f"must be positive (N/m), got {law_weight_ref}")
        if camera is not None:
            camera_from_record(camera, "model camera")
        self.save_hyperparameters(logger=False)  # train() logs the resolved config once
        self.encoder = DepthEncoder(embed_dim=embed_dim, hidden=encoder_hidden, max_depth=max_depth)
        self.head = HeightHead(embed_dim=embed_dim, hidden=gru_hidden, num_layers=gru_layers, mlp_hidden=mlp_hidden,
                               use_gru=use_gru)
        if encoder_ckpt:
            state = load_encoder_state(encoder_ckpt)
            try:
                self.encoder.load_state_dict(state)
            except RuntimeError as e:
                raise InputError(encoder_ckpt, f"encoder does not match this architecture: {e}") from None
            self.hparams["pretrained_from"] = str(encoder_ckpt)
            self.hparams["encoder_ckpt"] = None
        # keys "<stage>_": a ModuleDict key "train" would clash with nn.Module.train
        self.rmse_d = torch.nn.ModuleDict({f"{s}_": MeanSquaredError(squared=False) for s in STAGES})
        self.rmse_fa = torch.nn.ModuleDict({f"{s}_": MeanSquaredError(squared=False) for s in STAGES})

    def camera_model(self) -> CameraModel | None:
        """The camera the model was trained through (hyperparameter ``camera``), None if it carries none."""
        record = self.hparams.get("camera")
        return None if record is None else camera_from_record(record, "model camera")

    def forward(self, depth: torch.Tensor, h0: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor | None]:
        """Heights for depth sequences.

        Parameters
        ----------
        depth : (B, T, 1, H, W) depth [m].
        h0 : GRU state (num_layers, B, gru_hidden) or None.

        Returns
        -------
        d : (B, T) heights [m]; h_T : last GRU state (None without GRU).
        """
        B, T = depth.shape[:2]
        e = self.encoder(depth.flatten(0, 1)).view(B, T, -1)
        return self.head(e, h0)

    def predict_fa(self, d: torch.Tensor, sum_omega2: torch.Tensor) -> torch.Tensor:
        """``f_a`` [N] from heights [m] and ``sum Omega^2`` [rad^2/s^2] with this module's alpha, beta."""
        return phi_alpha_beta(d, sum_omega2, self.hparams.alpha, self.hparams.beta)

    def loss_weights(self, d_true: torch.Tensor, sum_omega2: torch.Tensor) -> torch.Tensor:
        """``w = 1 + (phi'(d*, Omega) / g_ref)^2`` [-] of the ``law_weighted`` loss, shape of ``d_true``."""
        slope = phi_alpha_beta_slope(d_true, sum_omega2, self.hparams.alpha, self.hparams.beta)
        return 1.0 + (slope / self.hparams.law_weight_ref) ** 2

    def height_loss(self, d_hat: torch.Tensor, d_true: torch.Tensor, sum_omega2: torch.Tensor) -> torch.Tensor:
        """The training loss [m^2] of ``(B, T)`` predicted and true heights (module docstring)."""
        if self.hparams.loss_frames == "last":
            d_hat, d_true, sum_omega2 = d_hat[:, -1], d_true[:, -1], sum_omega2[:, -1]
        if self.hparams.loss == "height":
            return F.mse_loss(d_hat, d_true)
        w = self.loss_weights(d_true, sum_omega2).detach()
        return (w * (d_hat - d_true) ** 2).sum() / w.sum()

    def _step(self, batch: dict[str, torch.Tensor], stage: str) -> torch.Tensor:
        d_hat, _ = self(batch["depth"])
        d_true = batch["d"]
        loss = self.height_loss(d_hat, d_true, batch["sum_omega2"])
        d_last = d_hat[:, -1].detach().float()  # metrics in float32 whatever the training precision
        fa_hat = self.predict_fa(d_last, batch["sum_omega2"][:, -1])
        bs = d_hat.shape[0]
        self.rmse_d[f"{stage}_"].update(d_last, d_true[:, -1])
        self.rmse_fa[f"{stage}_"].update(fa_hat, batch["fa"][:, -1])
        on_step = stage == "train"
        self.log(f"{stage}/loss", loss, prog_bar=True, on_step=on_step, on_epoch=True, batch_size=bs,
                 sync_dist=stage != "train")  # mean over DDP ranks (metrics objects sync themselves)
        self.log(f"{stage}/rmse_d", self.rmse_d[f"{stage}_"], prog_bar=stage == "val", on_step=False, on_epoch=True,
                 batch_size=bs)
        self.log(f"{stage}/rmse_fa", self.rmse_fa[f"{stage}_"], on_step=False, on_epoch=True, batch_size=bs)
        return loss

    def training_step(self, batch, batch_idx):
        return self._step(batch, "train")

    def validation_step(self, batch, batch_idx):
        self._step(batch, "val")

    def test_step(self, batch, batch_idx):
        self._step(batch, "test")

    def configure_optimizers(self):
        groups = [{"params": list(self.head.parameters()), "lr": self.hparams.lr_head}]
        enc = [p for p in self.encoder.parameters() if p.requires_grad]
        if enc:
            groups.append({"params": enc, "lr": self.hparams.lr_encoder})
        return torch.optim.Adam(groups)
