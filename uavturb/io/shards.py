"""Simulator shards: the on-disk dataset the height model trains on (the writer/reader contract).

Layout of a dataset folder ``ROOT``::

    ROOT/manifest.json                  # splits, counts, image size, generator config + hash, version
                                        # (+ any extra keys of update_manifest)
    ROOT/<trajectory>/meta.json         # one folder per trajectory (any name, e.g. traj_00000)
    ROOT/<trajectory>/<array>.npy       # one plain .npy file per array (np.load(mmap_mode="r"))

Arrays of a trajectory of ``T`` frames (``N`` rotors, images ``H x W`` pixels); the writer casts
to the dtype given here, the reader checks it (:data:`ARRAYS`, :data:`OPTIONAL_ARRAYS`):

==============  ===========  ============  ===================================================
name            dtype        shape         meaning
==============  ===========  ============  ===================================================
depth           float32      (T, H, W)     z-depth [m] in the camera's optical frame (x right,
                                           y down, z forward); 0 where nothing is hit
rotor_speeds    float32      (T, N)        rotor speeds Omega_i [rad/s]
state           float64      (T, 13)       p (3, world, m), q (4: w, x, y, z, body to world),
                                           v (3, world, m/s), omega (3, body, rad/s)
d               float32      (T,)          height of the body origin over the surface below [m]
fa              float32      (T,)          ground-effect force along world +z [N]:
                                           phi(d, k_T sum Omega^2, mu, r)
                                           (:func:`uavturb.physics.ground_effect.phi`)
t               float64      (T,)          time [s], increasing
normals         float32      (T, H, W, 3)  optional: unit surface normals in the optical frame,
                                           towards the camera; 0 where nothing is hit
==============  ===========  ============  ===================================================

``meta.json`` holds the writer's metadata (required keys :data:`REQUIRED_META`: ``scene_id``,
``split`` (one of :data:`SPLITS`), ``trajectory_id``, ``vehicle``, ``k_T`` [N/(rad/s)^2], ``mu``
[-], ``rotor_radius`` [m]; any other JSON value is kept) plus what the writer adds:
``version``, ``frames``, ``image_size`` ``[H, W]``, ``n_rotors`` and ``arrays``
(``{name: {"dtype", "shape"}}``).

Writing is atomic: :func:`write_trajectory` writes into a hidden temporary folder next to the
target and renames it when complete, so a reader never sees half a trajectory;
:func:`write_manifest` writes ``manifest.json`` through a temporary file. Splits are by
**scene**: a scene in two splits is an error.

Pre-training pairs (:func:`write_pairs`, :func:`read_pairs`) live in ``ROOT/pairs/``:
``depth.npy`` float32 ``(M, H, W)``, ``normals.npy`` float32 ``(M, H, W, 3)`` (same frames
and conventions as above) and ``meta.json`` (``count``, ``image_size``, ``version`` ...).

Synthetic data with known answers (analytic scenes seen by a pinhole camera) come from
:mod:`uavturb.data.synthetic`.
"""

from __future__ import annotations

import hashlib
import json
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from uavturb.errors import InputError
from uavturb.io.publish import atomic_folder, write_text_atomic

VERSION = 1
MANIFEST = "manifest.json"
META = "meta.json"
PAIRS_DIR = "pairs"
SPLITS = ("train", "val", "test")
STATE_DIM = 13

#: required arrays: name -> (dtype, shape with symbolic dimensions)
ARRAYS: dict[str, tuple[np.dtype, tuple[str, ...]]] = {
    "depth": (np.dtype(np.float32), ("T", "H", "W")),
    "rotor_speeds": (np.dtype(np.float32), ("T", "N")),
    "state": (np.dtype(np.float64), ("T", "13")),
    "d": (np.dtype(np.float32), ("T",)),
    "fa": (np.dtype(np.float32), ("T",)),
    "t": (np.dtype(np.float64), ("T",)),
}
#: optional arrays: name -> (dtype, shape)
OPTIONAL_ARRAYS: dict[str, tuple[np.dtype, tuple[str, ...]]] = {
    "normals": (np.dtype(np.float32), ("T", "H", "W", "3")),
}
#: keys every trajectory's metadata must hold
REQUIRED_META = ("scene_id", "split", "trajectory_id", "vehicle", "k_T", "mu", "rotor_radius")
#: keys of manifest.json written by :func:`write_manifest`
MANIFEST_KEYS = ("version", "splits", "counts", "image_size", "config", "config_hash")
#: keys the writer adds to meta.json (a caller may not set them)
WRITER_META = ("version", "frames", "image_size", "n_rotors", "arrays")


