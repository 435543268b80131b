"""Dependencies run one way (pyproject.toml's import-linter contracts), checked on the real tree and
shown to fail when a lower layer imports a higher one or two modules import each other."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
LINT = Path(sys.executable).with_name("lint-imports")


def _lint(tree: Path) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": str(tree)}
    return subprocess.run([str(LINT), "--config", str(ROOT / "pyproject.toml"), "--no-cache"], cwd=tree, env=env,
                          capture_output=True, text=True, timeout=300)


@pytest.fixture(scope="module")
def copy_of_package(tmp_path_factory) -> Path:
    tree = tmp_path_factory.mktemp("tree")
    shutil.copytree(ROOT / "uavturb", tree / "uavturb", ignore=shutil.ignore_patterns("__pycache__"))
    return tree


def test_the_tree_keeps_every_contract():
    res = _lint(ROOT)
    assert res.returncode == 0, res.stdout[-3000:]
    assert "Contracts: 3 kept, 0 broken." in res.stdout


def test_a_lower_layer_importing_a_higher_one_fails(copy_of_package):
    bad = copy_of_package / "uavturb" / "physics" / "sneaky.py"
    bad.write_text("from uavturb.runs import config  # physics must not know about the run platform\n")
    try:
        res = _lint(copy_of_package)
    finally:
        bad.unlink()
    assert res.returncode != 0
    assert "Dependencies run one way BROKEN" in res.stdout
    assert "uavturb.physics.sneaky -> uavturb.runs.config" in res.stdout


def test_siblings_importing_each_other_fail(copy_of_package):
    a = copy_of_package / "uavturb" / "gap" / "uses_sim.py"
    a.write_text("import uavturb.sim.flights.simulate\n")
    try:
        res = _lint(copy_of_package)
    finally:
        a.unlink()
    assert res.returncode != 0 and "BROKEN" in res.stdout


@pytest.mark.parametrize("room, imports", [("core", "uavturb.sim.flights.simulate"),
                                           ("flights", "uavturb.sim.dataset.planning"),
                                           ("dataset", "uavturb.sim.flights.plans")])
def test_the_simulators_rooms_keep_to_themselves(copy_of_package, room, imports):
    """core imports neither flights nor dataset; flights and dataset do not import each other."""
    bad = copy_of_package / "uavturb" / "sim" / room / "sneaky.py"
    bad.write_text(f"import {imports}\n")
    try:
        res = _lint(copy_of_package)
    finally:
        bad.unlink()
    assert res.returncode != 0
    assert "The simulator's rooms: flights and dataset build on core, not on each other BROKEN" in res.stdout
    assert f"uavturb.sim.{room}.sneaky -> {imports}" in res.stdout
