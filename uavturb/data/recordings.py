"""EuRoC-layout recordings as evaluation sequences for the height model (paper, "Experimental setup").

EuRoC's vehicles carry no depth camera. As the paper does, every camera frame's depth image
is the room's point cloud (``pointcloud0``) projected into ``cam0`` with its intrinsics and
extrinsics (:func:`uavturb.scene.projection.depth_from_points`). ``cam0/sensor.yaml``'s
``T_BS`` is the camera's pose in the sensor frame S (EuRoC), and the recording's state is in
the rotor frame B, so the camera's pose in W is ``T_WB T_BS(vehicle.yaml) T_SC(cam0)``; the true height ``d_down``
(body origin over the surface below, m) is measured on the same cloud
(:class:`uavturb.scene.heights.SurfaceIndex`); the ground-truth turbulence ``f_a`` is the
world-z component of the residual force of the identified model
(:func:`uavturb.sysid.residuals.residual_forces`, N), with the accelerometer's bias, measured against the
motion capture (:func:`uavturb.sysid.accelerometer.flight_accel_bias`), taken off its specific force.

Choices (ours):

- **Frame times**: ``cam0/data.csv``'s timestamps when the recording lists frames, else every
  ``frame_dt`` (evaluate gives the model camera's frame period, the training data's; default:
  ``cam0/sensor.yaml``'s ``rate_hz``, else 0.05 s, 20 Hz) over the span all streams cover.
- **Image and camera**: the model's own camera (:class:`uavturb.scene.camera.CameraModel`, carried
  by the trained model), at its image size. A recording with a ``cam0`` is seen through it instead:
  cropped to the centred crop of the model's image aspect and scaled to its size (intrinsics
  changed accordingly, no resampling of pixels: the cloud is projected straight at the target size).
  Flights without cam0 (``uavturb generate flight``) are seen through the model's camera itself.
- **GT f_a per frame**: the residual (IMU rate) averaged over ``[t - w/2, t + w/2)`` with
  ``w = min(frame period, gt_window_s = 0.05 s)`` (a centred box filter that removes most of
  the accelerometer's white noise without delay); heights and rotor speeds are taken at the
  frame instant.
- **Airborne frames**: ``airborne`` marks frames whose rotor thrust ``k_T sum(Omega^2)`` is at
  least ``0.3 m g`` (:data:`AIRBORNE_THRUST_FRACTION`); below that the vehicle sits on the
  ground or a table (real flights start and end so) and the residual holds the contact
  force, not turbulence. Evaluations leave those frames out.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np
import torch

from uavturb.errors import InputError
from uavturb.gap.preparation import contact_masks
from uavturb.io import align
from uavturb.io.body_frame import to_body
from uavturb.io.reader import POINTS_PLY
from uavturb.io.recording import Recording
from uavturb.physics import quaternion as quat
from uavturb.physics.dynamics import GRAVITY
from uavturb.physics.vehicle import Vehicle
from uavturb.progress import progress_bar
from uavturb.scene.camera import CameraModel, scaled_intrinsics
from uavturb.scene.heights import SurfaceIndex
from uavturb.scene.projection import camera_pose_world, depth_from_points, prepare_cloud
from uavturb.sysid.accelerometer import flight_accel_bias
from uavturb.sysid.flight_data import FlightData, flight_data
from uavturb.sysid.residuals import residual_forces

DEFAULT_FRAME_DT = 0.05  # s: the training shards' 20 Hz camera
AIRBORNE_THRUST_FRACTION = 0.3  # frames with less rotor thrust than this share of the weight are on the ground


def cam0_pose_in_body(rec: Recording) -> np.ndarray:
    """``T_BC = T_BS(vehicle.yaml) T_SC(cam0/sensor.yaml)`` (4, 4): the camera's pose in the frame of
    the recording's state (B; for a recording kept in S, ``T_SC`` alone)."""
    T_SC = np.asarray(rec.cam0.T_BS, float)
    return rec.vehicle.T_BS_matrix @ T_SC if rec.frame == "B" else T_SC


def cam0_camera(rec: Recording, width: int, height: int | None = None) -> CameraModel:
    """``cam0`` as the centred crop of aspect ``width : height`` (default square) scaled to that size,
    posed in B (:func:`cam0_pose_in_body`); the crop and scale of the registered cameras
    (:func:`uavturb.scene.camera.scaled_intrinsics`)."""
    height = width if height is None else height
    cam = rec.cam0
    K = scaled_intrinsics(cam.intrinsics, (int(cam.resolution[0]), int(cam.resolution[1])), width, height)
    return CameraModel("cam0", K, int(width), int(height), cam0_pose_in_body(rec),
                       "cam0/sensor.yaml (centre square, scaled)" if width == height
                       else "cam0/sensor.yaml (centre crop, scaled)")


