"""Training stage "frozen encoder, then fine-tuning" as a Lightning callback.

Paper: "We then load and freeze the weights from the encoder head and train the height
prediction head ... until convergence. Finally, we fine-tune the entire model end-to-end,
freeing the parameters of the encoder with the same optimizer configuration."

While frozen, the encoder's parameters take no gradient and the whole encoder (its batch
norms included) is kept in eval mode, so its pre-trained running statistics are used and
left untouched (unlike Lightning's ``BaseFinetuning.freeze``, which switches batch norms to
batch statistics). At epoch ``unfreeze_at_epoch`` the encoder is made trainable and added to
the optimizer as its own parameter group with learning rate ``lr``.
"""

from __future__ import annotations

import lightning as L
from lightning.pytorch.callbacks import BaseFinetuning
from torch.optim import Optimizer


class FreezeThenFinetune(BaseFinetuning):
    """Freeze ``pl_module.<module_name>`` until ``unfreeze_at_epoch``, then fine-tune it.

    Parameters
    ----------
    unfreeze_at_epoch : int
        Epoch (0-based) at which the encoder joins training; negative = stays frozen
        (Table 1's "x finetune" rows).
    lr : float
        Learning rate of the encoder's parameter group once unfrozen.
    module_name : str
        Attribute of the LightningModule to freeze.
    """

    def __init__(self, unfreeze_at_epoch: int = 10, lr: float = 1e-6, module_name: str = "encoder"):
        super().__init__()
        self.unfreeze_at_epoch, self.lr, self.module_name = unfreeze_at_epoch, lr, module_name
        self.frozen = False

    def _module(self, pl_module: L.LightningModule):
        return getattr(pl_module, self.module_name)

    def freeze_before_training(self, pl_module: L.LightningModule) -> None:
        module = self._module(pl_module)
        for p in module.parameters():
            p.requires_grad = False
        self.frozen = True

    def on_train_batch_start(self, trainer, pl_module, batch, batch_idx) -> None:
        if self.frozen:
            self._module(pl_module).eval()

    def finetune_function(self, pl_module: L.LightningModule, epoch: int, optimizer: Optimizer) -> None:
        if self.frozen and 0 <= self.unfreeze_at_epoch <= epoch:
            module = self._module(pl_module)
            module.train()
            self.unfreeze_and_add_param_group(module, optimizer, lr=self.lr, train_bn=True)
            self.frozen = False
