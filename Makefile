# The two commands of the README: `make demo` (the main job) and `make test`.
SHELL := /bin/bash
PYTHON ?= python3
VENV ?= .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.uavturb-installed
export PYOPENGL_PLATFORM ?= egl
export MPLBACKEND ?= Agg

.PHONY: setup demo test test-all ui clean

setup: $(STAMP)

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
