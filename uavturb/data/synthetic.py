"""Synthetic shards and pre-training pairs with known answers: box rooms, pinhole camera.

A scene is a closed room ``[-L, L]^2 x [0, ceiling]`` (floor, four walls, ceiling) with
axis-aligned boxes standing on the floor (tables, crates): a single-room layout of the one scene
model (:func:`random_box_room`, :func:`uavturb.scene.layouts.box_room`). Depth and normals are exact
ray casts (:func:`cast_rays`: slab tests), so every pixel hits a surface; heights are exact (the
box top or the floor under the body origin, :func:`uavturb.scene.queries.surface_below`), and the ground-effect
force is the physics core's law ``f_a = phi(d, k_T sum Omega^2, mu, r)`` (:func:`uavturb.physics.ground_effect.phi`)
with the paper's simulated quadrotor (``k_T = 5.45e-6``, ``r = 0.01 m``) and ``mu = 2``.

Frames and conventions are those of the simulator (:mod:`uavturb.sim.core.render`): world z up;
the camera's optical frame has x right, y down, z forward; it looks along body +x, pitched
down by ``pitch_deg``; pixel ``(i, j)`` has the ray ``((j - (W-1)/2) / f, (i - (H-1)/2) / f, 1)``
with ``f = (H/2) / tan(yfov/2)`` (:func:`pixel_rays`; the forward camera of :mod:`uavturb.scene.camera`),
so a ray parameter is the z-depth.
The body flies level (roll = pitch = 0), heading along its horizontal velocity.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from uavturb.errors import InputError
from uavturb.io import shards
from uavturb.physics import quaternion as quat
from uavturb.physics.effects import DEFAULT_EFFECTS
from uavturb.physics.ground_effect import phi
from uavturb.physics.vehicle import QUADROTOR
from uavturb.progress import progress_bar, show_rate
from uavturb.scene.indoor import Scene
from uavturb.scene.layouts import box_room
from uavturb.scene.queries import surface_below
from uavturb.scene.camera import forward_intrinsics

YFOV_DEG = 70.0        # vertical field of view, as the simulator's renderer
PITCH_DEG = 45.0       # camera pitched down [deg]
DT = 0.05              # s, 20 Hz camera
ROOM_HALF = 4.0        # m, room half-width
CEILING = 3.0          # m
MU = DEFAULT_EFFECTS["ground_effect"]["mu"]


def pixel_rays(size: int | tuple[int, int], yfov_deg: float = YFOV_DEG) -> np.ndarray:
    """Camera-frame rays of pixel centres with unit z: ``point = rays * depth``.

    Parameters
    ----------
    size : side (square) or ``(H, W)`` in pixels.
    yfov_deg : vertical field of view [deg].

    Returns
    -------
    (H, W, 3) float64 rays ``(x, y, 1)`` in the optical frame (x right, y down, z forward).
    """
    H, W = (size, size) if np.isscalar(size) else size
    K = forward_intrinsics(W, H, yfov_deg)  # the forward camera of uavturb.scene.camera
    u = (np.arange(W) - K[0, 2]) / K[0, 0]
    v = (np.arange(H) - K[1, 2]) / K[1, 1]
    uu, vv = np.meshgrid(u, v)
    return np.stack([uu, vv, np.ones_like(uu)], axis=-1)


def random_box_room(rng: np.random.Generator, n_boxes: tuple[int, int] = (3, 7)) -> Scene:
    """A random room of the synthetic data: ``[-ROOM_HALF, ROOM_HALF]^2 x [0, CEILING]`` with
    ``n_boxes`` (inclusive range) boxes standing on the floor, 0.6-1.8 m wide, 0.2-0.8 m high
    (a :func:`~uavturb.scene.layouts.box_room`)."""
    k = int(rng.integers(n_boxes[0], n_boxes[1] + 1))
    c = rng.uniform(-ROOM_HALF + 1.0, ROOM_HALF - 1.0, (k, 2))
    s = rng.uniform(0.3, 0.9, (k, 2))
    top = rng.uniform(0.2, 0.8, k)
    boxes = np.column_stack([c[:, 0] - s[:, 0], c[:, 0] + s[:, 0], c[:, 1] - s[:, 1], c[:, 1] + s[:, 1], top])
    return box_room((2 * ROOM_HALF, 2 * ROOM_HALF), CEILING, boxes)


def _highest_top(room: Scene) -> float:
    """m, the highest box top of a room (0 without boxes)."""
    return max((f.surface for f in room.furniture), default=0.0)


def cast_rays(room: Scene, origin: np.ndarray, dirs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Exact ray cast into a single-room layout (:mod:`uavturb.scene.layouts`) from origins inside
    the room, outside every box: its walls, floor and ceiling, then a slab test per box.

    Parameters
    ----------
    room : Scene of kind ``'room'``.
    origin : (F, 3) ray origins [m], world.
    dirs : (F, P, 3) ray directions, world (any length: the result is in their units).

    Returns
    -------
    t : (F, P) ray parameter of the first hit; normals : (F, P, 3) unit world normals of
    the surfaces hit (not yet oriented).
    """
    o = origin[:, None, :]
    dd = np.where(np.abs(dirs) < 1e-12, 1e-12, dirs)
    rect = room.rooms[0].rect
    lo = np.array([rect[0], rect[1], 0.0])
    hi = np.array([rect[2], rect[3], room.ceiling_height])
    # room: exit through the slab each direction points to
    t_axis = (np.where(dd > 0, hi, lo) - o) / dd                        # (F, P, 3)
    axis = t_axis.argmin(-1)
    t = np.take_along_axis(t_axis, axis[..., None], -1)[..., 0]
    n = np.zeros(dirs.shape)
    np.put_along_axis(n, axis[..., None], 1.0, -1)
    # boxes: slab test
    for box in room.furniture:
        blo, bhi = box.lo, box.hi
        t1, t2 = (blo - o) / dd, (bhi - o) / dd
        tn, tf = np.minimum(t1, t2), np.maximum(t1, t2)
        t_in, t_out = tn.max(-1), tf.min(-1)
        hit = (t_in <= t_out) & (t_in > 0) & (t_in < t)
        if hit.any():
            ax = tn.argmax(-1)
            nb = np.zeros(dirs.shape)
            np.put_along_axis(nb, ax[..., None], 1.0, -1)
            t = np.where(hit, t_in, t)
            n = np.where(hit[..., None], nb, n)
    return t, n


