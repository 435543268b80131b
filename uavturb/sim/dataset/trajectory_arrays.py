"""One trajectory of a dataset (:func:`make_trajectory`): fly (:mod:`uavturb.sim.dataset.flying`),
truncate before a collision, measure ``d`` and ``f_a``, render depth (one renderer per scene and
process), write it atomically (:func:`work`, in a worker or in-process)."""

from __future__ import annotations

import os
import time
from functools import lru_cache
from pathlib import Path
from typing import Any

import numpy as np

from uavturb.errors import InputError
from uavturb.io import shards
from uavturb.io.vehicle_file import named_vehicle
from uavturb.physics.ground_effect import phi
from uavturb.scene.procedural import generate_scene
from uavturb.scene.projection import camera_pose_world
from uavturb.scene.queries import collides, height_below, inside_obstacle
from uavturb.scene.camera import preset_intrinsics, preset_mount
from uavturb.sim.core.render import SceneRenderer, camera_pose
from uavturb.sim.dataset.assignment import Task
from uavturb.sim.dataset.flying import FLYERS
from uavturb.sim.dataset.presets import SimPreset

LOW_HEIGHT = 0.5  # m, "ground effect matters" threshold of the statistics
SURFACE_MEMORY_S = 1.0  # s, look-back of the "surface below changed" statistic
SURFACE_STEP = 0.05  # m, a change of the surface height below larger than this counts
COLLISION_HALF_HEIGHT = 0.005  # m, vertical half-extent of the vehicle in the collision check


@lru_cache(maxsize=2)
def _scene(index: int):
    return generate_scene(int(index))


class _RendererCache:
    """One renderer (one EGL context) per process, for the last scene asked for."""

    def __init__(self):
        self.key = None
        self.renderer = None

    def get(self, scene_index: int, preset: SimPreset):
        key = (scene_index, preset.width, preset.height, preset.yfov_deg, preset.rgb, preset.camera)
        if key != self.key:
            if self.renderer is not None:
                self.renderer.close()
            self.renderer = SceneRenderer(_scene(scene_index), preset.width, preset.height, preset.yfov_deg,
                                          rgb=preset.rgb, K=preset_intrinsics(preset.camera, preset.width,
                                                                              preset.height))
            self.key = key
        return self.renderer

    def close(self) -> None:
        if self.renderer is not None:
            self.renderer.close()
        self.key = self.renderer = None


RENDERERS = _RendererCache()


def camera_poses(state: np.ndarray, pitch_deg: float, mount: np.ndarray | None = None) -> np.ndarray:
    """``T_WC`` (T, 4, 4) of the preset's camera at the states ``(T, 13)``: the forward camera of
    :func:`uavturb.sim.core.render.camera_pose` pitched ``pitch_deg`` down, or the body mount ``T_BC``
    (4, 4) of a calibrated camera (:func:`uavturb.scene.camera.preset_mount`)."""
    if mount is not None:
        return camera_pose_world(state[:, 3:7], state[:, :3], mount)
    return np.stack([camera_pose(x[:3], x[3:7], pitch_deg) for x in state]) if len(state) else np.zeros((0, 4, 4))


def below_out_of_view(state: np.ndarray, d: np.ndarray, depth: np.ndarray, K: np.ndarray,
                      pitch_deg: float, tol: float = 0.05, mount: np.ndarray | None = None) -> np.ndarray:
    """Whether the surface point straight below the vehicle is out of the camera's view.

    The point ``p - d e_z`` is projected with the camera pose of :func:`camera_poses`;
    it is *in view* when it lies in front of the camera, inside the image, and the rendered
    z-depth at its pixel matches its own within ``tol`` relative (+ 2 cm): not hidden.

    Parameters
    ----------
    state : (T, 13), d : (T,) m, depth : (T, H, W) m, K : (3, 3) intrinsics, pitch_deg : deg
    mount : (4, 4) ``T_BC`` of a calibrated camera (``None``: the forward camera)

    Returns
    -------
    (T,) bool
    """
    T, H, W = depth.shape
    out = np.ones(T, dtype=bool)
    poses = camera_poses(state, pitch_deg, mount)
    for i in range(T):
        if not np.isfinite(d[i]):
            continue
        Twc = poses[i]
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
    t_start, cpu_start = time.perf_counter(), time.process_time()
    scene = _scene(task.scene)
    vehicle = named_vehicle(preset.vehicle)
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
    rend = RENDERERS.get(task.scene, preset)
    T = len(t)
    depth = np.empty((T, preset.height, preset.width), np.float32)
    normals = np.empty((T, preset.height, preset.width, 3), np.float32) if preset.normals else None
    rgb = np.empty((T, preset.height, preset.width, 3), np.uint8) if preset.rgb else None
    mount = preset_mount(preset.camera)
    poses = camera_poses(state, preset.pitch_deg, mount)
    for i in range(T):
        Twc = poses[i]
        if normals is not None:
            depth[i], normals[i] = rend.depth_and_normals(Twc)
        else:
            depth[i] = rend.depth(Twc)
        if rgb is not None:
            rgb[i] = rend.rgb(Twc)
    t_rendered = time.perf_counter()
    oov = below_out_of_view(state, d, depth, rend.K, preset.pitch_deg, mount=mount)
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
    if mount is not None:  # a calibrated camera: its name and pose on the body (T_BC, m)
        meta["camera"].update(name=preset.camera, T_BC=mount.tolist())
        del meta["camera"]["pitch_deg"]
    return arrays, meta


def _write(folder: Path, arrays: dict[str, np.ndarray], meta: dict[str, Any]) -> None:
    """Write a trajectory atomically; ``rgb`` rides along in the same atomic rename."""
    rgb = arrays.pop("rgb", None)
    extra = None if rgb is None else {"rgb": np.asarray(rgb, np.uint8)}
    shards.write_trajectory(folder, arrays, meta, extra_arrays=extra)


def work(job: tuple[Task, SimPreset, int, str, str]) -> dict[str, Any]:
    """Generate and write one trajectory (in a worker or in-process); returns its meta."""
    task, preset, seed, controller, out = job
    folder = Path(out) / task.name
    arrays, meta = make_trajectory(task, preset, seed, controller)
    meta["config_hash"] = _CONFIG_HASH.get(out, "")
    _write(folder, arrays, meta)
    return meta


_CONFIG_HASH: dict[str, str] = {}


def init_worker(out: str, chash: str) -> None:
    os.environ.setdefault("PYOPENGL_PLATFORM", "egl")
    _CONFIG_HASH[out] = chash
