"""Training shards from simulated flights: ``uavturb generate sim`` and ``uavturb generate merge``.

One trajectory = one flight through one procedural scene (:mod:`uavturb.sim.scenes`),
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
   :func:`uavturb.sim.trajectories.plan_trajectory` (random points, Christofides, A*,
   take-offs, low hovers, landings, edge passes); ``mpc`` flies with the CasADi MPC of
   :mod:`uavturb.sim.mpc` through :func:`~uavturb.sim.trajectories.fly_trajectory`,
   ``geometric`` with the geometric controller through :func:`uavturb.sim.flight.simulate_flight`.
   The flyer is pluggable (:data:`FLYERS`).
2. *collide*: the flight is truncated before the first sample where the vehicle (a
   cylinder of radius ``arm_length + rotor_radius``) touches the scene
   (:func:`uavturb.sim.trajectories.collides`); truncations are counted.
3. *measure*: ``d`` and ``f_a``.
4. *render*: depth (and normals, colour) with one :class:`~uavturb.sim.render.SceneRenderer`
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

import math
import os
import shutil
import sys
import time
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np

from uavturb.errors import InputError
from uavturb.io.publish import atomic_folder
from uavturb.sim.presets import SimPreset, get_preset

GENERATOR_VERSION = 1
LOW_HEIGHT = 0.5  # m, "ground effect matters" threshold of the statistics
SURFACE_MEMORY_S = 1.0  # s, look-back of the "surface below changed" statistic
SURFACE_STEP = 0.05  # m, a change of the surface height below larger than this counts
COLLISION_HALF_HEIGHT = 0.005  # m, vertical half-extent of the vehicle in the collision check


# ----------------------------------------------------------------------------------------------
# tasks


@dataclass(frozen=True)
class Task:
    """One trajectory to generate.

    Attributes
    ----------
    index : int, position in the preset's list of trajectories (scene-major)
    scene : int, scene index (its generator seed)
    k : int, trajectory number within the scene
    split : str
    n_points : int, random points of its plan
    """

    index: int
    scene: int
    k: int
    split: str
    n_points: int

    @property
    def name(self) -> str:
        return f"traj_{self.index:05d}"

    def task_seed(self, seed: int) -> int:
        """The trajectory's own seed, from ``(seed, scene, k)`` only."""
        return int(np.random.SeedSequence([int(seed), int(self.scene), int(self.k)]).generate_state(1)[0])


def scene_splits(preset: SimPreset) -> dict[str, list[int]]:
    """Scene indices per split (by scene, never by sample)."""
    from uavturb.sim.scenes import split_scenes

    return split_scenes(preset.n_scenes, preset.n_train, preset.n_val, preset.n_test, seed=preset.split_seed)


def plan_tasks(preset: SimPreset, seed: int) -> list[Task]:
    """Every trajectory of a preset, in order; plan sizes drawn from the seed."""
    split_of = {s: name for name, scenes in scene_splits(preset).items() for s in scenes}
    per_scene = [preset.trajectories // preset.n_scenes + (1 if s < preset.trajectories % preset.n_scenes else 0)
                 for s in range(preset.n_scenes)]
    tasks = []
    choices = [int(c) for c in preset.plan_points]
    for s in range(preset.n_scenes):
        for k in range(per_scene[s]):
            rng = np.random.default_rng(np.random.SeedSequence([int(seed), s, k, 1]))
            tasks.append(Task(len(tasks), s, k, split_of[s], choices[int(rng.integers(len(choices)))]))
    return tasks


def parse_shard(shard: str | tuple[int, int] | None) -> tuple[int, int]:
    """``"K/N"`` -> ``(K, N)`` with ``1 <= K <= N`` (``None``: ``(1, 1)``)."""
    if shard is None:
        return 1, 1
    if isinstance(shard, tuple):
        k, n = shard
    else:
        try:
            k_s, n_s = str(shard).split("/")
            k, n = int(k_s), int(n_s)
        except ValueError:
            raise InputError("--shard", f"expected K/N with integers 1 <= K <= N, got {shard!r}") from None
    if not (n >= 1 and 1 <= k <= n):
        raise InputError("--shard", f"expected K/N with 1 <= K <= N, got {k}/{n}")
    return int(k), int(n)


