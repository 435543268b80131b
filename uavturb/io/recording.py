"""In-memory flight recording: the streams of the EuRoC-MAV layout (``recordings.md``).

Timestamps are integer nanoseconds (``int64``). Frames: world W (z up), rotor frame B (x
forward, y left, z up along the rotor axes), sensor frame S (the frame of the ground truth and
the IMU on disk; ``vehicle.yaml``'s ``T_BS`` is its pose in B). A :class:`Recording` holds its
ground truth and IMU in the frame named by ``Recording.frame``: ``"B"`` (what the readers
return and all physics uses) or ``"S"`` (as stored on disk). Quaternions ``w, x, y, z``, that
frame to world.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from uavturb.physics.vehicle import Vehicle


@dataclass
class GroundTruth:
    """``mav0/state_groundtruth_estimate0``: MoCap-grade state, shapes ``(N, ·)``."""

    t_ns: np.ndarray  # (N,) int64 ns
    p: np.ndarray  # (N, 3) m, position of the frame's origin (B or S) in W
    q: np.ndarray  # (N, 4) quaternion w, x, y, z, frame (B or S) to world
    v: np.ndarray  # (N, 3) m/s, velocity of the frame's origin in W
    b_w: np.ndarray  # (N, 3) rad/s, gyroscope bias in the frame
    b_a: np.ndarray  # (N, 3) m/s^2, accelerometer bias in the frame

    def __len__(self) -> int:
        return len(self.t_ns)


@dataclass
class Imu:
    """``mav0/imu0``: gyroscope and accelerometer, shapes ``(N, 3)``, in the recording's frame
    (``Recording.frame``; on disk in the IMU's own frame, which ``T_BS`` places in S)."""

    t_ns: np.ndarray  # (N,) int64 ns
    gyro: np.ndarray  # (N, 3) rad/s, angular velocity of the body, in the frame
    acc: np.ndarray  # (N, 3) m/s^2, specific force at the frame's origin, in the frame
    T_BS: np.ndarray | None = None  # (4, 4) IMU pose in S, from imu0/sensor.yaml (EuRoC: identity)
    rate_hz: float | None = None

    def __len__(self) -> int:
        return len(self.t_ns)


@dataclass
class Rotors:
    """``mav0/rotors0``: rotor speeds in ``vehicle.yaml`` order."""

    t_ns: np.ndarray  # (N,) int64 ns
    speeds: np.ndarray  # (N, n_rotors) rad/s, already multiplied by rotor_speed_scale

    def __len__(self) -> int:
        return len(self.t_ns)


@dataclass
class Battery:
    """``mav0/battery0``: battery voltage and, where logged, current (``recordings.md``)."""

    t_ns: np.ndarray  # (N,) int64 ns
    voltage: np.ndarray  # (N,) V
    current: np.ndarray | None = None  # (N,) A, None when the file has no current column

    def __len__(self) -> int:
        return len(self.t_ns)


@dataclass
class Camera:
    """``mav0/cam0``: pinhole intrinsics, pose on the body, and the frame list."""

    intrinsics: np.ndarray  # (4,) fu, fv, cu, cv [px]
    resolution: tuple[int, int]  # (width, height) px
    T_BS: np.ndarray  # (4, 4) camera pose in S (x_S = T_BS x_C), as in EuRoC's cam0/sensor.yaml
    distortion_model: str = "radial-tangential"
    distortion: np.ndarray = field(default_factory=lambda: np.zeros(4))
    t_ns: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    files: list[str] = field(default_factory=list)  # file names under cam0/data/
    rate_hz: float | None = None

    @property
    def K(self) -> np.ndarray:
        """3x3 intrinsic matrix."""
        fu, fv, cu, cv = self.intrinsics
        return np.array([[fu, 0.0, cu], [0.0, fv, cv], [0.0, 0.0, 1.0]])


@dataclass
class Poses:
    """``mav0/vicon0``: EuRoC vicon pose stream (position and attitude only)."""

    t_ns: np.ndarray  # (N,) int64 ns
    p: np.ndarray  # (N, 3) m
    q: np.ndarray  # (N, 4) w, x, y, z


@dataclass
class Recording:
    """One flight. Optional streams are ``None`` when absent from the folder.

    ``frame`` is ``"B"`` when ground truth and IMU are in the rotor frame (readers' default),
    ``"S"`` when they are as stored (in the sensor frame, ``vehicle.T_BS`` away from B).
    """

    vehicle: Vehicle
    ground_truth: GroundTruth
    imu: Imu | None = None
    rotors: Rotors | None = None
    points: np.ndarray | None = None  # (P, 3) float, scene points in W [m]
    cam0: Camera | None = None
    vicon: Poses | None = None
    battery: Battery | None = None
    path: Path | None = None
    frame: str = "B"
    read_notes: tuple[str, ...] = ()  # what the reader changed in the files' rows (merged repeated timestamps)
    label: str | None = None  # the name reports give it where its folder's name is not enough (reader.recording_labels)

    @property
    def t0_ns(self) -> int:
        """Time origin: the first ground-truth row (``t`` in reports is seconds since it)."""
        return int(self.ground_truth.t_ns[0])

    def seconds(self, t_ns: np.ndarray) -> np.ndarray:
        """Seconds since the first ground-truth row."""
        return (np.asarray(t_ns, dtype=np.int64) - self.t0_ns) * 1e-9

    @property
    def name(self) -> str:
        """The folder's name, or the :attr:`label` given it among recordings whose folders share a name."""
        if self.label is not None:
            return self.label
        return self.path.name if self.path is not None else self.vehicle.name
