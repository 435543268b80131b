"""Read a recording folder (the EuRoC-MAV layout of ``recordings.md``) into a :class:`Recording`.

Also holds the layout itself: the path of every file relative to the recording folder,
shared with :mod:`uavturb.io.writer`.
"""

from __future__ import annotations

import dataclasses
import errno
import hashlib
import os
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from uavturb.errors import InputError
from uavturb.io import align, euroc_csv, ply, sensor_yaml
from uavturb.io.body_frame import to_body
from uavturb.io.consistency import check_recording
from uavturb.io.crash import without_lost_tail
from uavturb.io.recording import Battery, Camera, GroundTruth, Imu, Poses, Recording, Rotors
from uavturb.io.stream_faults import (
    GLITCH_SHARE,
    STOPPED_BESIDE_SHARE,
    UNFILLED_VELOCITY_MOTION_M,
    VELOCITY_FROM_POSITIONS_S,
    clipped_axes,
    frozen_rows,
    rotor_glitches,
    stopped_rotor_rows,
    velocity_from_positions,
)
from uavturb.io.vehicle_file import load_vehicle, named_vehicle
from uavturb.numerics.threads import in_threads
from uavturb.physics import quaternion as quat
from uavturb.physics.vehicle import Vehicle

# --- the layout (paths relative to the recording folder) -----------------------------------
VEHICLE_YAML = "vehicle.yaml"
GROUNDTRUTH_CSV = "mav0/state_groundtruth_estimate0/data.csv"
IMU_CSV = "mav0/imu0/data.csv"
IMU_YAML = "mav0/imu0/sensor.yaml"
ROTORS_CSV = "mav0/rotors0/data.csv"
POINTS_PLY = "mav0/pointcloud0/data.ply"
CAM_CSV = "mav0/cam0/data.csv"
CAM_YAML = "mav0/cam0/sensor.yaml"
CAM_DATA = "mav0/cam0/data"
VICON_CSV = "mav0/vicon0/data.csv"
BATTERY_CSV = "mav0/battery0/data.csv"

#: Set to 1 to read stream files that are links to places outside the recording folder.
FOLLOW_LINKS_ENV = "UAVTURB_FOLLOW_LINKS"

#: A quaternion whose norm differs from 1 by more than this is an error, not rounding.
QUATERNION_NORM_TOLERANCE = 1e-2


def checked_quaternions(path: str | Path, q: np.ndarray, lines: np.ndarray | None = None,
                        unit: str = "line") -> np.ndarray:
    """Validate, normalise and make sign-continuous a quaternion series.

    Parameters
    ----------
    path : file (or bag) the quaternions come from, named in errors
    q : (N, 4) quaternions ``w, x, y, z``
    lines : (N,) line numbers of the rows (default ``1..N``)
    unit : what ``lines`` count (``"line"``, ``"message"``)

    Returns
    -------
    (N, 4) unit quaternions with ``q_k · q_{k-1} > 0``

    Raises
    ------
    InputError
        ``"quaternion at line L has norm X (expected 1)"`` when ``|‖q‖ - 1| > 1e-2``.
    """
    q = np.asarray(q, dtype=np.float64)
    norm = np.linalg.norm(q, axis=1)
    bad = np.flatnonzero(np.abs(norm - 1.0) > QUATERNION_NORM_TOLERANCE)
    if len(bad):
        k = bad[0]
        at = lines[k] if lines is not None else k + 1
        raise InputError(path, f"quaternion at {unit} {at} has norm {norm[k]:.6g} (expected 1)")
    return quat.make_continuous(q / norm[:, None])


#: rad/s, the fastest rotor speed taken as real once scaled by ``rotor_speed_scale``: about 950,000 rpm, fifteen
#: times the fastest small propellers (60,000 rpm, 6,300 rad/s); a raw 16-bit command (65,535) read as rad/s stays
#: under it. Above it a value is a logging fault, and its square would overflow the least squares downstream.
MAX_ROTOR_SPEED_RAD_S = 1e5