# flyers: plan a reference in the scene, fly it, sample at the camera rate


@dataclass
class Flight:
    """What a flyer returns, sampled at the camera rate.

    Attributes
    ----------
    t : (T,) s from the start
    state : (T, 13) ``p`` (m, W), ``q`` (w, x, y, z, body to world), ``v`` (m/s, W), ``omega`` (rad/s, B)
    rotor_speeds : (T, N) rad/s, actual rotor speeds
    timing : seconds spent in ``control`` and ``physics``
    info : free-form (controller, tracking error...)
    """

    t: np.ndarray
    state: np.ndarray
    rotor_speeds: np.ndarray
    timing: dict[str, float] = field(default_factory=dict)
    info: dict[str, Any] = field(default_factory=dict)


class _SceneHeights:
    """``d_down`` / ``d_up`` [m] of a scene for :func:`simulate_flight`, one position at a time.

    Generated scenes: the exact box heights of :func:`uavturb.sim.scenes.height_below` /
    ``height_above`` (same formula), with the boxes pre-binned on a ``cell`` [m] grid in x, y
    so that a query looks at the few boxes over its cell only; one pass answers both (the
    second call for the same position is a cache hit). Other scenes: the scene queries.
    """

    def __init__(self, scene, cell: float = 0.25):
        self.scene = scene
        self._last: tuple[bytes, float, float] | None = None
        self.bins: dict[tuple[int, int], np.ndarray] = {}
        if not scene.has_boxes:
            return
        self.cell = float(cell)
        self.origin = np.asarray(scene.bounds[0, :2], float)
        lo = np.floor((scene.boxes[:, 0, :2] - self.origin) / self.cell).astype(int)
        hi = np.floor((scene.boxes[:, 1, :2] - self.origin) / self.cell).astype(int)
        bins: dict[tuple[int, int], list[int]] = {}
        for m in range(len(scene.boxes)):
            for i in range(lo[m, 0], hi[m, 0] + 1):
                for j in range(lo[m, 1], hi[m, 1] + 1):
                    bins.setdefault((i, j), []).append(m)
        self.bins = {k: np.asarray(v) for k, v in bins.items()}

    def _both(self, pos: np.ndarray) -> tuple[float, float]:
        p = np.asarray(pos, float).reshape(3)
        key = p.tobytes()
        if self._last is not None and self._last[0] == key:
            return self._last[1], self._last[2]
        idx = self.bins.get(tuple(np.floor((p[:2] - self.origin) / self.cell).astype(int)))
        down = up = np.inf
        if idx is not None:
            b = self.scene.boxes[idx]
            x, y, z = p
            over = (x >= b[:, 0, 0]) & (x <= b[:, 1, 0]) & (y >= b[:, 0, 1]) & (y <= b[:, 1, 1])
            below = over & (b[:, 1, 2] <= z + 1e-12)
            above = over & (b[:, 0, 2] >= z - 1e-12)
            if below.any():
                down = max(float(np.min(z - b[below, 1, 2])), 0.0)
            if above.any():
                up = max(float(np.min(b[above, 0, 2] - z)), 0.0)
        self._last = (key, down, up)
        return down, up

    def d_down(self, pos: np.ndarray) -> np.ndarray:
        pos = np.atleast_2d(pos)
        if not self.scene.has_boxes or len(pos) != 1:
            from uavturb.sim.scenes import height_below

            return height_below(self.scene, pos)
        return np.array([self._both(pos[0])[0]])

    def d_up(self, pos: np.ndarray) -> np.ndarray:
        pos = np.atleast_2d(pos)
        if not self.scene.has_boxes or len(pos) != 1:
            from uavturb.sim.scenes import height_above

            return height_above(self.scene, pos)
        return np.array([self._both(pos[0])[1]])


def _plan(scene, vehicle, task_seed: int, n_points: int, preset: SimPreset):
    from uavturb.sim.trajectories import PlanConfig, plan_trajectory

    cfg = PlanConfig(**{**preset.plan, "n_points": int(n_points)})
    return plan_trajectory(scene, task_seed, cfg, rotor_radius=vehicle.rotor_radius,
                           vehicle_radius=vehicle.arm_length + vehicle.rotor_radius)


