"""Scenes and their geometry: the one scene model and its queries.

- :mod:`uavturb.scene.indoor` -- :class:`~uavturb.scene.indoor.Scene`, the one scene model:
  generated scenes (:mod:`uavturb.scene.procedural`, on floor plans of
  :mod:`uavturb.scene.floor_plans` and furniture of :mod:`uavturb.scene.furniture`), single-room
  layouts (:mod:`uavturb.scene.layouts`) and external meshes.
- :mod:`uavturb.scene.queries` -- heights below and above, the surface under a point, collisions;
  over boxes through the one surface query :func:`~uavturb.scene.boxes.surface_heights`.
- :mod:`uavturb.scene.heights` -- :class:`~uavturb.scene.heights.SurfaceIndex` (``d_down``,
  ``d_up`` of ``effects.md`` on a point cloud) and :func:`~uavturb.scene.heights.sample_mesh_points`.
- :mod:`uavturb.scene.projection` -- depth images of a cloud seen by a pinhole camera
  (the paper's projection of the EuRoC room scan into ``cam0``).
"""

from __future__ import annotations