def check_rotor_speeds(path: str | Path, speeds: np.ndarray, vehicle: Vehicle, lines: np.ndarray | None = None,
                       unit: str = "line") -> None:
    """Rotor speeds ``(N, K)`` (as written, before ``rotor_speed_scale``) have one column per rotor of ``vehicle``,
    none is negative and none, scaled, is over :data:`MAX_ROTOR_SPEED_RAD_S`."""
    if speeds.shape[1] != vehicle.rotor_count:
        raise InputError(path, f"has {speeds.shape[1]} rotor speed columns but the vehicle "
                               f"'{vehicle.name}' has rotor_count {vehicle.rotor_count}")
    neg = np.argwhere(speeds < 0)
    if len(neg):
        k, c = neg[0]
        at = lines[k] if lines is not None else k + 1
        raise InputError(path, f"{unit} {at}: negative rotor speed {speeds[k, c]} for rotor {c} (speeds are "
                               "magnitudes; vehicle.yaml's rotor_directions gives each rotor's spin)")
    with np.errstate(over="ignore"):  # 1e308 scaled is inf, and refused
        scaled = speeds * float(vehicle.rotor_speed_scale)
    fast = np.argwhere(scaled > MAX_ROTOR_SPEED_RAD_S)
    if len(fast):
        k, c = fast[0]
        at = lines[k] if lines is not None else k + 1
        raise InputError(path, f"{unit} {at}: rotor speed {speeds[k, c]:.4g} for rotor {c} is {scaled[k, c]:.3g} rad/s "
                               f"with rotor_speed_scale {vehicle.rotor_speed_scale:g}, over the "
                               f"{MAX_ROTOR_SPEED_RAD_S:.0e} rad/s no rotor reaches ({len(fast)} value"
                               f"{'s' if len(fast) > 1 else ''} over it)")
    check_tip_speed(path, scaled, vehicle)


#: m/s, the speed of sound in air at 20 C: no propeller's blade tips reach it (small multirotors hover with tips at
#: 40-150 m/s; a Crazyflie's 0.0231 m rotors at 2300 rad/s, 53 m/s)
SPEED_OF_SOUND_M_S = 343.0


def check_tip_speed(path: str | Path, speeds: np.ndarray, vehicle: Vehicle) -> None:
    """Rotor speeds ``(N, K)`` [rad/s] (scaled) whose blade tips, at ``vehicle.rotor_radius``, stay under the speed
    of sound while all rotors spin (the median row): speeds written in rpm and read as rad/s put a Crazyflie's tips at
    550 m/s and a 2.5 kg hexarotor's at 700, and every law in rotor speed (a rotor drag per rad/s) came out 9.5
    times off with a 1 % error bar.

    Raises
    ------
    InputError
        ``<rotors0>: its rotor speeds put the blade tips at 707 m/s ...``
    """
    spinning = speeds[np.all(speeds > 0, axis=1)]
    if not len(spinning) or not vehicle.rotor_radius:
        return
    typical = float(np.median(spinning.mean(axis=1)))
    tip = typical * float(vehicle.rotor_radius)
    if tip > SPEED_OF_SOUND_M_S:
        raise InputError(path, f"its rotor speeds put the blade tips at {tip:.0f} m/s ({typical:.4g} rad/s, the median "
                               f"while all rotors spin, times rotor_radius {vehicle.rotor_radius:g} m), beyond the "
                               f"speed of sound ({SPEED_OF_SOUND_M_S:g} m/s), which no propeller reaches: speeds in "
                               f"rpm (rotor_speed_scale: 0.10472 turns rpm into rad/s) or other units than rad/s "
                               f"(rotor_speed_scale {vehicle.rotor_speed_scale:g} now)")


#: ns: a stream whose rows are closer than this (over 100 kHz) holds timestamps in other units than nanoseconds
MIN_STEP_NS = 10_000


