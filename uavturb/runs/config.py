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
the wrong type raises :class:`~uavturb.errors.InputError` naming the key and the allowed keys;
then every value is checked against the range or choices declared next to its field
(:func:`uavturb.schema.allowed`, checked by :func:`uavturb.schema.check_values` as every settings
schema of the package is), so ``trainer.max_epochs=0`` fails naming the key, the value and what is
allowed, before any data is read or any run opened.

Sweep files (``sweeps/ablation.yaml``) have their schema here too (:class:`SweepSpec`, read by
:func:`load_spec`): a typo fails naming the file and the key. The shipped sweep files are
package data (``uavturb/sweeps``, :data:`SWEEPS_DIR`); a sweep is named by a path to a file or by
the name of a shipped one (``ablation``; ``sweeps/ablation.yaml`` too, where no such file exists
in the working folder): :func:`resolve_spec`. A sweep's rows and profiles hold overrides in the
one syntax of :func:`load_config` (``key=value``, ``group=choice``). A sweep's profile
(:class:`SweepProfile`, ``uavturb sweep --profile quick``) is how it runs -- seeds and overrides --
not a dataset preset: the data a profile trains on is one of its overrides.
"""

from __future__ import annotations

import dataclasses
import typing
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any

from omegaconf import MISSING, DictConfig, OmegaConf
from omegaconf.errors import OmegaConfBaseException

from uavturb import schema
from uavturb.errors import InputError
from uavturb.io.yaml_mapping import read_yaml_mapping
from uavturb.schema import allowed

#: the shipped config folder (package data)
CONF_DIR = Path(str(resources.files("uavturb") / "conf"))
GROUPS = ("model", "data", "trainer")


_POSITIVE_INT = {"ge": 1}
_POSITIVE = {"gt": 0}
#: Lightning's accepted values (tests/test_config.py checks them against Lightning's registries;
#: importing Lightning here would cost seconds for every config read)
ACCELERATORS = ("auto", "cpu", "gpu", "cuda", "mps", "tpu")
PRECISIONS = ("32-true", "16-mixed", "bf16-mixed", "16-true", "bf16-true", "64-true", "transformer-engine",
              "transformer-engine-float16", "64", "32", "16", "bf16")
STRATEGIES = ("auto", "ddp", "ddp_spawn", "ddp_fork", "ddp_notebook", "ddp_find_unused_parameters_false",
              "ddp_find_unused_parameters_true", "ddp_spawn_find_unused_parameters_false",
              "ddp_spawn_find_unused_parameters_true", "ddp_fork_find_unused_parameters_false",
              "ddp_fork_find_unused_parameters_true", "ddp_notebook_find_unused_parameters_false",
              "ddp_notebook_find_unused_parameters_true", "deepspeed", "deepspeed_stage_1", "deepspeed_stage_2",
              "deepspeed_stage_2_offload", "deepspeed_stage_3", "deepspeed_stage_3_offload",
              "deepspeed_stage_3_offload_nvme", "fsdp", "fsdp_cpu_offload", "single_device", "single_xla",
              "xla_debug", "xla", "single_tpu")


@dataclass
class ModelConfig:
    """Networks, pre-training variant and optimisation (Table 1's rows are files of conf/model)."""

    pretraining: str = allowed("normals", choices=("none", "depth", "normals"))
    #                                     none | depth | normals: stage pretrain trains this target;
    #                                     stage height loads an encoder pre-trained this way
    encoder_ckpt: str | None = None     # stage height: the pre-training checkpoint (unless pretraining=none)
    finetune: bool = True               # stage height: unfreeze the pre-trained encoder at unfreeze_at_epoch
    unfreeze_at_epoch: int = allowed(10, ge=0)  # epoch the encoder joins training (finetune=true)
    use_gru: bool = True                # false: Table 1's "x GRU" ablation
    embed_dim: int = allowed(50, **_POSITIVE_INT)
    encoder_hidden: int = allowed(128, **_POSITIVE_INT)
    gru_hidden: int = allowed(50, **_POSITIVE_INT)
    gru_layers: int = allowed(2, **_POSITIVE_INT)
    mlp_hidden: int = allowed(50, **_POSITIVE_INT)
    max_depth: float = allowed(10.0, **_POSITIVE)            # m, encoder input clamp
    lr_pretrain: float = allowed(1e-3, **_POSITIVE)          # paper: Adam 1e-3, 500 epochs
    lam: float = allowed(10000.0, ge=0)                      # paper: lambda = 10,000
    lr_head: float = allowed(1e-6, **_POSITIVE)              # paper: 1e-6
    lr_encoder: float = allowed(1e-6, **_POSITIVE)           # paper: "the same optimizer configuration"
    alpha: float | None = allowed(None, ge=0)  # ground-effect law f_a = alpha S / (d^2 - beta) [N m^2/(rad/s)^2]
    beta: float | None = allowed(None, ge=0)   # m^2; both None: the training data's law (its k_T, mu, r), else
    #                                            the paper's quadrotor (ALPHA_PAPER, BETA_PAPER)
    loss_frames: str = allowed("all", choices=("all", "last"))  # frames of a window the height loss uses
    loss: str = allowed("height", choices=("height", "law_weighted"))  # systems.height.LOSSES: the paper's height
    #                                     MSE, or ours weighted by the law's slope at the true height
    #                                     (systems/height.py)
    law_weight_ref: float = allowed(1.0, **_POSITIVE)        # N/m, g_ref of loss=law_weighted


@dataclass
class SyntheticConfig:
    """Generate a synthetic dataset where none exists (smoke runs); see uavturb.data.shards."""

    enabled: bool = False
    n_scenes: int = allowed(6, ge=3, text="an integer >= 3 (train, val and test rooms)")
    trajs_per_scene: int = allowed(3, **_POSITIVE_INT)
    T: int = allowed(64, ge=2)
    pairs: int = allowed(512, ge=2)
    seed: int = allowed(0, ge=0, lt=2**32)


@dataclass
class DataConfig:
    root: str = allowed("data/sim", nonempty=True)            # shard dataset (manifest.json)
    pairs_root: str = allowed("data/pairs", nonempty=True)    # pre-training pairs (holds pairs/)
    window: int = allowed(8, **_POSITIVE_INT)                 # H, frames of memory per sample
    stride: int = allowed(1, **_POSITIVE_INT)                 # frames between training windows
    eval_stride: int = allowed(1, **_POSITIVE_INT)            # frames between val/test windows
    batch_size: int = allowed(16, **_POSITIVE_INT)
    num_workers: int = allowed(2, ge=0)
    image_size: int = allowed(128, ge=0)                      # px (square); 0 = whatever the data holds
    pin_memory: bool | None = None                            # DataLoader pinned memory; null: when training on
    #                                                           a CUDA device (runs/accelerators.py)
    val_fraction: float = allowed(0.1, gt=0, lt=1)            # pairs held out for validation
    synthetic: SyntheticConfig = field(default_factory=SyntheticConfig)


@dataclass
class TrainerConfig:
    max_epochs: int = allowed(100, **_POSITIVE_INT)
    max_steps: int = allowed(-1, ge=1, also=(-1,), text="an integer >= 1, or -1 (no limit)")
    accelerator: str = allowed("auto", choices=ACCELERATORS)
    devices: str = allowed("auto", pattern=r"auto|-1|[1-9][0-9]*|[0-9]+(,[0-9]+)*,?",
                           text='"auto", a count ("2"), -1 (all) or device ids ("0,1")')
    strategy: str = allowed("auto", choices=STRATEGIES)
    num_nodes: int = allowed(1, **_POSITIVE_INT)
    precision: str = allowed("32-true", choices=PRECISIONS)  # bf16-mixed: CPU and Ampere+ GPUs; 16-mixed: GPUs only
    cudnn_benchmark: bool = False       # cuDNN picks the fastest convolution for the (fixed) image size; GPU only
    matmul_precision: str = allowed("highest", choices=("highest", "high", "medium"))
    #                                     torch.set_float32_matmul_precision: high = TF32 on Ampere+ GPUs
    seed: int = allowed(0, ge=0, lt=2**32)
    limit_train_batches: float = allowed(1.0, **_POSITIVE)    # <= 1: fraction; > 1: number of batches
    limit_val_batches: float = allowed(1.0, **_POSITIVE)
    limit_test_batches: float = allowed(1.0, **_POSITIVE)
    log_every_n_steps: int = allowed(50, **_POSITIVE_INT)
    early_stopping_patience: int = allowed(0, ge=0)          # epochs without val improvement; 0 = off
    enable_progress_bar: bool = True
    default_root_dir: str = allowed("runs", nonempty=True)   # checkpoints go to <default_root_dir>/checkpoints/<run>
    deterministic: bool = False
    num_threads: int = allowed(0, ge=0)  # torch CPU threads (torch.set_num_threads); 0 = torch's default


@dataclass
class TrackingConfig:
    enabled: bool = True
    experiment: str = allowed("uavturb", nonempty=True)
    run_name: str | None = None
    system_metrics: bool = False        # CPU, memory, GPU use logged as system/* metrics (needs psutil)


@dataclass
class TrainConfig:
    stage: str = allowed("height", choices=("pretrain", "height"))
    model: ModelConfig = field(default_factory=ModelConfig)
    data: DataConfig = field(default_factory=DataConfig)
    trainer: TrainerConfig = field(default_factory=TrainerConfig)
    tracking: TrackingConfig = field(default_factory=TrackingConfig)


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
        parent, _, last = key.rpartition(".")
        msg = str(e).splitlines()[0]
        if "not in" in msg or "Missing key" in msg or "ConfigKeyError" in type(e).__name__:
            known = allowed_keys(parent)
            problem = f"unknown key (in {source}){schema.did_you_mean(last, known)}; allowed: {', '.join(known)}"
        else:
            problem = f"bad value (in {source}): {msg}"
        raise InputError(key, problem) from None


def override_layer(overrides: list[str]) -> dict[str, Any]:
    """``key=value`` overrides as a nested layer to merge, each value typed by :class:`TrainConfig`
    (:func:`uavturb.schema.parse_overrides`, the one override syntax of every command)."""
    return schema.nested(schema.parse_overrides(overrides, TrainConfig))


def _read_config_file(path: Path) -> dict[str, Any]:
    return read_yaml_mapping(path, not_found="config file not found")


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
    """Merge into the schema (types, unknown keys) and check every value against its declared range
    (:func:`uavturb.schema.check_values`)."""
    cfg = _merge(OmegaConf.structured(TrainConfig), cfg, "config")
    schema.check_values(cfg, TrainConfig)
    return cfg


def load_config(overrides: list[str] | None = None, experiment: str | None = None,
                conf_dir: str | Path | None = None) -> DictConfig:
    """Compose the training config.

    Parameters
    ----------
    overrides : ``key=value`` strings (:func:`uavturb.schema.parse_overrides`: ``model.use_gru=false``); also
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
        key, value = schema.split_override(item)
        if key == "experiment":
            experiment = value
        elif key in GROUPS and "." not in value and not value.startswith(("{", "[")):
            group_choice[key] = value
        else:
            dotlist.append(item)

    top_path = _locate(dirs, "config.yaml") or dirs[0] / "config.yaml"
    top = _read_config_file(top_path)
    defaults = _defaults(top, top_path)
    exp: dict[str, Any] = {}
    if experiment:
        exp_path = _locate(dirs, "experiment", f"{experiment}.yaml")
        if exp_path is None:
            raise InputError("experiment", f"no experiment {experiment!r}; choices: "
                             f"{', '.join(_choices(dirs, 'experiment'))}")
        exp = _read_config_file(exp_path)
        defaults.update(_defaults(exp, exp_path))
    defaults.update(group_choice)

    cfg = OmegaConf.structured(TrainConfig)
    cfg = _merge(cfg, top, str(top_path))
    for group in GROUPS:
        if group in defaults:
            path = _group_file(dirs, group, defaults[group])
            cfg = _merge(cfg, {group: _read_config_file(path)}, str(path))
    if exp:
        cfg = _merge(cfg, exp, f"experiment {experiment}")
    cfg = _merge(cfg, override_layer(dotlist), "overrides")
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


# --- sweep files -----------------------------------------------------------------------------

#: the shipped sweep files (package data)
SWEEPS_DIR = Path(str(resources.files("uavturb") / "sweeps"))
DEFAULT_SPEC = SWEEPS_DIR / "ablation.yaml"


def shipped_sweeps() -> list[str]:
    """Names of the shipped sweep files (``ablation``)."""
    return sorted(p.stem for p in SWEEPS_DIR.glob("*.yaml"))


def resolve_spec(spec: str | Path) -> Path:
    """A sweep file: ``spec`` itself where it exists, else the shipped sweep of that name.

    ``ablation``, ``ablation.yaml`` and ``sweeps/ablation.yaml`` (from a folder without such a file)
    all name the shipped ``uavturb/sweeps/ablation.yaml``.

    Raises
    ------
    InputError : neither a file nor a shipped sweep's name (listing the shipped ones).
    """
    path = Path(spec)
    if path.is_file():
        return path
    shipped = SWEEPS_DIR / f"{path.stem}.yaml"
    if path.suffix in ("", ".yaml") and shipped.is_file():
        return shipped
    raise InputError(path, f"sweep file not found (shipped sweeps: {', '.join(shipped_sweeps())})")


@dataclass
class RowSpec:
    """One table row: a ``conf/model`` choice and overrides; the paper's values for reference."""

    name: str = MISSING
    model: str = MISSING
    overrides: list[str] = field(default_factory=list)
    paper_rmse_d: float | None = None      # m
    paper_rmse_fa: float | None = None     # N


@dataclass
class SweepProfile:
    """How a sweep runs (``uavturb sweep --profile NAME``; ``--preset`` is its old spelling): the
    number of seeds and the overrides of every run, of the pre-training runs and of the rows' runs.

    Not a dataset preset (``generate sim --preset``): a profile names the data it trains on in its
    overrides. The shipped ``ablation`` sweep's ``quick`` trains on synthetic box rooms
    (``data=synthetic``), ``medium`` on the simulator preset ``medium``'s shards, ``paper`` and
    ``gpu`` on the shards of ``data.root`` (those of ``generate sim --preset paper`` for the paper).
    """

    seeds: int = 1
    overrides: list[str] = field(default_factory=list)   # every run
    pretrain: list[str] = field(default_factory=list)    # pre-training runs
    height: list[str] = field(default_factory=list)      # the rows' runs


@dataclass
class SweepSpec:
    name: str = "ablation"
    experiment: str = "uavturb-ablation"
    rows: list[RowSpec] = field(default_factory=list)
    pretraining: dict[str, str] = field(default_factory=dict)  # model.pretraining -> conf/experiment bundle
    profiles: dict[str, SweepProfile] = field(default_factory=dict)


def load_spec(path: str | Path = DEFAULT_SPEC) -> DictConfig:
    """Read and check a sweep file; a typo fails naming the file and the key."""
    path = resolve_spec(path)
    body = read_yaml_mapping(path, expected="a mapping of sweep keys")
    if "presets" in body and "profiles" not in body:  # the key's old name, in a user's sweep file
        body["profiles"] = body.pop("presets")
    try:
        spec = OmegaConf.merge(OmegaConf.structured(SweepSpec), body)
        OmegaConf.to_container(spec, throw_on_missing=True)
    except OmegaConfBaseException as e:
        key = str(getattr(e, "full_key", "") or getattr(e, "key", "") or "?")
        raise InputError(f"{path}: {key}", str(e).splitlines()[0]) from None
    if not spec.rows:
        raise InputError(f"{path}: rows", "no rows")
    names = [r.name for r in spec.rows]
    if len(set(names)) != len(names):
        raise InputError(f"{path}: rows", f"row names repeat: {names}")
    if not spec.profiles:
        raise InputError(f"{path}: profiles", "no profiles")
    return spec

