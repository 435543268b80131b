"""Quaternion helpers on numpy arrays.

Convention (``recordings.md``): Hamilton quaternions stored ``w, x, y, z``; ``q`` rotates
body vectors into the world, ``v_W = R(q) v_B``. ``q`` and ``-q`` are the same attitude.
All functions broadcast over leading dimensions: ``q`` has shape ``(..., 4)``.
"""

from __future__ import annotations

import numpy as np


def normalize(q: np.ndarray) -> np.ndarray:
    """Unit quaternions, shape ``(..., 4)``."""
    q = np.asarray(q, dtype=float)
    return q / np.linalg.norm(q, axis=-1, keepdims=True)


def multiply(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product ``a ∘ b``, shapes ``(..., 4)``."""
    aw, ax, ay, az = np.moveaxis(np.asarray(a, float), -1, 0)
    bw, bx, by, bz = np.moveaxis(np.asarray(b, float), -1, 0)
    return np.stack(
        [
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ],
        axis=-1,
    )


def conjugate(q: np.ndarray) -> np.ndarray:
    """Conjugate ``q̄`` (the inverse of a unit quaternion), shape ``(..., 4)``."""
    q = np.asarray(q, dtype=float)
    return q * np.array([1.0, -1.0, -1.0, -1.0])


def to_rotation_matrix(q: np.ndarray) -> np.ndarray:
    """Rotation matrices ``R(q)`` (body to world), shape ``(..., 3, 3)``; each element written in place (stacked
    rows of columns had held a 10^6-row flight's matrices three times over)."""
    w, x, y, z = np.moveaxis(normalize(q), -1, 0)
    R = np.empty(np.shape(w) + (3, 3))
    R[..., 0, 0], R[..., 0, 1], R[..., 0, 2] = 1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)
    R[..., 1, 0], R[..., 1, 1], R[..., 1, 2] = 2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)
    R[..., 2, 0], R[..., 2, 1], R[..., 2, 2] = 2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)
    return R


