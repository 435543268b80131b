"""MLflow tracking, set up once for every kind of run.

The store is MLflow 3's own default: an embedded SQLite ``mlflow.db`` with artifacts under
``mlruns/`` in the working directory; ``MLFLOW_TRACKING_URI`` points elsewhere (a server).
"""

from __future__ import annotations

import os
import subprocess
from pathlib import Path
from typing import Any


def tracking_uri() -> str:
    return os.environ.get("MLFLOW_TRACKING_URI", "sqlite:///mlflow.db")


def git_commit() -> str:
    try:
        out = subprocess.run(["git", "rev-parse", "HEAD"], capture_output=True, text=True, timeout=5,
                             cwd=Path(__file__).resolve().parent)
        return out.stdout.strip() or "unknown"
    except (OSError, subprocess.SubprocessError):
        return "unknown"




def log_run(experiment: str, *, run_name: str, params: dict[str, Any], metrics: dict[str, float],
            tags: dict[str, str] | None = None, artifacts: Path | None = None) -> str:
    """One MLflow run with params, metrics, tags and a folder of artifacts; returns its id."""
    import logging

    import mlflow

    logging.getLogger("mlflow").setLevel(logging.ERROR)
    logging.getLogger("alembic").setLevel(logging.ERROR)
    mlflow.set_tracking_uri(tracking_uri())
    mlflow.set_experiment(experiment)
    with mlflow.start_run(run_name=run_name) as run:
        mlflow.set_tags({"git_commit": git_commit(), **(tags or {})})
        mlflow.log_params({k: str(v)[:500] for k, v in params.items()})
        mlflow.log_metrics({k: float(v) for k, v in metrics.items() if v is not None})
        if artifacts is not None:
            mlflow.log_artifacts(str(artifacts))
        return run.info.run_id
