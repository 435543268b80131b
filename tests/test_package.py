"""The package outside its checkout: shipped configs and sweeps, a user's config folder, --version,
and (slow) a non-editable install training from another folder."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from uavturb.errors import InputError
from uavturb.runs.config import CONF_DIR, load_config
from uavturb.runs.config import DEFAULT_SPEC, resolve_spec

ROOT = Path(__file__).resolve().parents[1]


def test_configs_and_sweeps_ship_inside_the_package():
    import uavturb

    package = Path(uavturb.__file__).parent
    assert CONF_DIR == package / "conf" and (CONF_DIR / "config.yaml").is_file()
    assert DEFAULT_SPEC == package / "sweeps" / "ablation.yaml"


def test_a_shipped_sweep_by_name(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # no sweeps/ folder here
    for name in ("ablation", "ablation.yaml", "sweeps/ablation.yaml"):
        assert resolve_spec(name) == DEFAULT_SPEC
    mine = tmp_path / "sweeps" / "ablation.yaml"  # a file of the user's wins over the shipped one
    mine.parent.mkdir()
    mine.write_text(DEFAULT_SPEC.read_text())
    assert resolve_spec("sweeps/ablation.yaml") == Path("sweeps/ablation.yaml")
    with pytest.raises(InputError, match="shipped sweeps: ablation"):
        resolve_spec("nope.yaml")


def test_a_users_config_folder_replaces_and_adds_files(tmp_path):
    (tmp_path / "model").mkdir()
    (tmp_path / "model" / "wide.yaml").write_text("pretraining: none\nuse_gru: true\ngru_hidden: 96\n")
    (tmp_path / "experiment").mkdir()
    (tmp_path / "experiment" / "smoke.yaml").write_text("defaults:\n  model: wide\n  data: synthetic\n"
                                                       "tracking:\n  experiment: mine\n")
    cfg = load_config(["trainer=smoke"], experiment="smoke", conf_dir=tmp_path)
    assert cfg.model.gru_hidden == 96 and cfg.tracking.experiment == "mine"  # the user's files
    assert cfg.data.synthetic.enabled and cfg.trainer.max_epochs == 2  # the shipped ones still there
    with pytest.raises(InputError) as e:
        load_config(["model=nope"], conf_dir=tmp_path)
    assert "wide" in e.value.problem and "none_gru" in e.value.problem  # choices from both folders
    with pytest.raises(InputError, match="config folder not found"):
        load_config(conf_dir=tmp_path / "missing")


def test_version(capsys):
    from uavturb.cli import main

    with pytest.raises(SystemExit) as e:
        main(["--version"])
    assert e.value.code == 0 and capsys.readouterr().out.strip() == "uavturb 0.1.0"


@pytest.mark.slow
def test_non_editable_install_trains_from_another_folder(tmp_path):
    """`pip install .` (here into a target folder, dependencies from this environment) leaves nothing in the
    source tree, and `uavturb train --experiment smoke` runs from an empty folder with output fit for a log."""
    source = tmp_path / "source"
    files = subprocess.run(["git", "ls-files", "-co", "--exclude-standard"], cwd=ROOT, capture_output=True, text=True,
                           check=True).stdout.split()
    for f in files:
        if (ROOT / f).is_file():
            (source / f).parent.mkdir(parents=True, exist_ok=True)
            (source / f).write_bytes((ROOT / f).read_bytes())
    site = tmp_path / "site"
    pip = subprocess.run([sys.executable, "-m", "pip", "install", "-q", "--no-deps", "--no-build-isolation",
                          "--target", str(site), "."], cwd=source, capture_output=True, text=True, timeout=300)
    assert pip.returncode == 0, pip.stderr[-2000:]
    assert not (source / "build").exists() and not list(source.glob("*.egg-info"))  # nothing left in the tree
    assert (site / "uavturb" / "conf" / "experiment" / "smoke.yaml").is_file()
    assert (site / "uavturb" / "sweeps" / "ablation.yaml").is_file()
    assert (site / "uavturb" / "vehicles" / "firefly.yaml").is_file()  # the shipped vehicle files

    work = tmp_path / "elsewhere"
    work.mkdir()
    env = {**os.environ, "PYTHONPATH": str(site), "MLFLOW_TRACKING_URI": f"sqlite:///{work / 'mlflow.db'}"}
    run = lambda *args: subprocess.run([sys.executable, "-m", "uavturb.cli", *args], cwd=work, env=env,  # noqa: E731
                                       capture_output=True, text=True, timeout=600)
    version = run("--version")
    assert version.returncode == 0 and version.stdout.strip() == "uavturb 0.1.0"
    proc = run("train", "--experiment", "smoke")
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert '"stage": "height"' in proc.stdout and "test/rmse_fa_1e-4N" in proc.stdout
    # stderr is a log: one line per epoch, no redrawn bar, no tips or deprecation warnings
    assert "\r" not in proc.stderr and "Tip" not in proc.stderr and "deprecated" not in proc.stderr
    assert [line.split(" (")[0] for line in proc.stderr.splitlines() if line.startswith("epoch ")] == \
        ["epoch 1/2", "epoch 2/2"]
    assert max(len(line) for line in proc.stderr.splitlines()) < 300
    imported = subprocess.run([sys.executable, "-c", "import uavturb; print(uavturb.__file__)"], cwd=work, env=env,
                              capture_output=True, text=True)
    assert imported.stdout.startswith(str(site))  # the installed copy, not the checkout
    bad = run("sweep", "sweeps/missing.yaml")
    assert bad.returncode == 2 and "shipped sweeps: ablation" in bad.stderr
