"""Trajectory tasks of a dataset: which scene, which split, which seed, which shard."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from uavturb.errors import InputError
from uavturb.scene.procedural import split_scenes
from uavturb.sim.dataset.presets import SimPreset


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
