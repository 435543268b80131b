"""Headless rendering of depth maps and surface normals with pyrender (EGL).

Frames and conventions
----------------------
Callers give camera poses ``T_WC`` (4x4, camera to world) in the **optical frame** C used
throughout the project (and by EuRoC ``cam0``): x right, y down, z forward (the viewing
direction). pyrender (OpenGL) looks down its own ``-z`` with ``y`` up; the renderer
converts internally with ``T_WG = T_WC @ diag(1, -1, -1, 1)`` (G: the OpenGL camera frame).
Nobody outside this module needs to know about G.

Pixel ``(row i, col j)`` is centred at ``u = j``, ``v = i`` with the intrinsics of
:attr:`SceneRenderer.K`: the forward camera's of :mod:`uavturb.scene.camera`
(:func:`~uavturb.scene.camera.forward_intrinsics`: ``fx = fy = (H / 2) / tan(yfov / 2)``,
``cx = (W - 1) / 2``, ``cy = (H - 1) / 2``), or the calibrated ``K`` it is given
(``SceneRenderer(..., K=...)``, a registered camera of that module).

- :meth:`SceneRenderer.depth` returns the **z-depth** (distance along the optical axis,
  not along the ray) in metres, ``0`` where nothing is hit within ``[znear, zfar]``.
- :meth:`SceneRenderer.normals` returns unit surface normals in the camera (optical)
  frame, oriented towards the camera, ``0`` where nothing is hit. They are exact face
  normals: a flat-shaded, unlit copy of the mesh carries its world face normal as a
  colour (``c = round(127 n + 128)``, so axis-aligned normals decode exactly; others to
  about ``4e-3``), decoded, rotated into C and renormalised.
- Rendering is single-sample (no anti-aliasing): every pixel is the surface at its
  centre ray. pyrender's default 4x multisampling is switched off on the renderer
  instance, because its depth resolve reads one sample ~0.4 px off the pixel centre.
- Surfaces are two-sided (each triangle is uploaded twice, once per winding), so scans
  with inconsistent winding render whole and a camera inside a solid sees its inside.
- :meth:`SceneRenderer.rgb` (``rgb=True``) renders a cheap colour image: per-face
  colours (by box kind for generated scenes) with a fixed Lambertian-like shading baked
  in, unlit (flat) rendering.

:func:`camera_pose` builds ``T_WC`` for a forward-facing camera on the body (looking along
body +x, pitched down by ``pitch_deg``).
"""

from __future__ import annotations

import os
import time
import types

os.environ.setdefault("PYOPENGL_PLATFORM", "egl")

import numpy as np  # noqa: E402
import pyrender  # noqa: E402
import trimesh  # noqa: E402

from uavturb.errors import InputError  # noqa: E402
from uavturb.physics import quaternion as quat  # noqa: E402
from uavturb.scene.camera import forward_intrinsics, forward_rotation  # noqa: E402
from uavturb.scene.indoor import Scene  # noqa: E402
from uavturb.scene.procedural import generate_scene  # noqa: E402
from uavturb.scene.queries import inside_obstacle  # noqa: E402

#: Optical frame C (x right, y down, z forward) to OpenGL camera frame G (x right, y up, z back).
T_CG = np.diag([1.0, -1.0, -1.0, 1.0])


_KIND_COLOURS = {
    "floor": (0.55, 0.42, 0.30),
    "ceiling": (0.92, 0.92, 0.90),
    "wall": (0.85, 0.83, 0.78),
    "lintel": (0.85, 0.83, 0.78),
    "table": (0.50, 0.33, 0.20),
    "desk": (0.75, 0.75, 0.72),
    "bed": (0.35, 0.45, 0.65),
    "sofa": (0.55, 0.25, 0.25),
    "shelf": (0.60, 0.45, 0.30),
    "counter": (0.90, 0.90, 0.88),
    "box": (0.70, 0.58, 0.40),
}


