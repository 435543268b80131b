"""One vehicle lands at one height: recordings that land at different rotor-plane heights measure their heights
from different references, and are moved to one (``recordings.md``, "Heights over surfaces").

A multirotor standing on its landing gear holds its rotor plane at one height over the floor, session after
session. Where two or more recordings of one vehicle (``gap`` analyses one vehicle, described alike) land at
rotor-plane heights (:func:`uavturb.sysid.contact.landed_height`, read from the point cloud) that differ by more
than the motion capture's noise and a landing gear's give (:data:`LANDED_ALIKE_M`), what differs is where each
recording counts its heights from: the motion capture's origin set on the markers anew, markers moved, or one
build's several airframes under one ``vehicle.yaml``. Each such recording's heights are moved so that it lands
at the median of the landed heights (:func:`landed_alignment`, :func:`moved_heights`); ``vehicle.yaml``'s
``rotor_plane_z``, give or take each stated error's height-reference term, stays the reference of that median.

Neural-Swarm's June Crazyflies cf50, cf51 and cf52 (three airframes of one build, one ``vehicle.yaml`` with
``rotor_plane_z: -0.025``) land at rotor-plane heights of 0.025, 0.028 and 0.031 m. Alone, cf51 and cf52 read a
Cheeseman-Bennett mu of 5.4 and 8.5; with their heights counted to land at cf50's height, 5.2 and 6.1 (the
December take-off of cf50, landing at 0.0245 m, reads 6.3).

Recordings that never land cannot be checked this way; where the landed ones differ, every stated error covers
heights off by half their spread (:attr:`LandedHeights.uncertainty_m`). Landed heights more than
:data:`LANDED_ALIGN_MAX_M` apart are no one vehicle on one gear (another gear, a box under one landing that the
cloud does not hold): they are not moved, and the errors cover half the spread.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np

from uavturb.sysid.flight_data import FlightData

__all__ = ["LANDED_ALIKE_M", "LANDED_ALIGN_MAX_M", "LandedHeights", "landed_alignment", "moved_heights"]

#: m, landed rotor-plane heights this close are one height: motion capture's noise (under a millimetre) and a
#: landing gear's give on a hard floor (a millimetre or two)
LANDED_ALIKE_M = 0.003
#: m, landed heights further apart than this are not one vehicle on one landing gear, and are not moved (a
#: Crazyflie's whole gear is 2.5 cm)
LANDED_ALIGN_MAX_M = 0.02


@dataclass(frozen=True)
class LandedHeights:
    """Each recording's landed rotor-plane height and the move of its heights.

    Attributes
    ----------
    heights : m per recording, its landed rotor-plane height as recorded (None: it never lands)
    shifts : m per recording, added to its ``d_down`` (and taken from its ``d_up``); 0 where not moved
    common_m : m, the height every moved recording lands at (the landed heights' median); None where none moved
    applied : whether any heights were moved
    """

    heights: tuple[float | None, ...]
    shifts: tuple[float, ...]
    common_m: float | None
    applied: bool

    @property
    def spread_m(self) -> float:
        """m, the largest difference between the recordings' landed heights as recorded (0: under two land)."""
        seen = [h for h in self.heights if h is not None]
        return float(max(seen) - min(seen)) if len(seen) > 1 else 0.0

    @property
    def uncertainty_m(self) -> float:
        """m, how far the heights of a recording left unmoved may be off, for every stated error's height-reference
        term: half the spread where landed heights differ beyond :data:`LANDED_ALIKE_M` and some recording was
        not moved (it never lands, or the spread is too wide to move); else 0."""
        if self.spread_m <= LANDED_ALIKE_M:
            return 0.0
        unmoved = not self.applied or any(h is None for h in self.heights)
        return self.spread_m / 2.0 if unmoved else 0.0

    def as_report(self, paths: Sequence[str]) -> dict[str, Any] | None:
        """The report's ``height_reference.landed_heights`` (None where under two recordings land)."""
        if sum(h is not None for h in self.heights) < 2:
            return None
        return {"recordings": [{"recording": p, "landed_m": h, "shift_m": s}
                               for p, h, s in zip(paths, self.heights, self.shifts)],
                "spread_m": self.spread_m, "common_m": self.common_m, "applied": self.applied,
                "uncertainty_m": self.uncertainty_m, "why": self.sentence([str(p) for p in paths])}

    @classmethod
    def from_report(cls, entry: dict[str, Any]) -> "LandedHeights":
        """Back from :meth:`as_report`'s dictionary."""
        rows = entry["recordings"]
        return cls(heights=tuple(r["landed_m"] for r in rows), shifts=tuple(r["shift_m"] for r in rows),
                   common_m=entry["common_m"], applied=entry["applied"])

    def sentence(self, names: Sequence[str]) -> str | None:
        """What the landed heights say and what was done, in a sentence or two (None where under two land)."""
        landed = [(n, h) for n, h in zip(names, self.heights) if h is not None]
        if len(landed) < 2:
            return None
        listed = ", ".join(f"{h:.4f} m ({n})" for n, h in landed)
        spread = f"{1000 * self.spread_m:.1f} mm"
        if self.spread_m <= LANDED_ALIKE_M:
            return f"the recordings land at rotor-plane heights {listed}: one height, within {spread}"
        never = [n for n, h in zip(names, self.heights) if h is None]
        one = len(never) == 1
        left = (f"; {', '.join(never)} never land{'s' if one else ''}, so {'its' if one else 'their'} heights "
                "cannot be checked so, and every stated error covers heights off by "
                f"{1000 * self.uncertainty_m:.1f} mm (half that spread)") if never else ""
        if not self.applied:
            return (f"the recordings land at rotor-plane heights {listed}: {spread} apart, more than the "
                    f"{1000 * LANDED_ALIGN_MAX_M:.0f} mm by which one vehicle on one landing gear can differ (another "
                    "gear, or something under one landing that the point cloud does not hold), so their heights are "
                    f"taken as recorded, and every stated error covers heights off by "
                    f"{1000 * self.uncertainty_m:.1f} mm (half that spread)")
        moves = ", ".join(f"{1000 * s:+.1f} mm ({n})" for n, s, h in zip(names, self.shifts, self.heights)
                          if h is not None)
        return (f"the recordings land at rotor-plane heights {listed}: {spread} apart, where one vehicle on its "
                "landing gear stands at one height, so they count their heights from references that far apart "
                "(the motion capture's origin on the markers, or airframes of one build under one vehicle.yaml); "
                f"each is moved to land at {self.common_m:.4f} m, their median: {moves}{left}")


def landed_alignment(heights: Sequence[float | None]) -> LandedHeights:
    """How to move each recording's heights so that one vehicle lands at one height.

    Parameters
    ----------
    heights : per recording, its landed rotor-plane height [m] (None: it never lands)

    Returns
    -------
    LandedHeights: moved to the landed heights' median where two or more land and they differ by more than
    :data:`LANDED_ALIKE_M` and at most :data:`LANDED_ALIGN_MAX_M`; otherwise nothing moved.
    """
    heights = tuple(None if h is None else float(h) for h in heights)
    seen = np.array([h for h in heights if h is not None], float)
    zero = tuple(0.0 for _ in heights)
    if len(seen) < 2 or not (LANDED_ALIKE_M < np.ptp(seen) <= LANDED_ALIGN_MAX_M):
        return LandedHeights(heights=heights, shifts=zero, common_m=None, applied=False)
    common = float(np.median(seen))
    shifts = tuple(0.0 if h is None else common - h for h in heights)
    return LandedHeights(heights=heights, shifts=shifts, common_m=common, applied=True)


def moved_heights(fd: FlightData, shift: float) -> FlightData:
    """``fd`` with its rotor plane's heights counted ``shift`` [m] higher over the surface below (and as much
    nearer the surface above): its reference moved up by ``shift``. Unchanged where ``shift`` is 0 or it has no
    heights."""
    if shift == 0.0 or fd.d_down is None:
        return fd
    return dataclasses.replace(fd, d_down=fd.d_down + shift, d_up=None if fd.d_up is None else fd.d_up - shift)