def _duration(planned, preset: SimPreset) -> float:
    """Flight length [s]: the plan's, cut at ``max_seconds``, on the camera grid."""
    dur = float(planned.reference.duration)
    if preset.max_seconds > 0:
        dur = min(dur, preset.max_seconds)
    return math.floor(dur * preset.camera_hz + 1e-9) / preset.camera_hz


def fly_geometric(scene, vehicle, task_seed: int, n_points: int, preset: SimPreset) -> Flight:
    """Plan with :func:`uavturb.sim.trajectories.plan_trajectory`, fly with the geometric controller.

    Physics: :func:`uavturb.sim.flight.simulate_flight` (RK4 and controller every
    ``geometric_dt`` with the preset's effects and the exact heights of the scene; the
    reference sampled once, vectorised), noise-free, recorded at the camera rate. The
    controller's share of the time is measured by timing its ``update`` calls.
    """
    from uavturb.sim import flight as flight_mod
    from uavturb.sim.controller import GeometricController

    t0 = time.perf_counter()
    planned = _plan(scene, vehicle, task_seed, n_points, preset)
    t_plan = time.perf_counter() - t0
    spent = [0.0]

    class _Timed(GeometricController):
        def update(self, *a, **kw):
            t1 = time.perf_counter()
            out = super().update(*a, **kw)
            spent[0] += time.perf_counter() - t1
            return out

    t0 = time.perf_counter()
    original = flight_mod.GeometricController
    flight_mod.GeometricController = _Timed  # measured, process-local, restored below
    try:
        _, truth = flight_mod.simulate_flight(
            vehicle, planned.reference, duration=_duration(planned, preset),
            effects={k: dict(v) for k, v in preset.effects.items()}, points=np.zeros((1, 3)),
            surfaces=_SceneHeights(scene), physics_dt=preset.geometric_dt, control_dt=preset.geometric_dt,
            record_dt=1.0 / preset.camera_hz, noise=flight_mod.SensorNoise.none(), seed=0)
    finally:
        flight_mod.GeometricController = original
    total = time.perf_counter() - t0
    return Flight(t=truth.t, state=truth.x, rotor_speeds=truth.rotor_speeds,
                  timing={"control": t_plan + spent[0], "physics": total - spent[0]},
                  info={"controller": "geometric", "plan_s": t_plan, "plan_points": int(n_points),
                        "tracking_rms_m": truth.tracking_rms()})


def _mpc_available() -> bool:
    try:
        from uavturb.sim import mpc, trajectories  # noqa: F401
    except ImportError:
        return False
    return hasattr(trajectories, "fly_trajectory") and hasattr(mpc, "MPCController")


def fly_mpc(scene, vehicle, task_seed: int, n_points: int, preset: SimPreset) -> Flight:
    """Plan and fly with :func:`uavturb.sim.trajectories.fly_trajectory` and its CasADi MPC
    (physics at ``1 / physics_dt``, the MPC at its default rate; truncated at a collision)."""
    from uavturb.sim import trajectories

    t0 = time.perf_counter()
    planned = _plan(scene, vehicle, task_seed, n_points, preset)
    t_plan = time.perf_counter() - t0
    states, rotor_speeds, t, info = trajectories.fly_trajectory(
        scene, vehicle, task_seed, controller="mpc", camera_rate=preset.camera_hz,
        physics_rate=1.0 / preset.physics_dt, effects={k: dict(v) for k, v in preset.effects.items()},
        plan=planned, duration=_duration(planned, preset))
    return Flight(t=np.asarray(t), state=np.asarray(states), rotor_speeds=np.asarray(rotor_speeds),
                  timing={"control": t_plan + float(info.get("control_s", float("nan"))),
                          "physics": float(info.get("physics_s", float("nan")))},
                  info={"controller": "mpc", "plan_s": t_plan, "plan_points": int(n_points),
                        "collided": bool(info.get("collided", False)),
                        "tracking_rms_m": float(np.sqrt(np.mean(np.asarray(info.get("tracking_error", [0.0])) ** 2)))})