def camera_pose(
    p_WB: np.ndarray,
    q_WB: np.ndarray,
    pitch_deg: float = 0.0,
    offset: np.ndarray | None = None,
) -> np.ndarray:
    """Pose ``T_WC`` of a forward-facing camera on the body, in the optical convention.

    The camera looks along body +x (image right = body -y, image down = body -z) and is
    pitched down by ``pitch_deg`` (a rotation about body +y), then placed at ``offset``.

    Parameters
    ----------
    p_WB : (3,) float array, m
        Body position in the world frame.
    q_WB : (4,) float array
        Body attitude, Hamilton ``w, x, y, z``, body to world.
    pitch_deg : float, deg
        Downward pitch of the camera relative to body +x (positive looks down).
    offset : (3,) float array, m, optional
        Camera centre in the body frame (default: the body origin).

    Returns
    -------
    (4, 4) float array: camera (optical frame C) to world.
    """
    p_WB = np.asarray(p_WB, dtype=float).reshape(3)
    R_WB = quat.to_rotation_matrix(np.asarray(q_WB, dtype=float).reshape(4))
    R_BC = forward_rotation(pitch_deg)
    off = np.zeros(3) if offset is None else np.asarray(offset, dtype=float).reshape(3)
    T = np.eye(4)
    T[:3, :3] = R_WB @ R_BC
    T[:3, 3] = p_WB + R_WB @ off
    return T


def look_at(eye: np.ndarray, target: np.ndarray, up: np.ndarray = (0.0, 0.0, 1.0)) -> np.ndarray:
    """``T_WC`` (optical frame) of a camera at ``eye`` [m] looking at ``target`` [m], image up ~ ``up``."""
    eye, target, up = (np.asarray(v, dtype=float) for v in (eye, target, up))
    z = target - eye
    z /= np.linalg.norm(z)
    x = np.cross(z, up)
    if np.linalg.norm(x) < 1e-9:
        raise InputError("look_at", "viewing direction is parallel to 'up'")
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    T = np.eye(4)
    T[:3, :3] = np.c_[x, y, z]
    T[:3, 3] = eye
    return T


def _configure_single_sample_framebuffer(self) -> None:
    """pyrender's ``Renderer._configure_main_framebuffer`` with 1 sample instead of 4.

    pyrender renders into a 4x multisampled buffer and resolves depth with ``GL_NEAREST``,
    which returns the depth at the first sample position (a fraction of a pixel off the
    pixel centre: ~0.4 px on Mesa), and blends colours across silhouettes. A single-sample
    buffer makes every pixel the value at its centre (exact z-depth, exact face normals).
    Bound to one renderer instance; pyrender itself is not modified.
    """
    from OpenGL import GL as gl

    if self._main_fb is not None and (
        self.viewport_width != self._main_fb_dims[0] or self.viewport_height != self._main_fb_dims[1]
    ):
        self._delete_main_framebuffer()
    if self._main_fb is not None:
        return
    w, h = self.viewport_width, self.viewport_height
    self._main_cb, self._main_db = gl.glGenRenderbuffers(2)
    gl.glBindRenderbuffer(gl.GL_RENDERBUFFER, self._main_cb)
    gl.glRenderbufferStorage(gl.GL_RENDERBUFFER, gl.GL_RGBA, w, h)
    gl.glBindRenderbuffer(gl.GL_RENDERBUFFER, self._main_db)
    gl.glRenderbufferStorage(gl.GL_RENDERBUFFER, gl.GL_DEPTH_COMPONENT24, w, h)
    self._main_fb = gl.glGenFramebuffers(1)
    gl.glBindFramebuffer(gl.GL_DRAW_FRAMEBUFFER, self._main_fb)
    gl.glFramebufferRenderbuffer(gl.GL_DRAW_FRAMEBUFFER, gl.GL_COLOR_ATTACHMENT0, gl.GL_RENDERBUFFER, self._main_cb)
    gl.glFramebufferRenderbuffer(gl.GL_DRAW_FRAMEBUFFER, gl.GL_DEPTH_ATTACHMENT, gl.GL_RENDERBUFFER, self._main_db)
    # the "multisample" buffer pyrender draws into, with 0 samples (= single-sample)
    self._main_cb_ms, self._main_db_ms = gl.glGenRenderbuffers(2)
    gl.glBindRenderbuffer(gl.GL_RENDERBUFFER, self._main_cb_ms)
    gl.glRenderbufferStorageMultisample(gl.GL_RENDERBUFFER, 0, gl.GL_RGBA, w, h)
    gl.glBindRenderbuffer(gl.GL_RENDERBUFFER, self._main_db_ms)
    gl.glRenderbufferStorageMultisample(gl.GL_RENDERBUFFER, 0, gl.GL_DEPTH_COMPONENT24, w, h)
    self._main_fb_ms = gl.glGenFramebuffers(1)
    gl.glBindFramebuffer(gl.GL_DRAW_FRAMEBUFFER, self._main_fb_ms)
    gl.glFramebufferRenderbuffer(gl.GL_DRAW_FRAMEBUFFER, gl.GL_COLOR_ATTACHMENT0, gl.GL_RENDERBUFFER, self._main_cb_ms)
    gl.glFramebufferRenderbuffer(gl.GL_DRAW_FRAMEBUFFER, gl.GL_DEPTH_ATTACHMENT, gl.GL_RENDERBUFFER, self._main_db_ms)
    self._main_fb_dims = (w, h)


