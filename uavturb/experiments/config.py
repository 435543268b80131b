"""Training configuration: OmegaConf structured configs from dataclasses, composed from ``conf/``.

The shipped ``conf/`` folder is package data (``uavturb/conf``, :data:`CONF_DIR`), so an installed
package trains from any folder. A user's own config folder (``uavturb train --config-dir DIR``) is
searched first: a file there replaces the shipped file of the same name, and its new choices
(``DIR/model/mine.yaml``) join the shipped ones.

Composition (``load_config``), later wins::

    conf/config.yaml                      # top level; its ``defaults`` picks one file per group
    conf/<group>/<choice>.yaml            # groups: model, data, trainer (the swappable axes)
    conf/experiment/<name>.yaml           # optional: a named bundle (may pick groups in ``defaults``)
    key=value overrides                   # e.g. model.use_gru=false, trainer.max_epochs=3;
                                          # <group>=<choice> picks a group file, experiment=<name>

Every layer is merged into the :class:`TrainConfig` schema, so a misspelt key or a value of
the wrong type raises :class:`~uavturb.errors.InputError` naming the key and the allowed keys.
"""

from __future__ import annotations

import dataclasses
import typing
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any

import yaml
from omegaconf import DictConfig, OmegaConf
from omegaconf.errors import OmegaConfBaseException

from uavturb.errors import InputError
from uavturb.physics.effects import ALPHA_PAPER, BETA_PAPER

#: the shipped config folder (package data)
CONF_DIR = Path(str(resources.files("uavturb") / "conf"))
GROUPS = ("model", "data", "trainer")


@dataclass
class ModelConfig:
    """Networks, pre-training variant and optimisation (Table 1's rows are files of conf/model)."""

    pretraining: str = "normals"        # none | depth | normals: stage pretrain trains this target;
    #                                     stage height loads an encoder pre-trained this way
    encoder_ckpt: str | None = None     # stage height: the pre-training checkpoint (unless pretraining=none)
    finetune: bool = True               # stage height: unfreeze the pre-trained encoder at unfreeze_at_epoch
    unfreeze_at_epoch: int = 10         # epoch the encoder joins training (finetune=true)
    use_gru: bool = True                # false: Table 1's "x GRU" ablation
    embed_dim: int = 50
    encoder_hidden: int = 128
    gru_hidden: int = 50
    gru_layers: int = 2
    mlp_hidden: int = 50
    max_depth: float = 10.0             # m, encoder input clamp
    lr_pretrain: float = 1e-3           # paper: Adam 1e-3, 500 epochs
    lam: float = 10000.0                # paper: lambda = 10,000
    lr_head: float = 1e-6               # paper: 1e-6
    lr_encoder: float = 1e-6            # paper: "the same optimizer configuration"
    alpha: float = ALPHA_PAPER          # ground-effect law f_a = alpha S / (d^2 - beta)
    beta: float = BETA_PAPER
    loss_frames: str = "all"            # all | last: frames of a window the height loss uses


@dataclass
class SyntheticConfig:
    """Generate a synthetic dataset where none exists (smoke runs); see uavturb.data.shards."""

    enabled: bool = False
    n_scenes: int = 6
    trajs_per_scene: int = 3
    T: int = 64
    pairs: int = 512
    seed: int = 0


@dataclass
class DataConfig:
    root: str = "data/sim"              # shard dataset (manifest.json)
    pairs_root: str = "data/pairs"      # pre-training pairs (holds pairs/)
    window: int = 8                     # H, frames of memory per sample
    stride: int = 1                     # frames between training windows
    eval_stride: int = 1                # frames between val/test windows
    batch_size: int = 16
    num_workers: int = 2
    image_size: int = 128               # px (square); 0 = whatever the data holds
    val_fraction: float = 0.1           # pairs held out for validation
    synthetic: SyntheticConfig = field(default_factory=SyntheticConfig)