#: name -> flyer(scene, vehicle, task_seed, n_points, preset) -> Flight
FLYERS: dict[str, Callable[..., Flight]] = {"geometric": fly_geometric, "mpc": fly_mpc}


def resolve_controller(name: str) -> str:
    """``auto`` -> ``mpc`` when :mod:`uavturb.sim.trajectories` provides ``fly_trajectory``, else ``geometric``."""
    if name == "auto":
        return "mpc" if _mpc_available() else "geometric"
    if name == "mpc" and not _mpc_available():
        raise InputError("controller", "mpc needs uavturb.sim.trajectories.fly_trajectory, which is not installed")
    if name not in FLYERS:
        raise InputError("controller", f"unknown controller {name!r} (known: auto, {', '.join(FLYERS)})")
    return name


# ----------------------------------------------------------------------------------------------
# one trajectory


@lru_cache(maxsize=2)
def _scene(index: int):
    from uavturb.sim.scenes import generate_scene

    return generate_scene(int(index))


class _RendererCache:
    """One renderer (one EGL context) per process, for the last scene asked for."""

    def __init__(self):
        self.key = None
        self.renderer = None

    def get(self, scene_index: int, preset: SimPreset):
        from uavturb.sim.render import SceneRenderer

        key = (scene_index, preset.width, preset.height, preset.yfov_deg, preset.rgb)
        if key != self.key:
            if self.renderer is not None:
                self.renderer.close()
            self.renderer = SceneRenderer(_scene(scene_index), preset.width, preset.height, preset.yfov_deg,
                                          rgb=preset.rgb)
            self.key = key
        return self.renderer

    def close(self) -> None:
        if self.renderer is not None:
            self.renderer.close()
        self.key = self.renderer = None


_RENDERERS = _RendererCache()


def below_out_of_view(state: np.ndarray, d: np.ndarray, depth: np.ndarray, K: np.ndarray,
                      pitch_deg: float, tol: float = 0.05) -> np.ndarray:
    """Whether the surface point straight below the vehicle is out of the camera's view.

    The point ``p - d e_z`` is projected with the camera pose of :func:`uavturb.sim.render.camera_pose`;
    it is *in view* when it lies in front of the camera, inside the image, and the rendered
    z-depth at its pixel matches its own within ``tol`` relative (+ 2 cm): not hidden.

    Parameters
    ----------
    state : (T, 13), d : (T,) m, depth : (T, H, W) m, K : (3, 3) intrinsics, pitch_deg : deg

    Returns
    -------
    (T,) bool
    """
    from uavturb.sim.render import camera_pose

    T, H, W = depth.shape
    out = np.ones(T, dtype=bool)
    for i in range(T):
        if not np.isfinite(d[i]):
            continue
        Twc = camera_pose(state[i, :3], state[i, 3:7], pitch_deg)
        pc = Twc[:3, :3].T @ (state[i, :3] - np.array([0.0, 0.0, d[i]]) - Twc[:3, 3])
        if pc[2] <= 1e-3:
            continue
        u, v = K[0, 0] * pc[0] / pc[2] + K[0, 2], K[1, 1] * pc[1] / pc[2] + K[1, 2]
        j, r = int(round(u)), int(round(v))
        if 0 <= j < W and 0 <= r < H:
            z = depth[i, r, j]
            out[i] = not (z > 0 and abs(z - pc[2]) <= tol * pc[2] + 0.02)
    return out


