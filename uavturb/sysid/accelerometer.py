"""The accelerometer's bias, measured against motion capture (no model of the thrust in it).

Along the thrust axis a constant bias ``b_z`` is nearly the same regressor as the thrust coefficient at
hover: a fit that leaves both free lets them trade (``k_T`` 8-57 % low, ``b_z`` 0.65-5.8 m/s^2 on real
flights). Where a recording has an IMU *and* motion capture, the bias is instead what the accelerometer
reads beyond the specific force the motion capture shows, ``b = mean(a_imu - R^T (v_dot + g e_z))`` in B,
with its standard error from the spread of :data:`BLOCK_S` block means. ``identify``, ``gap`` and
``residuals`` all take it from here, so they agree.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from uavturb.numerics.blocks import block_labels, block_mean_and_se
from uavturb.physics import quaternion as quat
from uavturb.physics.constants import GRAVITY
from uavturb.sysid.flight_data import FlightData

#: s, blocks whose means are taken as independent (errors of the bias and the thrust levels)
BLOCK_S = 1.0


@dataclass(frozen=True)
class AnchoredBias:
    """Accelerometer bias of one recording, measured against motion capture.

    Attributes
    ----------
    b : (3,) m/s^2 in B, what the accelerometer reads beyond the motion capture's specific force
    stderr : (3,) m/s^2, from the spread of 1 s block means
    n : rows used
    """

    b: np.ndarray
    stderr: np.ndarray
    n: int


def mocap_specific_force(R: np.ndarray, dv: np.ndarray) -> np.ndarray:
    """(K, 3) m/s^2 in B, the specific force motion capture shows: ``R^T (v_dot + g e_z)``.

    Parameters
    ----------
    R : (K, 3, 3) body to world; dv : (K, 3) m/s^2, derivative of the world velocity
    """
    return np.einsum("kji,kj->ki", R, dv + np.array([0.0, 0.0, GRAVITY]))


def anchored_bias(t: np.ndarray, R: np.ndarray, acc: np.ndarray, dv: np.ndarray, use: np.ndarray) -> AnchoredBias:
    """The accelerometer bias as the mean of ``acc - R^T (dv + g e_z)`` over the rows ``use``.

    Parameters
    ----------
    t : (K,) s
    R : (K, 3, 3) body to world
    acc : (K, 3) m/s^2, specific force in B (state file's biases already removed)
    dv : (K, 3) m/s^2, smoothed derivative of the motion-capture velocity in W
    use : (K,) bool, rows in flight (no ground contact; the filter's edges out)
    """
    diff = (acc - mocap_specific_force(R, dv))[use]
    if len(diff) == 0:
        return AnchoredBias(np.zeros(3), np.full(3, np.inf), 0)
    mean, se = block_mean_and_se(diff, block_labels(t[use], BLOCK_S))
    return AnchoredBias(mean, se, int(use.sum()))


def flight_accel_bias(fd: FlightData, in_flight: np.ndarray) -> AnchoredBias | None:
    """The accelerometer bias of one aligned flight over its rows ``in_flight`` (K,) bool whose motion-capture
    derivative is defined (``None`` without an IMU). Rows on the ground are to be left out: a touch-down's impact
    is in the accelerometer and smoothed out of the motion capture's derivative (a take-off and landing of a 32 g
    vehicle read a z bias of -0.27 m/s^2 with them, +0.018 in flight)."""
    if fd.acc is None:
        return None
    use = np.asarray(in_flight, bool) & np.all(np.isfinite(fd.dv), axis=1)
    return anchored_bias(fd.t, quat.to_rotation_matrix(fd.q), fd.acc, fd.dv, use)