@dataclass
class TrainerConfig:
    max_epochs: int = 100
    max_steps: int = -1
    accelerator: str = "auto"
    devices: str = "auto"               # "auto", a count ("2") or ids ("0,1")
    strategy: str = "auto"
    num_nodes: int = 1
    precision: str = "32-true"
    seed: int = 0
    limit_train_batches: float = 1.0    # <= 1: fraction; > 1: number of batches
    limit_val_batches: float = 1.0
    limit_test_batches: float = 1.0
    log_every_n_steps: int = 50
    early_stopping_patience: int = 0    # epochs without val improvement; 0 = off
    enable_progress_bar: bool = True
    default_root_dir: str = "runs"      # checkpoints go to <default_root_dir>/checkpoints/<run>
    deterministic: bool = False
    num_threads: int = 0                # torch CPU threads (torch.set_num_threads); 0 = torch's default


@dataclass
class TrackingConfig:
    enabled: bool = True
    experiment: str = "uavturb"
    run_name: str | None = None
    system_metrics: bool = False        # CPU, memory, GPU use logged as system/* metrics (needs psutil)


@dataclass
class TrainConfig:
    stage: str = "height"               # pretrain | height
    model: ModelConfig = field(default_factory=ModelConfig)
    data: DataConfig = field(default_factory=DataConfig)
    trainer: TrainerConfig = field(default_factory=TrainerConfig)
    tracking: TrackingConfig = field(default_factory=TrackingConfig)


#: keys whose values come from a closed set
CHOICES: dict[str, tuple[str, ...]] = {
    "stage": ("pretrain", "height"),
    "model.pretraining": ("none", "depth", "normals"),
    "model.loss_frames": ("all", "last"),
}


def allowed_keys(path: str) -> list[str]:
    """Keys allowed under a dotted path of :class:`TrainConfig` (``""`` = top level)."""
    cls: Any = TrainConfig
    for part in [p for p in path.split(".") if p]:
        hints = typing.get_type_hints(cls)
        if part not in hints or not dataclasses.is_dataclass(hints[part]):
            return []
        cls = hints[part]
    return [f.name for f in dataclasses.fields(cls)]


def _merge(base: DictConfig, layer: Any, source: str) -> DictConfig:
    try:
        return OmegaConf.merge(base, layer)
    except OmegaConfBaseException as e:
        key = str(getattr(e, "full_key", "") or getattr(e, "key", "") or "?")
        parent = key.rsplit(".", 1)[0] if "." in key else ""
        allowed = allowed_keys(parent)
        msg = str(e).splitlines()[0]
        if "not in" in msg or "Missing key" in msg or "ConfigKeyError" in type(e).__name__:
            problem = f"unknown key (in {source}); allowed: {', '.join(allowed)}"
        else:
            problem = f"bad value (in {source}): {msg}"
        raise InputError(key, problem) from None


def _read_yaml(path: Path) -> dict[str, Any]:
    if not path.is_file():
        raise InputError(path, "config file not found")
    try:
        d = yaml.safe_load(path.read_text()) or {}
    except yaml.YAMLError:
        raise InputError(path, "not valid YAML") from None
    if not isinstance(d, dict):
        raise InputError(path, "expected a mapping")
    return d


def search_path(conf_dir: str | Path | None = None) -> list[Path]:
    """Config folders searched in order: ``conf_dir`` (a user's, if given), then the shipped one."""
    if conf_dir is None:
        return [CONF_DIR]
    conf_dir = Path(conf_dir)
    if not conf_dir.is_dir():
        raise InputError(conf_dir, "config folder not found (--config-dir)")
    return [conf_dir] if conf_dir.resolve() == CONF_DIR.resolve() else [conf_dir, CONF_DIR]


def _locate(dirs: list[Path], *parts: str) -> Path | None:
    """The first ``dir/parts...`` that exists along the search path."""
    for d in dirs:
        path = d.joinpath(*parts)
        if path.is_file():
            return path
    return None


def _choices(dirs: list[Path], group: str) -> list[str]:
    return sorted({p.stem for d in dirs for p in (d / group).glob("*.yaml")})


def _group_file(dirs: list[Path], group: str, choice: str) -> Path:
    path = _locate(dirs, group, f"{choice}.yaml")
    if path is None:
        raise InputError(group, f"no config {choice!r}; choices: {', '.join(_choices(dirs, group))}")
    return path