def check_time_unit(path: str | Path, t_ns: np.ndarray) -> None:
    """Timestamps in integer nanoseconds (``recordings.md``): a median step under :data:`MIN_STEP_NS` is refused
    in one line (microseconds or milliseconds read as nanoseconds make a 200 Hz stream 200 kHz or 200 MHz)."""
    if len(t_ns) < 10:
        return
    step = float(np.median(np.diff(t_ns)))
    if step < MIN_STEP_NS:
        raise InputError(path, f"timestamps step by {step:.4g} ns ({1e9 / step:.3g} Hz): they must be integer "
                               "nanoseconds; these look like microseconds or milliseconds")


#: ns, the longest median step of a ground-truth stream: under 1 Hz no acceleration can be read (recordings.md:
#: 50 Hz and up), and nanosecond timestamps written from milliseconds (a factor 10^6) step by minutes or more
MAX_STATE_STEP_NS = 10**9


def check_state_rate(path: str | Path, t_ns: np.ndarray) -> None:
    """A ground-truth stream's median step is at most :data:`MAX_STATE_STEP_NS`; refused in one line otherwise."""
    if len(t_ns) < 10:
        return
    step = float(np.median(np.diff(t_ns)))
    if step > MAX_STATE_STEP_NS:
        raise InputError(path, f"timestamps step by {step * 1e-9:.4g} s ({1e9 / step:.2g} Hz): "
                               f"a flight's state runs at "
                               "50 Hz and up (recordings.md); these are not nanoseconds, or not a flight's state")


#: the largest magnitude each stream's values may take, per column group (start, stop, limit, unit): a position
#: 1000 km off the origin, a speed of Mach 3, an angular rate of 160 turns a second or an acceleration of 1000 g is a
#: logging fault, not a multirotor's flight, and squared it would overflow downstream
STATE_LIMITS = ((0, 3, 1e6, "m"), (7, 10, 1e3, "m/s"), (10, 13, 1e3, "rad/s"), (13, 16, 1e4, "m/s^2"))
IMU_LIMITS = ((0, 3, 1e3, "rad/s"), (3, 6, 1e4, "m/s^2"))


def check_magnitudes(path: str | Path, x: np.ndarray, lines: np.ndarray,
                     limits: Sequence[tuple[int, int, float, str]]) -> None:
    """Refuse, in one line naming the line and column (the timestamp is column 1), a value over its group's limit
    (``limits``: columns ``start:stop`` of the values ``x``, the largest magnitude, its unit)."""
    for start, stop, limit, unit in limits:
        over = np.argwhere(np.abs(x[:, start:stop]) > limit)
        if len(over):
            k, c = over[0]
            raise InputError(path, f"line {lines[k]}, column {start + c + 2}: {x[k, start + c]:.4g} {unit}, beyond "
                                   f"the {limit:.0e} {unit} of any multirotor's flight "
                                   f"({len(over)} value{'s' if len(over) > 1 else ''} "
                                   "over it)")