# ----------------------------------------------------------------------------------------------
# small helpers


def _json_default(x: Any) -> Any:
    if isinstance(x, np.generic):
        return x.item()
    if isinstance(x, np.ndarray):
        return x.tolist()
    if isinstance(x, Path):
        return str(x)
    raise TypeError(f"{type(x).__name__} is not JSON serialisable")


def _dumps(obj: Any) -> str:
    return json.dumps(obj, indent=1, sort_keys=True, default=_json_default)


def _read_json(path: Path) -> dict[str, Any]:
    if not path.is_file():
        raise InputError(path, "file not found")
    try:
        body = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as e:
        raise InputError(path, f"not valid JSON ({e})") from None
    if not isinstance(body, dict):
        raise InputError(path, "expected a JSON object")
    return body


def config_hash(config: Any) -> str:
    """Short SHA-256 of a JSON-serialisable config (key order does not matter)."""
    return hashlib.sha256(json.dumps(config, sort_keys=True, default=_json_default).encode()).hexdigest()[:16]


# ----------------------------------------------------------------------------------------------
# trajectories


@dataclass
class Trajectory:
    """One trajectory as read back; arrays are read-only memory maps unless ``mmap=False``.

    Attributes are the arrays of :data:`ARRAYS` (``normals`` is None when absent), ``meta``
    (the parsed ``meta.json``) and ``folder``.
    """

    folder: Path
    meta: dict[str, Any]
    depth: np.ndarray
    rotor_speeds: np.ndarray
    state: np.ndarray
    d: np.ndarray
    fa: np.ndarray
    t: np.ndarray
    normals: np.ndarray | None = None

    def __len__(self) -> int:
        return int(self.meta["frames"])

    @property
    def sum_omega2(self) -> np.ndarray:
        """(T,) ``sum_i Omega_i^2`` [rad^2/s^2], float64."""
        return (np.asarray(self.rotor_speeds, dtype=np.float64) ** 2).sum(axis=1)


def _check_arrays(arrays: dict[str, Any], where: Path) -> dict[str, np.ndarray]:
    """Cast to the contract's dtypes and check names, shapes, frame counts and finiteness."""
    unknown = sorted(set(arrays) - set(ARRAYS) - set(OPTIONAL_ARRAYS))
    if unknown:
        raise InputError(where, f"unknown array {unknown[0]!r}; allowed: "
                         f"{', '.join([*ARRAYS, *OPTIONAL_ARRAYS])}")
    missing = [n for n in ARRAYS if n not in arrays]
    if missing:
        raise InputError(where, f"missing array {missing[0]!r} (required: {', '.join(ARRAYS)})")
    out: dict[str, np.ndarray] = {}
    for name, value in arrays.items():
        if value is None and name in OPTIONAL_ARRAYS:
            continue
        dtype, shape = {**ARRAYS, **OPTIONAL_ARRAYS}[name]
        try:
            a = np.ascontiguousarray(np.asarray(value), dtype=dtype)
        except (TypeError, ValueError):
            raise InputError(where, f"array {name!r} is not numeric") from None
        if a.ndim != len(shape) or any(s.isdigit() and int(s) != n for s, n in zip(shape, a.shape)):
            raise InputError(where, f"array {name!r} has shape {a.shape}, expected ({', '.join(shape)})")
        if not np.isfinite(a).all():
            raise InputError(where, f"array {name!r} holds non-finite values")
        out[name] = a
    T = out["depth"].shape[0]
    H, W = out["depth"].shape[1:]
    N = out["rotor_speeds"].shape[1]
    for name, a in out.items():
        if a.shape[0] != T:
            raise InputError(where, f"array {name!r} has {a.shape[0]} frames, depth has {T}")
    if "normals" in out and out["normals"].shape[1:3] != (H, W):
        raise InputError(where, f"array 'normals' is {out['normals'].shape[1:3]} px, depth is {(H, W)}")
    if T < 1 or H < 1 or W < 1 or N < 1:
        raise InputError(where, f"empty arrays (T={T}, H={H}, W={W}, N={N})")
    if (out["depth"] < 0).any():
        raise InputError(where, "array 'depth' holds negative depths")
    if T > 1 and not (np.diff(out["t"]) > 0).all():
        raise InputError(where, "array 't' is not increasing")
    return out