def recording_camera(rec: Recording, camera: CameraModel) -> CameraModel:
    """The camera a recording is seen through for a model with ``camera``: the recording's ``cam0``
    at the model's image size when it has one, else the model's camera itself."""
    return cam0_camera(rec, camera.width, camera.height) if rec.cam0 is not None else camera


@dataclass
class RecordingSequence:
    """One flight at camera frames, ``K`` frames.

    Attributes
    ----------
    name : recording name
    t : (K,) s since the recording's first ground-truth row
    depth : (K, S, S) float32 z-depth [m], 0 where no data
    d : (K,) true height over the surface below [m] (``inf``: none)
    fa : (K,) ground-truth turbulence, world z [N]
    sum_omega2 : (K,) ``sum_i Omega_i^2`` [rad^2/s^2]
    rotor_speeds : (K, N) rad/s
    p : (K, 3) body position in W [m]
    camera : CameraModel used
    airborne : (K,) bool, rotor thrust >= 0.3 m g (else on the ground: contact forces)
    """

    name: str
    t: np.ndarray
    depth: np.ndarray
    d: np.ndarray
    fa: np.ndarray
    sum_omega2: np.ndarray
    rotor_speeds: np.ndarray
    p: np.ndarray
    camera: CameraModel
    airborne: np.ndarray

    def __len__(self) -> int:
        return len(self.t)


def box_average(t_src: np.ndarray, x: np.ndarray, t_dst: np.ndarray, width: float) -> np.ndarray:
    """Mean of the samples ``x`` (at ``t_src``) within ``[t - width/2, t + width/2)`` of each ``t_dst``.

    Falls back to linear interpolation where a window holds no sample.
    """
    c = np.concatenate([[0.0], np.cumsum(x)])
    lo = np.searchsorted(t_src, t_dst - width / 2, side="left")
    hi = np.searchsorted(t_src, t_dst + width / 2, side="left")
    n = hi - lo
    out = np.interp(t_dst, t_src, x)
    ok = n > 0
    out[ok] = (c[hi[ok]] - c[lo[ok]]) / n[ok]
    return out


