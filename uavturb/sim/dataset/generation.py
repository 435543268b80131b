"""Training shards from simulated flights: ``uavturb generate sim`` and ``uavturb generate merge``.

One trajectory = one flight through one procedural scene (:mod:`uavturb.scene.procedural`),
sampled at the camera rate. Every sample holds what the paper lists (section "Large-scale
generation of simulated UAV trajectory data"): the state ``x`` (``p``, ``q`` w-x-y-z body to
world, ``v`` world, ``omega`` body), the rotor speeds ``Omega`` [rad/s], the depth map ``D``
of the forward camera [m] (the colour image ``I`` when the preset asks for it), the height
``d`` of the body origin over the surface below [m] (exact, from the scene's boxes, the
equivalent of a vertical ray cast into the mesh), and the ground-effect force
``f_a = phi(d, k_T sum Omega^2, mu, r)`` [N] of :func:`uavturb.physics.ground_effect.phi`,
plus scene and trajectory ids and time. The arrays follow :mod:`uavturb.data.shards`.

Pipeline of a trajectory (:func:`make_trajectory`)
--------------------------------------------------
1. *fly*: a flyer (:data:`FLYERS`) plans a reference in the scene and closes the loop
   around the physics (dynamics of :mod:`uavturb.physics.dynamics`, effects of the
   preset) and returns states and rotor speeds at the camera rate. Both flyers plan with
   :func:`uavturb.sim.dataset.planning.plan_trajectory` (random points, Christofides, A*,
   take-offs, low hovers, landings, edge passes); ``mpc`` flies with the CasADi MPC of
   :mod:`uavturb.sim.core.mpc` through :func:`~uavturb.sim.dataset.flying.fly_trajectory`,
   ``geometric`` with the geometric controller through :func:`uavturb.sim.core.closed_loop.track_reference`
   (the closed loop both share).
   The flyer is pluggable (:data:`FLYERS`).
2. *collide*: the flight is truncated before the first sample where the vehicle (a
   cylinder of radius ``arm_length + rotor_radius``) touches the scene
   (:func:`uavturb.scene.queries.collides`); truncations are counted.
3. *measure*: ``d`` and ``f_a``.
4. *render*: depth (and normals, colour) with one :class:`~uavturb.sim.core.render.SceneRenderer`
   per scene and worker (headless EGL), camera pitched down by ``pitch_deg``.
5. *write*: :func:`uavturb.data.shards.write_trajectory` (atomic).

Guarantees
----------
- Deterministic: the seed of trajectory ``k`` of scene ``s`` is
  ``SeedSequence([seed, s, k])``; scenes are fixed by their index; nothing depends on the
  number of workers, the shard split or the order of completion.
- Resumable: a trajectory folder exists under its final name only when complete, and an
  existing one is never rewritten; a re-run generates what is missing and rewrites the
  manifest. A folder holding a dataset of another config is refused.
- ``--shard K/N`` (``1 <= K <= N``) generates trajectories ``i`` with ``i % N == K - 1``;
  :func:`merge_datasets` joins the shard folders (hard links, no copy where possible).

Statistics in ``manifest.json`` (``statistics``): share of samples with ``d < 0.5 m``; share
whose surface point straight below is out of the camera's view (outside the image, behind
the camera, or hidden; with a forward camera pitched 20 deg down and a 70 deg vertical field
of view, the lowest ray is 55 deg under the horizon, so this is nearly every sample: the
paper's point); the sharper share of samples whose surface below changed height by more
than 5 cm within the last second while out of view (edge passes: where the GRU's memory is
needed); samples inside obstacles (0: truncation); truncated trajectories. ``throughput``:
samples/s and the worker seconds spent in control (planning included), physics, rendering
and the rest.
"""

from __future__ import annotations

import os
import shutil
import time
from pathlib import Path
from typing import Any, Callable, Sequence

from uavturb.errors import InputError
from uavturb.io import shards
from uavturb.io.publish import atomic_folder
from uavturb.progress import progress_bar, show_rate
from uavturb.sim.dataset.assignment import Task, parse_shard, plan_tasks
from uavturb.sim.dataset.flying import resolve_controller
from uavturb.sim.dataset.presets import SimPreset, get_preset
from uavturb.sim.dataset.trajectory_arrays import RENDERERS, init_worker, work

GENERATOR_VERSION = 1


def dataset_config(preset: SimPreset, seed: int, controller: str) -> dict[str, Any]:
    """The config stored in the manifest (and hashed): everything that fixes the arrays."""
    # "generator" names the writer as manifests have always named it (part of the config hash: kept as it was)
    return {"generator": "uavturb.sim.dataset", "generator_version": GENERATOR_VERSION, "seed": int(seed),
            "controller": controller, "preset": preset.to_dict()}