def from_rotation_matrix(R: np.ndarray) -> np.ndarray:
    """Quaternions ``w, x, y, z`` (``w >= 0``) of rotation matrices ``(..., 3, 3)``."""
    R = np.asarray(R, dtype=float)
    shape = R.shape[:-2]
    R = R.reshape(-1, 3, 3)
    q = np.empty((R.shape[0], 4))
    tr = np.trace(R, axis1=1, axis2=2)
    for k in range(R.shape[0]):  # Shepperd's method: pick the best-conditioned pivot
        m = R[k]
        diag = [tr[k], m[0, 0], m[1, 1], m[2, 2]]
        i = int(np.argmax(diag))
        if i == 0:
            s = 2.0 * np.sqrt(1.0 + tr[k])
            q[k] = [0.25 * s, (m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s]
        elif i == 1:
            s = 2.0 * np.sqrt(1.0 + m[0, 0] - m[1, 1] - m[2, 2])
            q[k] = [(m[2, 1] - m[1, 2]) / s, 0.25 * s, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s]
        elif i == 2:
            s = 2.0 * np.sqrt(1.0 + m[1, 1] - m[0, 0] - m[2, 2])
            q[k] = [(m[0, 2] - m[2, 0]) / s, (m[0, 1] + m[1, 0]) / s, 0.25 * s, (m[1, 2] + m[2, 1]) / s]
        else:
            s = 2.0 * np.sqrt(1.0 + m[2, 2] - m[0, 0] - m[1, 1])
            q[k] = [(m[1, 0] - m[0, 1]) / s, (m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, 0.25 * s]
    q *= np.where(q[:, :1] < 0, -1.0, 1.0)
    return q.reshape(*shape, 4)


def rotate(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """``R(q) v`` for body vectors ``v`` of shape ``(..., 3)``: the vector in the world frame."""
    return np.einsum("...ij,...j->...i", to_rotation_matrix(q), v)


def rotate_inverse(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """``R(q)^T v`` for world vectors ``v`` of shape ``(..., 3)``: the vector in the body frame."""
    return np.einsum("...ji,...j->...i", to_rotation_matrix(q), v)


def from_euler(roll: np.ndarray, pitch: np.ndarray, yaw: np.ndarray) -> np.ndarray:
    """Quaternions of ZYX Euler angles [rad]: ``R = Rz(yaw) Ry(pitch) Rx(roll)``."""
    cr, sr = np.cos(np.asarray(roll) / 2), np.sin(np.asarray(roll) / 2)
    cp, sp = np.cos(np.asarray(pitch) / 2), np.sin(np.asarray(pitch) / 2)
    cy, sy = np.cos(np.asarray(yaw) / 2), np.sin(np.asarray(yaw) / 2)
    return np.stack(
        [
            cr * cp * cy + sr * sp * sy,
            sr * cp * cy - cr * sp * sy,
            cr * sp * cy + sr * cp * sy,
            cr * cp * sy - sr * sp * cy,
        ],
        axis=-1,
    )


def yaw_of(q: np.ndarray) -> np.ndarray:
    """ZYX yaw angle [rad] of quaternions ``(..., 4)``."""
    w, x, y, z = np.moveaxis(normalize(q), -1, 0)
    return np.arctan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))


def make_continuous(q: np.ndarray) -> np.ndarray:
    """Flip signs along a time series ``(N, 4)`` so consecutive quaternions have ``q_k · q_{k-1} > 0`` (a new array)."""
    q = np.asarray(q, dtype=float)
    if len(q) < 2:
        return q.copy()
    flips = np.sum(q[1:] * q[:-1], axis=1) < 0
    sign = np.concatenate([[1.0], np.cumprod(np.where(flips, -1.0, 1.0))])
    return q * sign[:, None]


#: destination times interpolated at once by :func:`slerp` (its dozen temporaries a row: a 10^6-row recording's
#: attitudes, interpolated whole, peaked 265 MB above the imports for their 32 MB)
SLERP_CHUNK = 1 << 16


def slerp(t_src: np.ndarray, q_src: np.ndarray, t_dst: np.ndarray) -> np.ndarray:
    """Spherical linear interpolation of a quaternion series onto new times.

    Parameters
    ----------
    t_src : (N,) array, increasing
    q_src : (N, 4) array of unit quaternions
    t_dst : (M,) array, inside ``[t_src[0], t_src[-1]]`` (clamped otherwise)

    Returns
    -------
    (M, 4) array of unit quaternions, sign-continuous with ``q_src``: each row as interpolated alone, computed
    :data:`SLERP_CHUNK` rows at a time.
    """
    t_src = np.asarray(t_src, dtype=float)
    t_dst = np.clip(np.asarray(t_dst, dtype=float), t_src[0], t_src[-1])
    q = make_continuous(normalize(q_src))
    out = np.empty((len(t_dst), 4))
    for a in range(0, len(t_dst), SLERP_CHUNK):
        out[a:a + SLERP_CHUNK] = _slerp_rows(t_src, q, t_dst[a:a + SLERP_CHUNK])
    return out


def _slerp_rows(t_src: np.ndarray, q: np.ndarray, t_dst: np.ndarray) -> np.ndarray:
    """(M, 4) :func:`slerp` of the sign-continuous unit quaternions ``q`` at ``t_src`` onto ``t_dst`` (clamped)."""
    i = np.clip(np.searchsorted(t_src, t_dst, side="right") - 1, 0, len(t_src) - 2)
    dt = t_src[i + 1] - t_src[i]
    u = np.where(dt > 0, (t_dst - t_src[i]) / np.where(dt > 0, dt, 1.0), 0.0)
    q0, q1 = q[i], q[i + 1]
    cos = np.clip(np.sum(q0 * q1, axis=1), -1.0, 1.0)
    theta = np.arccos(cos)
    sin = np.sin(theta)
    small = sin < 1e-9
    w0 = np.where(small, 1.0 - u, np.sin((1.0 - u) * theta) / np.where(small, 1.0, sin))
    w1 = np.where(small, u, np.sin(u * theta) / np.where(small, 1.0, sin))
    return normalize(w0[:, None] * q0 + w1[:, None] * q1)


def angular_velocity_body(t: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Body angular velocity [rad/s] from a quaternion series: ``ω_B = 2 Im(q̄ ∘ q̇)``.

    Parameters
    ----------
    t : (N,) times [s]
    q : (N, 4) quaternions, body to world

    Returns
    -------
    (N, 3) array, ``q̇`` by central differences (one-sided at the ends).
    """
    q = make_continuous(normalize(q))
    qdot = np.gradient(q, np.asarray(t, dtype=float), axis=0)
    return 2.0 * multiply(conjugate(q), qdot)[:, 1:]