def _check_meta(meta: dict[str, Any], where: Path) -> dict[str, Any]:
    if not isinstance(meta, dict):
        raise InputError(where, "meta must be a mapping")
    for key in REQUIRED_META:
        if key not in meta:
            raise InputError(where, f"meta lacks key {key!r} (required: {', '.join(REQUIRED_META)})")
    taken = [k for k in WRITER_META if k in meta]
    if taken:
        raise InputError(where, f"meta key {taken[0]!r} is set by the writer")
    if meta["split"] not in SPLITS:
        raise InputError(where, f"meta split {meta['split']!r} is not one of {', '.join(SPLITS)}")
    for key in ("k_T", "mu", "rotor_radius"):
        try:
            ok = float(meta[key]) > 0
        except (TypeError, ValueError):
            ok = False
        if not ok:
            raise InputError(where, f"meta {key} must be a positive number, got {meta[key]!r}")
    try:
        return json.loads(_dumps(meta))
    except TypeError as e:
        raise InputError(where, f"meta is not JSON serialisable: {e}") from None


def write_trajectory(folder: str | Path, arrays: dict[str, Any], meta: dict[str, Any],
                     overwrite: bool = False, extra_arrays: dict[str, np.ndarray] | None = None) -> Path:
    """Write one trajectory atomically.

    Parameters
    ----------
    folder : the trajectory's folder (created; its parent too).
    arrays : ``{name: array}`` with the names, shapes and units of :data:`ARRAYS` (all
        required) and :data:`OPTIONAL_ARRAYS`; values are cast to the contract's dtypes.
    meta : JSON-serialisable metadata with at least :data:`REQUIRED_META`.
    overwrite : replace an existing trajectory (the old one stays whole until the new one
        is complete).
    extra_arrays : arrays outside the contract (``rgb``), written as they are in the same
        atomic step and listed in ``meta["extra_arrays"]``.

    Returns
    -------
    The folder (Path).

    Raises
    ------
    InputError : bad arrays or metadata (nothing is written), or the folder exists and
        ``overwrite`` is false.
    """
    folder = Path(folder)
    if folder.exists() and not overwrite:
        raise InputError(folder, "already exists (pass overwrite=True to replace it)")
    arrs = _check_arrays(arrays, folder)
    meta = _check_meta(meta, folder)
    T, H, W = arrs["depth"].shape
    meta.update(version=VERSION, frames=int(T), image_size=[int(H), int(W)],
                n_rotors=int(arrs["rotor_speeds"].shape[1]),
                arrays={n: {"dtype": str(a.dtype), "shape": list(a.shape)} for n, a in arrs.items()})
    extra = {n: np.ascontiguousarray(a) for n, a in (extra_arrays or {}).items()}
    if extra:
        meta["extra_arrays"] = {n: {"dtype": str(a.dtype), "shape": list(a.shape)} for n, a in extra.items()}
    with atomic_folder(folder) as tmp:
        for name, a in {**arrs, **extra}.items():
            np.save(tmp / f"{name}.npy", a)
        (tmp / META).write_text(_dumps(meta))
    return folder


def _load(path: Path, mmap: bool) -> np.ndarray:
    if not path.is_file():
        raise InputError(path, "file not found")
    try:
        return np.load(path, mmap_mode="r" if mmap else None, allow_pickle=False)
    except (OSError, ValueError) as e:
        raise InputError(path, f"not a readable .npy array ({e})") from None


def read_meta(folder: str | Path) -> dict[str, Any]:
    """The ``meta.json`` of a trajectory folder (no arrays are opened)."""
    path = Path(folder) / META
    meta = _read_json(path)
    for key in (*REQUIRED_META, *WRITER_META):
        if key not in meta:
            raise InputError(path, f"lacks key {key!r}")
    if meta["version"] != VERSION:
        raise InputError(path, f"version {meta['version']!r} is not supported (this reader: {VERSION})")
    return meta


def read_trajectory(folder: str | Path, mmap: bool = True) -> Trajectory:
    """Read a trajectory written by :func:`write_trajectory`.

    Parameters
    ----------
    folder : the trajectory's folder.
    mmap : memory-map the arrays read-only (``np.memmap``) instead of loading them.

    Raises
    ------
    InputError : naming the file that is missing or does not match ``meta.json``.
    """
    folder = Path(folder)
    meta = read_meta(folder)
    out: dict[str, Any] = {}
    for name, (dtype, _) in {**ARRAYS, **OPTIONAL_ARRAYS}.items():
        path = folder / f"{name}.npy"
        declared = meta["arrays"].get(name)
        if declared is None:
            if name in ARRAYS:
                raise InputError(path, "required array not listed in meta.json")
            out[name] = None
            continue
        a = _load(path, mmap)
        if a.dtype != dtype or list(a.shape) != list(declared["shape"]):
            raise InputError(path, f"holds {a.dtype} {a.shape}, meta.json says {declared['dtype']} "
                             f"{tuple(declared['shape'])} and the contract {dtype}")
        out[name] = a
    return Trajectory(folder=folder, meta=meta, **out)


