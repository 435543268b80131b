"""What every simulated flight runs on: :mod:`~uavturb.sim.core.signals` (references),
:mod:`~uavturb.sim.core.waypoint_plan`, :mod:`~uavturb.sim.core.controller`,
:mod:`~uavturb.sim.core.mpc`, :mod:`~uavturb.sim.core.closed_loop`,
:mod:`~uavturb.scene.camera` and :mod:`~uavturb.sim.core.render`."""

from __future__ import annotations
