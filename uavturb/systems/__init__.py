"""LightningModules and training-stage callbacks.

- :class:`~uavturb.systems.transcoder.TranscoderModule` -- pre-training, depth to normals (or depth).
- :class:`~uavturb.systems.height.HeightModule` -- height over ground (and ``f_a`` through phi).
- :class:`~uavturb.systems.finetune.FreezeThenFinetune` -- frozen encoder, then fine-tuning.
"""

from __future__ import annotations

from uavturb.systems.finetune import FreezeThenFinetune
from uavturb.systems.height import HeightModule
from uavturb.systems.transcoder import TranscoderModule, transcoding_loss

__all__ = ["TranscoderModule", "HeightModule", "FreezeThenFinetune", "transcoding_loss"]
