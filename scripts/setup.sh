#!/usr/bin/env bash
# One-time set-up on a fresh Debian machine with Python 3.11: EGL for headless rendering,
# a virtual environment in .venv, and the package with its test dependencies.
set -euo pipefail
cd "$(dirname "$0")/.."
PYTHON="${PYTHON:-python3}"
VENV="${VENV:-.venv}"

"$PYTHON" - <<'PY' || { echo "setup: Python >= 3.11 is needed (found $("$PYTHON" --version 2>&1))" >&2; exit 1; }
import sys; sys.exit(0 if sys.version_info >= (3, 11) else 1)
PY

have_egl() {
  ldconfig -p 2>/dev/null | grep -q 'libEGL.so.1' && ldconfig -p 2>/dev/null | grep -q 'libEGL_mesa.so.0' \
    && ls /usr/lib/*/dri/swrast_dri.so /usr/lib/*/dri/*_dri.so >/dev/null 2>&1
}
if ! have_egl; then
  if [ "$(id -u)" = "0" ] && command -v apt-get >/dev/null; then
    echo "setup: installing EGL/Mesa for headless rendering (apt-get)"
    export DEBIAN_FRONTEND=noninteractive
    apt-get update -qq && apt-get install -y -qq libegl1 libgl1-mesa-dri libegl-mesa0 >/dev/null
  else
    echo "setup: headless rendering needs EGL and Mesa; run as root: apt-get install -y libegl1 libgl1-mesa-dri libegl-mesa0" >&2
  fi
fi

if [ ! -x "$VENV/bin/python" ]; then
  "$PYTHON" -m venv "$VENV"
fi
# torch is pinned (torch==2.13.0 in pyproject.toml): here that is a CPU build already on disk.
"$VENV/bin/python" -m pip install -q --disable-pip-version-check -e ".[dev]"
echo "setup: ready ($VENV)"
