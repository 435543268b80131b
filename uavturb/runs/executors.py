"""Where a sweep's runs execute: one after another in this process, or as Ray tasks.

``uavturb sweep --executor sequential|ray [--address ADDRESS] [--max-retries N]``.

:class:`SequentialExecutor` (the default) runs each submitted job at once, in this process.
:class:`RayExecutor` turns each job into a Ray task on a local Ray instance (started here,
stopped at the end) or on an existing cluster (``address``, e.g. ``auto`` on a cluster node or
``ray://head:10001``). A height run that needs a pre-training gets the pre-training task's
``ObjectRef`` as an argument, so Ray starts it when that pre-training is done; nothing here
schedules. Each task asks for the CPUs (``trainer.num_threads`` + ``data.num_workers``, at least
one) and GPUs (``trainer.devices`` when ``trainer.accelerator`` is ``gpu``) its config needs.

Both executors run a job through :func:`run_job`, so the MLflow record is the same: the run
``train()`` logs is a child of the sweep's parent (tag ``mlflow.parentRunId``, passed to the
job); an attempt that raises leaves its child FAILED (KILLED when interrupted) with the error
as tag ``error`` and the traceback as artifact ``error.txt`` -- never RUNNING. Failed attempts
are retried ``max_retries`` times (Ray: ``max_retries`` with ``retry_exceptions``); a bad
config or bad data (:class:`~uavturb.errors.InputError`) is not retried and stops the sweep.
A job whose attempts all fail does not stop the others; the runs that need its checkpoint are
skipped, and :meth:`Executor.wait` raises :class:`RunsFailed` (one line) once the rest is done.

Ray workers see the driver's MLflow store: ``MLFLOW_TRACKING_URI`` (made absolute) goes to every
task through ``runtime_env={"env_vars": ...}``; relative data and output paths of a config are
made absolute for the same reason (a cluster needs them on a shared file system).
"""

from __future__ import annotations

import contextlib
import copy
import logging
import sys
import time
import traceback
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterator

from omegaconf import DictConfig

from uavturb.errors import InputError, UavturbError
from uavturb.runs import store
from uavturb.runs.accelerators import check_trainer_device
from uavturb.runs.trainer import quiet_lightning
from uavturb.runs.training_data import prepare_data

#: ``--executor`` choices of ``uavturb sweep``
EXECUTORS = ("sequential", "ray")
#: the pinned Ray of pyproject.toml, for the message when it is missing
RAY_REQUIREMENT = "ray[default]==2.60.0"
#: stands for the pre-training run's id in a job's tags until that run is known (a Ray task's
#: pre-training may still be queued when the job is submitted); :func:`run_job` fills it in
PRETRAIN_RUN = "{pretrain_run_id}"
#: config keys that name files or folders: made absolute before a config travels to a Ray worker
PATH_KEYS = ("data.root", "data.pairs_root", "trainer.default_root_dir", "model.encoder_ckpt")


class RunsFailed(UavturbError):
    """Some runs of a sweep failed after their retries (the others finished)."""


@dataclass
class Job:
    """One training run of a sweep and what became of it.

    ``encoder`` is the pre-training its encoder comes from: another :class:`Job`, or
    ``{"checkpoint": path, "run_id": id}`` of a finished pre-training run, or None.
    ``resume``: the id of this child's interrupted run, continued in place rather than trained
    again beside it (:func:`uavturb.runs.train.train`'s ``resume``).
    ``state``: ``pending``, ``finished``, ``failed`` or ``skipped`` (its pre-training failed).
    """

    label: str
    cfg: DictConfig
    tags: dict[str, str]
    encoder: Job | dict[str, Any] | None = None
    resume: str | None = None
    on_start: Callable[[], None] | None = None
    on_done: Callable[[dict[str, Any], float], None] | None = None
    state: str = "pending"
    result: dict[str, Any] | None = None
    error: str | None = None
    ref: Any = field(default=None, repr=False)
    t0: float = 0.0


# ----------------------------------------------------------------------------------------------
# what runs where the job runs (this process or a Ray worker)


def _one_line(e: BaseException) -> str:
    text = " ".join(str(e).split())
    return f"{type(e).__name__}: {text}" if text else type(e).__name__


def _record_failure(cfg: DictConfig, tags: dict[str, str], since_ms: int, error: BaseException) -> None:
    """Leave this attempt's MLflow child FAILED (KILLED when interrupted), never RUNNING
    (:func:`uavturb.runs.store.record_failure`; Lightning may have closed it already)."""
    store.record_failure(cfg.tracking.experiment, tags, since_ms, error, _one_line(error),
                         "".join(traceback.format_exception(error)), cfg.tracking.run_name)