def recording_sequence(rec: Recording, vehicle: Vehicle, camera: CameraModel, *, frame_dt: float | None = None,
                       gt_window_s: float = 0.05,
                       speeds_read: Callable[[FlightData], FlightData] | None = None,
                       progress: bool = False) -> RecordingSequence:
    """A recording as depth frames, true heights and ground-truth ``f_a`` (see the module docstring).

    Parameters
    ----------
    rec : recording with ground truth, rotor speeds and a point cloud
    vehicle : the identified model (``k_T``, ``k_M``, inertia) the residual is computed with
    camera : the model's camera (its image size; the camera itself where there is no cam0:
        :func:`recording_camera`)
    frame_dt : s, frame period where the recording lists no cam0 frames (default: cam0's
        ``rate_hz``, else 0.05)
    gt_window_s : s, longest averaging window of the ground-truth f_a
    speeds_read : the flight data with its rotor speeds read as ``vehicle`` was identified on them
        (:meth:`~uavturb.sysid.identification.Identification.flight_data_read`: commands moved by an idle speed,
        lagged by the motors' lag); None: as recorded. The ground-truth f_a, ``sum_omega2`` and ``rotor_speeds``
        are read on them
    progress : print frames/s to stderr

    Raises
    ------
    InputError : no point cloud or rotor speeds (naming the file), no frame inside the span.
    """
    rec = to_body(rec)  # state in B (no-op for the readers' recordings): the camera is posed in B
    where = rec.path or rec.name
    if rec.points is None:
        raise InputError(f"{where}/{POINTS_PLY}", "point cloud needed (depth images and heights come from it)")
    fd = flight_data(rec, heights=False)
    if speeds_read is not None:
        fd = speeds_read(fd)
    (contact,), _ = contact_masks([fd], vehicle, [str(where)])  # the bias is measured in flight
    bias = flight_accel_bias(fd, ~contact)  # an accelerometer's bias, measured against the motion capture
    res = residual_forces(fd, vehicle, accel_bias=None if bias is None else bias.b)
    t0, t1 = int(fd.t_ns[0]), int(fd.t_ns[-1])
    if rec.cam0 is not None and len(rec.cam0.t_ns):
        t_ns = np.asarray(rec.cam0.t_ns, np.int64)
        t_ns = t_ns[(t_ns >= t0) & (t_ns <= t1)]
        dt = float(np.median(np.diff(t_ns))) * 1e-9 if len(t_ns) > 1 else DEFAULT_FRAME_DT
    else:  # cam0 described by its sensor.yaml alone: its own rate, where the caller gives none
        own = 1.0 / float(rec.cam0.rate_hz) if rec.cam0 is not None and rec.cam0.rate_hz else DEFAULT_FRAME_DT
        dt = float(own if frame_dt is None else frame_dt)
        if not dt > 0:
            raise InputError("frame_dt", f"must be positive, got {dt}")
        t_ns = np.arange(t0, t1 + 1, int(round(dt * 1e9)), dtype=np.int64)
    if len(t_ns) == 0:
        raise InputError(f"{where}/mav0/cam0/data.csv", "no camera frame inside the span of the other streams")
    t = (t_ns - rec.t0_ns) * 1e-9
    p = align.interpolate(fd.t_ns, fd.p, t_ns)
    q = align.interpolate_quaternions(fd.t_ns, fd.q, t_ns)
    rotors = align.interpolate(fd.t_ns, fd.rotor_speeds, t_ns)
    fa = box_average(fd.t, res.force[:, 2], t, min(dt, gt_window_s))
    # the law's height: the rotor plane's over the surface below (recordings.md, "Heights over surfaces")
    d = SurfaceIndex(rec.points).d_down(rec.vehicle.rotor_plane_positions(p, quat.to_rotation_matrix(q)))

    camera = recording_camera(rec, camera)
    cloud = prepare_cloud(rec.points)
    T_WC = camera_pose_world(q, p, camera.T_BC)
    depth = np.empty((len(t_ns), camera.height, camera.width), np.float32)
    with progress_bar(len(t_ns), f"{rec.name}: depth frames", "frames", disable=not progress) as bar:
        for k in range(len(t_ns)):
            depth[k] = depth_from_points(cloud, T_WC[k], camera.K, camera.width, camera.height)
            bar.update(1)
    S = (rotors**2).sum(1)
    airborne = vehicle.thrust_coefficient * S >= AIRBORNE_THRUST_FRACTION * vehicle.mass * GRAVITY
    return RecordingSequence(name=rec.name, t=t, depth=depth, d=d, fa=fa, sum_omega2=S, rotor_speeds=rotors, p=p,
                             camera=camera, airborne=airborne)


class RecordingWindowsDataset:
    """Windows of ``window`` consecutive frames of :class:`RecordingSequence` s, as the shard windows.

    Items: ``depth (window, 1, S, S)``, ``d``, ``fa``, ``sum_omega2`` ``(window,)`` float32 tensors
    (the keys :class:`~uavturb.systems.HeightModule` reads), so ``Trainer.test`` runs on flights.
    Windows holding a frame with no surface below (``d = inf``) are left out.
    """

    def __init__(self, sequences: list[RecordingSequence], window: int = 8, stride: int = 1):
        if window < 1 or stride < 1:
            raise InputError("window", f"window and stride must be >= 1, got {window}, {stride}")
        self.sequences, self.window = sequences, window
        self.index = [(i, s) for i, seq in enumerate(sequences) for s in range(0, len(seq) - window + 1, stride)
                      if np.all(np.isfinite(seq.d[s:s + window]))]

    def __len__(self) -> int:
        return len(self.index)

    def __getitem__(self, k: int) -> dict:
        i, s = self.index[k]
        seq, e = self.sequences[i], s + self.window
        return {"depth": torch.from_numpy(np.ascontiguousarray(seq.depth[s:e, None])),
                "d": torch.from_numpy(seq.d[s:e].astype(np.float32)),
                "fa": torch.from_numpy(seq.fa[s:e].astype(np.float32)),
                "sum_omega2": torch.from_numpy(seq.sum_omega2[s:e].astype(np.float32))}


__all__ = ["RecordingSequence", "RecordingWindowsDataset", "box_average", "cam0_camera", "cam0_pose_in_body",
           "recording_camera", "recording_sequence", "DEFAULT_FRAME_DT", "AIRBORNE_THRUST_FRACTION"]

