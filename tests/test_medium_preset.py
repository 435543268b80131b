"""The ``medium`` presets (simulator and ablation sweep) load, validate and agree (no training)."""

from __future__ import annotations

import pytest

from uavturb.errors import InputError
from uavturb.experiments.config import load_config
from uavturb.experiments.sweep_spec import DEFAULT_SPEC, load_spec
from uavturb.sim.presets import get_preset
from uavturb.sim.tasks import plan_tasks, scene_splits


def test_medium_sim_preset_splits_scenes_and_trajectories():
    p = get_preset("medium")
    assert (p.n_scenes, p.n_train, p.n_val, p.n_test) == (27, 18, 3, 6)
    splits = scene_splits(p)
    assert {k: len(v) for k, v in splits.items()} == {"train": 18, "val": 3, "test": 6}
    assert sorted(s for v in splits.values() for s in v) == list(range(27))  # every scene once
    tasks = plan_tasks(p, seed=0)
    assert len(tasks) == 60
    # 60 trajectories over 27 scenes: the first 6 scenes get 3, the others 2
    per_scene = [sum(t.scene == s for t in tasks) for s in range(27)]
    assert per_scene == [3] * 6 + [2] * 21
    assert {t.n_points for t in tasks} <= {1, 2}
    assert (p.width, p.height, p.pairs) == (32, 32, 2000)
    with pytest.raises(InputError, match="n_train/n_val/n_test"):
        get_preset("medium", n_train=17)


def test_medium_sweep_preset_resolves_every_run_config():
    spec = load_spec(DEFAULT_SPEC)
    pre = spec.presets["medium"]
    assert pre.seeds == 5
    for row in spec.rows:
        cfg = load_config([f"model={row.model}", *pre.overrides, *pre.height])
        assert (cfg.data.root, cfg.data.pairs_root) == ("data/medium/sim", "data/medium/pairs")
        assert cfg.data.image_size == get_preset("medium").width == 32
        assert cfg.model.lr_head == pytest.approx(1e-3)
        # early stopping must not end a run before the encoder is unfrozen
        assert cfg.trainer.early_stopping_patience > cfg.model.unfreeze_at_epoch
        assert cfg.trainer.max_epochs > cfg.model.unfreeze_at_epoch
    for bundle in spec.pretraining.values():
        cfg = load_config([*pre.overrides, *pre.pretrain], experiment=bundle)
        assert cfg.stage == "pretrain" and cfg.trainer.max_epochs == 15