def _existing(out: Path, tasks: Sequence[Task], chash: str) -> dict[str, dict[str, Any]]:
    """Metas of finished trajectories of ``tasks`` under ``out``; refuses another config's data."""
    done = {}
    for task in tasks:
        folder = out / task.name
        if folder.is_dir():
            meta = shards.read_meta(folder)
            if meta.get("config_hash") != chash:
                raise InputError(folder, f"belongs to a dataset of another config (hash {meta.get('config_hash')}, "
                                         f"this run {chash}); use another --out")
            done[task.name] = meta
    return done


def summarize(metas: Sequence[dict[str, Any]]) -> dict[str, Any]:
    """Dataset statistics from trajectory metas (their ``stats``)."""
    st = [m.get("stats", {}) for m in metas]
    n = sum(s.get("samples", 0) for s in st)
    low = sum(s.get("low", 0) for s in st)
    oov = sum(s.get("out_of_view", 0) for s in st)
    inside = sum(s.get("inside", 0) for s in st)
    changed = sum(s.get("surface_changed_out_of_view", 0) for s in st)
    return {"trajectories": len(metas), "samples": int(n),
            "share_d_below_0.5m": low / n if n else float("nan"),
            "share_below_out_of_view": oov / n if n else float("nan"),
            "share_surface_changed_out_of_view": changed / n if n else float("nan"),
            "samples_inside_obstacles": int(inside),
            "truncated_by_collision": int(sum(s.get("truncated", 0) for s in st))}


def time_split(metas: Sequence[dict[str, Any]]) -> dict[str, float]:
    """Seconds of worker time per stage (control, physics, render, other), summed over trajectories."""
    keys = ("control", "physics", "render", "other")
    return {k: float(sum(m.get("stats", {}).get("seconds", {}).get(k, 0.0) for m in metas)) for k in keys}


def _write_manifest(out: Path, tasks: Sequence[Task], metas: dict[str, dict[str, Any]], config: dict[str, Any],
                    extra: dict[str, Any]):
    splits: dict[str, list[str]] = {s: [] for s in shards.SPLITS}
    for task in tasks:
        if task.name in metas:
            splits[task.split].append(task.name)
    manifest = shards.write_manifest(out, splits, config)
    shards.update_manifest(out, statistics=summarize(list(metas.values())), **extra)
    return manifest


def generate_sim(preset: str | SimPreset = "quick", out: str | Path = "data/sim", *, workers: int = 1,
                 seed: int = 0, shard: str | tuple[int, int] | None = None, progress: bool = True,
                 on_trajectory: Callable[[dict[str, Any]], None] | None = None, executor: str = "local",
                 **overrides: Any):
    """``uavturb generate sim``: write (or complete) a shard dataset.

    Parameters
    ----------
    preset : ``tiny``, ``quick``, ``paper`` or a :class:`~uavturb.sim.dataset.presets.SimPreset`
    out : dataset folder (created)
    workers : processes (each with its own EGL renderer); 1 runs in this process
    seed : dataset seed
    shard : ``"K/N"``: generate only trajectories ``i`` with ``i % N == K - 1``
    progress : print a progress line (samples/s, ETA) on stderr
    on_trajectory : called in this process with each new trajectory's meta (tests use it
        to interrupt a run)
    executor : ``local`` (this process, or a Pool of ``workers`` processes) or ``ray`` (one
        Ray task per trajectory on the Ray this process is connected to; ``workers`` unused)
    overrides : preset fields to change (``width=64``, ``trajectories=4``...; unknown keys fail)

    Returns
    -------
    uavturb.data.shards.Manifest of what ``out`` holds for this shard.
    """
    p = get_preset(preset, **overrides)
    if int(workers) < 1:
        raise InputError("--workers", f"must be at least 1, got {workers}")
    if executor not in ("local", "ray"):
        raise InputError("--executor", f"unknown executor {executor!r}; choices: local, ray")
    k, n = parse_shard(shard)
    controller = resolve_controller(p.controller)
    config = dataset_config(p, seed, controller)
    chash = shards.config_hash(config)
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise InputError(out, "exists and is not a folder")
    created = not out.exists()
    shards.check_manifest_replaceable(out)  # a user's manifest.json is never replaced
    out.mkdir(parents=True, exist_ok=True)
    all_tasks = plan_tasks(p, seed)
    tasks = [t for t in all_tasks if t.index % n == k - 1]
    if not tasks:
        raise InputError("--shard", f"shard {k}/{n} holds no trajectory (the preset has {len(all_tasks)})")
    _remove_unfinished(out, tasks, created=False)  # leftovers of an interrupted writer of this shard
    metas = _existing(out, tasks, chash)
    todo = [t for t in tasks if t.name not in metas]
    # scene-major order keeps each worker's renderer on one scene for several trajectories
    todo.sort(key=lambda t: (t.scene, t.k))
    label = f"generate sim ({p.name}{'' if n == 1 else f', shard {k}/{n}'})" if progress else None
    try:
        jobs = [(t, p, int(seed), controller, str(out.resolve() if executor == "ray" else out)) for t in todo]
        new, wall = _generate_trajectories(jobs, executor, int(workers), out, chash, metas, label, on_trajectory)
    except BaseException:  # Interrupted (SIGTERM, SIGINT) or an error: the workers are stopped by now
        _remove_unfinished(out, todo, created)
        raise
    new_samples = sum(m["stats"]["samples"] for m in new)
    throughput = {"this_run": {"trajectories": len(new), "samples": int(new_samples), "wall_s": wall,
                               "samples_per_s": new_samples / wall if wall > 0 and new else None,
                               "workers": int(workers), "worker_seconds": time_split(new)},
                  "all_trajectories_worker_seconds": time_split(list(metas.values()))}
    extra = {"throughput": throughput, "shard": f"{k}/{n}", "complete": len(metas) == len(all_tasks),
             "expected_trajectories": len(all_tasks)}
    return _write_manifest(out, tasks, metas, config, extra)


