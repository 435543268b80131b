"""The camera model: one registry of named cameras (intrinsics, native size, mount on the
vehicle) and the pinhole camera at an image size on the body (:class:`CameraModel`) that the
renderer, the projection of point clouds, the synthetic data, training and evaluation all use.

Units and conventions
---------------------
- Intrinsics ``fu, fv, cu, cv`` and resolutions in pixels; pixel ``(row i, col j)`` is centred at
  ``u = j``, ``v = i`` (as in :mod:`uavturb.scene.projection` and :mod:`uavturb.sim.core.render`, and
  as in EuRoC's Kalibr calibrations). Translations in metres, frame periods in seconds, rates in hertz.
- Optical frame C: x right, y down, z forward (the viewing direction).
- B is the rotor frame (``recordings.md``); a camera's mount is its pose in B, ``x_B = T_BC x_C``.
- S is EuRoC's body frame (the VI-sensor's IMU). A registered camera gives its pose in S
  (``x_S = T_SC x_C``, ``cam0/sensor.yaml``'s ``T_BS``) and the vehicle file whose ``T_BS`` places S
  in B (``x_B = T_BS x_S``); its mount in B is ``T_BC = T_BS T_SC`` (:func:`body_mount`).
- Images are ideal pinhole images: the lens distortion of an entry is recorded (it goes into
  ``cam0/sensor.yaml``) but not applied, as :mod:`uavturb.scene.projection` projects undistorted.

Cameras
-------
``forward`` (:data:`FORWARD`, :func:`forward_camera`)
    The simulator's and the synthetic data's camera, set by two numbers: at the body origin,
    looking along body +x pitched down by ``pitch_deg``, square pixels, vertical field of view
    ``yfov_deg``, principal point at the image centre: ``f = (H / 2) / tan(yfov / 2)``,
    ``cu = (W - 1) / 2``, ``cv = (H - 1) / 2`` (:func:`forward_intrinsics`, :func:`forward_rotation`).
``euroc_cam0`` (:data:`CAMERAS`)
    The left camera of EuRoC's VI-sensor, mounted on the AscTec Firefly as in the V1 sequences:
    752 x 480 px at 20 Hz, looking forward about 20 deg down, its optical centre 0.13 m under
    the rotor frame's origin (:func:`hang_below_body`).

A camera with another size than its native resolution (the networks' square inputs) is the
centred crop of the target's aspect ratio, scaled uniformly (:func:`scaled_intrinsics`): square
pixels and the principal point's place within the crop are kept, and the field of view along the
axis the crop keeps whole (the vertical one for a square image from 752 x 480). Evaluation
(:func:`uavturb.data.recordings.cam0_camera`) and training data use this one function.

A trained model carries its camera: :meth:`CameraModel.record` is the JSON form kept in the
model's hyperparameters and its MLflow run, :func:`camera_from_record` reads it back (checked).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from uavturb.errors import InputError
from uavturb.io.recording import Camera
from uavturb.io.vehicle_file import SHIPPED_DIR, load_vehicle
from uavturb.scene.projection import intrinsics_matrix

#: the simulator's default camera (preset fields ``yfov_deg``, ``pitch_deg``)
FORWARD = "forward"


@dataclass(frozen=True)
class CameraSpec:
    """A calibrated camera and where it sits on its vehicle.

    Attributes
    ----------
    name : registry name
    resolution : (width, height) px, native
    intrinsics : (fu, fv, cu, cv) px at the native resolution, pixel centres at integers
    rate_hz : Hz, frame rate
    T_SC : 4x4, camera (optical frame) pose in S, ``x_S = T_SC x_C`` [m] (EuRoC's ``T_BS``)
    vehicle : shipped vehicle file (``uavturb/vehicles/<vehicle>.yaml``) whose ``T_BS`` places S in B
    distortion_model, distortion : lens model and coefficients (recorded, not applied)
    source : where the numbers come from
    """

    name: str
    resolution: tuple[int, int]
    intrinsics: tuple[float, float, float, float]
    rate_hz: float
    T_SC: tuple[tuple[float, ...], ...]
    vehicle: str
    distortion_model: str = "radial-tangential"
    distortion: tuple[float, ...] = (0.0, 0.0, 0.0, 0.0)
    source: str = ""

    def K(self, width: int | None = None, height: int | None = None) -> np.ndarray:
        """(3, 3) intrinsics [px] at ``width x height`` (default: native; see :func:`scaled_intrinsics`)."""
        W, H = self.resolution
        return scaled_intrinsics(self.intrinsics, self.resolution, W if width is None else width,
                                 H if height is None else height)

    def sensor(self) -> Camera:
        """The camera as ``cam0/sensor.yaml`` describes it (no frames listed)."""
        return Camera(intrinsics=np.asarray(self.intrinsics, float), resolution=tuple(self.resolution),
                      T_BS=np.asarray(self.T_SC, float), distortion_model=self.distortion_model,
                      distortion=np.asarray(self.distortion, float), rate_hz=float(self.rate_hz))


#: EuRoC MAV dataset (Burri et al., IJRR 2016), ``mav0/cam0/sensor.yaml`` of every sequence
#: (V1_01_easy, V1_02_medium, ...): the VI-sensor's left camera (MT9V034, global shutter),
#: calibrated with Kalibr. ``T_BS`` there is cam0's pose in EuRoC's body frame S (the VI-sensor's
#: IMU). The same numbers are in the EuRoC configs of ORB-SLAM3 (``Examples/Monocular/EuRoC.yaml``),
#: OpenVINS and Kimera-VIO.
EUROC_CAM0 = CameraSpec(
    name="euroc_cam0",
    resolution=(752, 480),  # px, width x height
    intrinsics=(458.654, 457.296, 367.215, 248.375),  # fu, fv, cu, cv [px]
    rate_hz=20.0,  # Hz
    T_SC=((0.0148655429818, -0.999880929698, 0.00414029679422, -0.0216401454975),
          (0.999557249008, 0.0149672133247, 0.025715529948, -0.064676986768),
          (-0.0257744366974, 0.00375618835797, 0.999660727178, 0.00981073058949),
          (0.0, 0.0, 0.0, 1.0)),  # x_S = T_SC x_C, translation in m
    vehicle="firefly",  # S in B: uavturb/vehicles/firefly.yaml (the inverse of V1's vicon0 T_BS)
    distortion_model="radial-tangential",
    distortion=(-0.28340811, 0.07395907, 0.00019359, 1.76187114e-05),  # k1, k2, p1, p2
    source="EuRoC MAV dataset, mav0/cam0/sensor.yaml (Burri et al. 2016)",
)

#: name -> calibrated camera (``forward`` is the preset's own, see the module docstring)
CAMERAS: dict[str, CameraSpec] = {EUROC_CAM0.name: EUROC_CAM0}
CAMERA_NAMES = (FORWARD, *CAMERAS)


def camera_spec(name: str) -> CameraSpec:
    """The registered camera ``name``.

    Raises
    ------
    InputError : unknown name, or ``forward`` (which is no calibrated camera: the preset sets it)
    """
    if name in CAMERAS:
        return CAMERAS[name]
    raise InputError("camera", f"unknown camera {name!r} (known: {', '.join(CAMERA_NAMES)})")


def scaled_intrinsics(intrinsics, resolution: tuple[int, int], width: int, height: int) -> np.ndarray:
    """``K`` (3, 3) [px] of the centred crop of aspect ``width : height`` of a ``resolution`` image,
    scaled uniformly to ``width x height`` px.

    Parameters
    ----------
    intrinsics : (fu, fv, cu, cv) px at ``resolution``, pixel centres at integer coordinates
    resolution : (W, H) px
    width, height : px, target size

    Returns
    -------
    (3, 3) intrinsics: ``f' = s f`` and ``c' + 0.5 = s (c - offset + 0.5)`` with ``s`` the scale and
    ``offset`` the crop's first pixel edge (pixel centres move with their pixels).
    """
    W, H = (float(v) for v in resolution)
    fu, fv, cu, cv = (float(v) for v in intrinsics)
    if int(width) < 1 or int(height) < 1:
        raise InputError("image size", f"width and height must be >= 1, got {width} x {height}")
    aspect = width / height
    crop_w, crop_h = (H * aspect, H) if W / H > aspect else (W, W / aspect)
    x0, y0 = (W - crop_w) / 2, (H - crop_h) / 2
    s = width / crop_w
    return intrinsics_matrix(fu * s, fv * s, (cu - x0 + 0.5) * s - 0.5, (cv - y0 + 0.5) * s - 0.5)


@lru_cache(maxsize=8)
def _mount(name: str) -> np.ndarray:
    spec = camera_spec(name)
    T_BS = load_vehicle(SHIPPED_DIR / f"{spec.vehicle}.yaml").T_BS_matrix
    T = T_BS @ np.asarray(spec.T_SC, float)
    T.setflags(write=False)
    return T


def body_mount(name: str) -> np.ndarray:
    """``T_BC = T_BS T_SC`` (4, 4): the registered camera's pose in the rotor frame B of its vehicle
    (read-only). ``forward`` has none here (its pose follows ``pitch_deg``)."""
    return _mount(name)


def hang_below_body(name: str) -> float:
    """How far [m] the camera's optical centre sits under B's origin (0 for ``forward``):
    ``-z`` of :func:`body_mount`'s translation (0.130 m for ``euroc_cam0``)."""
    return 0.0 if name == FORWARD else float(max(-body_mount(name)[2, 3], 0.0))


#: m, the least height of a camera hanging under the body over the surface below it (ours)
CAMERA_CLEARANCE = 0.03


def least_body_height(name: str) -> float:
    """Lowest height [m] of the body origin over a surface that keeps the camera ``name``
    :data:`CAMERA_CLEARANCE` over it (0 for a camera not under the body: ``forward``). The
    vehicle stands on legs that tall: 0.16 m for ``euroc_cam0``."""
    hang = hang_below_body(name)
    return hang + CAMERA_CLEARANCE if hang > 0 else 0.0


def check_camera(name: str) -> str:
    """``name`` if it is a known camera (``forward`` or a registered one), else :class:`InputError`."""
    if name != FORWARD:
        camera_spec(name)
    return name


def preset_intrinsics(camera: str, width: int, height: int) -> np.ndarray | None:
    """``K`` of a preset's camera at its image size; ``None`` for ``forward`` (the renderer's own,
    :func:`forward_intrinsics` of the preset's ``yfov_deg``)."""
    return None if camera == FORWARD else camera_spec(camera).K(width, height)


def preset_mount(camera: str) -> np.ndarray | None:
    """``T_BC`` of a preset's camera; ``None`` for ``forward`` (the pose follows ``pitch_deg``)."""
    return None if camera == FORWARD else body_mount(camera)


# --- the forward camera ----------------------------------------------------------------------

#: Optical axes of a level, forward-looking camera in the body frame (columns x_C, y_C, z_C):
#: x_C = -y_B (right), y_C = -z_B (down), z_C = x_B (forward). Use as ``T_BC[:3, :3]``.
R_BC_FORWARD = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])