def _quiet_worker() -> None:
    """Lightning's and MLflow's per-run notices off in a worker too, as in the sweep's process."""
    quiet_lightning()
    store.quiet_mlflow()


def run_job(train_fn: Callable[..., dict[str, Any]], cfg: DictConfig, tags: dict[str, str],
            encoder: dict[str, Any] | None, resume: str | None = None) -> dict[str, Any]:
    """Train one run (in this process or a Ray worker); ``encoder``: the pre-training's result
    (its run id goes to the tag ``pretrain_run_id`` and replaces :data:`PRETRAIN_RUN` in the
    other tags); ``resume``: an interrupted run of this job to continue.

    Returns ``train()``'s dict; ``{"input_error": [where, problem]}`` for bad input (so that
    Ray does not retry it). Any other error leaves the MLflow child FAILED and is raised.
    """
    _quiet_worker()
    cfg = copy.deepcopy(cfg)
    since_ms = int(time.time() * 1000)  # MLflow clients stamp start_time with this machine's clock too
    try:
        if encoder is not None:
            # a Ray task may run on another node than the pre-training: then its artifact is downloaded
            cache = Path(cfg.trainer.default_root_dir) / "checkpoints" / "downloaded"
            cfg.model.encoder_ckpt = str(store.run_checkpoint(str(encoder["run_id"]), cache, encoder.get("checkpoint"),
                                                              option=f"run {encoder['run_id']}"))
            tags = {**{k: v.replace(PRETRAIN_RUN, str(encoder["run_id"])) for k, v in tags.items()},
                    "pretrain_run_id": str(encoder["run_id"])}
        t0 = time.perf_counter()
        out = train_fn(cfg, tags=tags, resume=resume) if resume else train_fn(cfg, tags=tags)
        out = {**out, "seconds": time.perf_counter() - t0}  # the run's own time (a Ray task may have queued)
        if cfg.stage == "pretrain" and not out.get("checkpoint"):
            raise InputError(cfg.tracking.run_name or "pretrain", "training produced no checkpoint")
        return out
    except InputError as e:
        _record_failure(cfg, tags, since_ms, e)
        return {"input_error": [e.where, e.problem]}
    except BaseException as e:
        _record_failure(cfg, tags, since_ms, e)
        raise


# ----------------------------------------------------------------------------------------------
# executors


class Executor:
    """Runs a sweep's jobs: :meth:`submit` each (pre-trainings first), then :meth:`wait`."""

    name = "?"

    def __init__(self, max_retries: int = 1):
        if int(max_retries) < 0:
            raise InputError("--max-retries", f"must be 0 or more, got {max_retries}")
        self.max_retries = int(max_retries)
        self.jobs: list[Job] = []

    def __enter__(self) -> Executor:
        return self

    def __exit__(self, *exc: Any) -> None:
        return None

    def check(self, cfg: DictConfig) -> None:
        """Raise :class:`~uavturb.errors.InputError` if this executor cannot run ``cfg``."""

    def submit(self, train_fn: Callable[..., dict[str, Any]], job: Job) -> Job:
        raise NotImplementedError

    def wait(self) -> list[Job]:
        """Wait for every job; raise :class:`RunsFailed` (one line) when some failed."""
        raise NotImplementedError

    def _finish(self, job: Job, out: dict[str, Any]) -> None:
        if "input_error" in out:
            raise InputError(*out["input_error"])
        job.state, job.result = "finished", out
        if job.on_done is not None:
            job.on_done(out, out.get("seconds", time.perf_counter() - job.t0))

    def _raise_failures(self) -> None:
        failed = [j for j in self.jobs if j.state == "failed"]
        skipped = [j for j in self.jobs if j.state == "skipped"]
        if not failed:
            return
        first = failed[0]
        raise RunsFailed(f"{len(failed)} of {len(self.jobs)} runs failed after {self.max_retries + 1} attempt(s)"
                         f"{f', {len(skipped)} skipped (their pre-training failed)' if skipped else ''}: "
                         f"{', '.join(j.label for j in failed)}; first error: {first.error}; the FAILED runs in "
                         f"MLflow hold the tracebacks (error.txt); run the same command again to retry them")


