"""What the sensors of ``recordings.md`` report on a simulated flight: motion capture (position,
attitude, velocity), IMU (gyroscope, accelerometer with biases and their random walks) and the
commanded rotor speeds, with the noise and quantisation of :class:`SensorNoise`
(:func:`sensor_readings`)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from uavturb.physics import quaternion as quat
from uavturb.physics.dynamics import IDX_Q, IDX_V, IDX_W


@dataclass(frozen=True)
class SensorNoise:
    """Sensor noise and biases of a synthetic recording. Discrete white-noise standard
    deviations follow from the densities as ``density * sqrt(1 / record_dt)``.

    Attributes
    ----------
    gyro_noise_density : rad/s/sqrt(Hz) (ADIS16448 of EuRoC: 1.7e-4)
    acc_noise_density : m/s^2/sqrt(Hz) (EuRoC: 2.0e-3)
    gyro_bias : (3,) rad/s, initial gyroscope bias in B
    acc_bias : (3,) m/s^2, initial accelerometer bias in B
    gyro_random_walk : rad/s^2/sqrt(Hz), bias random walk (0: constant bias; EuRoC: 1.9393e-5)
    acc_random_walk : m/s^3/sqrt(Hz) (0: constant bias; EuRoC: 3.0e-3)
    position_std : m, motion-capture position noise
    attitude_std : rad, motion-capture attitude noise (per axis, small rotation)
    velocity_std : m/s, noise on the recorded velocity
    rotor_quantum : rad/s, resolution of the recorded rotor speeds (0: none)
    """

    gyro_noise_density: float = 1.7e-4
    acc_noise_density: float = 2.0e-3
    gyro_bias: tuple[float, float, float] = (0.0, 0.0, 0.0)
    acc_bias: tuple[float, float, float] = (0.0, 0.0, 0.0)
    gyro_random_walk: float = 0.0
    acc_random_walk: float = 0.0
    position_std: float = 1e-3
    attitude_std: float = 5e-4
    velocity_std: float = 5e-3
    rotor_quantum: float = 1.0

    @classmethod
    def none(cls, **biases: Any) -> "SensorNoise":
        """No noise and no quantisation (biases may still be given: ``gyro_bias``, ``acc_bias``)."""
        return cls(gyro_noise_density=0.0, acc_noise_density=0.0, position_std=0.0, attitude_std=0.0,
                   velocity_std=0.0, rotor_quantum=0.0, **biases)


@dataclass
class SensorReadings:
    """What the sensors report at the record times: the true state with noise, biases and quantisation."""

    p: np.ndarray  # (K, 3) m in W, motion capture position
    q: np.ndarray  # (K, 4) quaternion w,x,y,z, B to W
    v: np.ndarray  # (K, 3) m/s in W
    gyro: np.ndarray  # (K, 3) rad/s in B
    acc: np.ndarray  # (K, 3) m/s^2 in B
    gyro_bias: np.ndarray  # (K, 3) rad/s
    acc_bias: np.ndarray  # (K, 3) m/s^2
    rotors: np.ndarray  # (K, N) rad/s, the commanded rotor speeds as reported (quantised)


def sensor_readings(X: np.ndarray, spec_force: np.ndarray, W_cmd: np.ndarray, noise: SensorNoise, seed: int,
                     dt_rec: float) -> SensorReadings:
    """Sensor readings of states ``X`` (K, 13) sampled every ``dt_rec`` [s], seeded by ``seed``."""
    K = len(X)
    rng = np.random.default_rng([int(seed), 7])
    rate = 1.0 / dt_rec

    def bias(b0: tuple[float, float, float], walk: float) -> np.ndarray:
        b = np.broadcast_to(np.asarray(b0, float), (K, 3)).copy()
        if walk > 0:
            steps = rng.normal(0.0, walk * np.sqrt(dt_rec), size=(K, 3))
            steps[0] = 0.0
            b += np.cumsum(steps, axis=0)
        return b

    b_w = bias(noise.gyro_bias, noise.gyro_random_walk)
    b_a = bias(noise.acc_bias, noise.acc_random_walk)
    gyro = X[:, IDX_W] + b_w + rng.normal(0.0, noise.gyro_noise_density * np.sqrt(rate), size=(K, 3))
    acc = spec_force + b_a + rng.normal(0.0, noise.acc_noise_density * np.sqrt(rate), size=(K, 3))
    p_meas = X[:, 0:3] + rng.normal(0.0, noise.position_std, size=(K, 3))
    q_meas = X[:, IDX_Q]
    if noise.attitude_std > 0:
        half = 0.5 * rng.normal(0.0, noise.attitude_std, size=(K, 3))
        q_meas = quat.normalize(quat.multiply(q_meas, np.concatenate([np.ones((K, 1)), half], axis=1)))
    v_meas = X[:, IDX_V] + rng.normal(0.0, noise.velocity_std, size=(K, 3))
    rotors = W_cmd if noise.rotor_quantum <= 0 else np.round(W_cmd / noise.rotor_quantum) * noise.rotor_quantum
    return SensorReadings(p_meas, q_meas, v_meas, gyro, acc, b_w, b_a, rotors)