def forward_intrinsics(width: int, height: int, yfov_deg: float) -> np.ndarray:
    """``K`` (3, 3) [px] of the forward camera: ``f = (height / 2) / tan(yfov / 2)`` [px] for both
    axes (square pixels), principal point at the image centre ``((W - 1) / 2, (H - 1) / 2)``."""
    if not 0 < yfov_deg < 180:
        raise InputError("yfov_deg", f"must be in (0, 180), got {yfov_deg}")
    f = (height / 2) / np.tan(np.deg2rad(yfov_deg) / 2)
    return np.array([[f, 0.0, (width - 1) / 2], [0.0, f, (height - 1) / 2], [0.0, 0.0, 1.0]])


def forward_rotation(pitch_deg: float) -> np.ndarray:
    """``R_BC`` (3, 3): the forward camera's optical axes in B, looking along body +x pitched down
    by ``pitch_deg`` [deg] (a rotation about body +y applied to :data:`R_BC_FORWARD`)."""
    a = np.deg2rad(pitch_deg)
    R_y = np.array([[np.cos(a), 0.0, np.sin(a)], [0.0, 1.0, 0.0], [-np.sin(a), 0.0, np.cos(a)]])
    return R_y @ R_BC_FORWARD


# --- a camera at an image size on the body ---------------------------------------------------