# ----------------------------------------------------------------------------------------------
# manifest


@dataclass
class Manifest:
    """A dataset's ``manifest.json`` (see :func:`write_manifest`)."""

    root: Path
    splits: dict[str, list[str]]
    counts: dict[str, dict[str, int]]
    image_size: tuple[int, int]
    config: dict[str, Any] = field(default_factory=dict)
    config_hash: str = ""
    version: int = VERSION
    extra: dict[str, Any] = field(default_factory=dict)  # other keys (:func:`update_manifest`)

    def folders(self, split: str) -> list[Path]:
        """Trajectory folders of a split, in manifest order."""
        if split not in self.splits:
            raise InputError(self.root / MANIFEST, f"no split {split!r}")
        return [self.root / name for name in self.splits[split]]


def write_manifest(root: str | Path, splits: dict[str, list[str]], config: dict[str, Any] | None = None) -> Manifest:
    """Write ``ROOT/manifest.json`` for trajectories already written under ``root``.

    Parameters
    ----------
    root : the dataset folder.
    splits : ``{"train": [folder names], "val": [...], "test": [...]}`` (names relative to
        ``root``); a scene may appear in one split only.
    config : the generator's config (JSON), stored with its :func:`config_hash`.

    Returns
    -------
    The :class:`Manifest` as written.

    Raises
    ------
    InputError : unknown or missing split, missing trajectory, a scene in two splits, a
        trajectory whose ``meta.json`` names another split, image sizes that differ.
    """
    root = Path(root)
    config = dict(config or {})
    where = root / MANIFEST
    if not isinstance(splits, dict) or set(splits) != set(SPLITS):
        raise InputError(where, f"splits must have exactly the keys {', '.join(SPLITS)}")
    metas: dict[str, dict[str, dict[str, Any]]] = {}
    scene_split: dict[str, str] = {}
    for split in SPLITS:
        metas[split] = {}
        for name in splits[split]:
            meta = read_meta(root / name)
            metas[split][name] = meta
            scene = str(meta["scene_id"])
            if scene_split.setdefault(scene, split) != split:
                raise InputError(where, f"scene {scene!r} is in splits {scene_split[scene]} and {split} "
                                 "(splits are by scene, never by sample)")
    sizes = set()
    counts: dict[str, dict[str, int]] = {}
    for split in SPLITS:
        for name, meta in metas[split].items():
            if meta["split"] != split:
                raise InputError(root / name / META, f"says split {meta['split']!r}, the manifest lists it "
                                 f"under {split!r}")
            sizes.add(tuple(meta["image_size"]))
        counts[split] = {"trajectories": len(metas[split]),
                         "frames": int(sum(m["frames"] for m in metas[split].values())),
                         "scenes": len({str(m["scene_id"]) for m in metas[split].values()})}
    if len(sizes) > 1:
        raise InputError(where, f"trajectories have different image sizes: {sorted(sizes)}")
    if not sizes:
        raise InputError(where, "no trajectories")
    image_size = tuple(int(x) for x in sizes.pop())
    body = {"version": VERSION, "splits": {s: list(splits[s]) for s in SPLITS}, "counts": counts,
            "image_size": list(image_size), "config": config, "config_hash": config_hash(config)}
    write_text_atomic(where, _dumps(body))
    return Manifest(root=root, splits=body["splits"], counts=counts, image_size=image_size,  # type: ignore[arg-type]
                    config=config, config_hash=body["config_hash"])