def _generate_trajectories(jobs: list, executor: str, workers: int, out: Path, chash: str,
                           metas: dict[str, dict[str, Any]], label: str | None,
                           on_trajectory: Callable[[dict[str, Any]], None] | None
                           ) -> tuple[list[dict[str, Any]], float]:
    """(the new trajectories' metas, the wall time [s]): ``jobs`` run on Ray or here (:func:`_run_jobs`),
    each finished one added to ``metas`` and shown on a progress bar ``label`` (None: none)."""
    bar = progress_bar(len(jobs), label, "trajectories") if label is not None else None
    t0 = time.perf_counter()
    new: list[dict[str, Any]] = []

    def done(meta: dict[str, Any]) -> None:
        metas[meta["trajectory_id"]] = meta
        new.append(meta)
        if bar is not None:
            show_rate(bar, sum(m["stats"]["samples"] for m in new), "samples")
            bar.update(1)
        if on_trajectory is not None:
            on_trajectory(meta)

    try:
        if executor == "ray":
            _run_on_ray(jobs, chash, done)
        else:
            _run_jobs(jobs, workers, str(out), chash, done)
    finally:
        if bar is not None:
            bar.close()
    return new, time.perf_counter() - t0


def _run_jobs(jobs: list, workers: int, out: str, chash: str, done: Callable[[dict[str, Any]], None]) -> None:
    """Generate and write the trajectories of ``jobs`` in this process (one worker or one job) or in
    a pool of ``workers`` spawned processes; ``done(meta)`` for each, in order of completion."""
    if workers == 1 or len(jobs) <= 1:
        init_worker(out, chash)
        try:
            for job in jobs:
                done(work(job))
        finally:
            RENDERERS.close()  # free this process's GL context
        return
    import multiprocessing as mp

    ctx = mp.get_context("spawn")
    with ctx.Pool(min(workers, len(jobs)), initializer=_init_pool_worker,
                  initargs=(out, chash)) as pool:  # on an exception: pool.terminate()
        for meta in pool.imap_unordered(work, jobs, chunksize=1):
            done(meta)


def _ray_work(job: tuple[Task, SimPreset, int, str, str], chash: str) -> dict[str, Any]:
    """:func:`uavturb.sim.dataset.trajectory_arrays.work` as a Ray task (a worker process is reused: its renderers
    too)."""
    init_worker(job[4], chash)
    return work(job)


def _run_on_ray(jobs: list[tuple[Task, SimPreset, int, str, str]], chash: str,
                done: Callable[[dict[str, Any]], None]) -> None:
    """One Ray task (1 CPU) per trajectory on the Ray this process is connected to (started if none).

    Each trajectory's arrays depend only on its task, the preset and the seed, so the dataset is
    the same as with the Pool; ``out`` must be on a file system every node shares.
    """
    import ray  # only with --executor ray

    task = ray.remote(num_cpus=1)(_ray_work)
    pending = [task.options(name=job[0].name).remote(job, chash) for job in jobs]
    try:
        while pending:
            ready, pending = ray.wait(pending, num_returns=1)
            done(ray.get(ready[0]))
    except BaseException:
        for ref in pending:
            ray.cancel(ref)
        raise


def _init_pool_worker(out: str, chash: str) -> None:
    """A pool worker: Ctrl-C (SIGINT to the whole process group) is the parent's to handle; it
    stops the workers (SIGTERM, ``Pool.terminate``) and removes what they left half-written."""
    import signal

    signal.signal(signal.SIGINT, signal.SIG_IGN)
    init_worker(out, chash)


