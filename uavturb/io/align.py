"""Time alignment of recording streams: interpolation onto other timestamps, and overlap.

Streams of a recording need not share timestamps or rates (``recordings.md``). Times are
integer nanoseconds; interpolation works in float64 seconds relative to the first source
timestamp, so that 19-digit EuRoC timestamps lose no precision.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from uavturb.errors import InputError
from uavturb.physics import quaternion as quat


def _relative_seconds(t_src_ns: np.ndarray, t_dst_ns: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Both time arrays as float64 seconds since ``t_src_ns[0]`` (integer subtraction first)."""
    t_src_ns = np.asarray(t_src_ns, dtype=np.int64)
    t_dst_ns = np.asarray(t_dst_ns, dtype=np.int64)
    if t_src_ns.ndim != 1 or len(t_src_ns) == 0:
        raise ValueError("source timestamps must be a non-empty 1-D array")
    origin = t_src_ns[0]
    return (t_src_ns - origin) * 1e-9, (t_dst_ns - origin) * 1e-9


def interpolate(t_src_ns: np.ndarray, values: np.ndarray, t_dst_ns: np.ndarray) -> np.ndarray:
    """Linear interpolation of each column onto new timestamps.

    Parameters
    ----------
    t_src_ns : (N,) int64, increasing source timestamps [ns]
    values : (N,) or (N, K) samples at ``t_src_ns``
    t_dst_ns : (M,) int64 timestamps [ns] to interpolate at; outside the source span the
        first or last sample is held (use :func:`overlap` to stay inside)

    Returns
    -------
    (M,) or (M, K) float64, same trailing shape as ``values``
    """
    t_src, t_dst = _relative_seconds(t_src_ns, t_dst_ns)
    values = np.asarray(values, dtype=np.float64)
    if len(values) != len(t_src):
        raise ValueError(f"{len(t_src)} timestamps but {len(values)} samples")
    if values.ndim == 1:
        return np.interp(t_dst, t_src, values)
    flat = values.reshape(len(values), -1)
    out = np.empty((len(t_dst), flat.shape[1]))
    for j in range(flat.shape[1]):  # into one array (a list of columns stacked had held the output twice)
        out[:, j] = np.interp(t_dst, t_src, flat[:, j])
    return out.reshape((len(t_dst),) + values.shape[1:])


def interpolate_quaternions(t_src_ns: np.ndarray, q: np.ndarray, t_dst_ns: np.ndarray) -> np.ndarray:
    """Spherical linear interpolation of attitudes onto new timestamps.

    Parameters
    ----------
    t_src_ns : (N,) int64, increasing source timestamps [ns]
    q : (N, 4) quaternions ``w, x, y, z`` (normalised and made sign-continuous here)
    t_dst_ns : (M,) int64 timestamps [ns]; clamped to the source span

    Returns
    -------
    (M, 4) unit quaternions, sign-continuous with ``q``
    """
    t_src, t_dst = _relative_seconds(t_src_ns, t_dst_ns)
    q = np.asarray(q, dtype=np.float64)
    if q.shape != (len(t_src), 4):
        raise ValueError(f"quaternions must have shape ({len(t_src)}, 4), got {q.shape}")
    if len(t_src) == 1:
        return np.repeat(quat.normalize(q), len(t_dst), axis=0)
    return quat.slerp(t_src, q, t_dst)


def overlap(t_a: np.ndarray, t_b: np.ndarray, *more: np.ndarray) -> tuple[int, int]:
    """The time span ``(start, end)`` [ns] covered by every stream.

    Parameters
    ----------
    t_a, t_b, *more : (N_i,) increasing timestamps [ns]

    Returns
    -------
    ``(start, end)`` as ints; ``end <= start`` when the streams do not overlap.
    """
    streams = (t_a, t_b) + more
    start = max(int(np.asarray(t)[0]) for t in streams)
    end = min(int(np.asarray(t)[-1]) for t in streams)
    return start, end


def require_overlap(t_ref: np.ndarray, t: np.ndarray, where: str | Path,
                    reference: str = "the ground truth") -> tuple[int, int]:
    """:func:`overlap` of two streams, raising when they share no time at all.

    Parameters
    ----------
    t_ref : (N,) timestamps [ns] of the reference stream
    t : (M,) timestamps [ns] of the stream being checked
    where : the file of ``t``, named in the error
    reference : what ``t_ref`` is, for the message

    Raises
    ------
    InputError
        ``where``: the stream's span does not overlap ``reference``.
    """
    if len(t_ref) and t_ref[-1] == t_ref[0]:  # a recording of one instant: no stream can overlap it
        raise InputError(where, f"cannot be aligned with {reference}, which holds {len(t_ref)} row(s) at one instant "
                                f"({int(t_ref[0])} ns): a recording needs a flight's worth of rows")
    start, end = overlap(t_ref, t)
    if end <= start:
        span = lambda x: f"[{int(x[0])}, {int(x[-1])}] ns"  # noqa: E731
        raise InputError(where, f"does not overlap {reference} in time (stream spans {span(t)}, "
                                f"{reference} spans {span(t_ref)})")
    return start, end