class SequentialExecutor(Executor):
    """Each job at once, in this process, in the order submitted."""

    name = "sequential"

    def check(self, cfg: DictConfig) -> None:
        """The runs train here: this machine must have the device they ask for (a GPU, bf16)."""
        check_trainer_device(cfg.trainer)

    def submit(self, train_fn: Callable[..., dict[str, Any]], job: Job) -> Job:
        self.jobs.append(job)
        encoder = job.encoder
        if isinstance(encoder, Job):
            if encoder.state != "finished":
                job.state, job.error = "skipped", f"pre-training {encoder.label} {encoder.state}"
                return job
            encoder = {"checkpoint": encoder.result["checkpoint"], "run_id": encoder.result["run_id"]}
        if job.on_start is not None:
            job.on_start()
        job.t0 = time.perf_counter()
        for attempt in range(self.max_retries + 1):
            try:
                out = run_job(train_fn, job.cfg, job.tags, encoder, job.resume)
            except Exception as e:  # noqa: BLE001 - retried, then reported with the others
                job.state, job.error = "failed", _one_line(e)
                print(f"{job.label}: attempt {attempt + 1} failed: {job.error}", file=sys.stderr, flush=True)
                continue
            self._finish(job, out)
            break
        return job

    def wait(self) -> list[Job]:
        self._raise_failures()
        return self.jobs


def _absolute(value: Any) -> Any:
    if value in (None, "") or "://" in str(value):
        return value
    return str(Path(str(value)).expanduser().resolve())


def absolute_tracking_uri(uri: str) -> str:
    """The tracking URI as every process sees it: a relative SQLite file or folder made absolute."""
    if uri.startswith("sqlite:///") and not uri.startswith("sqlite:////"):
        return "sqlite:///" + str(Path(uri[len("sqlite:///"):]).resolve())
    if "://" not in uri:
        return str(Path(uri).resolve())
    return uri


def task_resources(cfg: DictConfig) -> dict[str, float]:
    """Ray resources a run needs: CPUs for its torch threads and loader workers, its GPUs."""
    t = cfg.trainer
    res = {"num_cpus": float(max(1, int(t.num_threads)) + max(0, int(cfg.data.num_workers))), "num_gpus": 0.0}
    if str(t.accelerator).lower() in ("gpu", "cuda"):
        devices = str(t.devices).strip()
        if devices.isdigit():
            res["num_gpus"] = float(devices)
        elif "," in devices:
            res["num_gpus"] = float(len([d for d in devices.split(",") if d.strip()]))
        else:
            raise InputError("trainer.devices", f"{devices!r}: with --executor ray give the number of GPUs (e.g. 1) "
                                                "or their list, so that Ray reserves them")
    if int(t.num_nodes) > 1:
        raise InputError("trainer.num_nodes", "one Ray task trains on one node: use num_nodes=1 with --executor ray")
    return res


class RayExecutor(Executor):
    """Each job a Ray task; height runs depend on their pre-training's ``ObjectRef``.

    Parameters
    ----------
    address : an existing cluster (``auto``, ``ray://host:10001``, ``host:6379``); None starts a
        local Ray instance with ``num_cpus`` CPUs (default: all) and stops it at the end. A Ray
        already initialised in this process (tests) is used as it is and left running.
    max_retries : extra attempts of a failed task.
    """

    name = "ray"

    def __init__(self, address: str | None = None, max_retries: int = 1, num_cpus: int | None = None):
        super().__init__(max_retries)
        try:
            import ray
        except ImportError:
            raise InputError("--executor ray", f"Ray is not installed: pip install '{RAY_REQUIREMENT}'") from None
        self.ray, self.address, self.num_cpus = ray, address, num_cpus
        self._session: Any = None
        self._task: Any = None
        self._options: dict[str, Any] = {}
        self._train_ref: Any = None
        self._prepared: set[tuple[str, str]] = set()

    def check(self, cfg: DictConfig) -> None:
        task_resources(cfg)

    def __enter__(self) -> RayExecutor:
        self._session = ray_session(self.address, self.num_cpus)
        self._session.__enter__()
        env = {"MLFLOW_TRACKING_URI": absolute_tracking_uri(store.tracking_uri())}
        self._task = self.ray.remote(run_job)
        self._options = {"max_retries": self.max_retries, "retry_exceptions": True, "runtime_env": {"env_vars": env}}
        return self

    def __exit__(self, *exc: Any) -> None:
        self._session.__exit__(*exc)

    def submit(self, train_fn: Callable[..., dict[str, Any]], job: Job) -> Job:
        from omegaconf import OmegaConf

        self.jobs.append(job)
        if self._train_ref is None:
            self._train_ref = self.ray.put(train_fn)
        cfg = copy.deepcopy(job.cfg)
        for key in PATH_KEYS:
            OmegaConf.update(cfg, key, _absolute(OmegaConf.select(cfg, key)))
        _prepare_data_once(cfg, self._prepared)
        encoder = job.encoder.ref if isinstance(job.encoder, Job) else job.encoder
        job.t0 = time.perf_counter()
        job.ref = self._task.options(**self._options, **task_resources(cfg), name=job.label).remote(
            self._train_ref, cfg, job.tags, encoder, job.resume)
        return job

    def wait(self) -> list[Job]:
        ray = self.ray
        pending = {j.ref: j for j in self.jobs if j.ref is not None}
        if pending:
            print(f"{len(pending)} run(s) submitted to Ray ({self.address or 'local instance'}, "
                  f"{ray.cluster_resources().get('CPU', 0):.0f} CPUs, {ray.cluster_resources().get('GPU', 0):.0f} "
                  f"GPUs); results as they finish", file=sys.stderr, flush=True)
        try:
            while pending:
                ready, _ = ray.wait(list(pending), num_returns=1)
                for ref in ready:
                    job = pending.pop(ref)
                    try:
                        out = ray.get(ref)
                    except ray.exceptions.RayError as e:
                        cause = getattr(e, "cause", None) or e
                        job.state, job.error = "failed", _one_line(cause)
                        print(f"{job.label}: failed: {job.error}", file=sys.stderr, flush=True)
                        continue
                    self._finish(job, out)
        except BaseException:
            for ref in pending:
                ray.cancel(ref)
            raise
        for job in self.jobs:  # a run whose pre-training failed never started: skipped, not failed
            if job.state == "failed" and isinstance(job.encoder, Job) and job.encoder.state == "failed":
                job.state = "skipped"
        self._raise_failures()
        return self.jobs


