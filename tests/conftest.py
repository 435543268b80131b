"""Shared fixtures: a small synthetic recording with every stream of ``recordings.md``."""

from __future__ import annotations

import numpy as np
import pytest

from uavturb.io.recording import Camera, GroundTruth, Imu, Poses, Recording, Rotors
from uavturb.physics import quaternion as quat
from uavturb.physics.vehicle import HEXAROTOR

T0_NS = 1403636579763555584  # a real EuRoC timestamp: 19 digits, beyond float64 precision


def make_recording(duration: float = 2.0, seed: int = 0) -> Recording:
    """Every stream filled, at different rates and offsets; rotor scale != 1."""
    rng = np.random.default_rng(seed)
    vehicle = HEXAROTOR.with_params(rotor_speed_scale=4.104)
    t = T0_NS + np.arange(int(duration * 200)) * 5_000_000
    s = (t - T0_NS) * 1e-9
    p = np.stack([np.sin(s), np.cos(0.5 * s), 1 + 0.1 * s], axis=1)
    q = quat.from_euler(0.1 * np.sin(s), 0.05 * s, 3.0 * s)
    n = len(t)
    gt = GroundTruth(t_ns=t, p=p, q=q, v=rng.normal(size=(n, 3)), b_w=rng.normal(size=(n, 3)) * 1e-3,
                     b_a=rng.normal(size=(n, 3)) * 1e-2)
    t_imu = t + 2_500_000
    imu = Imu(t_ns=t_imu, gyro=rng.normal(size=(n, 3)), acc=rng.normal(size=(n, 3)) + [0, 0, 9.81],
              T_BS=np.eye(4), rate_hz=200.0)
    t_rot = T0_NS + 1_234_567 + np.arange(int(duration * 100)) * 10_000_000
    rotors = Rotors(t_ns=t_rot, speeds=rng.uniform(400, 800, size=(len(t_rot), 6)))
    T_BS = np.eye(4)
    T_BS[:3, :3] = quat.to_rotation_matrix(quat.from_euler(0.0, np.pi / 2, 0.1))
    T_BS[:3, 3] = [0.1, 0.0, -0.02]
    t_cam = T0_NS + np.arange(int(duration * 20)) * 50_000_000
    cam = Camera(intrinsics=np.array([458.654, 457.296, 367.215, 248.375]), resolution=(752, 480), T_BS=T_BS,
                 distortion=np.array([-0.28340811, 0.07395907, 0.00019359, 1.76187114e-05]), t_ns=t_cam,
                 files=[f"{x}.png" for x in t_cam], rate_hz=20.0)
    vicon = Poses(t_ns=t[::2].copy(), p=p[::2] + 1e-4, q=q[::2].copy())
    points = rng.uniform(-3, 3, size=(500, 3))
    return Recording(vehicle=vehicle, ground_truth=gt, imu=imu, rotors=rotors, points=points, cam0=cam, vicon=vicon)


@pytest.fixture
def recording() -> Recording:
    return make_recording()


@pytest.fixture(autouse=True, scope="session")
def _private_mlflow_store(tmp_path_factory):
    """No test writes to the working directory's MLflow store: a session-wide temporary one is the
    default; tests that need their own set ``MLFLOW_TRACKING_URI`` themselves."""
    import os

    root = tmp_path_factory.mktemp("mlflow-default")
    old = os.environ.get("MLFLOW_TRACKING_URI")
    os.environ["MLFLOW_TRACKING_URI"] = f"sqlite:///{root / 'mlflow.db'}"
    yield
    if old is None:
        os.environ.pop("MLFLOW_TRACKING_URI", None)
    else:
        os.environ["MLFLOW_TRACKING_URI"] = old


@pytest.fixture(scope="module")
def module_mlflow_store(tmp_path_factory):
    """One temporary MLflow store (and working directory, for ``mlruns/``) per test module:
    creating a SQLite store takes seconds. Yields its tracking URI."""
    root = tmp_path_factory.mktemp("mlflow")
    with pytest.MonkeyPatch.context() as mp:
        mp.chdir(root)
        uri = f"sqlite:///{root / 'mlflow.db'}"
        mp.setenv("MLFLOW_TRACKING_URI", uri)
        yield uri
