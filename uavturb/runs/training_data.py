"""What a training stage reads: its dataset folder (synthetic data written where configured and
missing) and the ground-effect law of its ``f_a`` (from the data, else the paper's)."""

from __future__ import annotations

from pathlib import Path

from omegaconf import DictConfig

from uavturb.data import synthetic
from uavturb.data.datamodules import ground_effect_law
from uavturb.errors import InputError
from uavturb.io import shards
from uavturb.physics.effects import ALPHA_PAPER, BETA_PAPER


def stage_data_root(cfg: DictConfig) -> Path:
    """The dataset folder this stage reads, as it is now (nothing generated): the pairs of
    ``data.pairs_root`` (its ``pairs/`` folder where there is one), or the shards of ``data.root``."""
    if cfg.stage == "pretrain":
        root = Path(cfg.data.pairs_root)
        return root / shards.PAIRS_DIR if (root / shards.PAIRS_DIR).is_dir() else root
    return Path(cfg.data.root)


def prepare_data(cfg: DictConfig) -> Path:
    """The dataset folder of this stage, generated when ``data.synthetic.enabled`` and missing
    (pre-training: depth/target pairs under ``data.pairs_root``; height: shards under ``data.root``)."""
    syn = cfg.data.synthetic
    size = cfg.data.image_size or 32  # px
    if cfg.stage == "pretrain":
        root = Path(cfg.data.pairs_root)
        if syn.enabled and not (root / shards.PAIRS_DIR / "meta.json").is_file():
            synthetic.make_synthetic_pairs(root, M=syn.pairs, size=size, seed=syn.seed)
        return stage_data_root(cfg)
    root = Path(cfg.data.root)
    if syn.enabled and not (root / shards.MANIFEST).is_file():
        synthetic.make_synthetic_dataset(root, n_scenes=syn.n_scenes, trajs_per_scene=syn.trajs_per_scene, T=syn.T,
                                         size=size, seed=syn.seed)
    return root


def resolve_ground_effect_law(cfg: DictConfig, data_root: Path) -> None:
    """Fill ``model.alpha`` and ``model.beta`` left unset: the law the training data's ``f_a`` was
    made with (:func:`uavturb.data.datamodules.ground_effect_law`), else the paper's quadrotor's.
    The run then logs the values it trained with (the law-weighted loss and ``f_a`` metrics use them)."""
    m = cfg.model
    if (m.alpha is None) != (m.beta is None):
        raise InputError("model.alpha", "set model.alpha and model.beta together, or neither (the data's law)")
    if m.alpha is None:
        law = ground_effect_law(data_root) if cfg.stage == "height" else None
        m.alpha, m.beta = law if law is not None else (ALPHA_PAPER, BETA_PAPER)
