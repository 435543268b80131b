"""Sweep files (``sweeps/ablation.yaml``): typed schema and reader. A typo fails naming the key.

The shipped sweep files are package data (``uavturb/sweeps``, :data:`SWEEPS_DIR`); a sweep is named
by a path to a file or by the name of a shipped one (``ablation``; ``sweeps/ablation.yaml`` too, where
no such file exists in the working folder): :func:`resolve_spec`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path

from omegaconf import MISSING, DictConfig, OmegaConf
from omegaconf.errors import OmegaConfBaseException

from uavturb.errors import InputError
from uavturb.io.yaml_mapping import read_yaml_mapping

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
    path = resolve_spec(path)
    body = read_yaml_mapping(path, expected="a mapping of sweep keys")
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

