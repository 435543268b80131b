"""What loggers do to streams, found as they are read (:mod:`uavturb.io.reader`): a motion capture that lost the
vehicle and wrote its last pose on, velocity columns left unfilled, a sensor clipped at its range, measured rotor
speeds with telemetry glitches or dropouts written as 0. Each finder returns the rows or the sentences; the reader
leaves the rows out (they become dropouts) or takes the columns from what the stream holds, and says so in the
recording's notes."""

from __future__ import annotations

import numpy as np

from uavturb.io.differentiate import derivative
from uavturb.numerics.stream_updates import update_mask


#: m, how far the positions must move for velocity columns all at 0 to be unfilled ones (a vehicle at rest has them
#: at 0 by right), and s, the windows of the derivative that fills them
UNFILLED_VELOCITY_MOTION_M, VELOCITY_FROM_POSITIONS_S = 0.05, 0.05


def velocity_from_positions(t_ns: np.ndarray, p: np.ndarray) -> np.ndarray:
    """(N, 3) m/s, the derivative of positions ``p`` (N, 3) [m] at ``t_ns`` (N,) [ns], taken over
    :data:`VELOCITY_FROM_POSITIONS_S` windows of their updates (a held stream's repeats are no samples) and
    interpolated to every row."""
    t = (np.asarray(t_ns, np.int64) - int(t_ns[0])) * 1e-9
    m = update_mask(p)
    m[0] = m[-1] = True
    dp = derivative(t[m], p[m], VELOCITY_FROM_POSITIONS_S)
    return np.column_stack([np.interp(t, t[m], dp[:, k]) for k in range(3)])


#: m, how far the ground truth's own velocities must carry the vehicle through a run of one repeated position for
#: the run to be motion capture that lost it (positions rounded to 1 mm repeat in a still hover while the velocities
#: integrate to a few millimetres; a Crazyflie's state estimate on its gear, its velocity drifting at 6 cm/s, to
#: 1.4 cm over 0.22 s of one position)
FROZEN_MOVE_M = 0.05


#: a run of repeated positions longer than this many of the stream's median steps between changes (and
#: :data:`FROZEN_MIN_S`) may be frozen: a held stream (9 Hz in rows at 50 Hz) repeats each update for a step
FROZEN_STEPS, FROZEN_MIN_S = 5, 0.05


def frozen_rows(t_ns: np.ndarray, p: np.ndarray, q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """(N,) bool, the ground-truth rows (``t_ns`` [ns], positions, quaternions, velocities, (N, 3/4/3)) that
    repeat a frozen value: after a row, the rows that repeat its position for longer than :data:`FROZEN_STEPS` of
    the stream's median steps between changes (and :data:`FROZEN_MIN_S`) where every value repeats too, or where
    the velocities say the vehicle moved :data:`FROZEN_MOVE_M` meanwhile. A motion capture that loses the vehicle
    writes its last pose on (4.6 s of it in a minute had been refused as a gyroscope at odds with the attitude, or,
    positions alone frozen, read as a vehicle standing still in the air, the held-out error eleven times larger);
    left out, the stretch is a dropout like missing rows."""
    t = np.asarray(t_ns, np.int64)
    out = np.zeros(len(t), bool)
    if len(t) < 3:
        return out
    repeats = np.all(p[1:] == p[:-1], axis=1)  # row k + 1 repeats row k's position
    changes = t[np.r_[True, np.any(np.hstack([p, q, v])[1:] != np.hstack([p, q, v])[:-1], axis=1)]]
    if not repeats.any() or len(changes) < 3:
        return out
    limit = max(FROZEN_STEPS * float(np.median(np.diff(changes))), FROZEN_MIN_S * 1e9)
    edges = np.diff(np.r_[0, repeats.astype(np.int8), 0])
    for a, b in zip(np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)):  # rows a + 1 .. b repeat row a
        if t[b] - t[a] <= limit:
            continue
        rows = slice(a, b + 1)
        still = np.all(q[rows] == q[a]) and np.all(v[rows] == v[a])
        moved = float(np.sum(np.linalg.norm(v[a:b], axis=1) * np.diff(t[rows]) * 1e-9))
        if still or moved > FROZEN_MOVE_M:
            out[a + 1:b + 1] = True
    return out


#: share of a sensor's rows (and least count) at exactly its largest or smallest value on an axis for the axis to
#: read as clipped at its range: a noisy axis reaches its extreme once; one driven past its range (a vibrating
#: accelerometer at +-16 m/s^2) sits there
CLIPPED_SHARE, CLIPPED_ROWS = 0.005, 10


