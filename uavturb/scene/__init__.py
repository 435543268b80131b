"""Scene queries on point clouds: heights over/under surfaces and depth images.

- :mod:`uavturb.scene.heights` -- :class:`~uavturb.scene.heights.SurfaceIndex` (``d_down``,
  ``d_up`` of ``effects.md``) and :func:`~uavturb.scene.heights.sample_mesh_points`.
- :mod:`uavturb.scene.projection` -- depth images of a cloud seen by a pinhole camera
  (the paper's projection of the EuRoC room scan into ``cam0``).
"""

from __future__ import annotations