def read_recording(path: str | Path, *, vehicle: Vehicle | None = None, require_rotors: bool = False,
                   require_imu: bool = False, load_points: bool = True, frame: str = "B") -> Recording:
    """Read a recording folder.

    Parameters
    ----------
    path : the recording folder (holding ``vehicle.yaml`` and ``mav0/``)
    vehicle : used when the folder has no ``vehicle.yaml`` (a downloaded EuRoC sequence);
        a folder's own ``vehicle.yaml`` takes precedence
    require_rotors, require_imu : make ``rotors0`` / ``imu0`` required
    load_points : read ``pointcloud0/data.ply`` when present (large)
    frame : ``"B"`` (default): ground truth and IMU expressed in the rotor frame B with
        ``vehicle.yaml``'s ``T_BS`` (:func:`uavturb.io.body_frame.to_body`: attitude, position
        and velocity of B's origin, gyroscope rotated, accelerometer rotated with the lever-arm
        accelerations removed, biases rotated); ``"S"``: as stored, in the sensor frame

    Returns
    -------
    Recording
        Ground truth always; ``imu``, ``rotors`` (rad/s, scaled by ``rotor_speed_scale``),
        ``points``, ``cam0`` (frames listed, not loaded), ``vicon`` and ``battery`` when present.
        Rows of a stream sharing a timestamp (loggers write them) are merged, the last kept, and said in
        ``read_notes``.

    Raises
    ------
    InputError
        Naming the file at fault: missing folder or required file, malformed CSV, PLY or
        YAML, quaternion norm off by more than 1e-2, rotor column count different from the
        vehicle's ``rotor_count``, negative rotor speed, or an IMU/rotor stream that does not
        overlap the ground truth in time.
    """
    root = Path(path)
    if not root.exists():
        raise InputError(root, "recording folder not found")
    if not root.is_dir():
        raise InputError(root, "not a recording folder (it is a file)")
    check_links(root)
    vehicle = _folder_vehicle(root, vehicle)
    notes: list[str] = []  # rows sharing a timestamp, merged (loggers write them)
    gt = _read_ground_truth(root, notes)
    imu = _read_imu(root, gt.t_ns, notes, required=require_imu)
    rotors = _read_rotors(root, gt.t_ns, vehicle, notes, required=require_rotors)
    points = ply.scene_points(root / POINTS_PLY, notes) if load_points and (root / POINTS_PLY).is_file() else None
    rec = Recording(vehicle=vehicle, ground_truth=gt, imu=imu, rotors=rotors, points=points, cam0=_read_camera(root),
                    vicon=_read_vicon(root, notes), battery=_read_battery(root, notes), path=root, frame="S",
                    read_notes=tuple(notes))
    if frame == "S":
        return rec
    if frame != "B":
        raise ValueError(f"frame must be 'B' or 'S', got {frame!r}")
    return to_body(rec)


def check_links(root: Path) -> None:
    """Every file and folder of the layout (``vehicle.yaml``, ``mav0/*``, ``mav0/*/*``) stays inside
    ``root`` once links are followed, unless the user says so (``UAVTURB_FOLLOW_LINKS=1``): a
    recording from someone else cannot make a command read ``/etc/...`` or another user's files."""
    if os.environ.get(FOLLOW_LINKS_ENV) == "1":
        return
    top = root.resolve()
    for entry in [root / VEHICLE_YAML, root / "mav0", *root.glob("mav0/*"), *root.glob("mav0/*/*")]:
        if not entry.is_symlink():
            continue
        try:
            target = entry.resolve(strict=True)
        except (RuntimeError, OSError) as e:  # a loop of links, or a link to nothing
            why = "a loop of links" if isinstance(e, RuntimeError) or getattr(e, "errno", None) == errno.ELOOP \
                else "a link to nothing"
            raise InputError(entry, f"is {why} ({os.readlink(entry)})") from None
        if not target.is_relative_to(top):
            raise InputError(entry, f"is a link out of the recording folder (to {target}); it is not "
                                    f"followed unless you set {FOLLOW_LINKS_ENV}=1")


def _folder_vehicle(root: Path, vehicle: Vehicle | None) -> Vehicle:
    """The folder's own ``vehicle.yaml``, else ``vehicle``; neither: :class:`InputError`."""
    vehicle_file = root / VEHICLE_YAML
    if vehicle_file.is_file():
        return load_vehicle(vehicle_file)
    if vehicle is None:
        raise InputError(vehicle_file, "file not found (a folder without one needs a vehicle given explicitly)")
    return vehicle


