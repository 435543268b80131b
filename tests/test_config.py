"""The training configuration (``uavturb/conf``, :mod:`uavturb.runs.config`): every shipped
value is allowed, a value that makes no sense fails in one line before any run is opened or any
data made, and the choices offered are Lightning's own."""

from __future__ import annotations

import typing

import pytest
from lightning.fabric.connector import _PRECISION_INPUT_STR, _PRECISION_INPUT_STR_ALIAS
from lightning.pytorch.accelerators import AcceleratorRegistry
from lightning.pytorch.strategies import StrategyRegistry

from uavturb.cli import main
from uavturb.runs.config import ACCELERATORS, CONF_DIR, PRECISIONS, STRATEGIES, load_config

# --- values that make no sense ------------------------------------------------------------------


@pytest.mark.parametrize("override, allowed", [
    ("trainer.max_epochs=-1", "an integer >= 1"),
    ("trainer.max_epochs=0", "an integer >= 1"),
    ("model.lr_head=-1", "a number > 0"),
    ("data.batch_size=0", "an integer >= 1"),
    ("trainer.precision=bogus", "one of 32-true"),
    ("trainer.devices=abc", '"auto", a count'),
    ("trainer.limit_train_batches=-1", "a number > 0"),
    ("trainer.max_steps=0", "or -1 (no limit)"),
    ("data.val_fraction=1.5", "a number > 0 and < 1"),
    ("model.lr_encoder=nan", "a number > 0"),
])
def test_bad_values_fail_in_one_line_before_any_run(tmp_path, monkeypatch, capsys, override, allowed):
    uri = f"sqlite:///{tmp_path / 'mlflow.db'}"
    monkeypatch.setenv("MLFLOW_TRACKING_URI", uri)
    assert main(["train", "--experiment", "smoke", f"data.root={tmp_path / 'sim'}",
                 f"trainer.default_root_dir={tmp_path / 'runs'}", override]) == 2
    err = capsys.readouterr().err.strip()
    key = override.split("=")[0]
    assert len(err.splitlines()) == 1
    assert err.startswith(f"uavturb train: error: {key}: ") and "is not allowed; allowed: " in err and allowed in err
    assert not (tmp_path / "mlflow.db").exists() and not (tmp_path / "sim").exists()  # nothing opened or made


def test_every_value_of_the_defaults_and_shipped_configs_is_allowed():
    for group in ("model", "data", "trainer"):
        for f in sorted((CONF_DIR / group).glob("*.yaml")):
            load_config([f"{group}={f.stem}"])
    for f in sorted((CONF_DIR / "experiment").glob("*.yaml")):
        load_config(experiment=f.stem)


def test_lightning_choices_match_lightning():
    assert set(PRECISIONS) == (set(typing.get_args(_PRECISION_INPUT_STR))
                               | set(typing.get_args(_PRECISION_INPUT_STR_ALIAS)))
    assert set(ACCELERATORS) == set(AcceleratorRegistry.available_accelerators()) | {"auto", "gpu"}
    assert set(STRATEGIES) == set(StrategyRegistry.available_strategies()) | {"auto"}
