"""What every flight-log importer (``uavturb import ulog|csv``) does once the streams are read.

* The floor: a log carries no scan, so a flat floor at ``floor_z`` (m, in W, z up) becomes the
  recording's ``pointcloud0`` (:func:`flat_floor`), from which the heights over surfaces come.
  Without ``floor_z`` no point cloud is written.
* The check (:func:`check_conventions`): the rotor columns and the thrust axis against the data,
  as every physics command checks them (:func:`uavturb.io.consistency.check_recording`), and the
  sign of the vertical response (:func:`uavturb.io.consistency.check_vertical_response`). A failure
  names the convention of the log or map that looks wrong, and, where the importer can rebuild the
  recording with other conventions, the ones the data agree with.
* The summary (:class:`ImportSummary`): one line of what was written, left out and missing.

Sample-and-hold repeats and gaps (dropouts) are kept as they are: no resampling, no smoothing.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Callable

import numpy as np

from uavturb.errors import InputError
from uavturb.io.consistency import check_rotor_columns, check_thrust_axis, check_vertical_response
from uavturb.io.publish import check_apart
from uavturb.io.reader import MAX_ROTOR_SPEED_RAD_S
from uavturb.io.recording import Recording
from uavturb.io.writer import write_recording
from uavturb.physics.vehicle import MAX_SIZE_M

#: m, spacing of the flat floor's points: under the 5 cm columns of the height index, so none is empty
FLOOR_SPACING = 0.04
#: m, the floor reaches this far beyond the flight's horizontal extent
FLOOR_MARGIN = 1.0
#: at most this many floor points; a wider flight gets a coarser grid (its heights over the floor then
#: need no 5 cm resolution: such flights are outdoors, far above it)
FLOOR_MAX_POINTS = 2_000_000
#: m, how far under the floor the body origin may seem to be (a position's noise, a floor height given to the
#: centimetre) before the import says the height passes through the floor
UNDER_FLOOR_M = 0.02


def flat_floor(p: np.ndarray, floor_z: float) -> np.ndarray:
    """Points ``(P, 3)`` [m, W] of a flat floor at height ``floor_z`` under positions ``p`` ``(N, 3)``:
    a square grid of :data:`FLOOR_SPACING` covering their x, y extent plus :data:`FLOOR_MARGIN`."""
    lo = np.min(p[:, :2], axis=0) - FLOOR_MARGIN
    hi = np.max(p[:, :2], axis=0) + FLOOR_MARGIN
    area = float(np.prod(hi - lo))
    spacing = max(FLOOR_SPACING, float(np.sqrt(area / FLOOR_MAX_POINTS)))
    x = np.arange(lo[0], hi[0] + spacing / 2, spacing)
    y = np.arange(lo[1], hi[1] + spacing / 2, spacing)
    X, Y = np.meshgrid(x, y, indexing="ij")
    return np.column_stack([X.ravel(), Y.ravel(), np.full(X.size, float(floor_z))])


@dataclass
class ImportSummary:
    """What an import wrote, left out and could not find; :meth:`line` prints it as one line."""

    out: Path
    streams: dict[str, str] = field(default_factory=dict)  # stream -> "N rows (details)"
    left_out: list[str] = field(default_factory=list)  # "12 rows with nan before arming", ...
    lacks: list[str] = field(default_factory=list)  # what the log does not hold
    notes: list[str] = field(default_factory=list)  # anything else worth knowing

    def line(self) -> str:
        parts = [f"wrote {self.out}: " + ", ".join(f"{k} {v}" for k, v in self.streams.items())]
        if self.left_out:
            parts.append("left out: " + ", ".join(self.left_out))
        if self.lacks:
            parts.append("the log lacks: " + ", ".join(self.lacks))
        parts += self.notes
        return "; ".join(parts)


#: a function that builds the recording again with other conventions ({"world": "enu", ...})
Rebuild = Callable[[dict[str, str]], Recording]


def check_conventions(rec: Recording, conventions: dict[str, str], choices: dict[str, tuple[str, ...]],
                      where: str, rebuild: Rebuild | None = None,
                      rotor_column: Callable[[int], str] | None = None) -> float:
    """The import's checks of ``rec`` (in B); returns the thrust-axis angle [deg].

    Parameters
    ----------
    rec : the imported recording, in B
    conventions : the conventions it was built with, e.g. ``{"world": "ned", "body": "frd"}``
    choices : the other values each convention may take (tried with ``rebuild`` on a failure)
    where : the file named in errors (the map, or the log)
    rebuild : builds the recording with other conventions; ``None``: none are tried
    rotor_column : the log's name of vehicle rotor ``i`` (named when a rotor column is dead)

    Raises
    ------
    InputError
        ``<where>: body: frd looks wrong: ... (the data agree with body: flu)``.
    """
    if rec.rotors is not None and len(rec.rotors.speeds) and np.nanmax(rec.rotors.speeds) > MAX_ROTOR_SPEED_RAD_S:
        k, i = np.unravel_index(np.nanargmax(rec.rotors.speeds), rec.rotors.speeds.shape)
        name = rotor_column(int(i)) if rotor_column is not None else f"of vehicle rotor {i}"
        raise InputError(where, f"rotor column {name} reads {rec.rotors.speeds[k, i]:.3g} rad/s, over the "
                                f"{MAX_ROTOR_SPEED_RAD_S:.0e} rad/s no rotor reaches: not a rotor speed, "
                                f"or the wrong unit")
    try:
        check_rotor_columns(rec)
    except InputError as e:
        found = re.match(r"column w_(\d+) (.*)", e.problem)
        if rotor_column is None or found is None:  # the rotor columns as a whole, named in the log
            raise InputError(where, f"the rotor columns: {e.problem}") from None
        c = int(found.group(1))
        raise InputError(where, f"rotor column {rotor_column(c)} (vehicle rotor {c}) {found.group(2)}") from None
    try:
        return _checks(rec)
    except InputError as e:
        problem = e.problem.split(": ", 1)[1] if e.problem.startswith("T_BS:") else e.problem
    agree = _agreeing_conventions(conventions, choices, rebuild)
    suspects = [k for k in conventions if any(a[k] != conventions[k] for a in agree)] or list(conventions)
    named = " or ".join(f"{k}: {conventions[k]}" for k in suspects)
    hint = ("; the data agree with " + " or ".join(", ".join(f"{k}: {v}" for k, v in a.items() if v != conventions[k])
                                                    for a in agree)) if agree else ""
    raise InputError(where, f"{named} looks wrong: {problem.split('; set T_BS', 1)[0]}{hint}")


def _checks(rec: Recording) -> float:
    """The thrust axis from the IMU (where there is one) and from the ground truth's attitude and motion
    (a world turned upside down shows there, not in the IMU), then the vertical response."""
    angle = check_thrust_axis(rec)
    if rec.imu is not None:
        check_thrust_axis(replace(rec, imu=None))
    check_vertical_response(rec)
    return angle


def _agreeing_conventions(conventions: dict[str, str], choices: dict[str, tuple[str, ...]],
                          rebuild: Rebuild | None) -> list[dict[str, str]]:
    """The combinations of conventions (one or two changed) whose recording passes the checks."""
    if rebuild is None:
        return []
    keys = list(conventions)
    combos = [dict(conventions, **{k: v}) for k in keys for v in choices.get(k, ()) if v != conventions[k]]
    if len(keys) > 1:
        combos += [dict(conventions, **{keys[0]: a, keys[1]: b}) for a in choices.get(keys[0], ())
                   for b in choices.get(keys[1], ()) if a != conventions[keys[0]] and b != conventions[keys[1]]]
    agree = []
    for combo in combos:
        try:
            _checks(rebuild(combo))
        except InputError:
            continue
        agree.append(combo)
    return agree


#: m, the largest ``--floor-z`` taken as a height (a floor a kilometre up is a typing error)
MAX_FLOOR_Z_M = 1e3


def check_import_options(out: str | Path, inputs: list[str | Path], *, floor_z: float | None,
                         rotor_plane_z: float | None) -> None:
    """Before any work: ``out`` apart from the input files (:func:`uavturb.io.publish.check_apart`), and
    ``--floor-z`` / ``--rotor-plane-z`` finite and in range (a ``rotor_plane_z`` as ``vehicle.yaml`` allows it)."""
    check_apart(out, inputs)
    for option, value, top in (("--floor-z", floor_z, MAX_FLOOR_Z_M), ("--rotor-plane-z", rotor_plane_z, MAX_SIZE_M)):
        if value is not None and not (np.isfinite(value) and abs(value) <= top):
            raise InputError(option, f"must be a finite height within +-{top:g} m, got {value!r}")


def floor_note(rec: Recording, floor_z: float | None) -> str | None:
    """What the summary says where the body origin goes under the floor at ``floor_z`` [m] (in W, z up): a
    height that drifts (a barometer's, an estimator's without motion capture) or a floor set too high. The gap
    finder then tests no surface effect on the recording (``uavturb.gap.decide.floor_crossing``)."""
    if floor_z is None:
        return None
    gt = rec.ground_truth
    depth = float(floor_z) - gt.p[:, 2]
    under = depth > UNDER_FLOOR_M
    if not under.any():
        return None
    t = (gt.t_ns[under] - gt.t_ns[0]) * 1e-9
    return (f"the position goes up to {depth.max():.2f} m under the floor (--floor-z {float(floor_z):g}) in "
            f"{int(under.sum())} rows between {t.min():.1f} and {t.max():.1f} s: its height drifts (a barometer, an "
            f"estimator without motion capture) or the floor is lower; heights over the floor cannot be trusted")


def finish_import(rec: Recording, out: str | Path, *, floor_z: float | None, overwrite: bool) -> Recording:
    """Add the flat floor (when ``floor_z`` is given) and write ``rec`` atomically to ``out``."""
    if floor_z is not None:  # checked before any work (check_import_options)
        rec = replace(rec, points=flat_floor(rec.ground_truth.p, floor_z))
    write_recording(rec, out, overwrite=overwrite)
    return replace(rec, path=Path(out))
