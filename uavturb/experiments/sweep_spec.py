"""Sweep files (``sweeps/ablation.yaml``): typed schema and reader. A typo fails naming the key."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from omegaconf import MISSING, DictConfig, OmegaConf
from omegaconf.errors import OmegaConfBaseException

from uavturb.errors import InputError

DEFAULT_SPEC = Path(__file__).resolve().parents[2] / "sweeps" / "ablation.yaml"


FINAL_METRICS = ("test/rmse_d", "test/rmse_fa")


@dataclass
class RowSpec:
    """One table row: a ``conf/model`` choice and overrides; the paper's values for reference."""

    name: str = MISSING
    model: str = MISSING
    overrides: list[str] = field(default_factory=list)
    paper_rmse_d: float | None = None      # m
    paper_rmse_fa: float | None = None     # N


@dataclass
class PresetSpec:
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
    presets: dict[str, PresetSpec] = field(default_factory=dict)


def load_spec(path: str | Path = DEFAULT_SPEC) -> DictConfig:
    """Read and check a sweep file; a typo fails naming the file and the key."""
    import yaml

    path = Path(path)
    if not path.is_file():
        raise InputError(path, "sweep file not found")
    try:
        body = yaml.safe_load(path.read_text()) or {}
    except yaml.YAMLError as e:
        raise InputError(path, f"not valid YAML ({str(e).splitlines()[0]})") from None
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
    if not spec.presets:
        raise InputError(f"{path}: presets", "no presets")
    return spec