def camera_rotation(yaw: np.ndarray, pitch_deg: float | np.ndarray) -> np.ndarray:
    """(F, 3, 3) ``R_WC``: optical frame of a camera looking along body +x pitched down, level body:
    ``R_z(yaw) R_BC`` with the forward camera's mount ``R_BC`` (:func:`uavturb.scene.camera.forward_rotation`),
    written out per frame for arrays of yaws and pitches [rad, deg]."""
    yaw = np.asarray(yaw, float)
    th = np.deg2rad(np.broadcast_to(np.asarray(pitch_deg, float), yaw.shape))
    z = np.stack([np.cos(yaw) * np.cos(th), np.sin(yaw) * np.cos(th), -np.sin(th)], -1)
    x = np.stack([np.sin(yaw), -np.cos(yaw), np.zeros_like(yaw)], -1)
    y = np.cross(z, x)
    return np.stack([x, y, z], -1)


def render(room: Scene, p: np.ndarray, R_WC: np.ndarray, rays: np.ndarray, normals: bool = True,
           chunk: int = 16) -> tuple[np.ndarray, np.ndarray | None]:
    """Depth (and normals) images of a room.

    Parameters
    ----------
    room : the scene.
    p : (F, 3) camera positions [m], world.
    R_WC : (F, 3, 3) camera (optical) to world rotations.
    rays : (H, W, 3) from :func:`pixel_rays`.

    Returns
    -------
    depth : (F, H, W) z-depth [m]; normals : (F, H, W, 3) unit normals in the optical frame,
    towards the camera (None unless ``normals``).
    """
    H, W = rays.shape[:2]
    r = rays.reshape(-1, 3)
    depth = np.empty((len(p), H, W))
    nrm = np.empty((len(p), H, W, 3)) if normals else None
    for s in range(0, len(p), chunk):
        R = R_WC[s:s + chunk]
        dirs = np.einsum("fij,pj->fpi", R, r)
        t, n_w = cast_rays(room, p[s:s + chunk], dirs)
        depth[s:s + chunk] = t.reshape(-1, H, W)
        if normals:
            n_c = np.einsum("fji,fpj->fpi", R, n_w)  # R^T n
            n_c *= -np.sign((n_c * r).sum(-1, keepdims=True) + 1e-12)
            nrm[s:s + chunk] = n_c.reshape(-1, H, W, 3)
    return depth, nrm


