"""Where the recorded motion is measured from: a lever arm to the centre of mass, read from the rotation.

The physics works at B's origin, the centre of mass: an accelerometer there reads the thrust and the
external force alone (``recordings.md``, "Rotor forces and torques"). Motion capture tracks whatever origin
its rigid body was given (often the markers' centroid, on top of the frame) and an IMU sits where the board
is; ``vehicle.yaml``'s ``T_BS`` says where that is in B, and where it is absent the two are taken to
coincide. Where they do not, every recorded acceleration carries the rotation's, at a point ``r`` from the
centre of mass (in B)::

    a_S = a_B + alpha x r + omega x (omega x r)                          [m/s^2]

which no aerodynamic law explains: a 2.5 kg hexarotor's motion capture 8 cm above its centre of mass, read
as the centre, made the gap finder read an idle speed of 59 % of the hover speed into its rotor commands and
a ground effect's mu 5.3 +- 1.8 where it was 2; a 10 cm forward offset cost its rotor drag and ten times its
held-out error.

:func:`lever_arm` reads ``r`` from the specific force along x_B and y_B (the IMU's, or the motion capture's
acceleration rotated into B) as a linear least-squares fit, without any thrust model: there the specific force
is a constant (a thrust-axis tilt, a push), rotor drag (``Wsum v_B``) and ``(L(omega, alpha) r)_xy`` with
``L = [alpha]x + [omega]x [omega]x``. Roll and pitch accelerations, which every flight's attitude control
makes, pin the height ``r_z`` to a millimetre or less (``alpha x r`` is horizontal for a vertical ``r``): on
the hexarotor above, 8.1 +- 0.03 cm. Its errors are the delete-one jackknife's over :data:`BLOCK_S` blocks.

Only the height is acted on (the streams moved to the centre of mass: :func:`uavturb.io.body_frame.moved_origin`),
where it is decisive (:attr:`LeverArm.decisive`). The components across are read too, but only yaw
acceleration and the centripetal terms carry them (the z_B axis would, through ``alpha_y r_x``, but that is
also what rotors of slightly different thrust per speed squared give as the vehicle pitches, so it is not
read), and on real Crazyflies, whose boards lie within a centimetre of the centre, they read 2-10 cm at up to
5 errors, changing sign between flights of one vehicle; the height reads -0.3 to -1.3 cm there, under
:data:`PRACTICAL_M`, and is left alone. A height whose accelerations stay under :data:`PRACTICAL_ACCEL` is left
alone too (gentle flights barely rotate: there the reading is weak, and nothing it could move matters).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from uavturb.io.consistency import FLIGHT_SHARE
from uavturb.numerics.blocks import block_labels, jackknife_se
from uavturb.physics import frames
from uavturb.physics import quaternion as quat
from uavturb.physics.constants import GRAVITY
from uavturb.sysid.flight_data import FlightData

#: s, the blocks whose jackknife gives the lever arm's errors
BLOCK_S = 1.0
#: errors from zero at which a lever arm's largest component is read from the motion
DECISIVE_Z = 5.0
#: m, the smallest lever arm worth moving the streams for (Crazyflies' boards read 3-8 mm from the centre)
PRACTICAL_M = 0.02
#: m/s^2, the smallest root mean square of the rotation's accelerations at the lever arm worth moving the streams
#: for (half a percent of gravity: a 2.5 kg hexarotor's brisk flight with its motion capture 8-10 cm off reads 0.10;
#: gentle passes make so little angular acceleration that a reading of 5 +- 1 cm there moves nothing, 0.006)
PRACTICAL_ACCEL = 0.05
#: blocks a reading needs
MIN_BLOCKS = 10


@dataclass(frozen=True)
class LeverArm:
    """The point the streams are measured at, from the centre of mass, beyond ``vehicle.yaml``'s ``T_BS``.

    Attributes
    ----------
    r_m : (3,) m, in B, as read
    stderr_m : (3,) m, block jackknife
    accel_rms : m/s^2, the rotation's accelerations at the height ``r_m[2]`` on the z_B axis (root mean square
        over the rows read)
    rows : rows read (in flight)
    decisive : the height ``r_m[2]`` is read (:data:`DECISIVE_Z` errors from zero), at least :data:`PRACTICAL_M`
        and its accelerations matter (:data:`PRACTICAL_ACCEL`); the components across are never decisive (module
        docstring)
    """

    r_m: np.ndarray
    stderr_m: np.ndarray
    accel_rms: float
    rows: int
    decisive: bool

    @property
    def move_m(self) -> np.ndarray:
        """(3,) m, what the streams are moved by where the reading is decisive: its height alone."""
        return np.array([0.0, 0.0, float(self.r_m[2])])

    def as_dict(self) -> dict:
        return {"r_m": [float(x) for x in self.r_m], "stderr_m": [float(x) for x in self.stderr_m],
                "moved_m": [float(x) for x in self.move_m] if self.decisive else None,
                "accel_rms_m_s2": self.accel_rms, "rows": self.rows, "decisive": self.decisive}

    def text(self) -> str:
        """``8.1 +- 0.03 cm above the centre of mass (across, ...: 6, -0.39 +- 0.1, 0.1 cm, ...)``"""
        r, se = 100 * self.r_m, 100 * self.stderr_m
        return (f"{abs(r[2]):.2g} +- {se[2]:.1g} cm {'above' if r[2] > 0 else 'below'} the centre of mass (across, "
                f"along x_B and y_B: {r[0]:.2g}, {r[1]:.2g} +- {se[0]:.1g}, {se[1]:.1g} cm, which rotation reads too "
                "weakly to use)")


def _per_metre(omega_B: np.ndarray, alpha_B: np.ndarray) -> np.ndarray:
    """(K, 3, 3) m/s^2 per m: column ``j`` holds the rotation's accelerations of a point 1 m along B's axis ``j``
    (:func:`uavturb.physics.frames.lever_arm_acceleration`, linear in the lever arm), so ``L @ r`` is that of ``r``."""
    columns = []
    for j in range(3):
        T = np.eye(4)
        T[j, 3] = 1.0
        columns.append(frames.lever_arm_acceleration(omega_B, alpha_B, T))
    return np.stack(columns, axis=2)


#: rows whose regressors are built at once: a 10^6-row recording's, built whole and copied twice, peaked 426 MB above
#: its flight data; a chunk's temporaries (attitudes, accelerations per metre) stay small, the kept rows' design grows
DESIGN_CHUNK = 1 << 16


def _design(fd: FlightData, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The regressors (K', 2, 7) and specific force along x_B and y_B (K', 2) [m/s^2] of the rows ``rows`` (K,) bool
    where they are finite, the z_B column of the rotation's accelerations per metre of lever arm (K', 3) and those
    rows' indices (K',): unknowns ``r`` (3), a constant per axis (2) and rotor drag along each (2). Built
    :data:`DESIGN_CHUNK` rows at a time into arrays for the kept rows only (each row's values as built whole)."""
    n = int(rows.sum())
    X, f_xy, L_z, kept = np.empty((n, 2, 7)), np.empty((n, 2)), np.empty((n, 3)), np.empty(n, np.int64)
    done = 0
    for a in range(0, len(rows), DESIGN_CHUNK):
        part = np.flatnonzero(rows[a:a + DESIGN_CHUNK]) + a
        R = quat.to_rotation_matrix(fd.q[part])  # B to W
        if fd.acc is not None:
            f = fd.acc[part]
        else:
            f = np.einsum("kji,kj->ki", R, fd.dv[part] + np.array([0.0, 0.0, GRAVITY]))
        v_B = np.einsum("kji,kj->ki", R, fd.v[part])
        w_sum = fd.rotor_speeds[part].sum(axis=1)
        L = _per_metre(fd.w[part], fd.dw[part])  # alpha x r + omega x (omega x r) = L r
        x = np.zeros((len(part), 2, 7))
        x[:, :, 0:3] = L[:, 0:2]
        x[:, 0, 3] = x[:, 1, 4] = 1.0
        x[:, 0, 5] = w_sum * v_B[:, 0]
        x[:, 1, 6] = w_sum * v_B[:, 1]
        finite = np.isfinite(x).all(axis=(1, 2)) & np.isfinite(f).all(axis=1) & np.isfinite(L).all(axis=(1, 2))
        k = int(finite.sum())
        X[done:done + k], f_xy[done:done + k], L_z[done:done + k] = x[finite], f[finite, 0:2], L[finite, :, 2]
        kept[done:done + k] = part[finite]
        done += k
    return X[:done], f_xy[:done], L_z[:done], kept[:done]


