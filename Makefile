# The two commands of the README: `make demo` (the main job) and `make test`.
SHELL := /bin/bash
PYTHON ?= python3
VENV ?= .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.uavturb-installed
export PYOPENGL_PLATFORM ?= egl
export MPLBACKEND ?= Agg

.PHONY: setup demo test test-all ui clean

# the package's own modules compiled (pip compiles what it installs, not an editable checkout; quick when nothing
# changed): where Python writes no bytecode (PYTHONDONTWRITEBYTECODE, a read-only checkout), every command compiled
# them again, 0.15-0.3 s of each (`uavturb gap`'s imports: 0.97-1.13 s without, 0.83 s with)
setup: $(STAMP)
	@$(BIN)/python -m compileall -q uavturb

$(STAMP): pyproject.toml scripts/setup.sh
	PYTHON=$(PYTHON) VENV=$(VENV) bash scripts/setup.sh
	@touch $@

demo: setup
	$(BIN)/uavturb demo --out demo_out

test: setup
	$(BIN)/python -m pytest

test-all: setup
	$(BIN)/python -m pytest -m ""

# the MLflow UI on the store of `make demo` (runs, Table 1, models): http://127.0.0.1:5000
ui: setup
	$(BIN)/mlflow ui --backend-store-uri sqlite:///mlflow.db --host 127.0.0.1 --port $${PORT:-5000}

clean:
	rm -rf demo_out .pytest_cache build *.egg-info