@dataclass(frozen=True, eq=False)
class CameraModel:
    """A pinhole camera at an image size, mounted on the body.

    Attributes
    ----------
    name : ``forward``, a registered camera's name, or ``cam0`` (a recording's own)
    K : (3, 3) intrinsics [px] at ``width x height``, pixel centres at integers
    width, height : px
    T_BC : (4, 4) camera (optical frame C) pose in the rotor frame B, ``x_B = T_BC x_C`` [m]
    source : where it came from, in words
    frame_dt : s, frame period of the images (the training data's), None where unknown
    """

    name: str
    K: np.ndarray
    width: int
    height: int
    T_BC: np.ndarray
    source: str
    frame_dt: float | None = None

    def record(self) -> dict:
        """The camera as JSON-ready plain values (a model's hyperparameter ``camera``, its MLflow
        run's tag ``camera``); :func:`camera_from_record` reads it back."""
        return {"name": self.name, "width": int(self.width), "height": int(self.height),
                "K": [[float(x) for x in row] for row in self.K],
                "T_BC": [[float(x) for x in row] for row in self.T_BC],
                "frame_dt": None if self.frame_dt is None else float(self.frame_dt), "source": self.source}


def forward_camera(width: int, height: int, yfov_deg: float, pitch_deg: float,
                   frame_dt: float | None = None) -> CameraModel:
    """The forward camera (module docstring) at ``width x height`` px, at the body origin."""
    T = np.eye(4)
    T[:3, :3] = forward_rotation(pitch_deg)
    return CameraModel(FORWARD, forward_intrinsics(width, height, yfov_deg), int(width), int(height), T,
                       f"default forward camera (pitch {pitch_deg:g} deg down, vertical fov {yfov_deg:g} deg)",
                       frame_dt)