def make_trajectory(task: Task, preset: SimPreset, seed: int, controller: str
                    ) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
    """Fly, measure and render one trajectory.

    Returns
    -------
    arrays : the shard arrays of :mod:`uavturb.data.shards` (plus ``rgb`` (T, H, W, 3) uint8
        when the preset asks for it)
    meta : the trajectory's metadata, with ``stats`` (counts and seconds)
    """
    from uavturb.io.vehicle_file import preset as vehicle_preset
    from uavturb.physics.ground_effect import phi
    from uavturb.sim.render import camera_pose
    from uavturb.sim.scenes import height_below, inside_obstacle
    from uavturb.sim.trajectories import collides

    t_start, cpu_start = time.perf_counter(), time.process_time()
    scene = _scene(task.scene)
    vehicle = vehicle_preset(preset.vehicle)
    fl = FLYERS[controller](scene, vehicle, task.task_seed(seed), task.n_points, preset)
    state, w, t = np.asarray(fl.state, float), np.asarray(fl.rotor_speeds, float), np.asarray(fl.t, float)
    t_flown = time.perf_counter()

    hit = collides(scene, state[:, :3], vehicle.arm_length + vehicle.rotor_radius, COLLISION_HALF_HEIGHT)
    truncated = bool(hit.any()) or bool(fl.info.get("collided", False))
    if hit.any():  # stop before the first sample that touches the scene
        n = max(int(np.argmax(hit)) - 1, 0)
        state, w, t = state[:n], w[:n], t[:n]
    if len(t) < 2:
        raise InputError(f"trajectory {task.name}", "collided at take-off (no samples left)")
    d = height_below(scene, state[:, :3])
    k_T, r = float(vehicle.thrust_coefficient), float(vehicle.rotor_radius)
    mu = float(preset.effects["ground_effect"]["mu"])
    fa = phi(d, k_T * np.sum(w**2, axis=1), mu, r)

    t_r = time.perf_counter()
    rend = _RENDERERS.get(task.scene, preset)
    T = len(t)
    depth = np.empty((T, preset.height, preset.width), np.float32)
    normals = np.empty((T, preset.height, preset.width, 3), np.float32) if preset.normals else None
    rgb = np.empty((T, preset.height, preset.width, 3), np.uint8) if preset.rgb else None
    for i in range(T):
        Twc = camera_pose(state[i, :3], state[i, 3:7], preset.pitch_deg)
        if normals is not None:
            depth[i], normals[i] = rend.depth_and_normals(Twc)
        else:
            depth[i] = rend.depth(Twc)
        if rgb is not None:
            rgb[i] = rend.rgb(Twc)
    t_rendered = time.perf_counter()
    oov = below_out_of_view(state, d, depth, rend.K, preset.pitch_deg)
    surface = state[:, 2] - d  # m, height of the surface below
    lag = max(int(round(preset.camera_hz * SURFACE_MEMORY_S)), 1)
    changed = np.abs(surface - surface[np.maximum(np.arange(T) - lag, 0)]) > SURFACE_STEP

    arrays: dict[str, np.ndarray] = {"depth": depth, "rotor_speeds": w, "state": state, "d": d, "fa": fa, "t": t}
    if normals is not None:
        arrays["normals"] = normals
    if rgb is not None:
        arrays["rgb"] = rgb
    stats = {
        "samples": int(T), "plan_points": int(task.n_points), "low": int(np.sum(d < LOW_HEIGHT)),
        "out_of_view": int(np.sum(oov)), "surface_changed": int(np.sum(changed)),
        "surface_changed_out_of_view": int(np.sum(changed & oov)),
        "inside": int(np.sum(inside_obstacle(scene, state[:, :3], 0.0))),
        "truncated": int(truncated), "cpu_s": float(time.process_time() - cpu_start),
        "seconds": {"control": float(fl.timing.get("control", float("nan"))),
                    "physics": float(fl.timing.get("physics", t_flown - t_start)),
                    "render": float(t_rendered - t_r),
                    "other": float(time.perf_counter() - t_start - (t_flown - t_start) - (t_rendered - t_r))},
    }
    meta = {"scene_id": f"scene_{task.scene:03d}", "scene_seed": int(task.scene), "split": task.split,
            "trajectory_id": task.name, "index": int(task.index), "k": int(task.k), "vehicle": preset.vehicle,
            "k_T": k_T, "mu": mu, "rotor_radius": r, "camera": {"K": rend.K.tolist(), "pitch_deg": preset.pitch_deg,
                                                              "rate_hz": preset.camera_hz},
            "controller": controller, "stats": stats, "flight": fl.info}
    return arrays, meta


def _write(folder: Path, arrays: dict[str, np.ndarray], meta: dict[str, Any]) -> None:
    """Write a trajectory atomically; ``rgb`` rides along in the same atomic rename."""
    from uavturb.io import shards

    rgb = arrays.pop("rgb", None)
    extra = None if rgb is None else {"rgb": np.asarray(rgb, np.uint8)}
    shards.write_trajectory(folder, arrays, meta, extra_arrays=extra)