def _read_ground_truth(root: Path, notes: list[str]) -> GroundTruth:
    """``state_groundtruth_estimate0`` (required), its quaternions checked."""
    gt_file = root / GROUNDTRUTH_CSV
    t_gt, x, lines = euroc_csv.read_csv(gt_file, euroc_csv.GROUNDTRUTH_COLUMNS, "ground truth", return_lines=True,
                                        repeated_times=notes, missing_rows=notes)
    check_time_unit(gt_file, t_gt)
    check_state_rate(gt_file, t_gt)
    check_magnitudes(gt_file, x, lines, STATE_LIMITS)
    frozen = frozen_rows(t_gt, x[:, 0:3], x[:, 3:7], x[:, 7:10])
    if frozen.any():
        starts = np.flatnonzero(frozen & ~np.r_[False, frozen[:-1]])
        notes.append(f"{root.name}/state_groundtruth_estimate0: {int(frozen.sum())} rows repeat a position frozen "
                     f"for longer than the stream's changes allow, in {len(starts)} stretch"
                     f"{'es' if len(starts) > 1 else ''} from line {lines[starts[0]]} (the motion capture lost the "
                     "vehicle and wrote its last pose on): left out, read as dropouts")
        t_gt, x, lines = t_gt[~frozen], x[~frozen], lines[~frozen]
    v = x[:, 7:10]
    moved = float(np.max(np.ptp(x[:, 0:3], axis=0)))
    if not np.any(v) and moved > UNFILLED_VELOCITY_MOTION_M:
        v = velocity_from_positions(t_gt, x[:, 0:3])
        notes.append(f"{root.name}/state_groundtruth_estimate0: every velocity is 0 while the positions move over "
                     f"{moved:.2g} m (an exporter that left the columns unfilled): velocities taken from the "
                     f"positions' derivative ({VELOCITY_FROM_POSITIONS_S:g} s windows over their updates)")
    # columns of their own, so that the parsed table is let go (its quaternions are normalised into a new array;
    # views would keep all sixteen columns of it: 23 MB of a flight-hour at 200 Hz that nothing reads)
    own = np.ascontiguousarray
    return GroundTruth(t_ns=t_gt, p=own(x[:, 0:3]), q=checked_quaternions(gt_file, x[:, 3:7], lines), v=own(v),
                       b_w=own(x[:, 10:13]), b_a=own(x[:, 13:16]))


def _read_imu(root: Path, t_gt: np.ndarray, notes: list[str], *, required: bool) -> Imu | None:
    """``imu0`` with its ``sensor.yaml`` (pose, rate) when present; it must overlap the ground truth."""
    imu_file = root / IMU_CSV
    if not imu_file.is_file():
        if required:
            raise InputError(imu_file, "file not found (IMU data are required)")
        return None
    if not required and _absent_if_empty(imu_file, notes):
        return None
    t, x, lines = euroc_csv.read_csv(imu_file, euroc_csv.IMU_COLUMNS, "IMU", return_lines=True, repeated_times=notes,
                                     missing_rows=notes, lost="no sample logged")
    check_time_unit(imu_file, t)
    check_magnitudes(imu_file, x, lines, IMU_LIMITS)
    align.require_overlap(t_gt, t, imu_file)
    imu = Imu(t_ns=t, gyro=x[:, 0:3], acc=x[:, 3:6], T_BS=np.eye(4))
    notes += [f"{root.name}/imu0: {line}" for line in clipped_axes(x[:, 0:3], "gyroscope", "rad/s")
              + clipped_axes(x[:, 3:6], "accelerometer", "m/s^2")]
    if (root / IMU_YAML).is_file():
        sensor = sensor_yaml.read_imu_yaml(root / IMU_YAML)
        imu.T_BS, imu.rate_hz = sensor.T_BS, sensor.rate_hz
    return imu


