"""Resume policy of ``uavturb train --resume RUN_ID``: which runs may be continued, with which config.

A run may be resumed when it is a uavturb training run (tags ``stage`` and ``checkpoint_dir``)
that no live process keeps (KILLED, FAILED, FINISHED, or RUNNING whose process on this host is
gone). Its config may change only in :data:`RESUMABLE_KEYS` (how long and where it trains, not
what it learns); it continues from ``last.ckpt`` in its checkpoint folder.
"""

from __future__ import annotations

import tempfile
from pathlib import Path
from typing import Any

from omegaconf import DictConfig, OmegaConf

from uavturb.errors import InputError
from uavturb.io.checkpoint import read_checkpoint
from uavturb.io.yaml_mapping import read_yaml_mapping
from uavturb.runs import store
from uavturb.runs.config import load_config, override_layer, to_flat_dict, validate
from uavturb.runs.processes import process_alive

#: keys a resumed run may change (how long and where it trains, not what it learns); any other
#: difference from the run's own config is refused
RESUMABLE_KEYS = ("trainer.max_epochs", "trainer.max_steps", "trainer.num_threads", "trainer.enable_progress_bar",
                  "trainer.accelerator", "trainer.devices", "trainer.strategy", "trainer.num_nodes",
                  "trainer.cudnn_benchmark", "data.num_workers", "data.pin_memory", "model.encoder_ckpt")
#: name of the checkpoint of the latest epoch, in the run's checkpoint folder (tag ``checkpoint_dir``)
LAST_CHECKPOINT = "last.ckpt"


def resumable_run(run_id: str) -> Any:
    """The run ``run_id`` if it is a training run that may be resumed now; InputError otherwise."""
    run = store.get_run(run_id, "--resume")
    tags = run.data.tags
    if "stage" not in tags or "checkpoint_dir" not in tags:
        raise InputError("--resume", f"run {run_id} is not a uavturb training run (no tags stage, checkpoint_dir)")
    alive = process_alive(tags)
    if run.info.status == "RUNNING" and alive is not False:  # False: its process is gone (stale)
        where = f"pid {tags.get('pid', '?')} on {tags.get('host', '?')}"
        state = "still runs" if alive else "is RUNNING on another host"
        raise InputError("--resume", f"run {run_id} {state} ({where}); stop it first or wait for it")
    return run


def last_checkpoint(run: Any) -> Path:
    """Where a run keeps the checkpoint of its latest epoch (it may not exist yet)."""
    return Path(run.data.tags["checkpoint_dir"]) / LAST_CHECKPOINT


def check_resume(cfg: DictConfig, run_id: str) -> None:
    """Refuse, before any work, a run that cannot be resumed with ``cfg``: not resumable now, a
    config that differs outside :data:`RESUMABLE_KEYS`, or a poisoned or broken ``last.ckpt``."""
    run = resumable_run(run_id)
    config_changes(cfg, run)
    last = last_checkpoint(run)
    if last.is_file():
        read_checkpoint(last)


def run_config(run_id: str) -> DictConfig:
    """The resolved config a training run logged (its ``config.yaml`` artifact), validated."""
    resumable_run(run_id)
    with tempfile.TemporaryDirectory() as tmp:
        try:
            path = store.download_artifact(run_id, "config.yaml", tmp)
        except Exception:  # noqa: BLE001 - MlflowException or OSError: the artifact is gone
            raise InputError("--resume", f"run {run_id} has no readable config.yaml artifact") from None
        return validate(OmegaConf.create(read_yaml_mapping(path)))  # within the YAML bounds: runs can be shared


def resume_config(run_id: str, overrides: list[str] | None = None, experiment: str | None = None) -> DictConfig:
    """The config of ``uavturb train --resume RUN_ID [overrides]``.

    With only :data:`RESUMABLE_KEYS` overrides (e.g. ``trainer.max_epochs=50``) and no
    ``--experiment``: the run's own config with those changes. Otherwise the config is composed
    as for a new run (repeating the run's command line); :func:`uavturb.runs.train.train` then
    refuses it if it differs from the run's in any other key.
    """
    overrides = list(overrides or [])
    if experiment is None and all(o.split("=", 1)[0] in RESUMABLE_KEYS for o in overrides):
        base = run_config(run_id)
        return validate(OmegaConf.merge(base, override_layer(overrides)))
    return load_config(overrides, experiment=experiment)


def config_changes(cfg: DictConfig, run: Any) -> dict[str, tuple[str, str]]:
    """``{key: (run's value, new value)}`` where ``cfg`` differs from a run's logged params; InputError
    where a key outside :data:`RESUMABLE_KEYS` differs."""
    changes = {}
    for key, value in to_flat_dict(cfg).items():
        new, old = str("null" if value is None else value)[:250], run.data.params.get(key)
        if old is None or old == new:
            continue
        if key not in RESUMABLE_KEYS:
            raise InputError("--resume", f"{key} is {new!r} here but {old!r} in run {run.info.run_id}; a resumed run "
                             f"keeps its config except {', '.join(RESUMABLE_KEYS)} (or start a new run)")
        changes[key] = (old, new)
    return changes
