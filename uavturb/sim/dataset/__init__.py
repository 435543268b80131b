"""``uavturb generate sim|normals|merge``: :mod:`~uavturb.sim.dataset.presets`,
:mod:`~uavturb.sim.dataset.assignment` (scene, split, seed and shard of every trajectory),
:mod:`~uavturb.sim.dataset.navigation` and :mod:`~uavturb.sim.dataset.planning` (plans through
generated scenes), :mod:`~uavturb.sim.dataset.plan_plot`, :mod:`~uavturb.sim.dataset.flying`
(the flyers), :mod:`~uavturb.sim.dataset.trajectory_arrays` (one trajectory's arrays),
:mod:`~uavturb.sim.dataset.generation` (the shard writer) and
:mod:`~uavturb.sim.dataset.pretraining_pairs`."""

from __future__ import annotations
