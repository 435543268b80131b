"""Depth/normal pairs for the encoder's pre-training: ``uavturb generate normals``, and IRS.

The paper pre-trains its depth encoder to predict surface normals on 22,705 depth/normal
pairs of the IRS dataset (Wang et al. 2019, synthetic indoor scenes). This module makes
the stand-in from the *training* scenes of a preset (never from validation or test
scenes), and reads IRS itself for users who have it. Both write the pairs layout of
:mod:`uavturb.data.shards` (``ROOT/pairs/depth.npy`` float32 ``(M, H, W)`` z-depth [m],
``ROOT/pairs/normals.npy`` float32 ``(M, H, W, 3)`` unit normals in the camera's optical
frame (x right, y down, z forward) facing the camera, 0 where nothing is hit).

Generated pairs (:func:`generate_normals`)
------------------------------------------
Viewpoints are random in the rooms of the training scenes: position uniform over a room's
free floor area (area-weighted choice of the room) at 0.05 m to 0.3 m under the ceiling,
at least 0.1 m from any solid; yaw uniform; camera pitch uniform in [-10, 60] deg (down
positive); roll normal with 5 deg standard deviation; the preset's camera intrinsics (``yfov_deg``,
or a calibrated camera's scaled to the image, ``camera``). A viewpoint whose median depth is
under 0.3 m (a camera against a wall) is drawn again. Chunk ``c`` of ``pairs_chunk`` pairs
comes from training scene ``c mod n_train`` with seed ``SeedSequence([seed, c])``, so the
pairs depend on the seed only (not on workers). Chunks are written atomically under
``ROOT/.pairs-chunks/`` as they finish (an interrupted run resumes there) and joined into
``ROOT/pairs`` at the end (atomic rename); a finished ``ROOT/pairs`` of the same config is
never rewritten.

IRS (:func:`read_irs`, :func:`import_irs`)
------------------------------------------
Expected layout (as IRS's archives unpack; any depth of sub-folders)::

    IRS/Home/<scene>/l_<n>.png    left colour image (not used)
    IRS/Home/<scene>/d_<n>.exr    left disparity [px], single channel, at 960 x 540
    IRS/Home/<scene>/n_<n>.exr    left surface normals, 3 channels (R, G, B = x, y, z)
    IRS/Office/..., IRS/Restaurant/..., IRS/Store/...

A pair is every ``d_<n>.exr`` with an ``n_<n>.exr`` beside it. Depth is ``f B / disparity``
with IRS's focal length ``f = 480 px`` at 960 px width and baseline ``B = 0.1 m`` (0 where the
disparity is not positive). Images are centre-cropped to a square and resized by nearest
neighbour to ``size`` (so depth and normals stay consistent and normals stay unit). The
axis convention of IRS's normal maps is not documented; it is resolved per folder, once,
as the signed axis permutation (of 48) under which the normals agree best with the
normals of the depth map itself, and rotated into the optical frame; normals are then
turned to face the camera. Reading EXR needs the ``OpenEXR`` package.
"""

from __future__ import annotations

import itertools
import os
import shutil
import time
from pathlib import Path
from typing import Any, Iterator

import numpy as np

from uavturb.errors import InputError
from uavturb.io import shards
from uavturb.io.publish import atomic_folder, write_text_atomic
from uavturb.physics import quaternion as quat
from uavturb.progress import progress_bar, show_rate
from uavturb.scene.procedural import generate_scene
from uavturb.scene.queries import inside_obstacle
from uavturb.scene.camera import preset_intrinsics
from uavturb.sim.core.render import SceneRenderer, camera_pose
from uavturb.sim.dataset.assignment import scene_splits
from uavturb.sim.dataset.presets import SimPreset, get_preset

CHUNKS_DIR = ".pairs-chunks"
IRS_FOCAL_PX = 480.0  # px, at IRS's 960 px image width
IRS_BASELINE_M = 0.1  # m
IRS_WIDTH_PX = 960


# ----------------------------------------------------------------------------------------------
# generated pairs