def clipped_axes(values: np.ndarray, sensor: str, unit: str) -> list[str]:
    """Sentences for the axes of ``values`` (N, 3) that sit at their extreme on :data:`CLIPPED_SHARE` of the rows or
    more: a clipped sensor. Clipped vibration shifts the mean (the probe's accelerometer clipped at 16 m/s^2 on 6.4 %
    of its z rows read as a -0.13 m/s^2 bias): said, for the bias measured against the motion capture holds it."""
    out = []
    for k, axis in enumerate("xyz"):
        column = values[:, k]
        for extreme in (float(np.max(column)), float(np.min(column))):
            n = int(np.sum(column == extreme))
            if extreme != 0.0 and n >= max(CLIPPED_ROWS, CLIPPED_SHARE * len(column)):
                out.append(f"the {sensor}'s {axis} axis reads its extreme {extreme:.4g} {unit} on {n} rows "
                           f"({100 * n / len(column):.2g} %): clipped at its range; what it measured beyond is lost, "
                           "and a bias measured against the motion capture holds the clipping's shift of the mean")
    return out


#: share of a rotor's speed by which one update departs from both its neighbours, in one direction, while they agree
#: within :data:`GLITCH_NEIGHBOURS`, for the update to be a glitch; and s, the longest time from the last row before
#: it to the next change for that to be read (a rotor's speed settles over 20-60 ms: it cannot jump by a quarter and
#: back within 50 ms)
GLITCH_SHARE, GLITCH_NEIGHBOURS, GLITCH_WITHIN_S = 0.25, 0.05, 0.05


def rotor_glitches(t_ns: np.ndarray, speeds: np.ndarray) -> np.ndarray:
    """(N,) bool, the rows of a measured rotor stream (``t_ns`` (N,) [ns], ``speeds`` (N, K) as written) where one
    rotor's speed is a glitch: read on the stream's updates, it departs from the updates before and after by more
    than :data:`GLITCH_SHARE` of their speed, both the same way, while those two agree within
    :data:`GLITCH_NEIGHBOURS`, and the value holds for under :data:`GLITCH_WITHIN_S` with the row before it (ESC
    telemetry that read 0 or twice the speed for one row had made the held-out error seven times larger, the thrust
    coefficient 8 stated errors off). Every row holding a glitch's value (a held stream repeats it) is marked.
    Commands may jump and back (the Crazyflies' commanded speeds do on 1-8 % of their rows, and the rotors follow
    them through their lag): they are not read for glitches."""
    out = np.zeros(len(t_ns), bool)
    if len(t_ns) < 3:
        return out
    change = np.r_[True, np.any(speeds[1:] != speeds[:-1], axis=1)]
    u = np.flatnonzero(change)
    if len(u) < 3:
        return out
    t = np.asarray(t_ns, np.int64) * 1e-9
    x = speeds[u]
    before, here, after = x[:-2], x[1:-1], x[2:]
    level = np.maximum(np.abs(before), np.abs(after))
    with np.errstate(invalid="ignore", divide="ignore"):
        up, down = here - before, here - after
        jump = (np.sign(up) == np.sign(down)) & (np.minimum(np.abs(up), np.abs(down)) > GLITCH_SHARE * level)
        agree = np.abs(after - before) <= GLITCH_NEIGHBOURS * level
    close = t[u[2:]] - t[u[1:-1] - 1] <= GLITCH_WITHIN_S  # from the last row before the value to the next change
    bad = np.flatnonzero(np.any(jump & agree & (level > 0), axis=1) & close) + 1  # indices into u
    rows = np.searchsorted(u, np.arange(len(t_ns)), side="right") - 1  # the update each row holds
    out[np.isin(rows, bad)] = True
    return out


#: share of the stream's flying speed (the 90th percentile, over the rows where every rotor turns, of their mean
#: speed: near hover, however long the vehicle idled on its gear first) above which another rotor must turn while
#: one reads 0 for the row to be a telemetry dropout: a multirotor does not fly with a rotor stopped beside others
#: near hover; on its gear, spinning up, ESCs start apart at idle speeds well under it
STOPPED_BESIDE_SHARE = 0.6
#: the percentile of :data:`STOPPED_BESIDE_SHARE`'s flying speed
FLYING_PERCENTILE = 90.0


def stopped_rotor_rows(speeds: np.ndarray) -> np.ndarray:
    """(N,) bool, the rows of a measured rotor stream (``speeds`` (N, K) as written) where some rotor reads exactly 0
    while another turns faster than :data:`STOPPED_BESIDE_SHARE` of the stream's flying speed: ESC telemetry that
    lost a rotor for a while and wrote 0 (:func:`rotor_glitches` finds one update of it, not a run). Half a second of
    one rotor at 0 mid-flight had moved a simulated quadrotor's ground effect from mu = 2.92 to 2.40 (truth 3), said
    nowhere. Every rotor at 0 (motors off) is no such row."""
    x = np.asarray(speeds, float)
    out = np.zeros(len(x), bool)
    if not len(x) or x.ndim != 2:
        return out
    zero = x == 0.0
    all_turn = ~zero.any(axis=1)
    if not all_turn.any():
        return out
    level = float(np.percentile(np.mean(x[all_turn], axis=1), FLYING_PERCENTILE))
    return zero.any(axis=1) & (np.max(x, axis=1) > STOPPED_BESIDE_SHARE * level)