def _defaults(d: dict[str, Any], path: Path) -> dict[str, str]:
    defaults = d.pop("defaults", None) or {}
    if not isinstance(defaults, dict):
        raise InputError(f"{path}: defaults", "expected a mapping of group to choice")
    bad = sorted(set(defaults) - set(GROUPS))
    if bad:
        raise InputError(f"{path}: defaults.{bad[0]}", f"unknown group; allowed: {', '.join(GROUPS)}")
    return {k: str(v) for k, v in defaults.items()}


def validate(cfg: DictConfig | TrainConfig | dict) -> DictConfig:
    """Merge into the schema (types, unknown keys) and check the closed-set values."""
    schema = OmegaConf.structured(TrainConfig)
    cfg = _merge(schema, cfg, "config")
    for key, allowed in CHOICES.items():
        value = OmegaConf.select(cfg, key)
        if value not in allowed:
            raise InputError(key, f"{value!r} is not allowed; choices: {', '.join(allowed)}")
    return cfg


def load_config(overrides: list[str] | None = None, experiment: str | None = None,
                conf_dir: str | Path | None = None) -> DictConfig:
    """Compose the training config.

    Parameters
    ----------
    overrides : ``key=value`` strings (OmegaConf dot-list: ``model.use_gru=false``); also
        ``<group>=<choice>`` (``model=none_gru``) and ``experiment=<name>``.
    experiment : name of a ``conf/experiment/*.yaml`` bundle.
    conf_dir : a user's config folder, searched before the shipped one (see :func:`search_path`).

    Returns
    -------
    A typed, struct-mode DictConfig of :class:`TrainConfig`.

    Raises
    ------
    InputError : unknown key or group choice (naming it and listing the allowed ones), wrong
        value type, value outside its closed set, malformed override, missing file.
    """
    dirs = search_path(conf_dir)
    overrides = list(overrides or [])
    group_choice: dict[str, str] = {}
    dotlist: list[str] = []
    for item in overrides:
        if "=" not in item:
            raise InputError(item, "override must be key=value")
        key, value = item.split("=", 1)
        if key == "experiment":
            experiment = value
        elif key in GROUPS and "." not in value and not value.startswith(("{", "[")):
            group_choice[key] = value
        else:
            dotlist.append(item)

    top_path = _locate(dirs, "config.yaml") or dirs[0] / "config.yaml"
    top = _read_yaml(top_path)
    defaults = _defaults(top, top_path)
    exp: dict[str, Any] = {}
    if experiment:
        exp_path = _locate(dirs, "experiment", f"{experiment}.yaml")
        if exp_path is None:
            raise InputError("experiment", f"no experiment {experiment!r}; choices: "
                             f"{', '.join(_choices(dirs, 'experiment'))}")
        exp = _read_yaml(exp_path)
        defaults.update(_defaults(exp, exp_path))
    defaults.update(group_choice)

    cfg = OmegaConf.structured(TrainConfig)
    cfg = _merge(cfg, top, str(top_path))
    for group in GROUPS:
        if group in defaults:
            path = _group_file(dirs, group, defaults[group])
            cfg = _merge(cfg, {group: _read_yaml(path)}, str(path))
    if exp:
        cfg = _merge(cfg, exp, f"experiment {experiment}")
    try:
        layer = OmegaConf.from_dotlist(dotlist)
    except OmegaConfBaseException as e:
        raise InputError(" ".join(dotlist), f"malformed override: {str(e).splitlines()[0]}") from None
    cfg = _merge(cfg, layer, "overrides")
    return validate(cfg)


def to_flat_dict(cfg: DictConfig) -> dict[str, Any]:
    """``{"model.use_gru": True, ...}`` of a resolved config (for MLflow params)."""
    out: dict[str, Any] = {}

    def walk(node: Any, prefix: str) -> None:
        if isinstance(node, dict):
            for k, v in node.items():
                walk(v, f"{prefix}{k}.")
        else:
            out[prefix[:-1]] = node

    walk(OmegaConf.to_container(cfg, resolve=True), "")
    return out
