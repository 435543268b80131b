"""``uavturb identify`` and ``uavturb residuals``: identification and residual series of recordings."""

from __future__ import annotations

import dataclasses
import sys
from pathlib import Path
from typing import Sequence

import numpy as np

from uavturb.errors import InputError
from uavturb.gap.preparation import contact_masks, delay_corrected
from uavturb.io.publish import check_apart, check_output_file
from uavturb.io.reader import load_recordings, recording_labels
from uavturb.io.recording import Recording
from uavturb.physics.vehicle import Vehicle
from uavturb.sysid.accelerometer import flight_accel_bias
from uavturb.sysid.flight_data import flight_data, rotor_repeats
from uavturb.sysid.identification import Identification, identify
from uavturb.sysid.residuals import Residuals, residual_forces, write_residuals
from uavturb.sysid.rotor_order import OTHER as OTHER_ORDER
from uavturb.sysid.rotor_order import REORDER
from uavturb.sysid.streams import needed_rate_hz, slow_for, stream_updates


def identify_recordings(paths: Sequence[str | Path], *, model: str = "auto",
                        vehicle: str | Vehicle | None = None) -> Identification:
    """``uavturb identify``: the paper's least-squares identification over one or more flights."""
    recs = load_recordings(paths, vehicle)
    _say_read_notes("identify", recs)
    ident = identify(recs, recs[0].vehicle, model=model)
    for note in (thrust_coefficient_disagreement(ident, recs[0].vehicle), commanded_speeds_caveat(ident, recs),
                 rotor_order_warning(ident)):
        if note:
            print(f"uavturb identify: {note}", file=sys.stderr)
    return ident


def rotor_order_warning(ident: Identification) -> str | None:
    """A sentence where the flights' roll and pitch accelerations follow the rotor columns in another order than
    vehicle.yaml's angles (:mod:`uavturb.sysid.rotor_order`): every torque, and the inertia from them, is then
    wrong, while the thrust, a sum over the rotors, is not. None otherwise."""
    order = ident.rotor_order
    if order is None or order.verdict != OTHER_ORDER:
        return None
    fix = ("check which column holds which rotor (a flight with roll and pitch manoeuvres tells more orders apart)"
           if order.alike else f"{REORDER}, or import the log again with its rotors in vehicle.yaml's order (`uavturb "
           "import ulog --motor-order`: each rotor the output its column above was read from)")
    return f"{order.sentence()}: {fix}; the torques and inertias here are read in vehicle.yaml's order"


def commanded_speeds_caveat(ident: Identification, recs: Sequence[Recording]) -> str | None:
    """A sentence where the rotational constants come from commanded rotor speeds (``rotor_speed_source``
    absent or ``commanded``), else None. A command map with an idle speed (``w = a + b u``, the recorded speeds a
    scale of ``u``) makes the recorded speeds' differences, and so the rotor torques, larger than the rotors' own,
    which scales the inertia and ``k_M`` alike (a probe's PX4-like commands, idle at 124 rad/s: the inertia 36 %
    high, at 63-80 stated errors). ``identify`` reads that offset (``Identification.rotor_speed_offset``): where it
    applied one, or stated the constants at the centre of the offsets left open, the sentence says so and what
    the errors carry; where it read none, that the constants rest on the recorded speeds. ``k_T`` holds at
    hover."""
    rotational = [n for n in ("J_x", "J_y", "J_z", "k_M") if ident.identified(n)]
    if not rotational or all(r.vehicle.rotor_speed_source == "measured" for r in recs):
        return None
    found = ident.rotor_speed_offset
    names = ", ".join(rotational)
    if found is not None and found["applied_rad_s"] != 0.0:
        read = (f"an offset of {found['delta_rad_s']:.4g} ± {found['stderr_rad_s']:.2g} rad/s "
                f"({100 * found['delta_rad_s'] / found['hover_speed_rad_s']:+.0f} % of the hover speed, "
                f"{found['z']:.0f} errors from zero)")
        how = ("so they were identified on the speeds moved by it" if found["decisive"] else
               f"which leaves {found['ends_rad_s'][0]:.4g}-{found['ends_rad_s'][1]:.4g} rad/s open, so they were "
               f"identified on the speeds moved to its centre, {found['applied_rad_s']:.4g} rad/s")
        return (f"{names} come from commanded rotor speeds (vehicle.yaml's rotor_speed_source); thrust per "
                f"sum((w + delta)^2) in free flight reads {read}: an idle speed in the command map, which scales the "
                f"rotor torques; {how} (the hover speed kept), and their errors carry half their change across "
                f"{found['ends_rad_s'][0]:.4g}-{found['ends_rad_s'][1]:.4g} rad/s")
    return (f"{names} come from commanded rotor speeds (vehicle.yaml's rotor_speed_source): they hold where the "
            "rotors turn as commanded; a command map with an idle speed scales the rotor torques and these with "
            "them, and these flights read no such offset that matters (uavturb gap reads it too: "
            "nominal.rotor_speed_offset)")