def _remove_unfinished(out: Path, tasks: Sequence[Task], created: bool) -> None:
    """After an interruption: the temporary folders of trajectories being written, and ``out``
    itself where this run created it and nothing was finished."""
    for t in tasks:
        for junk in out.glob(f".{t.name}.*"):
            shutil.rmtree(junk, ignore_errors=True)
    if created and out.is_dir() and not any(out.iterdir()):
        out.rmdir()


def merge_datasets(dirs: Sequence[str | Path], out: str | Path):
    """``uavturb generate merge``: join shard folders into one dataset at ``out``.

    Every folder must hold a manifest of the same config (hash). Trajectory folders are
    hard-linked into ``out`` (copied where links are impossible), atomically each; one
    already in ``out`` is kept. ``out`` may be one of ``dirs``.

    Returns
    -------
    uavturb.data.shards.Manifest of the merged dataset (``complete`` tells whether every
    trajectory of the config is there).
    """
    if not dirs:
        raise InputError("merge", "give at least one dataset folder")
    out = Path(out)
    manifests = [shards.read_manifest(d) for d in dirs]
    hashes = {m.config_hash for m in manifests}
    if len(hashes) > 1:
        raise InputError(Path(dirs[1]) / shards.MANIFEST, f"config hash {manifests[1].config_hash} differs from "
                         f"{Path(dirs[0]) / shards.MANIFEST}'s {manifests[0].config_hash}: not shards of one dataset")
    config = manifests[0].config
    out.mkdir(parents=True, exist_ok=True)
    metas: dict[str, dict[str, Any]] = {}
    for m in manifests:
        for split in shards.SPLITS:
            for name in m.splits[split]:
                src, dst = m.root / name, out / name
                if name in metas:
                    continue
                if not dst.exists():
                    _link_tree(src, dst)
                meta = shards.read_meta(dst)
                if meta.get("config_hash") != manifests[0].config_hash:
                    raise InputError(dst, "belongs to a dataset of another config")
                metas[name] = meta
    try:
        preset = get_preset(SimPreset.from_dict(config["preset"]))
        expected = len(plan_tasks(preset, config["seed"]))
    except (KeyError, TypeError):
        expected = None
    order = sorted(metas, key=lambda nme: metas[nme].get("index", 0))
    tasks = [Task(metas[nme].get("index", i), metas[nme].get("scene_seed", 0), metas[nme].get("k", 0),
                  metas[nme]["split"], metas[nme]["stats"].get("plan_points", 0)) for i, nme in enumerate(order)]
    extra = {"shard": "merged", "merged_from": [str(Path(d)) for d in dirs],
             "complete": expected is not None and len(metas) == expected, "expected_trajectories": expected,
             "throughput": {"all_trajectories_worker_seconds": time_split(list(metas.values()))}}
    return _write_manifest(out, tasks, metas, config, extra)


def _link_tree(src: Path, dst: Path) -> None:
    """Hard-link (or copy) the files of folder ``src`` into a new folder ``dst``, atomically."""
    if not src.is_dir():
        raise InputError(src, "trajectory folder listed in the manifest is missing")
    with atomic_folder(dst) as stage:
        for f in src.iterdir():
            try:
                os.link(f, stage / f.name)
            except OSError:
                shutil.copy2(f, stage / f.name)


def describe(root: str | Path) -> str:
    """A few lines on a dataset folder: counts per split, statistics, throughput."""
    import json


    m = shards.read_manifest(root)
    body = json.loads((Path(root) / shards.MANIFEST).read_text())
    st = body.get("statistics", {})
    c = m.counts
    lines = [f"{root}: " + ", ".join(f"{s} {c[s]['trajectories']} trajectories / {c[s]['frames']} samples "
                                     f"/ {c[s]['scenes']} scenes" for s in shards.SPLITS)
             + f"; config {m.config_hash}" + ("" if body.get("complete", True) else
                                              f" (incomplete: {st.get('trajectories')} of "
                                              f"{body.get('expected_trajectories')} trajectories)")]
    if st:
        lines.append(f"  d < 0.5 m: {st['share_d_below_0.5m']:.1%}, surface below out of view: "
                     f"{st['share_below_out_of_view']:.1%} (changed within 1 s while out of view: "
                     f"{st.get('share_surface_changed_out_of_view', float('nan')):.1%}), inside obstacles: "
                     f"{st['samples_inside_obstacles']}, truncated by collision: {st['truncated_by_collision']}")
    run = body.get("throughput", {}).get("this_run")
    if run and run.get("samples_per_s"):
        secs = run["worker_seconds"]
        busy = sum(secs.values())
        split = ", ".join(f"{k} {v / busy:.0%}" for k, v in secs.items()) if busy > 0 else ""
        lines.append(f"  this run: {run['samples']} samples in {run['wall_s']:.1f} s = {run['samples_per_s']:.0f} "
                     f"samples/s with {run['workers']} worker(s); worker time: {split}")
    return "\n".join(lines)
