"""A recording's tail after a crash or lost tracking, left out (``recordings.md``: the tools work with what
is there, saying what they could not do).

Onboard state estimates of real logs run on after the flight: a swarm's 67 g Crazyflies, their motors cut
at the end of an experiment, fell, and their estimates sank 0.3-32 m under the floor (and one rose 32 m above
it) within seconds. Every row there is impossible (a body origin under the floor), and the checks that read
the whole recording refused such logs for what they are not: positions "0.15 times as far as the velocities
say", an accelerometer "0.39 g from the motion capture: quaternions must be w, x, y, z".

:func:`without_lost_tail` cuts every stream from :data:`CUT_MARGIN_S` before the first row whose body origin
lies more than :data:`UNDER_FLOOR_M` under the floor (the point cloud's lowest point), where the rotors do not
fly on after it; a recording that flies on after such rows keeps them, for the checks to refuse (its floor,
or its heights' frame, is then what is wrong).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from uavturb.io.consistency import MIN_FLIGHT_ROWS, in_flight
from uavturb.io.recording import Recording

#: m, how far under the floor the body origin must seem to be for its rows to be impossible (a motion-capture
#: origin sits above the landing gear; a floor scanned a few centimetres off is not a crash)
UNDER_FLOOR_M = 0.05
#: s, left out before the first impossible row as well (the fall or the impact that led to it)
CUT_MARGIN_S = 1.0
#: largest share of the rows after the first impossible one that may be in flight for the tail to be cut
FLIGHT_AFTER_SHARE = 0.2


def _cut(stream, t_cut_ns: int):
    """``stream`` (a dataclass with ``t_ns`` and per-row arrays) with its rows before ``t_cut_ns`` [ns] only."""
    if stream is None:
        return None
    keep = np.asarray(stream.t_ns) < t_cut_ns
    rows = len(keep)
    fields = {f.name: getattr(stream, f.name) for f in dataclasses.fields(stream)}
    return dataclasses.replace(stream, **{k: v[keep] for k, v in fields.items()
                                          if isinstance(v, np.ndarray) and v.ndim >= 1 and len(v) == rows})


def without_lost_tail(rec: Recording) -> tuple[Recording, str | None]:
    """``rec`` without the tail after a crash or lost tracking, and a note saying what was left out (None, and
    ``rec`` itself, where there is nothing to leave out, no point cloud gives the floor, or too little would be
    left).

    Returns
    -------
    (the recording, the note for its ``read_notes`` or None)
    """
    gt = rec.ground_truth
    if rec.points is None or not len(rec.points) or len(gt) < MIN_FLIGHT_ROWS:
        return rec, None
    floor = float(np.min(rec.points[:, 2]))  # m, W
    under = np.flatnonzero(gt.p[:, 2] < floor - UNDER_FLOOR_M)
    if not len(under):
        return rec, None
    first = int(under[0])
    after = in_flight(rec, gt.t_ns)[first:]
    if np.mean(after) > FLIGHT_AFTER_SHARE:
        return rec, None
    t = rec.seconds(gt.t_ns)
    t_cut_ns = int(gt.t_ns[first]) - int(round(CUT_MARGIN_S * 1e9))
    if np.sum(gt.t_ns < t_cut_ns) < MIN_FLIGHT_ROWS:
        return rec, None
    depth = float(floor - np.min(gt.p[first:, 2]))
    cut = dataclasses.replace(rec, ground_truth=_cut(gt, t_cut_ns), imu=_cut(rec.imu, t_cut_ns),
                              rotors=_cut(rec.rotors, t_cut_ns), battery=_cut(rec.battery, t_cut_ns),
                              vicon=_cut(rec.vicon, t_cut_ns))
    where = f"{rec.path}/mav0/state_groundtruth_estimate0/data.csv" if rec.path is not None else rec.name
    note = (f"{where}: from {t[first]:.1f} s the state estimate lies under the floor (up to {depth:.2f} m under the "
            f"point cloud's lowest point, {floor:.2f} m) and the vehicle does not fly on: a crash, or tracking lost; "
            f"every stream's rows from {t[first] - CUT_MARGIN_S:.1f} s on ({t[-1] - t[first] + CUT_MARGIN_S:.1f} s) "
            "are left out")
    return cut, note