def pairs_config(preset: SimPreset, seed: int) -> dict[str, Any]:
    """What fixes the generated pairs (stored, with its hash, in ``pairs/meta.json``)."""
    keys = ("n_scenes", "n_train", "n_val", "n_test", "split_seed", "width", "height", "yfov_deg", "pairs",
            "pairs_chunk")
    # "generator" names the writer as pairs files have always named it (part of the config hash: kept as it was)
    conf = {"generator": "uavturb.sim.pretraining", "version": 1, "seed": int(seed),
            "preset": {"name": preset.name, **{k: getattr(preset, k) for k in keys}}}
    if preset.camera != "forward":  # a calibrated camera's intrinsics (the forward camera keeps the old hash)
        conf["preset"]["camera"] = preset.camera
    return conf


def random_viewpoints(scene, n: int, rng: np.random.Generator) -> np.ndarray:
    """``(n, 4, 4)`` camera poses ``T_WC`` (optical frame) at random in the rooms of ``scene``.

    See the module notes for the distribution.
    """
    rooms = scene.rooms
    if not rooms:
        raise InputError("scene", "random viewpoints need a generated scene (rooms)")
    areas = np.array([r.area for r in rooms])
    ceiling = scene.ceiling_height or 2.5
    out = np.empty((n, 4, 4))
    for k in range(n):
        for _ in range(1000):
            r = rooms[int(rng.choice(len(rooms), p=areas / areas.sum()))].rect
            p = np.array([rng.uniform(r[0], r[2]), rng.uniform(r[1], r[3]), rng.uniform(0.05, ceiling - 0.3)])
            if not inside_obstacle(scene, p[None], margin=0.1)[0]:
                break
        q = quat.from_euler(np.deg2rad(rng.normal(0.0, 5.0)), 0.0, rng.uniform(-np.pi, np.pi))
        out[k] = camera_pose(p, q, pitch_deg=rng.uniform(-10.0, 60.0))
    return out


def _chunk_pairs(job: tuple[int, int, int, int, str, SimPreset, int]) -> int:
    """Render chunk ``c`` (pairs ``[start, stop)``) of scene ``scene_index`` into its chunk folder."""
    c, start, stop, scene_index, root, preset, seed = job
    os.environ.setdefault("PYOPENGL_PLATFORM", "egl")

    rng = np.random.default_rng(np.random.SeedSequence([int(seed), c]))
    scene = generate_scene(scene_index)
    n = stop - start
    depth = np.empty((n, preset.height, preset.width), np.float32)
    normals = np.empty((n, preset.height, preset.width, 3), np.float32)
    K = preset_intrinsics(preset.camera, preset.width, preset.height)  # None: yfov_deg's camera
    with SceneRenderer(scene, preset.width, preset.height, preset.yfov_deg, K=K) as rend:
        for i in range(n):
            for _ in range(100):
                T = random_viewpoints(scene, 1, rng)[0]
                dd, nn = rend.depth_and_normals(T)
                if np.median(dd) >= 0.3:
                    break
            depth[i], normals[i] = dd, nn
    folder = Path(root) / CHUNKS_DIR / f"chunk_{c:05d}"
    with atomic_folder(folder) as stage:
        np.save(stage / "depth.npy", depth)
        np.save(stage / "normals.npy", normals)
    return n