#: Ray's switch for clusters (its default on macOS and Windows is off): off, a local instance's
#: node address is 127.0.0.1 and its servers listen on the loopback interface only.
RAY_CLUSTER_SWITCH = "RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER"


def _local_ray_on_loopback() -> None:
    """Make the local Ray instance about to start reachable from this machine only (Ray binds its
    gRPC servers to every interface otherwise). Set before Ray is imported, so its processes
    inherit it; a value the user set is kept."""
    import os

    os.environ.setdefault(RAY_CLUSTER_SWITCH, "0")
    constants = sys.modules.get("ray._private.ray_constants")
    if constants is not None and os.environ[RAY_CLUSTER_SWITCH] == "0":  # Ray imported already
        constants.ENABLE_RAY_CLUSTER = False


@contextlib.contextmanager
def ray_session(address: str | None = None, num_cpus: int | None = None) -> Iterator[Any]:
    """Ray, connected for the block: ``address`` (an existing cluster) or a local instance.

    A local instance has ``num_cpus`` CPUs (default: all), no dashboard, listens on 127.0.0.1
    only (:func:`_local_ray_on_loopback`), and stops at the end. A Ray this process already
    initialised (tests) is used as it is and left running.
    """
    if not address:
        _local_ray_on_loopback()
    try:
        import ray
    except ImportError:
        raise InputError("--executor ray", f"Ray is not installed: pip install '{RAY_REQUIREMENT}'") from None
    if ray.is_initialized():
        yield ray
        return
    kw: dict[str, Any] = {"logging_level": logging.ERROR, "log_to_driver": True}
    if address:
        kw["address"] = address
    else:
        kw.update(num_cpus=num_cpus, include_dashboard=False)
    try:
        ray.init(**kw)
    except (ConnectionError, RuntimeError, ValueError) as e:
        raise InputError(f"--address {address}" if address else "--executor ray",
                         f"cannot start or reach Ray: {_one_line(e)}") from None
    try:
        yield ray
    finally:
        ray.shutdown()


def _prepare_data_once(cfg: DictConfig, done: set[tuple[str, str]]) -> None:
    """Generate a synthetic dataset here, once, before parallel tasks would all write it at once."""
    key = (str(cfg.stage), str(cfg.data.pairs_root if cfg.stage == "pretrain" else cfg.data.root))
    if key not in done and cfg.data.synthetic.enabled:
        prepare_data(cfg)  # the same step train() takes first
    done.add(key)


def make_executor(name: str = "sequential", *, address: str | None = None, max_retries: int = 1,
                  num_cpus: int | None = None) -> Executor:
    """The executor of ``--executor NAME`` (a context manager: Ray starts and stops with it)."""
    if name == "sequential":
        if address:
            raise InputError("--address", "only with --executor ray")
        return SequentialExecutor(max_retries)
    if name == "ray":
        return RayExecutor(address, max_retries, num_cpus)
    raise InputError("--executor", f"unknown executor {name!r}; choices: {', '.join(EXECUTORS)}")
