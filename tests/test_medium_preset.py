"""The ``medium`` simulator preset and the ablation sweep's ``medium`` profile load, validate and agree
(no training)."""

from __future__ import annotations

import pytest

from uavturb.errors import InputError
from uavturb.runs.config import DEFAULT_SPEC, load_config, load_spec
from uavturb.sim.dataset.assignment import plan_tasks, scene_splits
from uavturb.sim.dataset.presets import get_preset


@pytest.mark.parametrize("name", ["quick", "medium", "paper"])
def test_sim_presets_split_every_scene_once_and_balance_trajectories(name):
    p = get_preset(name)
    assert p.n_train + p.n_val + p.n_test == p.n_scenes
    splits = scene_splits(p)
    assert {k: len(v) for k, v in splits.items()} == {"train": p.n_train, "val": p.n_val, "test": p.n_test}
    assert sorted(s for v in splits.values() for s in v) == list(range(p.n_scenes))  # every scene once
    tasks = plan_tasks(p, seed=0)
    assert len(tasks) == p.trajectories
    per_scene = [sum(t.scene == s for t in tasks) for s in range(p.n_scenes)]
    assert max(per_scene) - min(per_scene) <= 1 and min(per_scene) >= 1  # trajectories spread evenly
    assert plan_tasks(p, seed=0) == tasks  # planning is deterministic
    with pytest.raises(InputError, match="n_train/n_val/n_test"):
        get_preset(name, n_train=p.n_train - 1)


def test_medium_sweep_profile_resolves_every_run_config():
    spec = load_spec(DEFAULT_SPEC)
    pre = spec.profiles["medium"]
    sim = get_preset("medium")
    roots = set()
    for row in spec.rows:
        cfg = load_config([f"model={row.model}", *pre.overrides, *pre.height])
        roots.add((cfg.data.root, cfg.data.pairs_root))
        assert cfg.data.image_size == sim.width  # trained on the images the medium simulator renders
        # early stopping must not end a run before the encoder is unfrozen
        assert cfg.trainer.early_stopping_patience > cfg.model.unfreeze_at_epoch
        assert cfg.trainer.max_epochs > cfg.model.unfreeze_at_epoch
    assert len(roots) == 1  # every row reads the same data
    for bundle in spec.pretraining.values():
        cfg = load_config([*pre.overrides, *pre.pretrain], experiment=bundle)
        assert cfg.stage == "pretrain" and (cfg.data.root, cfg.data.pairs_root) in roots