#: identified k_T over vehicle.yaml's beyond which the two cannot both describe these rotor speeds; and the share
#: by which they differ, at least ``KT_NOTED_ERRORS`` stated errors, for a note that only k_T/m is measured
KT_DISAGREEMENT, KT_NOTED_SHARE, KT_NOTED_ERRORS = 1.5, 0.03, 3.0


def thrust_coefficient_disagreement(ident: Identification, vehicle: Vehicle) -> str | None:
    """A sentence where the identified thrust coefficient and ``vehicle.yaml``'s differ by more than a factor
    :data:`KT_DISAGREEMENT` (a mass off by two gives twice as much; rotor speeds in rpm read as rad/s, 91 times
    less, are refused by their blade tips' speed as they are read), or by :data:`KT_NOTED_SHARE` and
    :data:`KT_NOTED_ERRORS` stated errors (a probe's mass 10 % off had passed without a word), else None. The
    identified value is right for the numbers as given; the units or the mass may not be."""
    k_nominal, k = vehicle.thrust_coefficient, float(ident.thrust_coefficient)
    if not k_nominal or not np.isfinite(k) or k <= 0:
        return None
    ratio = k / k_nominal
    if 1 / KT_DISAGREEMENT <= ratio <= KT_DISAGREEMENT:
        se = float(ident.thrust_coefficient_se)
        if abs(ratio - 1) < KT_NOTED_SHARE or not abs(k - k_nominal) > KT_NOTED_ERRORS * se:
            return None
        return (f"the identified k_T {k:.4g} ± {se:.2g} N/(rad/s)^2 is {100 * (ratio - 1):+.1f} % off vehicle.yaml's "
                f"thrust_coefficient {k_nominal:.4g}: sessions, batteries and propellers differ by a few percent, "
                "and a mass off by as much reads alike (a flight measures k_T/m; k_T and the inertia scale with the "
                "mass given)")
    return (f"the identified k_T {k:.4g} N/(rad/s)^2 is {ratio:.3g} times vehicle.yaml's thrust_coefficient "
            f"{k_nominal:.4g}: check that rotors0 holds rad/s (rotor_speed_scale converts rpm or raw values) and "
            "vehicle.yaml's mass")


#: s, the time a residual force series resolves at its rows' rate, and Hz, the updates that asks of a stream it reads
RESIDUAL_TIMESCALE_S = 0.1
RESIDUAL_NEEDED_HZ = needed_rate_hz(RESIDUAL_TIMESCALE_S)


def _say_slow_streams(command: str, rec: Recording) -> None:
    """On stderr, each stream the residual force reads (ground truth, rotors) that updates slower than
    :data:`RESIDUAL_NEEDED_HZ`: between its updates the residual carries what that stream did not see (rotor
    speeds held at 3 Hz had tripled a probe's residual without a word; ``recordings.md``: the tools say when a
    stream updates too slowly for what they are asked)."""
    streams = [("state_groundtruth_estimate0", rec.ground_truth.t_ns,
                np.hstack([rec.ground_truth.p, rec.ground_truth.q, rec.ground_truth.v]))]
    if rec.rotors is not None:
        streams.append(("rotors0", rec.rotors.t_ns, rec.rotors.speeds))
    for name, t_ns, values in streams:
        if len(t_ns) < 3:
            continue
        rounded = name == "rotors0" and rotor_repeats(values) == "rounded"  # every row a sample
        said = slow_for(stream_updates(name, t_ns, values, rounded=rounded), RESIDUAL_NEEDED_HZ,
                        f"a residual force resolved to {RESIDUAL_TIMESCALE_S:g} s (between its updates the residual "
                        "carries what it did not see, not the air's force)")
        if said:
            print(f"uavturb {command}: {said}", file=sys.stderr)


