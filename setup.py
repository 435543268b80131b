"""Build in a temporary folder: ``pip install .`` leaves no ``build/`` or ``*.egg-info`` in the source tree.

Everything else is in pyproject.toml.
"""

import atexit
import shutil
import tempfile

from setuptools import setup

_tmp = tempfile.mkdtemp(prefix="uavturb-build-")
atexit.register(shutil.rmtree, _tmp, ignore_errors=True)
setup(options={"build": {"build_base": f"{_tmp}/build"}, "egg_info": {"egg_base": _tmp}})