def read_manifest(root: str | Path) -> Manifest:
    """Read and check ``ROOT/manifest.json``; errors name the file and the key."""
    root = Path(root)
    path = root / MANIFEST
    body = _read_json(path)
    for key in MANIFEST_KEYS:
        if key not in body:
            raise InputError(path, f"lacks key {key!r}")
    if body["version"] != VERSION:
        raise InputError(path, f"version {body['version']!r} is not supported (this reader: {VERSION})")
    splits = body["splits"]
    if (not isinstance(splits, dict) or set(splits) != set(SPLITS)
            or not all(isinstance(v, list) and all(isinstance(n, str) for n in v) for v in splits.values())):
        raise InputError(path, f"splits must map exactly {', '.join(SPLITS)} to lists of folder names")
    counts = body["counts"]
    if not isinstance(counts, dict) or set(counts) != set(SPLITS):
        raise InputError(path, f"counts must have exactly the keys {', '.join(SPLITS)}")
    size = body["image_size"]
    if not (isinstance(size, list) and len(size) == 2 and all(isinstance(x, int) and x > 0 for x in size)):
        raise InputError(path, f"image_size must be [H, W] in pixels, got {size!r}")
    if not isinstance(body["config"], dict):
        raise InputError(path, "config must be a mapping")
    extra = {k: v for k, v in body.items() if k not in MANIFEST_KEYS}
    return Manifest(root=root, splits=splits, counts=counts, image_size=(size[0], size[1]), config=body["config"],
                    config_hash=str(body["config_hash"]), version=body["version"], extra=extra)


def check_manifest_replaceable(root: str | Path) -> None:
    """``ROOT/manifest.json`` may be rewritten: it is absent or a dataset manifest uavturb wrote.

    Raises
    ------
    InputError : it is something else (a user's file, a link): it is never replaced.
    """
    path = Path(root) / MANIFEST
    if not os.path.lexists(path):
        return
    try:
        if path.is_symlink():
            raise InputError(path, "is a link")
        read_manifest(root)
    except InputError as e:
        raise InputError(path, f"is not a dataset manifest uavturb wrote ({e.problem}); it is not replaced: "
                               "choose another --out or move it away") from None


def update_manifest(root: str | Path, **fields: Any) -> Manifest:
    """Add or replace extra top-level keys of ``ROOT/manifest.json`` (atomically).

    The keys :func:`write_manifest` owns (:data:`MANIFEST_KEYS`) cannot be changed this way.
    """
    root = Path(root)
    read_manifest(root)  # checks it
    taken = sorted(set(fields) & set(MANIFEST_KEYS))
    if taken:
        raise InputError(root / MANIFEST, f"key {taken[0]!r} is written by write_manifest only")
    body = {**_read_json(root / MANIFEST), **fields}
    write_text_atomic(root / MANIFEST, _dumps(body))
    return read_manifest(root)


def dataset_hash(root: str | Path) -> str:
    """Content hash of a dataset folder (shards or pairs): every ``.json`` and ``.npy`` under it.

    Hidden entries (temporary folders of an interrupted writer) are left out.
    """
    root = Path(root)
    if not root.is_dir():
        raise InputError(root, "dataset folder not found")
    files = [p for p in root.rglob("*") if p.is_file() and p.suffix in (".json", ".npy")
             and not any(part.startswith(".") for part in p.relative_to(root).parts)]
    if not files:
        raise InputError(root, "holds no dataset files (.json, .npy)")
    h = hashlib.sha256()
    for p in sorted(files):
        h.update(str(p.relative_to(root)).encode())
        h.update(files_hash([p]).encode())
    return h.hexdigest()[:16]


# ----------------------------------------------------------------------------------------------
# pre-training pairs


def pairs_folder(root: str | Path) -> Path:
    """``ROOT/pairs`` when it exists, else ``ROOT`` itself (either may be given)."""
    root = Path(root)
    return root / PAIRS_DIR if (root / PAIRS_DIR).is_dir() else root


def write_pairs(root: str | Path, depth: np.ndarray, normals: np.ndarray, meta: dict[str, Any] | None = None,
                overwrite: bool = False) -> Path:
    """Write pre-training pairs atomically to ``ROOT/pairs``.

    Parameters
    ----------
    depth : (M, H, W) z-depth [m], 0 where nothing is hit.
    normals : (M, H, W, 3) unit normals in the optical frame, towards the camera.
    meta : extra JSON metadata (``count``, ``image_size``, ``version`` are added).
    """
    folder = Path(root) / PAIRS_DIR
    if folder.exists() and not overwrite:
        raise InputError(folder, "already exists (pass overwrite=True to replace it)")
    depth = np.ascontiguousarray(depth, dtype=np.float32)
    normals = np.ascontiguousarray(normals, dtype=np.float32)
    if depth.ndim != 3 or normals.shape != (*depth.shape, 3):
        raise InputError(folder, f"need depth (M, H, W) and normals (M, H, W, 3), got {depth.shape}, {normals.shape}")
    if not (np.isfinite(depth).all() and np.isfinite(normals).all()):
        raise InputError(folder, "non-finite values")
    body = {**(meta or {}), "count": int(depth.shape[0]), "image_size": list(depth.shape[1:]), "version": VERSION}
    with atomic_folder(folder) as tmp:
        np.save(tmp / "depth.npy", depth)
        np.save(tmp / "normals.npy", normals)
        (tmp / META).write_text(_dumps(body))
    return folder


