"""EuRoC ``sensor.yaml`` files: the camera (``cam0``) and IMU (``imu0``) descriptions.

Both hold ``T_BS`` (sensor to body, a 4x4 ``{cols, rows, data}`` matrix) and ``rate_hz``;
a camera adds its pinhole intrinsics, resolution and distortion, an IMU its noise
densities and random walks. Readers validate and raise :class:`InputError` naming the
file and the key; writers are atomic.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from uavturb.errors import InputError
from uavturb.io.euroc_csv import write_atomic
from uavturb.io.recording import Camera
from uavturb.io.yaml_mapping import parse_yaml_mapping, read_yaml_text
from uavturb.physics.vehicle import is_finite_number

IMU_NOISE_KEYS = ("gyroscope_noise_density", "gyroscope_random_walk",
                  "accelerometer_noise_density", "accelerometer_random_walk")


@dataclass
class ImuSensor:
    """``imu0/sensor.yaml``: pose on the body, rate and noise (``None`` where absent).

    Noise densities are in rad/s/sqrt(Hz) (gyroscope) and m/s^2/sqrt(Hz) (accelerometer);
    random walks in rad/s^2/sqrt(Hz) and m/s^3/sqrt(Hz), as in EuRoC.
    """

    T_BS: np.ndarray  # (4, 4) sensor to body
    rate_hz: float | None = None
    gyroscope_noise_density: float | None = None
    gyroscope_random_walk: float | None = None
    accelerometer_noise_density: float | None = None
    accelerometer_random_walk: float | None = None


# --- reading ---------------------------------------------------------------------------


def _load(path: Path) -> dict[str, Any]:
    text = read_yaml_text(path)
    # OpenCV-style files start with '%YAML:1.0', which is not a YAML 1.1 directive
    text = "\n".join("" if s.startswith("%YAML") else s for s in text.splitlines())
    return parse_yaml_mapping(text, path, expected="a mapping of sensor keys")


def _number(path: Path, d: dict, key: str, *, required: bool, positive: bool = True) -> float | None:
    v = d.get(key)
    if v is None:
        if required:
            raise InputError(path, f"missing required key '{key}'")
        return None
    if not is_finite_number(v):
        raise InputError(path, f"key '{key}' must be a finite number, got {v!r}")
    if positive and float(v) <= 0:
        raise InputError(path, f"key '{key}' must be positive, got {v!r}")
    return float(v)


def _numbers(path: Path, d: dict, key: str, length: int, *, label: str | None = None) -> np.ndarray:
    label = label or key
    v = d.get(key)
    if v is None:
        raise InputError(path, f"missing required key '{label}'")
    if not isinstance(v, (list, tuple)) or len(v) != length:
        raise InputError(path, f"key '{label}' must be a list of {length} numbers, got {v!r}")
    if not all(is_finite_number(x) for x in v):
        raise InputError(path, f"key '{label}' holds a non-numeric or non-finite value")
    return np.asarray(v, dtype=np.float64)


def _transform(path: Path, d: dict, key: str = "T_BS") -> np.ndarray:
    """A ``{cols: 4, rows: 4, data: [16]}`` rigid transform (row-major)."""
    m = d.get(key)
    if m is None:
        raise InputError(path, f"missing required key '{key}'")
    if not isinstance(m, dict) or m.get("cols") != 4 or m.get("rows") != 4:
        raise InputError(path, f"key '{key}' must be a mapping with cols: 4, rows: 4 and data: [16 numbers]")
    T = _numbers(path, m, "data", 16, label=f"{key}.data").reshape(4, 4)
    R = T[:3, :3]
    if not np.allclose(T[3], [0, 0, 0, 1], atol=1e-9) or not np.allclose(R @ R.T, np.eye(3), atol=1e-3) \
            or np.linalg.det(R) < 0:
        raise InputError(path, f"key '{key}' is not a rigid transform (rotation and translation, last row 0 0 0 1)")
    return T


def read_camera_yaml(path: str | Path) -> Camera:
    """Read ``cam0/sensor.yaml`` into a :class:`Camera` without frames.

    Required keys: ``T_BS``, ``resolution`` ([width, height] px), ``intrinsics``
    ([fu, fv, cu, cv] px); ``camera_model`` must be ``pinhole`` when present. Optional:
    ``rate_hz``, ``distortion_model`` (default ``radial-tangential``),
    ``distortion_coefficients`` (default zeros).
    """
    path = Path(path)
    d = _load(path)
    if d.get("sensor_type", "camera") != "camera":
        raise InputError(path, f"key 'sensor_type' is '{d['sensor_type']}', expected 'camera'")
    if d.get("camera_model", "pinhole") != "pinhole":
        raise InputError(path, f"key 'camera_model' is '{d['camera_model']}'; only 'pinhole' is supported")
    res = _numbers(path, d, "resolution", 2)
    if np.any(res <= 0) or np.any(res != np.round(res)):
        raise InputError(path, f"key 'resolution' must be two positive integers, got {d['resolution']!r}")
    intr = _numbers(path, d, "intrinsics", 4)
    if intr[0] <= 0 or intr[1] <= 0:
        raise InputError(path, "key 'intrinsics' must hold positive focal lengths fu, fv")
    model = d.get("distortion_model", "radial-tangential")
    if not isinstance(model, str):
        raise InputError(path, f"key 'distortion_model' must be a string, got {model!r}")
    dist = d.get("distortion_coefficients")
    if dist is None:
        dist = np.zeros(4)
    elif not isinstance(dist, (list, tuple)) or not dist:
        raise InputError(path, "key 'distortion_coefficients' must be a list of numbers")
    else:
        dist = _numbers(path, d, "distortion_coefficients", len(dist))
    return Camera(intrinsics=intr, resolution=(int(res[0]), int(res[1])), T_BS=_transform(path, d),
                  distortion_model=model, distortion=dist, rate_hz=_number(path, d, "rate_hz", required=False))


def read_sensor_pose(path: str | Path) -> np.ndarray:
    """``T_BS`` (4, 4) of any EuRoC ``sensor.yaml`` (e.g. ``vicon0/sensor.yaml``): the sensor's pose
    in EuRoC's body frame, which is the recordings' sensor frame S (``x_S = T_BS x_sensor``)."""
    path = Path(path)
    return _transform(path, _load(path))


def read_imu_yaml(path: str | Path) -> ImuSensor:
    """Read ``imu0/sensor.yaml``: ``T_BS`` required; rate and noise keys optional."""
    path = Path(path)
    d = _load(path)
    if d.get("sensor_type", "imu") != "imu":
        raise InputError(path, f"key 'sensor_type' is '{d['sensor_type']}', expected 'imu'")
    noise = {k: _number(path, d, k, required=False, positive=False) for k in IMU_NOISE_KEYS}
    for k, v in noise.items():
        if v is not None and v < 0:
            raise InputError(path, f"key '{k}' must not be negative, got {v!r}")
    return ImuSensor(T_BS=_transform(path, d), rate_hz=_number(path, d, "rate_hz", required=False), **noise)


# --- writing ---------------------------------------------------------------------------


def _matrix(T: np.ndarray) -> dict[str, Any]:
    return {"cols": 4, "rows": 4, "data": [float(x) for x in np.asarray(T, dtype=float).reshape(16)]}


def _dump(path: str | Path, d: dict[str, Any], comment: str) -> None:
    write_atomic(path, f"# {comment}\n" + yaml.safe_dump(d, sort_keys=False, default_flow_style=None))


def write_camera_yaml(path: str | Path, cam: Camera) -> None:
    """Write ``cam0/sensor.yaml`` (EuRoC keys) for ``cam`` atomically."""
    d: dict[str, Any] = {"sensor_type": "camera", "comment": "uavturb camera", "T_BS": _matrix(cam.T_BS)}
    if cam.rate_hz is not None:
        d["rate_hz"] = float(cam.rate_hz)
    d["resolution"] = [int(cam.resolution[0]), int(cam.resolution[1])]
    d["camera_model"] = "pinhole"
    d["intrinsics"] = [float(x) for x in cam.intrinsics]
    d["distortion_model"] = cam.distortion_model
    d["distortion_coefficients"] = [float(x) for x in cam.distortion]
    _dump(path, d, "Camera: EuRoC sensor.yaml; T_BS is camera to body")


def write_imu_yaml(path: str | Path, sensor: ImuSensor) -> None:
    """Write ``imu0/sensor.yaml`` (EuRoC keys; absent values left out) atomically."""
    d: dict[str, Any] = {"sensor_type": "imu", "comment": "uavturb IMU", "T_BS": _matrix(sensor.T_BS)}
    if sensor.rate_hz is not None:
        d["rate_hz"] = float(sensor.rate_hz)
    for k in IMU_NOISE_KEYS:
        if getattr(sensor, k) is not None:
            d[k] = float(getattr(sensor, k))
    _dump(path, d, "IMU: EuRoC sensor.yaml; T_BS is IMU to body")
