"""MLflow tracking, set up once for every kind of run.

The store is MLflow 3's own default: an embedded SQLite ``mlflow.db`` with artifacts under
``mlruns/`` in the working directory; ``MLFLOW_TRACKING_URI`` points elsewhere (a server).

MLflow's own conventions, so that its UI fills its columns: experiments are tagged
``mlflow.experimentKind = custom_model_development`` (the UI opens on the runs, not on MLflow 3's
GenAI overview), runs ``mlflow.source.git.commit`` (the Version column), datasets are logged
inputs with their digest (the Dataset column), descriptions are ``mlflow.note.content``. Paths
in tags and params are relative to the working folder where they lie under it
(:func:`project_path`). A run that a command logs again with the same inputs (tag
:data:`KEY_TAG`) is reused rather than duplicated (:func:`find_run`).
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


#: tag ``mlflow.experimentKind``: MLflow 3's UI opens experiments of this kind on their runs table
EXPERIMENT_KIND = "custom_model_development"
#: a run's inputs, hashed: a command run again on the same inputs finds and reuses its run
KEY_TAG = "uavturb.key"
#: the description MLflow's UI shows on a run's page (Markdown)
NOTE_TAG = "mlflow.note.content"


def quiet_mlflow() -> None:
    """MLflow's and its database's INFO lines off (table creation, experiment creation), and its
    artifact download bars (``\\r`` lines in log files)."""
    import logging

    os.environ.setdefault("MLFLOW_ENABLE_ARTIFACTS_PROGRESS_BAR", "false")
    for name in ("mlflow", "alembic"):
        logging.getLogger(name).setLevel(logging.ERROR)


def client():
    """An MlflowClient of :func:`tracking_uri`."""
    import mlflow

    quiet_mlflow()
    return mlflow.MlflowClient(tracking_uri())


def ensure_experiment(name: str, mlflow_client=None) -> str:
    """Id of the experiment ``name``, created if missing, tagged :data:`EXPERIMENT_KIND`."""
    c = mlflow_client or client()
    exp = c.get_experiment_by_name(name)
    exp_id = exp.experiment_id if exp is not None else c.create_experiment(name)
    if exp is None or exp.tags.get("mlflow.experimentKind") != EXPERIMENT_KIND:
        c.set_experiment_tag(exp_id, "mlflow.experimentKind", EXPERIMENT_KIND)
    return exp_id


def source_tags() -> dict[str, str]:
    """``mlflow.source.git.commit`` (when the package runs from a git checkout)."""
    commit = git_commit()
    return {"mlflow.source.git.commit": commit} if commit != "unknown" else {}


def project_path(path: str | Path) -> str:
    """``path`` relative to the working folder where it lies under it, else absolute."""
    p = Path(path).resolve()
    try:
        return str(p.relative_to(Path.cwd().resolve()))
    except ValueError:
        return str(p)


def input_key(**inputs: Any) -> str:
    """A short hash of a run's inputs (the value of :data:`KEY_TAG`)."""
    import hashlib
    import json

    return hashlib.sha256(json.dumps(inputs, sort_keys=True, default=str).encode()).hexdigest()[:16]


def find_run(mlflow_client, experiment_id: str, key: str, parent_run_id: str | None = None) -> Any | None:
    """The latest live run of an experiment tagged :data:`KEY_TAG` = ``key`` (and child of ``parent_run_id``)."""
    filt = f"tags.`{KEY_TAG}` = '{key}'"
    if parent_run_id is not None:
        filt += f" and tags.`mlflow.parentRunId` = '{parent_run_id}'"
    runs = mlflow_client.search_runs([experiment_id], filter_string=filt, order_by=["attributes.start_time DESC"],
                                     max_results=1)
    return runs[0] if runs else None


