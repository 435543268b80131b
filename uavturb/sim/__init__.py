"""Simulator, in three rooms (each imports only from the rooms under it):

- :mod:`uavturb.sim.core` -- what every simulated flight runs on: reference signals and
  stop-and-go waypoint plans, the geometric controller, the MPC, the closed loop (controller,
  effects, RK4 physics), the cameras and the headless renderer;
- :mod:`uavturb.sim.flights` -- ``uavturb generate flight``: flight plans in a room, the simulated
  recording and its sensors, the troubles of real recordings (conditions, stream troubles, ground
  contact) and the stand-in EuRoC flights;
- :mod:`uavturb.sim.dataset` -- ``uavturb generate sim|normals|merge``: dataset presets, plans
  through generated scenes (navigation grid, planning), the flyers, one trajectory's arrays, the
  shard writer and the pre-training pairs.

Submodules are imported on demand (``from uavturb.sim.dataset import flying``); importing this
package loads nothing heavy (no OpenGL, no CasADi).
"""

from __future__ import annotations