def _read_rotors(root: Path, t_gt: np.ndarray, vehicle: Vehicle, notes: list[str], *, required: bool
                 ) -> Rotors | None:
    """``rotors0`` in rad/s (scaled by ``rotor_speed_scale``), checked against the vehicle; it must overlap
    the ground truth."""
    rotors_file = root / ROTORS_CSV
    if not rotors_file.is_file():
        if required:
            raise InputError(rotors_file, "file not found (rotor speeds are required)")
        return None
    t, x, lines = euroc_csv.read_csv(rotors_file, None, "rotor speed", return_lines=True, repeated_times=notes,
                                     missing_rows=notes, lost="no speed logged")
    check_time_unit(rotors_file, t)
    check_rotor_speeds(rotors_file, x, vehicle, lines)
    align.require_overlap(t_gt, t, rotors_file)
    glitch = rotor_glitches(t, x) if vehicle.rotor_speed_source == "measured" else np.zeros(len(t), bool)
    if glitch.any():
        notes.append(f"{root.name}/rotors0: {int(glitch.sum())} row{'s' if glitch.sum() > 1 else ''} where one rotor's "
                     f"speed jumps by over {100 * GLITCH_SHARE:g} % for one update and back (first at line "
                     f"{lines[np.flatnonzero(glitch)[0]]}; no rotor turns that fast) left out: telemetry glitches")
        t, x, lines = t[~glitch], x[~glitch], lines[~glitch]
    stopped = stopped_rotor_rows(x) if vehicle.rotor_speed_source == "measured" else np.zeros(len(t), bool)
    if stopped.any():
        notes.append(f"{root.name}/rotors0: {int(stopped.sum())} row{'s' if stopped.sum() > 1 else ''} where a rotor "
                     f"reads 0 while another turns at over {100 * STOPPED_BESIDE_SHARE:g} % of the flying speed "
                     f"(first at line {lines[np.flatnonzero(stopped)[0]]}; no multirotor flies so) left out: "
                     "telemetry dropouts written as 0")
        t, x = t[~stopped], x[~stopped]
    return Rotors(t_ns=t, speeds=x * vehicle.rotor_speed_scale)


def _read_camera(root: Path) -> Camera | None:
    """``cam0``: its ``sensor.yaml`` and, when present, its frame list (frames not loaded)."""
    if not ((root / CAM_CSV).is_file() or (root / CAM_YAML).is_file()):
        return None
    cam0 = sensor_yaml.read_camera_yaml(root / CAM_YAML)
    if (root / CAM_CSV).is_file():
        t, files = euroc_csv.read_frame_list(root / CAM_CSV)
        cam0.t_ns, cam0.files = t, files
    return cam0


def _read_vicon(root: Path, notes: list[str]) -> Poses | None:
    """``vicon0`` poses when present, their quaternions checked."""
    vicon_file = root / VICON_CSV
    if not vicon_file.is_file():
        return None
    t, x, lines = euroc_csv.read_csv(vicon_file, euroc_csv.VICON_COLUMNS, "vicon", return_lines=True,
                                     repeated_times=notes)
    return Poses(t_ns=t, p=x[:, 0:3], q=checked_quaternions(vicon_file, x[:, 3:7], lines))


def _absent_if_empty(path: Path, notes: list[str]) -> bool:
    """Whether the optional stream ``path`` holds no data row (its header alone, or nothing: a logger that opened
    the file and never wrote to it), saying so in ``notes``; such a stream is read as absent (``recordings.md``:
    streams that may be missing), where it had refused the whole recording."""
    with open(path, "rb") as f:
        for line in f:
            text = line.strip().lstrip(b"\xef\xbb\xbf")
            if text and not text.startswith(b"#"):
                return False
    notes.append(f"{path.parents[2].name}/{path.parent.name}/{path.name} holds no data rows: read as absent (the "
                 "stream is optional)")
    return True


#: V, the highest median battery voltage read (a 24-cell pack is 100 V full; a log in millivolts reads thousands)
MAX_BATTERY_V = 150.0