def _block_sums(X: np.ndarray, y: np.ndarray, labels: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each block's ``X^T X`` (B, p, p) and ``X^T y`` (B, p) over its rows and axes (``labels`` ascending)."""
    starts = np.flatnonzero(np.r_[True, labels[1:] != labels[:-1]])
    ends = np.r_[starts[1:], len(labels)]
    p = X.shape[2]
    rows, ys = X.reshape(-1, p), y.reshape(-1)  # a row per sample and axis (matrix products: BLAS, not einsum)
    n = X.shape[1]
    xtx = np.stack([rows[n * a:n * b].T @ rows[n * a:n * b] for a, b in zip(starts, ends)])
    xty = np.stack([rows[n * a:n * b].T @ ys[n * a:n * b] for a, b in zip(starts, ends)])
    return xtx, xty


def lever_arm(fd: FlightData) -> LeverArm | None:
    """The lever arm from the centre of mass to the point ``fd``'s motion is measured at.

    Parameters
    ----------
    fd : a recording's flight data, in B as ``vehicle.yaml``'s ``T_BS`` puts it

    Returns
    -------
    :class:`LeverArm`, or None where the flight has fewer than :data:`MIN_BLOCKS` blocks in the air
    """
    S = np.sum(fd.rotor_speeds**2, axis=1)
    rows = S >= FLIGHT_SHARE * np.percentile(S, 95)  # in the air: on the gear the floor pushes back
    if fd.covered is not None:
        rows &= fd.covered
    X, f, L_z, kept = _design(fd, rows)
    t = fd.t[kept]
    labels = block_labels(t, BLOCK_S) if len(t) else np.zeros(0, np.int64)
    if len(np.unique(labels)) < MIN_BLOCKS:
        return None
    # the largest magnitude of each regressor (without a copy of them all in absolute values)
    scale = np.maximum(X.max(axis=(0, 1)), -X.min(axis=(0, 1)))
    scale[scale == 0] = 1.0
    X /= scale
    xtx, xty = _block_sums(X, f, labels)  # the whole fit and each delete-one fit from the blocks' sums
    A, b = xtx.sum(axis=0), xty.sum(axis=0)
    beta = np.linalg.lstsq(A, b, rcond=None)[0]
    left_out = np.stack([np.linalg.lstsq(A - xtx[k], b - xty[k], rcond=None)[0] for k in range(len(xtx))])
    beta, se = beta / scale, jackknife_se(left_out) / scale
    r, r_se = beta[:3], se[:3]
    accel = L_z * r[2]  # the height's part, on all three axes
    rms = float(np.sqrt(np.mean(np.sum(accel**2, axis=1))))
    z = abs(r[2]) / r_se[2] if r_se[2] > 0 else 0.0
    return LeverArm(r, r_se, rms, int(len(t)),
                    bool(z >= DECISIVE_Z and abs(r[2]) >= PRACTICAL_M and rms >= PRACTICAL_ACCEL))