def _work(job: tuple[Task, SimPreset, int, str, str]) -> dict[str, Any]:
    """Generate and write one trajectory (in a worker or in-process); returns its meta."""
    task, preset, seed, controller, out = job
    folder = Path(out) / task.name
    arrays, meta = make_trajectory(task, preset, seed, controller)
    meta["config_hash"] = _CONFIG_HASH.get(out, "")
    _write(folder, arrays, meta)
    return meta


_CONFIG_HASH: dict[str, str] = {}


def _init_worker(out: str, chash: str) -> None:
    os.environ.setdefault("PYOPENGL_PLATFORM", "egl")
    _CONFIG_HASH[out] = chash


def _ray_work(job: tuple[Task, SimPreset, int, str, str], chash: str) -> dict[str, Any]:
    """:func:`_work` as a Ray task (a worker process is reused: its renderers too)."""
    _init_worker(job[4], chash)
    return _work(job)


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


# ----------------------------------------------------------------------------------------------
# progress


class Progress:
    """A progress line on stderr: items done, samples, samples/s and ETA (from the items' pace)."""

    def __init__(self, label: str, total_items: int, stream=None, every: float = 0.5):
        self.label, self.total_items = label, total_items
        self.items, self.samples = 0, 0
        self.t0 = time.perf_counter()
        self.stream = stream if stream is not None else sys.stderr
        self.tty = hasattr(self.stream, "isatty") and self.stream.isatty()
        self.every = every if self.tty else 5.0
        self.last = 0.0

    def update(self, items: int, samples: int) -> None:
        self.items += items
        self.samples += samples
        now = time.perf_counter()
        if now - self.last >= self.every or self.items >= self.total_items:
            self.last = now
            self._print(now)

    def rate(self) -> float:
        """Samples per second since the start."""
        return self.samples / max(time.perf_counter() - self.t0, 1e-9)

    def _print(self, now: float) -> None:
        elapsed = now - self.t0
        left = self.total_items - self.items
        eta = elapsed / self.items * left if self.items else float("nan")
        line = (f"{self.label}: {self.items}/{self.total_items}, {self.samples} samples, "
                f"{self.rate():.0f} samples/s, elapsed {elapsed:.0f} s, ETA {eta:.0f} s")
        print(("\r" + line) if self.tty else line, end="" if self.tty else "\n", file=self.stream, flush=True)

    def close(self) -> None:
        if self.tty and self.items:
            print(file=self.stream, flush=True)


# ----------------------------------------------------------------------------------------------
# the dataset


def dataset_config(preset: SimPreset, seed: int, controller: str) -> dict[str, Any]:
    """The config stored in the manifest (and hashed): everything that fixes the arrays."""
    return {"generator": "uavturb.sim.dataset", "generator_version": GENERATOR_VERSION, "seed": int(seed),
            "controller": controller, "preset": preset.to_dict()}