def _smooth_noise(rng: np.random.Generator, T: int, dt: float, n: int, freqs=(0.2, 1.5)) -> np.ndarray:
    """(T, n) sums of random sines, each channel in about [-1, 1]."""
    t = np.arange(T)[:, None] * dt
    out = np.zeros((T, n))
    for _ in range(3):
        f = rng.uniform(*freqs, n)
        out += np.sin(2 * np.pi * f * t + rng.uniform(0, 2 * np.pi, n)) / 3
    return out


def fly(room: Scene, rng: np.random.Generator, T: int, dt: float = DT) -> dict[str, np.ndarray]:
    """A smooth level flight over the room: positions, yaw, heights.

    Returns
    -------
    dict with ``t`` (T,) s, ``p`` (T, 3) m, ``yaw`` (T,) rad, ``d`` (T,) m (height over the
    surface below), ``v`` (T, 3) m/s world, ``yaw_rate`` (T,) rad/s.
    """
    t = np.arange(T) * dt
    span = ROOM_HALF - 0.5
    # a random walk of the centre at ~0.8 m/s, wrapped smoothly inside the room
    c0 = rng.uniform(-span, span, 2)
    heading = rng.uniform(0, 2 * np.pi)
    turn = 0.8 * _smooth_noise(rng, T, dt, 1, (0.05, 0.4))[:, 0]
    speed = 0.6 + 0.3 * _smooth_noise(rng, T, dt, 1, (0.05, 0.3))[:, 0]
    psi = heading + np.cumsum(turn) * dt
    step = np.stack([np.cos(psi), np.sin(psi)], -1) * speed[:, None] * dt
    xy_free = c0 + np.cumsum(step, axis=0) - step[0]
    # reflect at the walls (triangle wave keeps positions continuous)
    xy = np.abs(np.mod(xy_free + span, 4 * span) - 2 * span) - span
    top = _highest_top(room)
    z_lo = top + rng.uniform(0.1, 0.3)
    z_hi = z_lo + rng.uniform(0.3, 1.0)
    z = z_lo + (z_hi - z_lo) * (0.5 + 0.5 * _smooth_noise(rng, T, dt, 1, (0.05, 0.5))[:, 0])
    p = np.column_stack([xy, z])
    v = np.gradient(p, dt, axis=0) if T > 1 else np.zeros((T, 3))
    yaw = np.unwrap(np.arctan2(v[:, 1], v[:, 0])) if T > 1 else np.array([heading])
    yaw_rate = np.gradient(yaw, dt) if T > 1 else np.zeros(T)
    d = z - surface_below(room, xy)
    return {"t": t, "p": p, "yaw": yaw, "d": d, "v": v, "yaw_rate": yaw_rate}


def synthetic_trajectory(room: Scene, rng: np.random.Generator, T: int, size: int, dt: float = DT,
                         yfov_deg: float = YFOV_DEG, pitch_deg: float = PITCH_DEG,
                         with_normals: bool = False) -> dict[str, np.ndarray]:
    """Arrays of one trajectory in the shard contract (:mod:`uavturb.data.shards`)."""
    fl = fly(room, rng, T, dt)
    veh = QUADROTOR
    omega_h = veh.hover_speed()
    omega = omega_h * (1.0 + 0.05 * _smooth_noise(rng, T, dt, veh.rotor_count, (0.2, 3.0)))
    thrust = veh.thrust_coefficient * (omega**2).sum(1)
    q = quat.from_euler(np.zeros(T), np.zeros(T), fl["yaw"])
    state = np.column_stack([fl["p"], q, fl["v"], np.zeros(T), np.zeros(T), fl["yaw_rate"]])
    depth, normals = render(room, fl["p"], camera_rotation(fl["yaw"], pitch_deg), pixel_rays(size, yfov_deg),
                            normals=with_normals)
    out = {"depth": depth, "rotor_speeds": omega, "state": state, "d": fl["d"],
           "fa": phi(fl["d"], thrust, MU, veh.rotor_radius), "t": fl["t"]}
    if with_normals:
        out["normals"] = normals
    return out


def scene_splits(n_scenes: int) -> list[str]:
    """Split of each scene index: the last ~15 % (at least one) test, the ~15 % before val."""
    if n_scenes < 3:
        raise InputError("n_scenes", f"need at least 3 scenes (one per split), got {n_scenes}")
    n_eval = max(1, round(0.15 * n_scenes))
    n_train = n_scenes - 2 * n_eval
    return ["train"] * n_train + ["val"] * n_eval + ["test"] * n_eval


