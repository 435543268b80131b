"""Errors a merge or a rename leaves behind (ruff's pyflakes rules, pyproject.toml [tool.ruff]):
undefined names, unused imports, redefinitions, syntax errors; shown to fail on one. Lines over
line-length (E501) fail too."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
RUFF = Path(sys.executable).with_name("ruff")


def _ruff(*paths: Path) -> subprocess.CompletedProcess:
    return subprocess.run([str(RUFF), "check", "--config", str(ROOT / "pyproject.toml"), "--no-cache",
                           *map(str, paths)], capture_output=True, text=True, timeout=300)


def test_package_and_tests_have_no_pyflakes_errors():
    res = _ruff(ROOT / "uavturb", ROOT / "tests")
    assert res.returncode == 0, res.stdout[-3000:]


def test_an_undefined_name_fails(tmp_path):
    shutil.copytree(ROOT / "uavturb" / "physics", tmp_path / "physics")
    (tmp_path / "physics" / "broken.py").write_text("def quiet():\n    logging.getLogger('x')  # never imported\n")
    res = _ruff(tmp_path)
    assert res.returncode == 1 and "F821" in res.stdout and "broken.py" in res.stdout