def _existing(out: Path, tasks: Sequence[Task], chash: str) -> dict[str, dict[str, Any]]:
    """Metas of finished trajectories of ``tasks`` under ``out``; refuses another config's data."""
    from uavturb.io import shards

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
    from uavturb.io import shards

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
    preset : ``tiny``, ``quick``, ``paper`` or a :class:`~uavturb.sim.presets.SimPreset`
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
    from uavturb.io import shards

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
    out.mkdir(parents=True, exist_ok=True)
    all_tasks = plan_tasks(p, seed)
    tasks = [t for t in all_tasks if t.index % n == k - 1]
    if not tasks:
        raise InputError("--shard", f"shard {k}/{n} holds no trajectory (the preset has {len(all_tasks)})")
    for t in tasks:  # leftovers of an interrupted writer of this shard's own trajectories
        for junk in out.glob(f".{t.name}.*"):
            shutil.rmtree(junk, ignore_errors=True)
    metas = _existing(out, tasks, chash)
    todo = [t for t in tasks if t.name not in metas]
    # scene-major order keeps each worker's renderer on one scene for several trajectories
    todo.sort(key=lambda t: (t.scene, t.k))
    bar = Progress(f"generate sim ({p.name}{'' if n == 1 else f', shard {k}/{n}'})", len(todo)) if progress else None
    t0 = time.perf_counter()
    new: list[dict[str, Any]] = []

    def done(meta: dict[str, Any]) -> None:
        metas[meta["trajectory_id"]] = meta
        new.append(meta)
        if bar is not None:
            bar.update(1, meta["stats"]["samples"])
        if on_trajectory is not None:
            on_trajectory(meta)

    jobs = [(t, p, int(seed), controller, str(out.resolve() if executor == "ray" else out)) for t in todo]
    try:
        if executor == "ray":
            _run_on_ray(jobs, chash, done)
        elif workers == 1 or len(jobs) <= 1:
            _init_worker(str(out), chash)
            try:
                for job in jobs:
                    done(_work(job))
            finally:
                _RENDERERS.close()  # free this process's GL context
        else:
            import multiprocessing as mp

            ctx = mp.get_context("spawn")
            with ctx.Pool(min(int(workers), len(jobs)), initializer=_init_worker, initargs=(str(out), chash)) as pool:
                for meta in pool.imap_unordered(_work, jobs, chunksize=1):
                    done(meta)
    finally:
        if bar is not None:
            bar.close()
    wall = time.perf_counter() - t0
    new_samples = sum(m["stats"]["samples"] for m in new)
    throughput = {"this_run": {"trajectories": len(new), "samples": int(new_samples), "wall_s": wall,
                               "samples_per_s": new_samples / wall if wall > 0 and new else None,
                               "workers": int(workers), "worker_seconds": time_split(new)},
                  "all_trajectories_worker_seconds": time_split(list(metas.values()))}
    extra = {"throughput": throughput, "shard": f"{k}/{n}", "complete": len(metas) == len(all_tasks),
             "expected_trajectories": len(all_tasks)}
    return _write_manifest(out, tasks, metas, config, extra)


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
    from uavturb.io import shards

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


# ----------------------------------------------------------------------------------------------
# benchmark


def benchmark(preset: str = "quick", workers: int = 2, seed: int = 0, out: str | Path | None = None,
              **overrides: Any) -> dict[str, float]:
    """``uavturb bench generate``: generate a preset from scratch and time it.

    The wall-clock rate depends on what else runs on the machine; the CPU time of the
    workers (all threads, rendering included) gives the rate the same work reaches on free
    cores. The split between control (MPC, planning included), physics, rendering and the
    rest is the workers' wall time per stage.

    Returns
    -------
    dict of printable figures (names carry units).
    """
    import tempfile

    with tempfile.TemporaryDirectory(prefix="uavturb-bench-") as tmp:
        root = Path(out) if out is not None else Path(tmp) / "sim"
        if root.exists():
            shutil.rmtree(root)
        t0 = time.perf_counter()
        generate_sim(preset, root, workers=workers, seed=seed, progress=True, **overrides)
        wall = time.perf_counter() - t0
        from uavturb.io import shards

        m = shards.read_manifest(root)
        metas = [shards.read_meta(f) for s in shards.SPLITS for f in m.folders(s)]
    n = sum(mt["stats"]["samples"] for mt in metas)
    secs = time_split(metas)
    busy = sum(v for v in secs.values() if np.isfinite(v))
    cpu = sum(mt["stats"].get("cpu_s", float("nan")) for mt in metas)
    p = get_preset(preset, **overrides)
    res = {"preset": p.name, "controller": metas[0]["controller"], "image": f"{p.width}x{p.height}",
           "workers": int(workers), "samples": int(n), "wall_s": wall, "samples_per_s (wall)": n / wall,
           "cpu_ms_per_sample (all threads)": 1e3 * cpu / n,
           "samples_per_s per free core (from CPU time)": n / cpu,
           f"samples_per_s on {workers} free cores (projected)": workers * n / cpu,
           "cores used on average": cpu / wall}
    for k, v in secs.items():
        res[f"share of worker time: {k}"] = v / busy if busy > 0 else float("nan")
    return res


def describe(root: str | Path) -> str:
    """A few lines on a dataset folder: counts per split, statistics, throughput."""
    import json

    from uavturb.io import shards

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