def make_synthetic_dataset(root: str | Path, n_scenes: int = 6, trajs_per_scene: int = 3, T: int = 64,
                           size: int = 32, seed: int = 0, with_normals: bool = False, dt: float = DT,
                           yfov_deg: float = YFOV_DEG, pitch_deg: float = PITCH_DEG, progress: bool = False):
    """Write a synthetic shard dataset (trajectories + manifest) under ``root``.

    Parameters
    ----------
    root : dataset folder (created; trajectories already there are replaced).
    n_scenes : rooms (>= 3; split by scene, see :func:`scene_splits`).
    trajs_per_scene : trajectories per room.
    T : frames per trajectory.
    size : image side [px].
    seed : the same seed gives the same bytes.
    with_normals : also store normals.
    progress : print frames/s to stderr.

    Returns
    -------
    :class:`uavturb.data.shards.Manifest`
    """
    if T < 1 or size < 1 or trajs_per_scene < 1:
        raise InputError("synthetic", f"T, size and trajs_per_scene must be positive, got {T}, {size}, "
                         f"{trajs_per_scene}")
    root = Path(root)
    rng = np.random.default_rng(seed)
    split_of = scene_splits(n_scenes)
    splits: dict[str, list[str]] = {s: [] for s in shards.SPLITS}
    k = 0
    bar = progress_bar(n_scenes * trajs_per_scene, "synthetic shards", "trajectories") if progress else None
    for s in range(n_scenes):
        room = random_box_room(rng)
        for j in range(trajs_per_scene):
            name = f"traj_{k:05d}"
            arrays = synthetic_trajectory(room, rng, T, size, dt, yfov_deg, pitch_deg, with_normals)
            meta = {"scene_id": f"synthetic_{s:03d}", "split": split_of[s], "trajectory_id": k,
                    "vehicle": QUADROTOR.name, "k_T": QUADROTOR.thrust_coefficient, "mu": MU,
                    "rotor_radius": QUADROTOR.rotor_radius, "dt": dt, "yfov_deg": yfov_deg, "pitch_deg": pitch_deg,
                    "generator": "uavturb.data.synthetic"}
            shards.write_trajectory(root / name, arrays, meta, overwrite=True)
            splits[split_of[s]].append(name)
            k += 1
            if bar is not None:
                show_rate(bar, k * T, "frames")
                bar.update(1)
    if bar is not None:
        bar.close()
    config: dict[str, Any] = {"generator": "synthetic", "n_scenes": n_scenes, "trajs_per_scene": trajs_per_scene,
                              "T": T, "size": size, "seed": seed, "with_normals": with_normals, "dt": dt,
                              "yfov_deg": yfov_deg, "pitch_deg": pitch_deg}
    return shards.write_manifest(root, splits, config)


def make_synthetic_pairs(root: str | Path, M: int = 512, size: int = 32, seed: int = 0, yfov_deg: float = YFOV_DEG,
                         per_room: int = 8, overwrite: bool = True) -> Path:
    """Write ``M`` (depth, normals) pre-training pairs to ``ROOT/pairs`` from random views of random rooms.

    Cameras sit anywhere above the boxes, look in any direction, pitched down 10-80 deg; a new
    room every ``per_room`` views. Returns the pairs folder.
    """
    if M < 1 or size < 1:
        raise InputError("pairs", f"M and size must be positive, got {M}, {size}")
    rng = np.random.default_rng(seed)
    rays = pixel_rays(size, yfov_deg)
    depth = np.empty((M, size, size), np.float32)
    normals = np.empty((M, size, size, 3), np.float32)
    for s in range(0, M, per_room):
        room = random_box_room(rng)
        n = min(per_room, M - s)
        top = _highest_top(room)
        p = np.column_stack([rng.uniform(-ROOM_HALF + 0.3, ROOM_HALF - 0.3, (n, 2)),
                             rng.uniform(top + 0.1, CEILING - 0.3, n)])
        R = camera_rotation(rng.uniform(0, 2 * np.pi, n), rng.uniform(10.0, 80.0, n))
        dep, nrm = render(room, p, R, rays)
        depth[s:s + n], normals[s:s + n] = dep, nrm
    meta = {"generator": "uavturb.data.synthetic", "seed": seed, "yfov_deg": yfov_deg, "per_room": per_room}
    return shards.write_pairs(root, depth, normals, meta, overwrite=overwrite)