def _read_battery(root: Path, notes: list[str]) -> Battery | None:
    """``battery0`` when present: voltage [V] and, in a third column, current [A]."""
    battery_file = root / BATTERY_CSV
    if not battery_file.is_file() or _absent_if_empty(battery_file, notes):
        return None
    t, x = euroc_csv.read_csv(battery_file, None, "battery", repeated_times=notes, missing_rows=notes,
                              lost="no reading logged", then="the voltage is interpolated over them")
    if x.shape[1] > 2:
        raise InputError(battery_file, f"has {x.shape[1] + 1} columns; expected timestamp, voltage [V] "
                                       "and optionally current [A]")
    if np.any(x[:, 0] <= 0):
        k = int(np.argmax(x[:, 0] <= 0))
        raise InputError(battery_file, f"row {k + 1}: battery voltage {x[k, 0]:.6g} V is not positive")
    if np.median(x[:, 0]) > MAX_BATTERY_V:
        raise InputError(battery_file, f"battery voltages of {np.median(x[:, 0]):.6g} V (median), over the "
                                       f"{MAX_BATTERY_V:g} V of any multirotor's pack: recordings.md asks for volts, "
                                       "not millivolts")
    return Battery(t_ns=t, voltage=x[:, 0], current=x[:, 1] if x.shape[1] == 2 else None)


def recording_labels(paths: Sequence[str | Path]) -> list[str]:
    """Short names for recording folders that tell them apart: each folder's name, with as many of its parent
    folders before it as it takes (``day1/flight``, ``day2/flight``; a flight engineer's sessions often name their
    logs alike, and per-recording results keyed by the folder's name alone would merge)."""
    parts = [Path(p).resolve().parts for p in paths]
    labels = []
    for i, mine in enumerate(parts):
        k = 1
        while k < len(mine) and any(other[-k:] == mine[-k:] for j, other in enumerate(parts) if j != i):
            k += 1
        labels.append("/".join(mine[-k:]))
    return labels


#: m and -, the resolution at which two recordings' ground-truth positions and quaternions must agree to hold the
#: same flight (a copy written again by another tool keeps them to a micrometre; two flights never do)
SAME_FLIGHT_RESOLUTION = 1e-6


def _flight_fingerprint(rec: Recording) -> str:
    """A digest of the flight a recording holds: its ground-truth positions [m] and attitudes, rounded to
    :data:`SAME_FLIGHT_RESOLUTION`, without the timestamps (a copy stamped on another clock is the same flight)."""
    gt = rec.ground_truth
    digest = hashlib.sha256()
    for part in (gt.p, gt.q):
        digest.update(np.ascontiguousarray(np.round(part / SAME_FLIGHT_RESOLUTION)).astype(np.int64).tobytes())
    return digest.hexdigest()


def _refuse_one_flight_twice(recs: Sequence[Recording], paths: Sequence[str | Path]) -> None:
    """One flight under two folders would count as two sessions that agree: the spread between recordings, which
    every stated error covers, would read zero for it and each error shrink by about sqrt(2).

    Raises
    ------
    InputError
        ``<path>: holds the same flight as <other> ...``
    """
    seen: dict[str, str | Path] = {}
    for rec, p in zip(recs, paths):
        key = _flight_fingerprint(rec)
        if key in seen:
            raise InputError(p, f"holds the same flight as {seen[key]} (the same ground-truth positions and "
                                "attitudes, row for row): each flight once, or a copy would count as a second "
                                "session that agrees and shrink every stated error")
        seen[key] = p


#: what one analysis of several recordings needs alike in their vehicle.yaml: the geometry the laws read, and how the
#: rotor speeds were recorded
SAME_VEHICLE_KEYS = ("rotor_angles_deg", "rotor_directions", "arm_length", "rotor_radius", "rotor_plane_z",
                     "rotor_speed_source")
#: relative difference of mass between recordings of one vehicle taken as the same vehicle (batteries differ by a
#: few percent; each recording's forces use its own mass)
SAME_MASS_SHARE = 0.05