def generate_normals(preset: str | SimPreset = "quick", out: str | Path = "data/pairs", *, workers: int = 1,
                     seed: int = 0, progress: bool = True, on_chunk=None, **overrides: Any) -> dict[str, Any]:
    """``uavturb generate normals``: depth/normal pairs from random viewpoints in training scenes.

    Parameters
    ----------
    preset : ``tiny``, ``quick``, ``paper`` (its ``pairs``, ``pairs_chunk``, camera and split)
    out : dataset folder; the pairs go to ``out/pairs``
    workers : processes (one EGL renderer each)
    seed : fixes every pair
    progress : progress line on stderr
    on_chunk : called after each new chunk with its index (tests interrupt a run with it)
    overrides : preset fields

    Returns
    -------
    The ``pairs/meta.json`` body (``count``, ``image_size``, ``config_hash``, ``scenes``...).
    """
    import json


    p = get_preset(preset, **overrides)
    if int(workers) < 1:
        raise InputError("--workers", f"must be at least 1, got {workers}")
    config = pairs_config(p, seed)
    chash = shards.config_hash(config)
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise InputError(out, "exists and is not a folder")
    final = out / shards.PAIRS_DIR
    if (final / shards.META).is_file():
        meta = json.loads((final / shards.META).read_text())
        if meta.get("config_hash") == chash:
            return meta
        raise InputError(final, f"holds pairs of another config (hash {meta.get('config_hash')}, this run {chash}); "
                                "use another --out")
    chunks_dir = _chunks_folder(out, seed, chash)
    train = scene_splits(p)["train"]
    n_chunks = -(-p.pairs // p.pairs_chunk)
    jobs = []
    for c in range(n_chunks):
        start, stop = c * p.pairs_chunk, min((c + 1) * p.pairs_chunk, p.pairs)
        jobs.append((c, start, stop, train[c % len(train)], str(out), p, int(seed)))
    todo = [j for j in jobs if not (chunks_dir / f"chunk_{j[0]:05d}").is_dir()]
    wall = _render_chunks(todo, workers, f"generate normals ({p.name})" if progress else None, on_chunk)
    new = sum(j[2] - j[1] for j in todo)
    files = [(chunks_dir / f"chunk_{c:05d}" / "depth.npy", chunks_dir / f"chunk_{c:05d}" / "normals.npy")
             for c in range(n_chunks)]
    meta = {"source": "generated", "config": config, "config_hash": chash, "scenes": sorted(set(train)),
            "split": "train", "throughput": {"pairs": new, "wall_s": wall,
                                             "pairs_per_s": new / wall if wall > 0 and new else None}}
    shards.write_pairs_chunks(out, files, meta)
    shutil.rmtree(chunks_dir, ignore_errors=True)
    return json.loads((final / shards.META).read_text())


def _chunks_folder(out: Path, seed: int, chash: str) -> Path:
    """The folder of finished chunks, ``out/<CHUNKS_DIR>``: created with this run's config, or left by an
    interrupted run of the same config (one of another config: :class:`InputError`)."""
    import json

    chunks_dir = out / CHUNKS_DIR
    chunks_dir.mkdir(parents=True, exist_ok=True)
    cfg_file = chunks_dir / "config.json"
    if cfg_file.is_file():
        old = json.loads(cfg_file.read_text())
        if old.get("config_hash") != chash:
            raise InputError(cfg_file, f"an interrupted run of another config (hash {old.get('config_hash')}) is "
                                       "there; use another --out or delete that folder")
    else:
        write_text_atomic(cfg_file, json.dumps({"seed": int(seed), "config_hash": chash}))
    return chunks_dir


def _render_chunks(todo: list[tuple], workers: int, label: str | None, on_chunk: Any) -> float:
    """Render the chunks ``todo`` here or in ``workers`` processes, with a progress bar ``label``
    (None: none); returns the wall time [s]."""
    bar = progress_bar(len(todo), label, "chunks") if label is not None else None
    t0 = time.perf_counter()
    pairs_done = 0

    def tick(n: int) -> None:
        nonlocal pairs_done
        pairs_done += n
        if bar is not None:
            show_rate(bar, pairs_done, "pairs")
            bar.update(1)

    try:
        if workers == 1 or len(todo) <= 1:
            for job in todo:
                tick(_chunk_pairs(job))
                if on_chunk is not None:
                    on_chunk(job[0])
        else:
            import multiprocessing as mp

            with mp.get_context("spawn").Pool(min(int(workers), len(todo))) as pool:
                for n in pool.imap_unordered(_chunk_pairs, todo, chunksize=1):
                    tick(n)
    finally:
        if bar is not None:
            bar.close()
    return time.perf_counter() - t0


# ----------------------------------------------------------------------------------------------
# IRS


def read_exr(path: str | Path) -> np.ndarray:
    """An EXR image as float32: ``(H, W)`` for one channel, ``(H, W, 3)`` (R, G, B) for colour."""
    path = Path(path)
    try:
        import OpenEXR
    except ImportError:
        raise InputError(path, "reading EXR needs the OpenEXR package (pip install OpenEXR)") from None
    try:
        with OpenEXR.File(str(path), separate_channels=True) as f:
            ch = {k: np.asarray(v.pixels, dtype=np.float32) for k, v in f.channels().items()}
    except Exception as e:  # OpenEXR raises plain exceptions
        raise InputError(path, f"not a readable EXR image ({e})") from None
    if not ch:
        raise InputError(path, "holds no channels")
    if all(k in ch for k in "RGB"):
        return np.stack([ch["R"], ch["G"], ch["B"]], axis=-1)
    for k in ("Y", "R", "G", "Z"):
        if k in ch:
            return ch[k]
    return next(iter(ch.values()))


def irs_pairs(root: str | Path) -> list[tuple[Path, Path]]:
    """``[(d_<n>.exr, n_<n>.exr), ...]`` under an IRS folder, sorted by path."""
    root = Path(root)
    if not root.is_dir():
        raise InputError(root, "IRS folder not found")
    out = []
    for d in sorted(root.rglob("d_*.exr")):
        n = d.with_name("n_" + d.name[2:])
        if n.is_file():
            out.append((d, n))
    if not out:
        raise InputError(root, "no IRS pairs found (expected <category>/<scene>/d_<n>.exr with n_<n>.exr beside it)")
    return out


def _crop_resize(img: np.ndarray, size: int) -> np.ndarray:
    """Centre square crop, then nearest-neighbour resize to ``size x size`` (pixel centres)."""
    H, W = img.shape[:2]
    s = min(H, W)
    r0, c0 = (H - s) // 2, (W - s) // 2
    idx = np.floor((np.arange(size) + 0.5) * s / size).astype(int)
    return img[r0 + idx[:, None], c0 + idx[None, :]]


def _depth_normals(depth: np.ndarray, f: float) -> tuple[np.ndarray, np.ndarray]:
    """Normals (optical frame, facing the camera) of a z-depth map with focal ``f`` [px] and the valid mask."""
    H, W = depth.shape
    u = np.arange(W) - (W - 1) / 2
    v = np.arange(H) - (H - 1) / 2
    P = np.stack([u[None, :] / f * depth, v[:, None] / f * depth, depth], axis=-1)
    n = np.cross(P[1:-1, 2:] - P[1:-1, :-2], P[2:, 1:-1] - P[:-2, 1:-1])
    norm = np.linalg.norm(n, axis=-1, keepdims=True)
    ok = (norm[..., 0] > 0) & (depth[1:-1, 1:-1] > 0) & (depth[1:-1, 2:] > 0) & (depth[1:-1, :-2] > 0) \
        & (depth[2:, 1:-1] > 0) & (depth[:-2, 1:-1] > 0)
    n = np.where(norm > 0, n / np.maximum(norm, 1e-12), 0.0)
    flip = np.sum(n * P[1:-1, 1:-1], axis=-1) > 0
    n[flip] *= -1
    return n, ok


#: the 48 signed axis permutations (3 x 3 matrices with one +-1 per row and column)
_SIGNED_PERMS = [np.diag(s) @ np.eye(3)[list(pm)] for pm in itertools.permutations(range(3))
                 for s in itertools.product((1.0, -1.0), repeat=3)]


def resolve_normal_axes(depth: np.ndarray, normals: np.ndarray, f: float) -> np.ndarray:
    """The signed permutation ``A`` (3 x 3) for which ``normals @ A.T`` (then turned to face the
    camera) agrees best with the normals of ``depth``: IRS's normal-map axes in the optical frame."""
    ref, ok = _depth_normals(depth, f)
    g = normals[1:-1, 1:-1][ok]
    r = ref[ok]
    if len(r) < 10:
        raise InputError("normals", "too few valid pixels to resolve the normal-map axes")
    rays = np.stack(np.meshgrid(np.arange(depth.shape[1]) - (depth.shape[1] - 1) / 2,
                                np.arange(depth.shape[0]) - (depth.shape[0] - 1) / 2), axis=-1)
    rays = np.concatenate([rays / f, np.ones((*depth.shape, 1))], axis=-1)[1:-1, 1:-1][ok]
    best, score = None, -np.inf
    for A in _SIGNED_PERMS:
        m = g @ A.T
        m = np.where((np.sum(m * rays, axis=-1) > 0)[:, None], -m, m)
        s = float(np.median(np.sum(m * r, axis=-1)))
        if s > score:
            best, score = A, s
    return best


def read_irs(root: str | Path, size: int = 128, limit: int | None = None
             ) -> Iterator[tuple[np.ndarray, np.ndarray, Path]]:
    """Iterate over IRS pairs as ``(depth (size, size) float32 m, normals (size, size, 3) float32, d-file)``.

    Normals are in the optical frame (x right, y down, z forward), unit, facing the camera,
    0 where the depth is invalid; see the module notes for the conversions.
    """
    if size < 1:
        raise InputError("size", f"must be positive, got {size}")
    axes: dict[Path, np.ndarray] = {}
    for k, (dfile, nfile) in enumerate(irs_pairs(root)):
        if limit is not None and k >= limit:
            return
        disp = read_exr(dfile)
        nmap = read_exr(nfile)
        if disp.ndim == 3:
            disp = disp[..., 0]
        if nmap.ndim != 3 or nmap.shape[:2] != disp.shape:
            raise InputError(nfile, f"expected a 3-channel normal map of {disp.shape}, got {nmap.shape}")
        f = IRS_FOCAL_PX * disp.shape[1] / IRS_WIDTH_PX
        with np.errstate(divide="ignore", invalid="ignore"):
            depth = np.where(disp > 0, f * IRS_BASELINE_M / disp, 0.0)
        depth = np.where(np.isfinite(depth), depth, 0.0)
        if dfile.parent not in axes:
            axes[dfile.parent] = resolve_normal_axes(depth, nmap, f)
        depth_s = _crop_resize(depth, size).astype(np.float32)
        n = _crop_resize(nmap, size).astype(np.float64) @ axes[dfile.parent].T
        fs = f * size / min(disp.shape)
        u = (np.arange(size) - (size - 1) / 2) / fs
        rays = np.concatenate([np.stack(np.meshgrid(u, u), axis=-1), np.ones((size, size, 1))], axis=-1)
        n = np.where((np.sum(n * rays, axis=-1) > 0)[..., None], -n, n)
        norm = np.linalg.norm(n, axis=-1, keepdims=True)
        n = np.where((norm > 1e-6) & (depth_s[..., None] > 0), n / np.maximum(norm, 1e-6), 0.0)
        yield depth_s, n.astype(np.float32), dfile


def import_irs(root: str | Path, out: str | Path, size: int = 128, limit: int | None = None,
               chunk: int = 512, progress: bool = True) -> dict[str, Any]:
    """Convert an IRS folder into ``out/pairs`` (the pre-training layout), atomically.

    Returns the ``pairs/meta.json`` body (``source: IRS``, ``count``...).
    """
    import json
    import tempfile


    out = Path(out)
    total = len(irs_pairs(root)) if limit is None else min(limit, len(irs_pairs(root)))
    out.mkdir(parents=True, exist_ok=True)
    bar = progress_bar(total, "import IRS", "pairs") if progress else None
    with tempfile.TemporaryDirectory(prefix=".irs-chunks.", dir=out) as tmp:
        files, D, N = [], [], []

        def flush():
            k = len(files)
            dp, np_ = Path(tmp) / f"d{k:05d}.npy", Path(tmp) / f"n{k:05d}.npy"
            np.save(dp, np.stack(D))
            np.save(np_, np.stack(N))
            files.append((dp, np_))
            if bar is not None:
                bar.update(len(D))
            D.clear()
            N.clear()

        for depth, normals, _ in read_irs(root, size, limit):
            D.append(depth)
            N.append(normals)
            if len(D) == chunk:
                flush()
        if D:
            flush()
        if bar is not None:
            bar.close()
        shards.write_pairs_chunks(out, files, {"source": "IRS", "irs_root": str(Path(root).resolve()),
                                               "focal_px_at_960": IRS_FOCAL_PX, "baseline_m": IRS_BASELINE_M})
    return json.loads((out / shards.PAIRS_DIR / shards.META).read_text())