def registered_camera(name: str, width: int, height: int, frame_dt: float | None = None) -> CameraModel:
    """The registered camera ``name`` (not ``forward``) at ``width x height`` px
    (:func:`scaled_intrinsics`), on its vehicle's body (:func:`body_mount`)."""
    return CameraModel(name, camera_spec(name).K(width, height), int(width), int(height), body_mount(name),
                       f"{name} (the training data's camera, uavturb.scene.camera)", frame_dt)


def named_camera(name: str, width: int, height: int, yfov_deg: float, pitch_deg: float,
                 frame_dt: float | None = None) -> CameraModel:
    """A simulator preset's camera: ``forward`` with ``yfov_deg`` and ``pitch_deg``, else the
    registered camera ``name`` (both numbers then unused)."""
    if name == FORWARD:
        return forward_camera(width, height, yfov_deg, pitch_deg, frame_dt)
    return registered_camera(name, width, height, frame_dt)


def _matrix(value, shape: tuple[int, int], where: str, key: str) -> np.ndarray:
    try:
        M = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        M = np.zeros(0)
    if M.shape != shape or not np.all(np.isfinite(M)):
        raise InputError(where, f"camera {key} must be a {shape[0]}x{shape[1]} matrix of finite numbers")
    return M


def camera_from_record(record, where: str) -> CameraModel:
    """The :class:`CameraModel` of :meth:`CameraModel.record`'s JSON form, checked.

    Raises
    ------
    InputError : naming ``where`` (the checkpoint or run it came from): a missing key, an image
        size below 1 px, a ``K`` without positive focal lengths, a ``T_BC`` that is no rigid motion.
    """
    if not isinstance(record, dict):
        raise InputError(where, f"camera must be a mapping, got {type(record).__name__}")
    missing = [k for k in ("name", "width", "height", "K", "T_BC") if k not in record]
    if missing:
        raise InputError(where, f"camera lacks {', '.join(missing)}")
    try:
        width, height = int(record["width"]), int(record["height"])
    except (TypeError, ValueError):
        width = height = 0
    if width < 1 or height < 1:
        raise InputError(where, f"camera image size must be >= 1 px, got {record['width']} x {record['height']}")
    K, T = _matrix(record["K"], (3, 3), where, "K"), _matrix(record["T_BC"], (4, 4), where, "T_BC")
    if min(K[0, 0], K[1, 1]) <= 0:
        raise InputError(where, "camera K needs positive focal lengths")
    R = T[:3, :3]
    if not np.allclose(R.T @ R, np.eye(3), atol=1e-6) or np.linalg.det(R) <= 0 or not np.allclose(T[3], [0, 0, 0, 1]):
        raise InputError(where, "camera T_BC is no rigid motion (rotation and translation, last row 0 0 0 1)")
    dt = record.get("frame_dt")
    if dt is not None and not (isinstance(dt, (int, float)) and dt > 0):
        raise InputError(where, f"camera frame_dt must be a positive number of seconds, got {dt!r}")
    return CameraModel(str(record["name"]), K, width, height, T, str(record.get("source", record["name"])),
                       None if dt is None else float(dt))


__all__ = ["CAMERAS", "CAMERA_CLEARANCE", "CAMERA_NAMES", "CameraModel", "CameraSpec", "EUROC_CAM0", "FORWARD",
           "R_BC_FORWARD", "body_mount", "camera_from_record", "camera_spec", "check_camera", "forward_camera",
           "forward_intrinsics", "forward_rotation", "hang_below_body", "least_body_height", "named_camera",
           "preset_intrinsics", "preset_mount", "registered_camera", "scaled_intrinsics"]