def _check_same_vehicle(first: Recording, other: Recording) -> None:
    """``other``'s vehicle.yaml describes ``first``'s vehicle: the keys of :data:`SAME_VEHICLE_KEYS` alike (to 1e-6),
    the masses within :data:`SAME_MASS_SHARE`. A rotor radius or arm length differing in one file had been read from
    the first recording for all, the fit depending on the order of the folders (ground effect mu 0.89 or 2.00).

    Raises
    ------
    InputError
        ``<other>/vehicle.yaml: rotor_radius 0.19 here, 0.127 in <first>/vehicle.yaml: ...``
    """
    a, b = first.vehicle, other.vehicle
    where = f"{other.path}/vehicle.yaml" if other.path else "vehicle.yaml"
    for key in SAME_VEHICLE_KEYS:
        x, y = getattr(a, key), getattr(b, key)
        same = x == y if isinstance(x, str) else (np.shape(x) == np.shape(y)
                                                  and np.allclose(x, y, rtol=1e-6, atol=1e-9))
        if not same:
            raise InputError(where, f"{key} {_yaml_value(y)} here, {_yaml_value(x)} in {first.path}/vehicle.yaml: "
                                    "recordings analysed together must be of one vehicle, described alike")
    if abs(b.mass - a.mass) > SAME_MASS_SHARE * a.mass:
        raise InputError(where, f"mass {b.mass:g} kg here, {a.mass:g} kg in {first.path}/vehicle.yaml "
                                f"({100 * (b.mass / a.mass - 1):+.1f} %, over the {100 * SAME_MASS_SHARE:g} % "
                                "batteries make): recordings analysed together must be of one vehicle")


def _yaml_value(x: Any) -> str:
    """A vehicle.yaml value as written: a word, a number, or a list of numbers."""
    if isinstance(x, str):
        return x
    return f"{x:g}" if np.ndim(x) == 0 else "[" + ", ".join(f"{v:g}" for v in x) + "]"


def load_recordings(paths: Sequence[str | Path], vehicle: str | Vehicle | None = None, *,
                    repeats_allowed: bool = False) -> list[Recording]:
    """Read recording folders for physics (``identify``, ``residuals``, ``gap``, ``evaluate``): in
    the rotor frame B, rotor speeds required, and checked (:func:`uavturb.io.consistency.check_recording`:
    thrust axis against the data, no dead or frozen rotor column). ``vehicle`` (built-in vehicle name,
    yaml path or Vehicle) serves folders without a ``vehicle.yaml``. One flight in two folders is refused
    (:func:`_refuse_one_flight_twice`) unless ``repeats_allowed`` (``uavturb bench gap`` repeats flights on
    purpose: it measures time and memory, not results)."""
    v = named_vehicle(vehicle) if isinstance(vehicle, str) else vehicle
    seen: dict[Path, str | Path] = {}
    for p in paths:  # one flight twice would count as two recordings that agree (errors too small by sqrt(2))
        key = Path(p).resolve()
        if key in seen:
            raise InputError(p, f"is given twice (also as {seen[key]}): each recording once")
        seen[key] = p

    def read(p: str | Path) -> Recording:  # a crash's or lost tracking's tail left out before the checks read it all
        rec, lost = without_lost_tail(read_recording(p, vehicle=v, require_rotors=True))
        return dataclasses.replace(rec, read_notes=rec.read_notes + ((lost,) if lost else ()))

    recs = list(in_threads(read, paths))  # several at once: each alone, on a core of its own
    for r in recs[1:]:
        _check_same_vehicle(recs[0], r)
    if not repeats_allowed:
        _refuse_one_flight_twice(recs, paths)
    recs = list(in_threads(lambda r: dataclasses.replace(r, read_notes=r.read_notes + tuple(check_recording(r))),
                           recs))
    recs = [r if label == Path(p).name else dataclasses.replace(r, label=label)
            for r, p, label in zip(recs, paths, recording_labels(paths))]
    return recs