def _flat_copy(mesh: trimesh.Trimesh) -> tuple[np.ndarray, np.ndarray]:
    """Unmerged, two-sided triangle soup: vertices ``(6F, 3)`` and face normals ``(2F, 3)``.

    Every triangle is followed by a copy with reversed winding (the same normal is kept
    for both: the renderer turns normals towards the camera afterwards). With back-face
    culling on, exactly one copy is drawn per pixel, so the depth-only pass (where pyrender
    always culls back faces) and the colour pass see the same, two-sided surface.
    """
    tris = np.asarray(mesh.triangles, dtype=np.float32)  # (F, 3, 3)
    both = np.stack([tris, tris[:, ::-1]], axis=1).reshape(-1, 3)
    normals = np.repeat(np.asarray(mesh.face_normals, dtype=float), 2, axis=0)
    return both, normals


class SceneRenderer:
    """Renders depth, normals (and optionally colour) of one mesh from many poses.

    The mesh is uploaded once; one :class:`pyrender.OffscreenRenderer` is reused for all
    frames and deleted by :meth:`close` (or on leaving a ``with`` block).

    Parameters
    ----------
    scene_mesh : trimesh.Trimesh or uavturb.scene.indoor.Scene
        World-frame mesh [m]. A ``Scene`` also gives per-box colours for :meth:`rgb`.
    width, height : int, pixels
    yfov_deg : float, deg
        Vertical field of view.
    znear, zfar : float, m
        Clipping distances; surfaces beyond ``zfar`` read as no hit (depth 0).
    rgb : bool
        Also upload a coloured copy of the mesh for :meth:`rgb`.
    K : (3, 3) float array, px, optional
        Pinhole intrinsics (pixel centres at integer ``u, v``) instead of ``yfov_deg``'s symmetric
        camera: a calibrated camera scaled to this image size
        (:func:`uavturb.scene.camera.scaled_intrinsics`). ``yfov_deg`` is then unused.
    """

    def __init__(
        self,
        scene_mesh,
        width: int = 128,
        height: int = 128,
        yfov_deg: float = 70.0,
        znear: float = 0.05,
        zfar: float = 20.0,
        rgb: bool = False,
        K: np.ndarray | None = None,
    ):
        scene = scene_mesh if isinstance(scene_mesh, Scene) else None
        mesh = scene.mesh if scene is not None else scene_mesh
        if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
            raise InputError("scene_mesh", "expected a Scene or a non-empty trimesh.Trimesh")
        if width <= 0 or height <= 0:
            raise InputError("width/height", f"must be positive, got {width}x{height}")
        if not (0 < yfov_deg < 180):
            raise InputError("yfov_deg", f"must be in (0, 180), got {yfov_deg}")
        if not (0 < znear < zfar):
            raise InputError("znear/zfar", f"need 0 < znear < zfar, got {znear}, {zfar}")
        self.width, self.height = int(width), int(height)
        self.yfov = float(np.deg2rad(yfov_deg))
        self.znear, self.zfar = float(znear), float(zfar)
        if K is None:
            #: (3, 3) intrinsics of the optical frame, pixel centres at integer (u, v)
            self.K = forward_intrinsics(self.width, self.height, yfov_deg)
            f = self.K[1, 1]
            # camera-frame ray directions (z = 1) of pixel centres, for orienting normals
            u = np.arange(self.width) + 0.5 - self.width / 2
            v = np.arange(self.height) + 0.5 - self.height / 2
            uu, vv = np.meshgrid(u / f, v / f)
        else:
            self.K = np.array(K, dtype=float)
            if self.K.shape != (3, 3) or not np.all(np.isfinite(self.K)) or min(self.K[0, 0], self.K[1, 1]) <= 0:
                raise InputError("K", "expected a (3, 3) pinhole matrix with positive focal lengths")
            uu, vv = np.meshgrid((np.arange(self.width) - self.K[0, 2]) / self.K[0, 0],
                                 (np.arange(self.height) - self.K[1, 2]) / self.K[1, 1])
        self._rays = np.stack([uu, vv, np.ones_like(uu)], axis=-1)

        tris, normals = _flat_copy(mesh)
        self._face_normals = normals
        ncol = np.clip(np.rint(127.0 * normals + 128.0), 0, 255) / 255.0
        colours = np.repeat(np.c_[ncol, np.ones(len(ncol))], 3, axis=0).astype(np.float32)
        material = pyrender.MetallicRoughnessMaterial(baseColorFactor=[1.0, 1.0, 1.0, 1.0], doubleSided=False)
        self._geom = pyrender.Mesh([pyrender.Primitive(positions=tris, color_0=colours, material=material, mode=4)])
        self._scene = pyrender.Scene(bg_color=[0.0, 0.0, 0.0, 0.0], ambient_light=[1.0, 1.0, 1.0])
        self._scene.add(self._geom)
        self._rgb_mesh = None
        if rgb:
            base = np.repeat(self._face_colours(scene, mesh), 2, axis=0)
            light = np.array([0.3, 0.5, 0.81])
            light /= np.linalg.norm(light)
            shade = 0.6 + 0.4 * np.abs(normals @ light)
            col = np.clip(base * shade[:, None], 0, 1)
            colours = np.repeat(np.c_[col, np.ones(len(col))], 3, axis=0).astype(np.float32)
            material = pyrender.MetallicRoughnessMaterial(baseColorFactor=[1.0, 1.0, 1.0, 1.0], doubleSided=False)
            self._rgb_mesh = pyrender.Mesh([pyrender.Primitive(positions=tris, color_0=colours, material=material,
                                                               mode=4)])
            self._rgb_mesh.is_visible = False
            self._scene.add(self._rgb_mesh)
        if K is None:
            cam = pyrender.PerspectiveCamera(yfov=self.yfov, znear=self.znear, zfar=self.zfar,
                                             aspectRatio=self.width / self.height)
        else:  # pyrender's principal point counts from the image edge, ours from the first pixel's centre
            cam = pyrender.IntrinsicsCamera(self.K[0, 0], self.K[1, 1], self.K[0, 2] + 0.5, self.K[1, 2] + 0.5,
                                            znear=self.znear, zfar=self.zfar)
        self._cam_node = self._scene.add(cam, pose=np.eye(4))
        self._renderer = pyrender.OffscreenRenderer(self.width, self.height)
        inner = getattr(self._renderer, "_renderer", None)
        if inner is not None and hasattr(inner, "_configure_main_framebuffer"):
            inner._configure_main_framebuffer = types.MethodType(_configure_single_sample_framebuffer, inner)

    @staticmethod
    def _face_colours(scene, mesh: trimesh.Trimesh) -> np.ndarray:
        """``(F, 3)`` base colours in ``[0, 1]``: by box kind for generated scenes, else the mesh's."""
        n_faces = len(mesh.faces)
        if scene is not None and len(scene.box_kinds) * 12 == n_faces:
            rng = np.random.default_rng(0 if scene.seed is None else scene.seed)
            col = np.array([_KIND_COLOURS.get(k, (0.6, 0.6, 0.6)) for k in scene.box_kinds])
            # vary furniture colours per piece
            owner = scene.box_owner
            tint = rng.uniform(0.75, 1.2, (max(owner.max() + 1, 1) if len(owner) else 1, 3))
            col = np.where(owner[:, None] >= 0, col * tint[np.maximum(owner, 0)], col)
            return np.clip(np.repeat(col, 12, axis=0), 0, 1)
        try:
            fc = np.asarray(mesh.visual.face_colors, dtype=float)[:, :3] / 255.0
            if fc.shape == (n_faces, 3):
                return fc
        except Exception:
            pass
        return np.full((n_faces, 3), 0.7)

    # --- poses ------------------------------------------------------------------------

    def _set_pose(self, T_WC: np.ndarray) -> np.ndarray:
        T_WC = np.asarray(T_WC, dtype=float)
        if T_WC.shape != (4, 4) or not np.all(np.isfinite(T_WC)):
            raise InputError("T_WC", f"expected a finite (4, 4) pose, got shape {T_WC.shape}")
        self._scene.set_pose(self._cam_node, T_WC @ T_CG)
        return T_WC

    def _check_open(self):
        if self._renderer is None:
            raise InputError("SceneRenderer", "renderer is closed")

    # --- rendering --------------------------------------------------------------------

    def depth(self, T_WC: np.ndarray) -> np.ndarray:
        """Z-depth image.

        Parameters
        ----------
        T_WC : (4, 4) float array
            Camera (optical frame: x right, y down, z forward) to world.

        Returns
        -------
        (H, W) float32 array, m: distance along the optical axis; 0 where nothing is hit.
        """
        self._check_open()
        self._set_pose(T_WC)
        self._geom.is_visible = True
        d = self._renderer.render(self._scene, flags=pyrender.RenderFlags.DEPTH_ONLY)
        return np.ascontiguousarray(d, dtype=np.float32)

    def depth_and_normals(self, T_WC: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Depth and normals from one render pass (see :meth:`depth`, :meth:`normals`).

        Returns
        -------
        depth : (H, W) float32 array, m
        normals : (H, W, 3) float32 array, unit, camera (optical) frame
        """
        self._check_open()
        T_WC = self._set_pose(T_WC)
        self._geom.is_visible = True
        if self._rgb_mesh is not None:
            self._rgb_mesh.is_visible = False
        colour, depth = self._renderer.render(self._scene, flags=pyrender.RenderFlags.FLAT)
        hit = depth > 0
        n_W = (colour[..., :3].astype(np.float32) - 128.0) / 127.0
        n_C = n_W @ T_WC[:3, :3].astype(np.float32)  # R_WC^T n_W, row-vector form
        norm = np.linalg.norm(n_C, axis=-1, keepdims=True)
        n_C = np.where(norm > 1e-6, n_C / np.maximum(norm, 1e-6), 0.0)
        # face the camera (surfaces are rendered two-sided)
        flip = np.sum(n_C * self._rays, axis=-1) > 0
        n_C[flip] *= -1.0
        n_C[~hit] = 0.0
        return np.ascontiguousarray(depth, dtype=np.float32), np.ascontiguousarray(n_C, dtype=np.float32)

    def normals(self, T_WC: np.ndarray) -> np.ndarray:
        """Unit surface normals in the camera (optical) frame, facing the camera.

        Parameters
        ----------
        T_WC : (4, 4) float array
            Camera (optical frame) to world.

        Returns
        -------
        (H, W, 3) float32 array; 0 where nothing is hit.
        """
        return self.depth_and_normals(T_WC)[1]

    def rgb(self, T_WC: np.ndarray) -> np.ndarray:
        """Colour image (needs ``rgb=True``).

        Returns
        -------
        (H, W, 3) uint8 array.
        """
        self._check_open()
        if self._rgb_mesh is None:
            raise InputError("SceneRenderer", "constructed with rgb=False; pass rgb=True for colour images")
        self._set_pose(T_WC)
        self._geom.is_visible = False
        self._rgb_mesh.is_visible = True
        try:
            colour, _ = self._renderer.render(self._scene, flags=pyrender.RenderFlags.FLAT)
        finally:
            self._geom.is_visible = True
            self._rgb_mesh.is_visible = False
        return np.ascontiguousarray(colour[..., :3])

    # --- lifetime ---------------------------------------------------------------------

    def close(self) -> None:
        """Free the OpenGL context (idempotent)."""
        if self._renderer is not None:
            self._renderer.delete()
            self._renderer = None

    def __enter__(self) -> SceneRenderer:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __del__(self):  # best effort
        try:
            self.close()
        except Exception:
            pass


def random_poses(scene, n: int, seed: int = 0, pitch_deg: float = 20.0) -> np.ndarray:
    """``(n, 4, 4)`` camera poses inside the rooms of a generated scene, for benchmarks.

    Positions are uniform over the rooms' free floor area at 0.3-1.8 m height, at least
    0.1 m from any solid, with random yaw, and the camera pitched down by ``pitch_deg``.
    """
    rng = np.random.default_rng(seed)
    rooms = scene.rooms
    T = np.empty((n, 4, 4))
    for k in range(n):
        for _ in range(1000):
            r = rooms[int(rng.integers(len(rooms)))].rect
            p = np.array([rng.uniform(r[0], r[2]), rng.uniform(r[1], r[3]), rng.uniform(0.3, 1.8)])
            if not inside_obstacle(scene, p[None], margin=0.1)[0]:
                break
        q = quat.from_euler(0.0, 0.0, rng.uniform(-np.pi, np.pi))
        T[k] = camera_pose(p, q, pitch_deg)
    return T


def benchmark(n: int = 500, width: int = 128, height: int = 128, seed: int = 3) -> dict[str, float]:
    """Rendering throughput on a generated scene (frames per second, wall clock).

    Parameters
    ----------
    n : int
        Frames per measurement.
    width, height : int, pixels
    seed : int
        Scene seed.

    Returns
    -------
    dict with ``depth_fps`` (depth only), ``normals_fps`` (depth and normals, one pass,
    decoding included), ``scene_faces``.
    """
    scene = generate_scene(seed)
    poses = random_poses(scene, n)
    with SceneRenderer(scene, width, height) as r:
        r.depth(poses[0])
        r.depth_and_normals(poses[0])
        t0 = time.perf_counter()
        for T in poses:
            r.depth(T)
        t1 = time.perf_counter()
        for T in poses:
            r.depth_and_normals(T)
        t2 = time.perf_counter()
    return {"depth_fps": n / (t1 - t0), "normals_fps": n / (t2 - t1), "scene_faces": float(len(scene.mesh.faces))}