def _telemetry_on_time(rec: Recording) -> Recording:
    """``rec`` with its measured rotor speeds' delay taken out of their timestamps where one is timed, as ``uavturb
    gap`` takes it out (:func:`~uavturb.gap.preparation.delay_corrected`), said on stderr: ESC telemetry 60 ms late
    had left a residual twice the IMU's noise in a probe's series without a word. Commanded speeds are returned as
    they are (they lead the force by the motor lag, which is physics)."""
    if rec.vehicle.rotor_speed_source != "measured":
        return rec
    moved, found = delay_corrected(rec, flight_data(rec))
    if found is not None and found["applied"]:
        print(f"uavturb residuals: {found['describe']}: taken out of its timestamps", file=sys.stderr)
    elif found is not None:
        print(f"uavturb residuals: {found['describe']}: read as stamped", file=sys.stderr)
    return moved


def _say_read_notes(command: str, recs: Sequence[Recording]) -> None:
    """What the reader changed in the files' rows (merged repeated timestamps), on stderr."""
    for rec in recs:
        for note in rec.read_notes:
            print(f"uavturb {command}: {note}", file=sys.stderr)


#: share of k_T's stated error from which the surface term is said (under it, it barely moves the error)
SURFACE_TERM_SAID = 0.25


def format_identification(ident: Identification) -> str:
    """A human-readable table of the constants the flights determine, with standard errors; then
    the ones they do not, each with its reason (estimate in brackets, or ``-``: never as a result)."""
    names = {"k_T": "k_T", "k_M": "k_M", "J_x": "J_x", "J_y": "J_y", "J_z": "J_z",
             "theta_0": "theta_0 = k_T/m", "theta_1": "theta_1 = l k_T/J_x", "theta_2": "theta_2 = k_M/J_z",
             "theta_3": "theta_3 = J_z/J_x", "accel_bias": "accelerometer bias"}
    lines = [f"identified from {len(ident.recordings)} recording(s), {ident.n_samples} samples in free flight, "
             f"inertia model {ident.model}"]
    if ident.near_surface_m is not None:
        lines.append(f"the flights stay near a surface: rows down to {ident.near_surface_m:.2g} m from it, its "
                     "Cheeseman-Bennett lift fitted beside k_T (not in it)")
    if ident.surface_term is not None and ident.surface_term >= SURFACE_TERM_SAID * ident.thrust_coefficient_se:
        lines.append(f"k_T's error carries {ident.surface_term:.2g} N/(rad/s)^2, half its change between the rows "
                     "six rotor radii or more from any surface and the rows nearer with a Cheeseman-Bennett lift "
                     "beside it (surface)")
    lag = ident.command_lag
    if lag is not None and lag["applied_s"] > 0.0:
        lines.append(f"the rotors lag the commanded speeds by {1e3 * lag['tau_s']:.1f} ± {1e3 * lag['stderr_s']:.1f} "
                     "ms "
                     f"(where the roll and pitch torques correlate best with the angular acceleration: "
                     f"{lag['correlation']:.3f}, against {lag['correlation_at_zero']:.3f} as recorded): the constants "
                     "are identified on the lagged speeds, their errors carry half their change across that error")
    elif lag is not None:
        lines.append(f"the rotors follow the commanded speeds without a lag the torques' timing shows (read "
                     f"{1e3 * lag['tau_s']:.1f} ± {1e3 * lag['stderr_s']:.1f} ms: not applied)")
    lines.append(f"{'parameter':<22}{'value':>14}{'std. error':>14}  unit")
    undetermined = []
    for key, label in names.items():
        s = ident.status[key]
        if not s.identifiable:
            undetermined.append((label, s))
        elif key == "accel_bias":
            lines.append(f"{label:<22}{_vector(s.value):>28} ± {_vector(s.stderr)}  m/s^2 (body, measured against "
                         "the motion capture)")
        else:
            lines.append(f"{label:<22}{s.value:>14.6g}{s.stderr:>14.3g}  {s.unit}")
    if ident.thrust_coefficient_per_recording:
        per = ident.thrust_coefficient_per_recording
        each = "; ".join(f"{label} {k:.4g} ± {se:.2g}" for label, (k, se) in zip(recording_labels(list(per)),
                                                                                   per.values()))
        lines.append(f"k_T of each recording alone: {each} (k_T's error is at least their spread)")
    if ident.accel_bias_per_recording:  # each recording's own, whether or not the pooled one is a result
        per_b = ident.accel_bias_per_recording
        label = dict(zip(ident.recordings, recording_labels(ident.recordings)))
        each = "; ".join(f"{label.get(n, n)} {_vector(b)}" for n, (b, _) in per_b.items())
        spread = " (the bias's error is at least their spread)" if len(per_b) > 1 else ""
        without = [label.get(n, n) for n in ident.recordings if n not in per_b]
        lines.append(f"accelerometer bias of each recording: {each} m/s^2{spread}"
                     + (f"; no IMU: {', '.join(without)}" if without else ""))
    if undetermined:
        lines.append("not determined by these flights (estimates in brackets are not results):")
        for label, s in undetermined:
            if s.reason == "absent" or np.ndim(s.value) or not np.isfinite(s.value):
                shown = "-"
            else:
                shown = f"[{s.value:.3g} +- {s.stderr:.2g}]"
            lines.append(f"  {label:<20}{shown:>24}  {s.reason}: {s.why}")
    return "\n".join(lines)


