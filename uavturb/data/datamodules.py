"""Lightning DataModules over the on-disk datasets of :mod:`uavturb.io.shards`.

- :class:`ShardWindowsDataModule`: windows of ``H`` consecutive frames of simulator shards,
  splits from the manifest (by scene). A sample is a dict of tensors::

      depth       (H, 1, h, w) float32   z-depth [m]
      d           (H,)         float32   height over the surface below [m]
      fa          (H,)         float32   ground-effect force [N]
      sum_omega2  (H,)         float32   sum_i Omega_i^2 [rad^2/s^2]

- :class:`PairsDataModule`: pre-training pairs ``{"depth": (1, h, w), "target": (C, h, w)}``
  with ``C = 3`` (normals) or ``1`` (depth itself).

The datasets memory-map their arrays lazily, **once per process** (the first ``__getitem__``
in each DataLoader worker), never per sample; they pickle as paths and indices only, so
spawning workers is cheap.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import lightning as L
import numpy as np
import torch
from torch.utils.data import DataLoader, Dataset, Subset

from uavturb.errors import InputError
from uavturb.io import shards
from uavturb.scene.camera import FORWARD, CameraModel, named_camera


class ShardWindowsDataset(Dataset):
    """Windows of ``window`` consecutive frames over trajectory folders.

    Parameters
    ----------
    folders : trajectory folders (:func:`uavturb.io.shards.write_trajectory`).
    window : frames per sample (H).
    stride : frames between the starts of consecutive windows of a trajectory.

    Attributes
    ----------
    index : list of ``(trajectory number, first frame)``.
    """

    def __init__(self, folders: list[str | Path], window: int = 8, stride: int = 1):
        if window < 1 or stride < 1:
            raise InputError("data.window/stride", f"must be positive, got {window}, {stride}")
        self.folders = [str(f) for f in folders]
        self.window, self.stride = int(window), int(stride)
        self.frames = [int(shards.read_meta(f)["frames"]) for f in self.folders]
        self.index: list[tuple[int, int]] = [(k, s) for k, n in enumerate(self.frames)
                                             for s in range(0, n - self.window + 1, self.stride)]
        self._trajs: list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]] | None = None

    def __getstate__(self) -> dict[str, Any]:
        state = self.__dict__.copy()
        state["_trajs"] = None  # memory maps are reopened in the receiving process
        return state

    def _open(self) -> list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]]:
        # depth stays a memory map (one file descriptor per trajectory); the per-frame
        # scalars are tiny and read into memory
        trajs = []
        for f in self.folders:
            tr = shards.read_trajectory(f, mmap=True)
            trajs.append((tr.depth, np.array(tr.d, np.float32), np.array(tr.fa, np.float32),
                          tr.sum_omega2.astype(np.float32)))
        return trajs

    def __len__(self) -> int:
        return len(self.index)

    def __getitem__(self, i: int) -> dict[str, torch.Tensor]:
        if self._trajs is None:
            self._trajs = self._open()
        k, s = self.index[i]
        depth, d, fa, s2 = self._trajs[k]
        e = s + self.window
        return {"depth": torch.from_numpy(np.array(depth[s:e], dtype=np.float32)).unsqueeze(1),
                "d": torch.from_numpy(d[s:e].copy()),
                "fa": torch.from_numpy(fa[s:e].copy()),
                "sum_omega2": torch.from_numpy(s2[s:e].copy())}


def _loader(ds: Dataset, batch_size: int, num_workers: int, shuffle: bool, seed: int = 0,
            pin_memory: bool | None = None) -> DataLoader:
    """A DataLoader whose workers live as long as it (one memory map per worker and dataset, opened once);
    ``pin_memory`` None: pinned when torch sees a CUDA device."""
    g = torch.Generator()
    g.manual_seed(seed)
    pin = torch.cuda.is_available() if pin_memory is None else bool(pin_memory)
    return DataLoader(ds, batch_size=batch_size, shuffle=shuffle, num_workers=num_workers,
                      persistent_workers=num_workers > 0, pin_memory=pin,
                      generator=g if shuffle else None, drop_last=False)


class ShardWindowsDataModule(L.LightningDataModule):
    """Simulator shards as windows of ``window`` frames, with the manifest's scene-level splits.

    Parameters
    ----------
    root : dataset folder (holds ``manifest.json``).
    window : frames per sample (H, the GRU's memory).
    stride : frames between training windows.
    eval_stride : frames between validation/test windows.
    batch_size, num_workers : DataLoader settings.
    image_size : expected image side [px]; 0 = whatever the data holds.
    seed : shuffling seed.
    pin_memory : DataLoader pinned memory (for copies to a GPU); None: when torch sees a CUDA device.
    """

    def __init__(self, root: str = "data/sim", window: int = 8, stride: int = 1, eval_stride: int = 1,
                 batch_size: int = 16, num_workers: int = 2, image_size: int = 0, seed: int = 0,
                 pin_memory: bool | None = None):
        super().__init__()
        self.root, self.window, self.stride, self.eval_stride = str(root), window, stride, eval_stride
        self.batch_size, self.num_workers, self.image_size, self.seed = batch_size, num_workers, image_size, seed
        self.pin_memory = pin_memory
        self.manifest: shards.Manifest | None = None
        self.sets: dict[str, ShardWindowsDataset] = {}

    def setup(self, stage: str | None = None) -> None:
        if self.sets:
            return
        m = shards.read_manifest(self.root)
        if self.image_size and tuple(m.image_size) != (self.image_size, self.image_size):
            raise InputError("data.image_size", f"is {self.image_size} but {Path(self.root) / shards.MANIFEST} "
                             f"holds {m.image_size[0]}x{m.image_size[1]} images (set data.image_size="
                             f"{m.image_size[0]} or 0)")
        self.manifest = m
        for split in shards.SPLITS:
            ds = ShardWindowsDataset(m.folders(split), window=self.window,
                                     stride=self.stride if split == "train" else self.eval_stride)
            if len(ds) == 0:
                raise InputError(self.root, f"split {split!r} has no window of {self.window} frames "
                                 f"({len(ds.folders)} trajectories, frames {ds.frames}); lower data.window")
            self.sets[split] = ds

    def train_dataloader(self) -> DataLoader:
        return _loader(self.sets["train"], self.batch_size, self.num_workers, True, self.seed, self.pin_memory)

    def val_dataloader(self) -> DataLoader:
        return _loader(self.sets["val"], self.batch_size, self.num_workers, False, pin_memory=self.pin_memory)

    def test_dataloader(self) -> DataLoader:
        return _loader(self.sets["test"], self.batch_size, self.num_workers, False, pin_memory=self.pin_memory)


def ground_effect_law(root: str | Path) -> tuple[float, float] | None:
    """``(alpha, beta)`` of the law the dataset's ``f_a`` was made with [N m^2/(rad/s)^2, m^2], from its
    first training trajectory's ``meta.json`` (``k_T``, ``mu``, ``rotor_radius``: the simulator's and
    the synthetic generator's): ``beta = mu r^2 / 16``, ``alpha = k_T beta`` (the paper's identification
    form of the Cheeseman-Bennett law). ``None`` where the dataset does not say (no manifest, no
    training trajectory, no ground effect)."""
    try:
        folders = shards.read_manifest(root).folders("train")
        meta = shards.read_meta(folders[0]) if folders else {}
    except InputError:
        return None
    try:
        k_T, mu, r = (float(meta[k]) for k in ("k_T", "mu", "rotor_radius"))
    except (KeyError, TypeError, ValueError):
        return None
    if not (k_T > 0 and mu > 0 and r > 0):
        return None
    beta = mu * r * r / 16.0
    return k_T * beta, beta


def dataset_camera(root: str | Path) -> CameraModel | None:
    """The camera a shard dataset's depth images were made with (:mod:`uavturb.scene.camera`), from its
    manifest: the image size, and the generator's camera in its config (the synthetic generator's
    ``yfov_deg``, ``pitch_deg`` and ``dt`` at the top; a simulator preset's ``camera``, ``yfov_deg``,
    ``pitch_deg`` and ``camera_hz`` under ``preset``). ``None`` where the dataset does not say (no
    manifest, a config naming no camera): a model trained on it carries no camera."""
    try:
        m = shards.read_manifest(root)
    except InputError:
        return None
    found: dict[str, Any] = {}
    for conf in (m.config, m.config.get("preset") or {}):  # the preset's entries win
        for k in ("yfov_deg", "pitch_deg"):
            if k in conf:
                found[k] = float(conf[k])
        if conf.get("camera"):
            found["camera"] = str(conf["camera"])
        if conf.get("dt"):
            found["frame_dt"] = float(conf["dt"])
        if conf.get("camera_hz"):
            found["frame_dt"] = 1.0 / float(conf["camera_hz"])
    H, W = (int(x) for x in m.image_size)
    name = found.get("camera", FORWARD)
    if name == FORWARD and not {"yfov_deg", "pitch_deg"} <= set(found):
        return None
    return named_camera(name, W, H, found.get("yfov_deg", 0.0), found.get("pitch_deg", 0.0), found.get("frame_dt"))


class PairsDataset(Dataset):
    """(depth, target) pre-training pairs of a pairs folder, memory-mapped once per process.

    Parameters
    ----------
    root : ``ROOT`` (holding ``pairs/``) or the pairs folder.
    target : ``normals`` (3 channels) or ``depth`` (1 channel, the input itself).
    """

    def __init__(self, root: str | Path, target: str = "normals"):
        if target not in ("normals", "depth"):
            raise InputError("model.pretraining", f"pairs target must be normals or depth, not {target!r}")
        self.root, self.target = str(root), target
        depth, _, meta = shards.read_pairs(self.root, mmap=True)
        self.count = int(meta["count"])
        self._maps: tuple[np.ndarray, np.ndarray] | None = None

    def __getstate__(self) -> dict[str, Any]:
        state = self.__dict__.copy()
        state["_maps"] = None
        return state

    def __len__(self) -> int:
        return self.count

    def __getitem__(self, i: int) -> dict[str, torch.Tensor]:
        if self._maps is None:
            depth, normals, _ = shards.read_pairs(self.root, mmap=True)
            self._maps = (depth, normals)
        depth, normals = self._maps
        x = torch.from_numpy(np.array(depth[i], dtype=np.float32)).unsqueeze(0)
        if self.target == "depth":
            y = x.clone()
        else:
            y = torch.from_numpy(np.array(normals[i], dtype=np.float32)).permute(2, 0, 1).contiguous()
        return {"depth": x, "target": y}


class PairsDataModule(L.LightningDataModule):
    """Pre-training pairs, a seeded random ``val_fraction`` held out (also used as the test set).

    Parameters
    ----------
    root : ``ROOT`` (holding ``pairs/``) or the pairs folder.
    target : ``normals`` or ``depth``.
    batch_size, num_workers : DataLoader settings.
    val_fraction : share of pairs held out.
    seed : of the hold-out draw and of shuffling.
    pin_memory : DataLoader pinned memory (for copies to a GPU); None: when torch sees a CUDA device.
    """

    def __init__(self, root: str = "data/pairs", target: str = "normals", batch_size: int = 16,
                 num_workers: int = 2, val_fraction: float = 0.1, seed: int = 0, pin_memory: bool | None = None):
        super().__init__()
        if not 0.0 < val_fraction < 1.0:
            raise InputError("data.val_fraction", f"must be in (0, 1), got {val_fraction}")
        self.root, self.target, self.batch_size, self.num_workers = str(root), target, batch_size, num_workers
        self.val_fraction, self.seed, self.pin_memory = val_fraction, seed, pin_memory
        self.train_set: Subset | None = None
        self.val_set: Subset | None = None

    def setup(self, stage: str | None = None) -> None:
        if self.train_set is not None:
            return
        ds = PairsDataset(self.root, self.target)
        n_val = max(1, int(round(self.val_fraction * len(ds))))
        if n_val >= len(ds):
            raise InputError(self.root, f"{len(ds)} pairs are too few to hold out {n_val} for validation")
        perm = np.random.default_rng(self.seed).permutation(len(ds))
        self.val_set = Subset(ds, sorted(int(i) for i in perm[:n_val]))
        self.train_set = Subset(ds, sorted(int(i) for i in perm[n_val:]))

    def train_dataloader(self) -> DataLoader:
        return _loader(self.train_set, self.batch_size, self.num_workers, True, self.seed, self.pin_memory)

    def val_dataloader(self) -> DataLoader:
        return _loader(self.val_set, self.batch_size, self.num_workers, False, pin_memory=self.pin_memory)

    def test_dataloader(self) -> DataLoader:
        return _loader(self.val_set, self.batch_size, self.num_workers, False, pin_memory=self.pin_memory)