def read_pairs(root: str | Path, mmap: bool = True) -> tuple[np.ndarray, np.ndarray, dict[str, Any]]:
    """``(depth (M, H, W), normals (M, H, W, 3), meta)`` of ``ROOT/pairs`` (or of that folder)."""
    folder = pairs_folder(root)
    meta = _read_json(folder / META)
    for key in ("count", "image_size", "version"):
        if key not in meta:
            raise InputError(folder / META, f"lacks key {key!r}")
    depth = _load(folder / "depth.npy", mmap)
    normals = _load(folder / "normals.npy", mmap)
    M = int(meta["count"])
    if depth.dtype != np.float32 or depth.shape != (M, *meta["image_size"]):
        raise InputError(folder / "depth.npy", f"holds {depth.dtype} {depth.shape}, expected float32 "
                         f"({M}, {meta['image_size'][0]}, {meta['image_size'][1]})")
    if normals.dtype != np.float32 or normals.shape != (*depth.shape, 3):
        raise InputError(folder / "normals.npy", f"holds {normals.dtype} {normals.shape}, expected float32 "
                         f"{(*depth.shape, 3)}")
    return depth, normals, meta


# ----------------------------------------------------------------------------------------------
# additions for the simulator's writers (uavturb.sim.dataset.generation, uavturb.sim.dataset.pretraining_pairs);
# update_manifest (above) serves them too


def write_pairs_chunks(root: str | Path, chunks: list[tuple[str | Path, str | Path]],
                       meta: dict[str, Any] | None = None, overwrite: bool = False) -> Path:
    """Write ``ROOT/pairs`` (the layout of :func:`write_pairs`) from chunk files, atomically,
    without holding the whole set in memory.

    Parameters
    ----------
    chunks : ``[(depth_k.npy, normals_k.npy), ...]``: float32 ``(M_k, H, W)`` and ``(M_k, H, W, 3)``
        arrays, concatenated in this order.
    meta : extra JSON metadata (``count``, ``image_size``, ``version`` are added).
    """
    folder = Path(root) / PAIRS_DIR
    if folder.exists() and not overwrite:
        raise InputError(folder, "already exists (pass overwrite=True to replace it)")
    if not chunks:
        raise InputError(folder, "no chunks to write")
    depths = [_load(Path(dp), True) for dp, _ in chunks]
    normals = [_load(Path(np_), True) for _, np_ in chunks]
    size = depths[0].shape[1:]
    for (dp, np_), dd, nn in zip(chunks, depths, normals):
        if dd.ndim != 3 or dd.shape[1:] != size or nn.shape != (*dd.shape, 3):
            raise InputError(dp, f"chunk shapes {dd.shape}, {nn.shape} do not match (M, {size[0]}, {size[1]}) "
                             "and (M, H, W, 3)")
    M = int(sum(len(dd) for dd in depths))
    body = {**(meta or {}), "count": M, "image_size": [int(s) for s in size], "version": VERSION}
    with atomic_folder(folder) as tmp:
        for name, parts, tail in (("depth", depths, ()), ("normals", normals, (3,))):
            dst = np.lib.format.open_memmap(tmp / f"{name}.npy", mode="w+", dtype=np.float32, shape=(M, *size, *tail))
            i = 0
            for a in parts:
                if not np.isfinite(a).all():
                    raise InputError(folder, f"non-finite values in a {name} chunk")
                dst[i:i + len(a)] = a
                i += len(a)
            dst.flush()
            del dst
        (tmp / META).write_text(_dumps(body))
    return folder


def files_hash(paths: list[Path]) -> str:
    """SHA-256 over the bytes of files (sorted by path): the data hash of a run."""
    h = hashlib.sha256()
    for p in sorted(Path(x) for x in paths):
        h.update(str(p.name).encode())
        with open(p, "rb") as f:
            for chunk in iter(lambda: f.read(1 << 20), b""):
                h.update(chunk)
    return h.hexdigest()[:16]