def _vector(x) -> str:
    """A (3,) vector in four decimals."""
    return np.array2string(np.asarray(x, float), precision=4, suppress_small=True)


def _identified_for_forces(ident: Identification, vehicle: Vehicle) -> Vehicle:
    """The vehicle with the identified constants; where the flight cannot determine a rotational one
    (``k_M``, inertia) and vehicle.yaml has none, the forces are still computed (torques ``nan``):
    the residual force needs only ``k_T``."""
    try:
        return ident.apply(vehicle)
    except InputError:
        k_T = ident._pick("k_T", float(ident.thrust_coefficient), vehicle.thrust_coefficient)
        print(f"uavturb residuals: torques left out (nan): {', '.join(ident.not_identified)} not determined by "
              "this flight and not in vehicle.yaml", file=sys.stderr)
        return vehicle.with_params(thrust_coefficient=k_T, moment_coefficient=None, inertia=None)


def residuals_to_file(path: str | Path, out: str | Path, *, source: str = "auto", derivative: str = "savgol",
                      params: str = "identified", vehicle: str | Vehicle | None = None,
                      overwrite: bool = False) -> tuple[Residuals, Path]:
    """``uavturb residuals``: the residual force series of one flight, written to CSV or Parquet
    (an existing ``out`` is replaced only with ``overwrite``), its rows on the ground flagged
    (``ground_contact``: the floor's reaction is in their residual, as ``uavturb gap`` finds it)."""
    out = Path(out)
    if out.suffix not in (".csv", ".parquet"):
        raise InputError(out, "output must end in .csv or .parquet")
    if not out.parent.exists():
        raise InputError(out.parent, "output folder does not exist")
    check_apart(out, [path])
    check_output_file(out, overwrite=overwrite)
    (rec,) = load_recordings([path], vehicle)
    _say_read_notes("residuals", [rec])
    _say_slow_streams("residuals", rec)
    rec = _telemetry_on_time(rec)
    ident = None
    if params == "identified":
        ident = identify([rec], rec.vehicle)
        said = rotor_order_warning(ident)  # why the torques are left out, where it is the columns' order
        if said:
            print(f"uavturb residuals: {said}", file=sys.stderr)
        v = _identified_for_forces(ident, rec.vehicle)
    elif params == "nominal":
        v = rec.vehicle
        if v.thrust_coefficient is None:
            raise InputError(Path(path) / "vehicle.yaml", "--params nominal needs thrust_coefficient")
        if not v.is_complete():  # the force needs k_T alone
            missing = [k for k, x in (("moment_coefficient", v.moment_coefficient), ("inertia", v.inertia))
                       if x is None]
            print(f"uavturb residuals: torques left out (nan): vehicle.yaml has no {' or '.join(missing)}",
                  file=sys.stderr)
            v = v.with_params(moment_coefficient=None, inertia=None)
    else:
        raise InputError("--params", f"unknown value '{params}' (allowed: identified, nominal)")
    fd = flight_data(rec, time_base="groundtruth" if source == "mocap" else "auto")  # an IMU unread cuts no rows
    how = ident.speeds_read_note() if ident is not None else None
    if how:
        fd = ident.flight_data_read(fd)
        print(f"uavturb residuals: the commanded rotor speeds read as identify read them, {how}: the torques of the "
              "identified inertia need the rotors' own speeds", file=sys.stderr)
    (contact,), _ = contact_masks([fd], v, [str(path)])  # the rows the gap finder leaves out
    bias = flight_accel_bias(fd, ~contact) if source in ("auto", "imu") else None  # a sensor's error, no force
    if bias is not None:
        print(f"uavturb residuals: accelerometer bias ({', '.join(f'{b:.3g}' for b in bias.b)}) ± "
              f"({', '.join(f'{e:.2g}' for e in bias.stderr)}) m/s^2 (body x, y, z), measured against the motion "
              "capture, taken off the IMU's specific force", file=sys.stderr)
    res = residual_forces(fd, v, source=source, derivative=derivative, accel_bias=None if bias is None else bias.b)
    res = dataclasses.replace(res, ground_contact=contact)
    return res, write_residuals(res, out, overwrite=overwrite)

