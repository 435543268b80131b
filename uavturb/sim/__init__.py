"""Simulator: procedural indoor scenes, headless rendering, reference trajectories,
controllers and closed-loop synthetic flights.

Submodules are imported on demand (``from uavturb.sim import scene_flight``); importing this
package loads nothing heavy (no OpenGL, no CasADi).
"""

from __future__ import annotations