def log_dataset(mlflow_client, run_id: str, root: str | Path, digest: str, context: str = "training") -> None:
    """The dataset folder as the run's input (name, digest, local source): the UI's Dataset column."""
    import json

    from mlflow.entities import Dataset, DatasetInput, InputTag

    root = Path(root)
    dataset = Dataset(name=root.parent.name if root.name == "pairs" else root.name, digest=digest[:36],
                      source_type="local", source=json.dumps({"uri": project_path(root)}))
    mlflow_client.log_inputs(run_id, datasets=[DatasetInput(dataset, [InputTag("mlflow.data.context", context)])])


def log_run(experiment: str, *, run_name: str, params: dict[str, Any], metrics: dict[str, float],
            tags: dict[str, str] | None = None, artifacts: Path | None = None) -> str:
    """One MLflow run with params, metrics, tags and a folder of artifacts; returns its id.

    A run of the same experiment, name and params already logged is reused (its metrics
    and artifacts written again), so a command run twice on the same inputs keeps one run.
    """
    import mlflow

    quiet_mlflow()
    mlflow.set_tracking_uri(tracking_uri())
    params = {k: str(v)[:500] for k, v in params.items()}
    c = client()
    exp_id = ensure_experiment(experiment, c)
    key = input_key(run_name=run_name, params=params)
    previous = find_run(c, exp_id, key)
    with mlflow.start_run(run_id=previous.info.run_id if previous else None, experiment_id=exp_id,
                          run_name=None if previous else run_name) as run:
        mlflow.set_tags({**source_tags(), KEY_TAG: key, **(tags or {})})
        if previous is None:
            mlflow.log_params(params)
        mlflow.log_metrics({k: float(v) for k, v in metrics.items() if v is not None})
        if artifacts is not None:
            mlflow.log_artifacts(str(artifacts))
        return run.info.run_id


#: MLflow UI's saved views: an experiment tag with this prefix holds a view of the runs table
VIEW_TAG_PREFIX = "mlflow.sharedViewState."


def save_view(mlflow_client, experiment_id: str, key: str, name: str, *, search_filter: str,
              columns: list[str], order_by: str | None = None, ascending: bool = True) -> str:
    """A saved view of the experiment's runs table (the UI's "Views" menu); returns its URL fragment.

    Parameters
    ----------
    key : the view's share key (letters, digits, ``-``, ``_``)
    name : the view's name in the UI
    search_filter : MLflow search syntax; a filter also lists nested runs flat, not under their parent
    columns : columns shown, in MLflow's canonical form (``metrics.`test/rmse_d```, ``tags.`seed```)
    order_by : a column to sort by (canonical form)

    Returns
    -------
    ``#/experiments/<id>/runs?workflowType=machine_learning&viewStateShareKey=<key>``: append it to
    the UI's address. ``workflowType`` opens the model-training pages: MLflow 3.17's UI decides
    between its GenAI and model-training pages by a switch of its own (stored in the browser), not
    by the experiment's ``mlflow.experimentKind``, so a fresh browser opens on the GenAI overview.
    """
    import json
    import time

    state = {"searchFilter": search_filter, "orderByKey": order_by or "attributes.start_time",
             "orderByAsc": ascending if order_by else False, "startTime": "ALL", "lifecycleFilter": "Active",
             "modelVersionFilter": "All Runs", "datasetsFilter": [], "selectedColumns": list(columns),
             "runsExpanded": {}, "runsPinned": [], "runsHidden": [], "viewMaximized": False, "runListHidden": False}
    now = int(time.time() * 1000)
    envelope = {"name": name, "createdAt": now, "updatedAt": now, "state": json.dumps(state)}
    mlflow_client.set_experiment_tag(experiment_id, VIEW_TAG_PREFIX + key, json.dumps(envelope))
    return f"#/experiments/{experiment_id}/runs?workflowType=machine_learning&viewStateShareKey={key}"


def ui_url(fragment: str) -> str:
    """The address of a UI page of :func:`save_view` on ``mlflow ui``'s default port (``make ui``)."""
    return f"http://127.0.0.1:5000/{fragment}"
