"""``uavturb gap`` on malformed or inconsistent recordings: one clear line naming the file and
the problem on stderr, a non-zero exit status, no traceback and no report folder
(gap-report.md, recordings.md)."""

import json
import os
import re
import shutil
import subprocess
import sys
from dataclasses import replace

import numpy as np
import pytest

from uavturb import progress
from uavturb.errors import InputError
from uavturb.cli import main
from uavturb.commands.identify import residuals_to_file
from uavturb.io.consistency import (
    MIN_VERTICAL_CORRELATION_RECORDING,
    check_quaternion_order,
    check_rotor_clock,
    check_vertical_response,
    stream_span_notes,
)
from uavturb.io.ply import read_ply, write_ply
from uavturb.gap.finder import MOVED_SPEEDS_STAGE, STAGES, analyse
from uavturb.gap.preparation import state_thinned, stream_limits
from uavturb.io.reader import load_recordings, read_recording, recording_labels
from uavturb.io.stream_faults import clipped_axes, stopped_rotor_rows
from uavturb.numerics.stream_updates import staggered
from uavturb.physics import quaternion as quat
from uavturb.io.recording import Battery, GroundTruth
from uavturb.sim.flights.condition_schema import Conditions
from uavturb.sim.flights.conditions import generate_conditioned_flight
from uavturb.sim.flights.simulate import generate_flight


@pytest.fixture(scope="module")
def good(tmp_path_factory):
    path = tmp_path_factory.mktemp("gapin") / "good"
    generate_flight(vehicle="hex", effects="none", duration=12.0, kind="mixed", seed=3, out=path)
    return path


@pytest.fixture(scope="module")
def another(tmp_path_factory):
    """Another flight of ``good``'s vehicle."""
    path = tmp_path_factory.mktemp("gapin") / "another"
    generate_flight(vehicle="hex", effects="none", duration=12.0, kind="mixed", seed=4, out=path)
    return path


def _copy(good, tmp_path, name="rec"):
    dst = tmp_path / name
    shutil.copytree(good, dst)
    return dst


def _rewrite_csv(path, fn):
    lines = path.read_text().splitlines()
    path.write_text("\n".join([lines[0]] + [fn(i, l) for i, l in enumerate(lines[1:])]) + "\n")


def _scaled_yaml_value(rec, key, factor=None, value=None) -> float:
    """Rewrite ``key`` of ``rec``'s vehicle.yaml to ``factor`` times its value (or to ``value``); returns the value
    as it was written."""
    yaml_path = rec / "vehicle.yaml"
    text = yaml_path.read_text()
    written = re.search(rf"^{key}: (\S+)$", text, re.M).group(1)
    new = value if value is not None else factor * float(written)
    yaml_path.write_text(text.replace(f"{key}: {written}", f"{key}: {new:.6g}"))
    return float(written)


def _gap_fails(tmp_path, capsys, recs, *extra, match: str):
    out = tmp_path / "report"
    code = main(["gap", *map(str, recs), "--out", str(out), "--sim-effects", "none", "--no-mlflow", *extra])
    err = capsys.readouterr().err
    assert code != 0
    lines = [l for l in err.splitlines() if l.strip()]
    assert len(lines) == 1, err
    assert "Traceback" not in err
    assert match in lines[0], lines[0]
    assert not out.exists()
    assert not any(p.name.startswith(".report") for p in tmp_path.iterdir())
    return lines[0]


def test_good_recording_runs_with_exit_0(tmp_path, capsys, good):
    out = tmp_path / "report"
    assert main(["gap", str(good), "--out", str(out), "--sim-effects", "none", "--no-mlflow"]) == 0
    assert (out / "report.json").exists() and (out / "report.md").exists()
    captured = capsys.readouterr()
    assert "effects named: none" in captured.out
    assert captured.err == ""  # a short run in a log: no progress line (one every 10 s)


def test_a_long_run_in_a_log_says_which_stage_runs(tmp_path, capsys, good, monkeypatch):
    monkeypatch.setattr(progress, "FILE_INTERVAL", 0.0)  # as if every stage took longer than the interval
    out = tmp_path / "report"
    assert main(["gap", str(good), "--out", str(out), "--sim-effects", "none", "--no-mlflow"]) == 0
    lines = capsys.readouterr().err.splitlines()
    stages = [line.rsplit(", ", 1)[-1] for line in lines if line.startswith("uavturb gap: ")]
    # each stage in order (no MLflow: not the last; no decisive speed offset: no second pass)
    expected = [s for s in STAGES[:-1] if s != MOVED_SPEEDS_STAGE]
    assert stages[-len(expected):] == expected, lines
    assert any(line.startswith("uavturb gap: 4/10 stages (40 %)") for line in lines), lines


def test_missing_folder(tmp_path, capsys):
    _gap_fails(tmp_path, capsys, [tmp_path / "nowhere"], match="nowhere")


def test_missing_groundtruth_file(tmp_path, capsys, good):
    rec = _copy(good, tmp_path)
    (rec / "mav0" / "state_groundtruth_estimate0" / "data.csv").unlink()
    _gap_fails(tmp_path, capsys, [rec], match="state_groundtruth_estimate0")


def test_missing_rotors_file(tmp_path, capsys, good):
    rec = _copy(good, tmp_path)
    shutil.rmtree(rec / "mav0" / "rotors0")
    _gap_fails(tmp_path, capsys, [rec], match="rotors0")


def test_missing_vehicle_yaml(tmp_path, capsys, good):
    rec = _copy(good, tmp_path)
    (rec / "vehicle.yaml").unlink()
    _gap_fails(tmp_path, capsys, [rec], match="vehicle.yaml")


def test_rotor_count_differs_from_vehicle_yaml(tmp_path, capsys, good):
    rec = _copy(good, tmp_path)
    csv = rec / "mav0" / "rotors0" / "data.csv"
    lines = csv.read_text().splitlines()
    head = ",".join(lines[0].split(",")[:-2])  # 4 rotor columns for a 6-rotor vehicle.yaml
    csv.write_text("\n".join([head] + [",".join(l.split(",")[:-2]) for l in lines[1:]]) + "\n")
    line = _gap_fails(tmp_path, capsys, [rec], match="rotors0")
    assert "6" in line and "4" in line


def test_streams_do_not_overlap_in_time(tmp_path, capsys, good):
    rec = _copy(good, tmp_path)
    shift = 3600 * 10**9  # rotor speeds an hour later than the ground truth
    _rewrite_csv(rec / "mav0" / "rotors0" / "data.csv",
                 lambda i, l: ",".join([str(int(l.split(",")[0]) + shift)] + l.split(",")[1:]))
    _gap_fails(tmp_path, capsys, [rec], match="overlap")


def test_timestamps_in_microseconds_are_refused(tmp_path, capsys, good):
    """A logger's microseconds written where nanoseconds belong make a 200 Hz stream 200 kHz (and a
    half-second window 100k rows): refused before any work, naming the stream."""
    rec = _copy(good, tmp_path)
    for stream in ("state_groundtruth_estimate0", "imu0", "rotors0"):
        _rewrite_csv(rec / "mav0" / stream / "data.csv",
                     lambda i, l: ",".join([str(int(l.split(",")[0]) // 1000)] + l.split(",")[1:]))
    line = _gap_fails(tmp_path, capsys, [rec], match="state_groundtruth_estimate0/data.csv: timestamps step by")
    assert line.endswith("they must be integer nanoseconds; these look like microseconds or milliseconds")


def test_rotor_speeds_that_never_lift_the_vehicle_are_refused(tmp_path, capsys, good):
    """Rotor speeds in Hz where rad/s belong carry 2.5 % of the weight with vehicle.yaml's thrust coefficient:
    one line naming rotors0 and the likely causes (was an internal error on an empty array)."""
    rec = _copy(good, tmp_path)
    _rewrite_csv(rec / "mav0" / "rotors0" / "data.csv",
                 lambda i, l: ",".join([l.split(",")[0]] + [f"{float(x) / (2 * np.pi):.6g}" for x in l.split(",")[1:]]))
    line = _gap_fails(tmp_path, capsys, [rec], match="rotors0/data.csv: its rotor speeds never carry more than")
    assert "speeds in other units than rad/s" in line


def test_rotor_speeds_in_rpm_are_refused_by_their_tip_speed(tmp_path, capsys, good):
    """Rotor speeds in rpm read as rad/s (9.55 times too fast): the blade tips would pass the speed of sound. Refused
    in one line naming rotors0 and the scale that converts, where the analysis had named a rotor drag 9.4 times too
    small with a 1 % error (a law per rad/s; the thrust coefficient had absorbed the square)."""
    rec = _copy(good, tmp_path)
    _rewrite_csv(rec / "mav0" / "rotors0" / "data.csv",
                 lambda i, l: ",".join([l.split(",")[0]] + [f"{float(x) * 60 / (2 * np.pi):.6g}"
                                                            for x in l.split(",")[1:]]))
    line = _gap_fails(tmp_path, capsys, [rec], match="rotors0/data.csv: its rotor speeds put the blade tips at")
    assert "beyond the speed of sound (343 m/s)" in line and "rotor_speed_scale: 0.10472" in line


def test_a_thrust_coefficient_that_would_lift_many_times_the_weight_is_refused(tmp_path, capsys, good):
    """vehicle.yaml's thrust coefficient ten times the vehicle's: the recorded speeds would lift about ten times the
    weight through the flight. One line naming rotors0 and the ratio (the fit had gone on with its own k_T, saying
    nothing of the disagreement)."""
    rec = _copy(good, tmp_path)
    _scaled_yaml_value(rec, "thrust_coefficient", 10.0)
    line = _gap_fails(tmp_path, capsys, [rec], match="rotors0/data.csv: its rotor speeds would lift")
    lift = float(re.search(r"would lift (\S+) times the weight", line).group(1))
    assert 8.0 < lift < 12.0 and "thrust coefficient or mass off" in line


def test_a_thrust_coefficient_off_by_half_is_said_beside_the_flights_own(tmp_path, capsys, good):
    """vehicle.yaml's thrust coefficient 1.5 times the vehicle's: within what a flight could need, so the analysis
    runs on the flights' own k_T; report.json keeps the yaml's value and report.md says how far the two differ."""
    rec = _copy(good, tmp_path)
    written = _scaled_yaml_value(rec, "thrust_coefficient", 1.5)
    out = tmp_path / "report"
    assert main(["gap", str(rec), "--out", str(out), "--sim-effects", "none", "--no-mlflow"]) == 0
    nominal = json.loads((out / "report.json").read_text())["nominal"]
    assert nominal["thrust_coefficient_vehicle_yaml"] == pytest.approx(1.5 * written, rel=1e-5)
    assert nominal["thrust_coefficient"] == pytest.approx(written, rel=0.02)
    assert re.search(r"vehicle.yaml states \S+ \(-3[34]\.\d %; the flights' own value is used",
                     (out / "report.md").read_text())


@pytest.mark.parametrize("key, value, match", [
    ("rotor_radius", 0.12, r"rotor_radius 0.12 here, [0-9.]+ in .*good/vehicle.yaml: recordings analysed together"),
    ("mass", None, r"mass [0-9.]+ kg here, [0-9.]+ kg in .*good/vehicle.yaml \(\+10.0 %, over the 5 % batteries"),
])
def test_recordings_of_vehicles_described_apart_are_refused_naming_the_key(tmp_path, capsys, good, another, key,
                                                                            value, match):
    """A second recording whose vehicle.yaml gives another rotor radius had been read with the first's (the ground
    effect's mu 0.89 or 2.00 by the folders' order); a mass 10 % off is another load. One line names the key and
    both values."""
    rec = _copy(another, tmp_path)
    _scaled_yaml_value(rec, key, 1.1, value)
    line = _gap_fails(tmp_path, capsys, [good, rec], match=f"{rec}/vehicle.yaml: {key}")
    assert re.search(match, line), line


def test_a_battery_that_weighs_a_little_more_is_the_same_vehicle(tmp_path, capsys, good, another):
    """Two recordings of one vehicle whose vehicle.yaml masses differ by 2 % (a heavier battery): analysed together
    (it had been refused for any difference), each with its own mass, the thrust level per recording as before."""
    rec = _copy(another, tmp_path)
    _scaled_yaml_value(rec, "mass", 1.02)
    out = tmp_path / "report"
    assert main(["gap", str(good), str(rec), "--out", str(out), "--sim-effects", "none", "--no-mlflow"]) == 0
    report = json.loads((out / "report.json").read_text())
    per = list(report["nominal"]["thrust_coefficient_per_recording"].values())
    assert report["effects"] == [] and len(per) == 2


def _scaled_columns(columns, factor):
    def rewrite(i, line):
        x = line.split(",")
        return ",".join(f"{float(v) * factor:.9g}" if k in columns else v for k, v in enumerate(x))
    return rewrite


@pytest.mark.parametrize("stream, rewrite, match", [
    ("state_groundtruth_estimate0", _scaled_columns({1, 2, 3}, 1000.0),
     "state_groundtruth_estimate0/data.csv: on axis x the positions move 1e+03 times as far as the velocities say"),
    ("state_groundtruth_estimate0", _scaled_columns({1, 2, 3, 8, 9, 10}, 1000.0),
     "state_groundtruth_estimate0/data.csv: the velocities change by "),
    ("state_groundtruth_estimate0", _scaled_columns({8, 9, 10}, 0.1),
     "state_groundtruth_estimate0/data.csv: on axis x the positions move 10 times as far as the velocities say"),
    ("imu0", _scaled_columns({4, 5, 6}, 1 / 9.81),
     "imu0/data.csv: the accelerometer reads 0.102 times the specific force the motion capture shows in flight, "
     "in the same directions: it must be in m/s^2 (not g)"),
    ("imu0", lambda i, l: ",".join(v if k != 6 else f"{float(v) - 9.81:.9g}" for k, v in enumerate(l.split(","))),
     "m/s^2 (the specific force that holds the vehicle up): gravity was taken out (a linear acceleration); imu0 must "
     "hold what an accelerometer reads, gravity included"),
    ("imu0", lambda i, l: ",".join(v if k != 6 else "9.81" for k, v in enumerate(l.split(","))),  # hid the effects
     "imu0/data.csv: the accelerometer's z axis barely moves, 0.000 m/s^2 rms (0.25 s means in flight, body frame), "
     "where the motion capture's specific force along it moves by"),
    ("imu0", _scaled_columns({1, 2, 3}, 180 / np.pi),
     "the rate the motion capture's attitude turns at (0.25 s means in flight, body frame): it must be in rad/s, "
     "not deg/s"),
    ("state_groundtruth_estimate0",  # quaternions written x, y, z, w
     lambda i, l: ",".join(l.split(",")[:4] + l.split(",")[5:8] + [l.split(",")[4]] + l.split(",")[8:]),
     "state_groundtruth_estimate0/data.csv: the accelerometer and the motion capture's specific force differ by 2 g "
     "rms, and by 0.0"),
    ("rotors0", lambda i, l: ",".join([l.split(",")[0]] + ["524"] * (len(l.split(",")) - 1)),
     "rotors0/data.csv: every rotor column holds one value throughout while the vehicle moves up and down"),
])
def test_units_and_frames_that_pass_the_format_are_refused(tmp_path, capsys, good, stream, rewrite, match):
    """Positions in millimetres, velocities a tenth of what they are, an accelerometer in g, quaternions in x, y, z,
    w order:
    each reads as a valid file and had given a report naming nothing over a residual the size of the weight (a
    gyroscope in deg/s, an inertia 57 times off from identify)."""
    rec = _copy(good, tmp_path)
    _rewrite_csv(rec / "mav0" / stream / "data.csv", rewrite)
    _gap_fails(tmp_path, capsys, [rec], match=match)


def test_quaternions_written_x_y_z_w_are_refused_without_an_imu_too(tmp_path, capsys):
    """Without an IMU no gyroscope tells the quaternions' order: the probe's quadrotor, its columns stored x, y, z, w,
    gave exit 0 and a report whose nominal model missed by 99 % of the weight. The rotor axis against the motion
    capture's specific force tells it (median over rows in flight) where the heading turns; the file as written
    reads within a few degrees. (A flight that holds its heading reads alike both ways: no refusal.)"""
    rec = tmp_path / "turning"
    generate_flight(vehicle="hex", effects="none", duration=40.0, kind="mixed", seed=3, out=rec)  # it turns
    shutil.rmtree(rec / "mav0" / "imu0")
    (kept,) = load_recordings([rec])
    read, swapped = check_quaternion_order(kept)
    assert read < 3.0 and swapped > 20.0
    _rewrite_csv(rec / "mav0" / "state_groundtruth_estimate0" / "data.csv",
                 lambda i, l: ",".join(l.split(",")[:4] + l.split(",")[5:8] + [l.split(",")[4]] + l.split(",")[8:]))
    line = _gap_fails(tmp_path, capsys, [rec], match="state_groundtruth_estimate0/data.csv: the rotor axis lies ")
    assert re.search(r"deg with the quaternion columns read as x, y, z, w: quaternions must be stored w, x, y, z", line)


def test_a_flight_under_the_floor_of_its_room_is_refused(tmp_path, capsys, good):
    """A room's cloud in another frame than the flight's (raised by 5 m), and no IMU: the whole flight lies under
    the room's floor, which read as a ceiling. A blind probe's flight with z-down positions (no IMU) had so named a
    ceiling effect; the vertical response refuses that one first (the next test)."""
    rec = _copy(good, tmp_path)
    shutil.rmtree(rec / "mav0" / "imu0")
    cloud = rec / "mav0" / "pointcloud0" / "data.ply"
    write_ply(cloud, read_ply(cloud) + np.array([0.0, 0.0, 5.0]))
    _gap_fails(tmp_path, capsys, [rec], match="state_groundtruth_estimate0/data.csv: the rotor plane flies under the "
                                              "point cloud's floor in 100 % of the rows")


def test_a_flight_with_z_down_over_a_flat_floor_is_refused_by_its_vertical_response(tmp_path, capsys, good):
    """The same z-down positions over a cloud of one flat layer (a floor, or a ceiling scanned alone: the flight may
    lie under it): the vehicle accelerates down when its rotors speed up. A Neural-Swarm walk so negated had
    reported no surface below the vehicle and a rejected ceiling effect."""
    rec = _copy(good, tmp_path)
    shutil.rmtree(rec / "mav0" / "imu0")
    cloud = rec / "mav0" / "pointcloud0" / "data.ply"
    points = read_ply(cloud)
    floor = float(np.percentile(points[:, 2], 1.0))
    xs, ys = np.meshgrid(np.linspace(-10, 10, 41), np.linspace(-10, 10, 41))
    write_ply(cloud, np.column_stack([xs.ravel(), ys.ravel(), np.full(xs.size, floor)]))
    (kept,) = load_recordings([rec])  # z up over the flat floor: read
    assert check_vertical_response(kept, MIN_VERTICAL_CORRELATION_RECORDING) > 0.5
    _rewrite_csv(rec / "mav0" / "state_groundtruth_estimate0" / "data.csv", _scaled_columns({3, 10}, -1.0))
    line = _gap_fails(tmp_path, capsys, [rec], match="state_groundtruth_estimate0/data.csv: the vehicle accelerates "
                                                     "down when its rotors speed up (correlation -0.")
    assert line.endswith("the world's z axis looks inverted against the attitudes (positions and velocities with z "
                         "down, NED, beside quaternions with z up?; recordings.md: world z up)")


def test_velocities_left_at_zero_are_taken_from_the_positions(tmp_path, capsys, good):
    """An exporter that left every velocity at 0 (the positions move): the velocities are the positions'
    derivative, said in one note, and the report is the complete file's (it had been refused: "the positions move
    infinitely many times as far as the velocities say")."""
    rec = _copy(good, tmp_path)
    _rewrite_csv(rec / "mav0" / "state_groundtruth_estimate0" / "data.csv", _scaled_columns({8, 9, 10}, 0.0))
    (loaded,) = load_recordings([rec])
    assert any(n.startswith("rec/state_groundtruth_estimate0: every velocity is 0 while the positions move over")
               for n in loaded.read_notes)
    (full,) = load_recordings([good])
    inside = slice(20, -20)  # the derivative's edges aside
    miss = np.abs(loaded.ground_truth.v[inside] - full.ground_truth.v[inside])
    assert np.sqrt(np.mean(miss**2)) < 0.05 and np.abs(full.ground_truth.v).max() > 0.5  # noise over 50 ms
    out = tmp_path / "report"
    assert main(["gap", str(rec), "--out", str(out), "--sim-effects", "none", "--no-mlflow"]) == 0
    assert json.loads((out / "report.json").read_text())["effects"] == []


def _shifted_stamps(seconds):
    return lambda i, l: ",".join([str(int(l.split(",")[0]) + int(round(seconds * 1e9)))] + l.split(",")[1:])


@pytest.mark.parametrize("seconds, said", [(0.3, r"0\.(29|30|31) s late"), (2.0, r"(1\.9\d|2\.0\d) s late"),
                                           (-1.5, r"1\.(4\d|5\d) s early")])
def test_an_imu_on_another_clock_is_refused(tmp_path, capsys, good, seconds, said):
    """IMU timestamps 0.3 s late against the motion capture: a residual of the thrust's swings that no effect
    explains, and a report naming nothing. The offset is found by the vertical specific force and said, up to
    5 s either way."""
    rec = _copy(good, tmp_path)
    _rewrite_csv(rec / "mav0" / "imu0" / "data.csv", _shifted_stamps(seconds))
    line = _gap_fails(tmp_path, capsys, [rec], match="imu0/data.csv: its specific force matches the motion capture's "
                                                     "best ")
    assert re.search(f"best {said} ", line) and line.endswith("it must be stamped on the ground truth's clock")


@pytest.mark.parametrize("seconds, said", [(0.3, r"0\.(29|30|31) s late"), (1.0, r"(0\.9\d|1\.0\d) s late"),
                                           (-3.0, r"(2\.9\d|3\.0\d) s early")])
def test_rotor_speeds_on_another_clock_are_refused(tmp_path, capsys, good, seconds, said):
    """Commanded rotor speeds stamped 0.3 s late: beyond any motor lag or telemetry delay, no effect of the
    vocabulary explains it (the report had named nothing); the offset is found by the vertical thrust. Rotors
    1 s late had passed (the search stopped at 0.6 s): a 0.5 N residual beside a report naming the right wind."""
    rec = _copy(good, tmp_path)
    _rewrite_csv(rec / "mav0" / "rotors0" / "data.csv", _shifted_stamps(seconds))
    line = _gap_fails(tmp_path, capsys, [rec], match="rotors0/data.csv: its vertical thrust matches the motion "
                                                     "capture's best ")
    assert re.search(f"best {said} ", line), line


@pytest.mark.parametrize("stream, seconds, match", [
    ("imu0", 0.1, r"imu0/data.csv: its specific force matches the motion capture's best 0\.(09|10|11) s late"),
    ("rotors0", 0.15, r"rotors0/data.csv: its vertical thrust matches the motion capture's best 0\.1\d s late .* "
                      r"\(commanded speeds lead the force they make by a motor lag; they cannot trail it\)"),
])
def test_a_stream_a_tenth_of_a_second_off_the_clock_is_refused(tmp_path, capsys, good, stream, seconds, match):
    """An IMU 0.1 s late (its correlation with the motion capture 0.95 against 0.87 as stamped: not the clear gain
    asked of far offsets) and commanded rotor speeds 0.15 s late (commands lead the force; they had passed, the
    held-out error up to nine times larger and a false ground contact) are refused in one line."""
    rec = _copy(good, tmp_path)
    _rewrite_csv(rec / "mav0" / stream / "data.csv", _shifted_stamps(seconds))
    line = _gap_fails(tmp_path, capsys, [rec], match=f"{stream}/data.csv: its ")
    assert re.search(match, line), line


@pytest.mark.parametrize("also_late_s, refused", [(0.0, False), (0.04, False), (0.1, True), (0.15, True)])
def test_round_robin_telemetry_a_little_late_is_read_on_each_rotors_updates(tmp_path, also_late_s, refused):
    """Rotor speeds reported one ESC at a time at 10 Hz and 40 ms late (``recordings.md``: telemetry 40-80 ms
    late), with no ``rotor_speed_source``: the rows any rotor changes on are nearly every row, and read as the
    stream's updates they had kept each rotor's 50 ms half step, read 0.08 s late and refused by every command
    (a probe's). Each rotor is now read between its own updates, and 80 ms late passes (the telemetry's range in
    ``recordings.md``, where vehicle.yaml does not say the speeds are measured); 0.14 s late is still refused, and
    0.19 s (0.94 against 0.16 as stamped: it had passed, under the stamps' least correlation)."""
    rec = tmp_path / "stag"
    generate_conditioned_flight("hex", "none", duration=20.0, kind="mixed", seed=31, out=rec,
                                conditions=Conditions(rotor_hold_hz=10, rotor_hold_staggered=True,
                                                      rotor_delay_s=0.04))
    assert staggered(read_recording(rec).rotors.speeds)
    _rewrite_csv(rec / "mav0" / "rotors0" / "data.csv", _shifted_stamps(also_late_s))
    if refused:
        with pytest.raises(InputError, match=r"rotors0/data.csv: its vertical thrust matches the motion capture's "
                                             r"best 0\.1\d s late .* they cannot trail it\): it must be stamped .* "
                                             r"rotor_speed_source: measured\)"):
            check_rotor_clock(read_recording(rec))
    else:
        assert check_rotor_clock(read_recording(rec)) is None


@pytest.fixture(scope="module")
def landed(tmp_path_factory):
    """A flight that rests 3 s on its landing gear at both ends (the contact its cloud must agree with)."""
    path = tmp_path_factory.mktemp("gapland") / "landed"
    assert main(["generate", "flight", "--kind", "low_passes", "--duration", "20", "--seed", "5",
                 "--effects", "ground_effect:mu=2", "--ground-contact-s", "3", "--out", str(path)]) == 0
    return path


def test_a_landed_flight_with_its_cloud_passes(tmp_path, landed):
    assert main(["gap", str(landed), "--out", str(tmp_path / "r"), "--sim-effects", "none", "--no-mlflow"]) == 0


@pytest.mark.parametrize("move, said", [
    (lambda p: p + [0.0, 0.0, 0.5] * (p[:, 2:3] < 0.05), "puts no surface under its rotor plane there"),
    (lambda p: p - [0.0, 0.0, 0.5] * (p[:, 2:3] < 0.05),
     "m over the surface below it there (a landing gear is at most 0.5 m)"),
    (lambda p: p * 1000.0 + [0.0, 0.0, 0.2], "puts no surface under its rotor plane there"),
])
def test_a_point_cloud_whose_floor_is_not_under_the_landed_vehicle_is_refused(tmp_path, capsys, landed, move, said):
    """The floor of the cloud 0.5 m up, 0.5 m down, or the cloud in millimetres (its floor 0.2 m up): the contact
    found from the cloud's heights missed the vehicle resting on its gear, whose floor reaction was analysed as
    flight (a 2.7 N residual, nothing named, on the probe's flights; a cloud in millimetres gave no heights)."""
    rec = _copy(landed, tmp_path)
    cloud = rec / "mav0" / "pointcloud0" / "data.ply"
    write_ply(cloud, move(read_ply(cloud)))
    line = _gap_fails(tmp_path, capsys, [rec], match="pointcloud0/data.ply: the vehicle rests on its landing gear (")
    assert said in line and line.endswith("the cloud's floor is not where the ground truth lands (its height, units or "
                                          "frame off)")


def test_a_point_cloud_in_millimetres_with_its_floor_at_zero_is_read_and_said(tmp_path, landed):
    """A scan written in millimetres whose floor lies at z = 0: the floor's heights are right in any unit (the
    floor's plane answers where the footprint finds no point), and the report says the cloud's span."""
    rec = _copy(landed, tmp_path)
    cloud = rec / "mav0" / "pointcloud0" / "data.ply"
    write_ply(cloud, read_ply(cloud) * 1000.0)
    report, _ = analyse(load_recordings([rec]), {})
    assert [e["name"] for e in report["effects"]] == ["ground_effect"]
    assert any("the cloud spans 8e+03 m where the flight spans" in line and "millimetres" in line
               for line in report["streams"]["streams"])


def test_one_recording_given_twice_is_refused(tmp_path, capsys, good):
    """The same folder twice (once through a link) would count as two agreeing sessions."""
    rec = _copy(good, tmp_path)
    (tmp_path / "again").symlink_to(rec)
    _gap_fails(tmp_path, capsys, [rec, tmp_path / "again"],
               match=f"{tmp_path / 'again'}: is given twice (also as {rec})")


def test_one_flight_under_two_folders_is_refused_even_restamped(tmp_path, capsys, good, another):
    """A copy of a flight (here also stamped an hour later) counted as a second session that agrees: every stated
    error shrank by about sqrt(2) and the spread between recordings read zero for it."""
    rec, copy = _copy(good, tmp_path), _copy(good, tmp_path, "copy")
    for csv in (copy / "mav0").glob("*/data.csv"):
        _rewrite_csv(csv, lambda i, l: ",".join([str(int(l.split(",")[0]) + 3_600_000_000_000), *l.split(",")[1:]]))
    _gap_fails(tmp_path, capsys, [rec, copy], match=f"{copy}: holds the same flight as {rec} (the same ground-truth "
                                                    "positions and attitudes, row for row)")
    assert not (tmp_path / "report").exists()
    other = _copy(another, tmp_path, "other")  # another flight of the same vehicle is welcome
    assert [r.name for r in load_recordings([rec, other])] == ["rec", "other"]


def test_recordings_named_alike_are_told_apart_by_their_parent_folders(tmp_path):
    assert recording_labels(["x/day1/flight", "x/day2/flight", "y/other"]) == ["day1/flight", "day2/flight", "other"]
    assert recording_labels(["a/s/f", "b/s/f"]) == ["a/s/f", "b/s/f"]  # as many parents as it takes
    assert recording_labels(["m/a", "m/b"]) == ["a", "b"]
    assert recording_labels([tmp_path / "d1" / "log", "d2/log"])[0] == "d1/log"  # absolute or relative alike


def test_sessions_whose_folders_share_a_name_keep_their_own_entries(tmp_path, good, another):
    """Two days' logs both called ``flight``: per-recording results keyed by the folder's name alone merged into
    one entry (a thrust coefficient and an accelerometer bias lost, report.md's lines alike)."""
    one, two = _copy(good, tmp_path / "day1", "flight"), _copy(another, tmp_path / "day2", "flight")
    recs = load_recordings([one, two])
    assert [r.name for r in recs] == ["day1/flight", "day2/flight"]
    assert load_recordings([one])[0].name == "flight" and load_recordings([one])[0].label is None
    out = tmp_path / "report"
    assert main(["gap", str(one), str(two), "--out", str(out), "--sim-effects", "none", "--no-mlflow"]) == 0
    report = json.loads((out / "report.json").read_text())
    assert set(report["nominal"]["thrust_coefficient_per_recording"]) == {"day1/flight", "day2/flight"}
    md = (out / "report.md").read_text()
    assert "- day1/flight/rotors0: " in md and "- day2/flight/rotors0: " in md


def test_an_optional_stream_with_no_rows_is_read_as_absent_and_said(tmp_path, good):
    """A logger that opened ``imu0`` and ``battery0`` and never wrote a row: the recording is analysed without them
    (both optional, ``recordings.md``), and the read notes say so; it had been refused whole."""
    rec = _copy(good, tmp_path)
    imu = rec / "mav0" / "imu0" / "data.csv"
    imu.write_text(imu.read_text().splitlines()[0] + "\n")
    (rec / "mav0" / "battery0").mkdir(exist_ok=True)
    (rec / "mav0" / "battery0" / "data.csv").write_text("#timestamp [ns],voltage [V]\n\n")
    loaded = read_recording(rec)
    assert loaded.imu is None and loaded.battery is None
    assert f"{rec.name}/imu0/data.csv holds no data rows: read as absent (the stream is optional)" in loaded.read_notes
    assert any(n.startswith(f"{rec.name}/battery0/data.csv holds no data rows") for n in loaded.read_notes)
    assert read_recording(good).imu is not None  # a stream with rows is read as before


def test_nan_in_imu_is_a_dropout_and_inf_is_refused(tmp_path, capsys, good):
    """An IMU row with a value missing is left out and said (the stream has a dropout there, as the ground truth's
    and the rotors'); an infinite value is refused naming the line."""
    rec = _copy(good, tmp_path)
    imu = rec / "mav0" / "imu0" / "data.csv"
    rows = len(imu.read_text().splitlines()) - 1
    _rewrite_csv(imu, lambda i, l: ",".join(l.split(",")[:4] + ["nan"] + l.split(",")[5:]) if i == 100 else l)
    (loaded,) = load_recordings([rec])
    assert any("imu0/data.csv: 1 row with a value missing (empty or NaN: no sample logged) left out, in 1 stretch "
               "from line 102: read as dropouts" in n for n in loaded.read_notes)
    assert len(loaded.imu.t_ns) == rows - 1
    _rewrite_csv(imu, lambda i, l: ",".join(l.split(",")[:4] + ["inf"] + l.split(",")[5:]) if i == 200 else l)
    _gap_fails(tmp_path, capsys, [rec], match="imu0/data.csv: line 202, column 5: value inf is not finite")


def test_nan_in_groundtruth_is_a_missing_row_and_inf_is_refused(tmp_path, capsys, good):
    """A NaN in the ground truth is a motion capture that lost the vehicle for a row: left out and said, the
    analysis runs; an infinite value is no measurement and is refused naming the line."""
    rec = _copy(good, tmp_path)
    _rewrite_csv(rec / "mav0" / "state_groundtruth_estimate0" / "data.csv",
                 lambda i, l: ",".join(l.split(",")[:2] + ["NaN"] + l.split(",")[3:]) if i == 50 else l)
    (loaded,) = load_recordings([rec])
    assert any("1 row with a value missing (empty or NaN: tracking lost) left out, in 1 stretch from line 52" in n
               for n in loaded.read_notes)
    _rewrite_csv(rec / "mav0" / "state_groundtruth_estimate0" / "data.csv",
                 lambda i, l: ",".join(l.split(",")[:2] + ["inf"] + l.split(",")[3:]) if i == 60 else l)
    line = _gap_fails(tmp_path, capsys, [rec], match="state_groundtruth_estimate0/data.csv: line 62, column 3: value "
                                                     "inf is not finite")
    assert "Traceback" not in line


def test_missing_rotor_speeds_are_dropouts_and_inf_is_refused(tmp_path, capsys, good):
    """Rotor speeds missing (NaN or an empty field: ESC telemetry that logged none) leave their rows out, said, and
    the stream has a dropout there; an infinite speed is refused naming the line."""
    rec = _copy(good, tmp_path)
    csv = rec / "mav0" / "rotors0" / "data.csv"
    _rewrite_csv(csv, lambda i, l: ",".join(l.split(",")[:2] + ["nan"] + l.split(",")[3:]) if 300 <= i < 320 else
                 ",".join(l.split(",")[:3] + [""] + l.split(",")[4:]) if i == 700 else l)
    (loaded,) = load_recordings([rec])
    assert any("rotors0/data.csv: 21 rows with a value missing (empty or NaN: no speed logged) left out, in 2 "
               "stretches from line 302: read as dropouts" in n for n in loaded.read_notes)
    assert len(loaded.rotors.t_ns) == len(csv.read_text().splitlines()) - 1 - 21
    _rewrite_csv(csv, lambda i, l: ",".join(l.split(",")[:2] + ["inf"] + l.split(",")[3:]) if i == 60 else l)
    line = _gap_fails(tmp_path, capsys, [rec], match="rotors0/data.csv: line 62, column 3: value inf is not finite")
    assert "Traceback" not in line


def test_missing_battery_readings_are_left_out(tmp_path, good):
    """A battery0 row with its voltage or current missing (NaN, empty) is left out and said; the voltage is
    interpolated over the rest."""
    rec = _copy(good, tmp_path)
    (rec / "mav0" / "battery0").mkdir(exist_ok=True)
    t0 = int((rec / "mav0" / "rotors0" / "data.csv").read_text().splitlines()[1].split(",")[0])
    rows = [f"{t0 + k * 100_000_000},{16.0 - 0.01 * k:.2f},{'nan' if k == 5 else 12.0}" for k in range(120)]
    rows[7] = f"{t0 + 700_000_000},,12.0"
    (rec / "mav0" / "battery0" / "data.csv").write_text("#timestamp [ns],voltage [V],current [A]\n"
                                                         + "\n".join(rows) + "\n")
    (loaded,) = load_recordings([rec])
    assert len(loaded.battery.t_ns) == 118 and loaded.battery.voltage[5] == pytest.approx(15.94)
    assert any("battery0/data.csv: 2 rows with a value missing (empty or NaN: no reading logged) left out, in 2 "
               "stretches from line 7: the voltage is interpolated over them" in n for n in loaded.read_notes)


def test_two_recordings_of_different_vehicles(tmp_path, capsys, good):
    a = _copy(good, tmp_path, "a")
    b = _copy(good, tmp_path, "b")
    text = (b / "vehicle.yaml").read_text()
    (b / "vehicle.yaml").write_text(text.replace("mass: 1.5", "mass: 2.5"))
    assert "mass: 2.5" in (b / "vehicle.yaml").read_text()
    _gap_fails(tmp_path, capsys, [a, b], match="vehicle.yaml")


def test_unknown_sim_effect(tmp_path, capsys, good):
    out = tmp_path / "report"
    code = main(["gap", str(good), "--out", str(out), "--sim-effects", "gust", "--no-mlflow"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code != 0 and len(err) == 1 and "--sim-effects" in err[0] and "gust" in err[0]
    assert not out.exists()


def test_out_parent_missing_is_created(tmp_path, good):
    out = tmp_path / "no" / "such" / "dir"
    assert main(["gap", str(good), "--out", str(out), "--no-mlflow"]) == 0
    assert (out / "report.json").is_file()


def test_out_never_deletes_a_users_files(tmp_path, capsys, good):
    out = tmp_path / "notes"
    out.mkdir()
    (out / "my_notes.txt").write_text("keep")
    code = main(["gap", str(good), "--out", str(out), "--no-mlflow", "--overwrite"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and "not written by uavturb" in err[0]
    assert sorted(p.name for p in out.iterdir()) == ["my_notes.txt"]
    # a report folder uavturb wrote is replaced only with --overwrite
    rep = tmp_path / "rep"
    assert main(["gap", str(good), "--out", str(rep), "--no-mlflow"]) == 0
    assert main(["gap", str(good), "--out", str(rep), "--no-mlflow"]) == 2
    assert "--overwrite" in capsys.readouterr().err
    assert main(["gap", str(good), "--out", str(rep), "--no-mlflow", "--overwrite"]) == 0


def test_out_current_directory_is_refused(tmp_path, monkeypatch, capsys, good):
    work = tmp_path / "checkout"
    work.mkdir()
    (work / "mlflow.db").write_text("store")
    monkeypatch.chdir(work)
    assert main(["gap", str(good), "--out", ".", "--no-mlflow", "--overwrite"]) == 2
    assert (work / "mlflow.db").read_text() == "store"


def test_default_sim_effects_follow_the_simulator_config(tmp_path, good):
    from pathlib import Path

    from uavturb.commands.gap import gap
    from uavturb.io.physics_config import load_physics_config

    conf = load_physics_config(Path(__file__).parents[1] / "uavturb" / "conf" / "physics" / "default.yaml")["effects"]
    report = gap([str(good)], tmp_path / "r", log_mlflow=False)
    assert report["sim_effects"] == list(conf)
    assert set(report["sim_effect_params"]) == set(conf)
    for name, params in conf.items():
        assert report["sim_effect_params"][name]["sim"] == pytest.approx(params)
    assert np.isfinite(report["final"]["heldout_rmse_N"])


def test_rotor_quantum_and_rounding_floor_known_answers():
    from uavturb.numerics.stream_updates import rotor_quantum

    rng = np.random.default_rng(0)
    w = rng.uniform(400, 700, size=(1000, 6))
    assert rotor_quantum(np.round(w)) == pytest.approx(1.0)
    assert rotor_quantum(np.round(w / 5.0) * 5.0) == pytest.approx(5.0)  # EuRoC-like: integer units times a scale
    assert rotor_quantum(w) == 0.0  # not quantised
    # commands u = (w - a) / b of speeds rounded to 1 rad/s, written as u times a scale of 350 rad/s: steps of
    # 350 / b rad/s on a lattice offset from zero (a = 37.5 rad/s, b = 262.5 rad/s)
    written = 350.0 * (np.round(w) - 37.5) / 262.5
    assert rotor_quantum(written) == pytest.approx(350.0 / 262.5)
    assert rotor_quantum(written + 0.3) == pytest.approx(350.0 / 262.5)
    assert rotor_quantum(350.0 * (w - 37.5) / 262.5) == 0.0
    stopped = np.vstack([np.zeros((200, 6)), written])  # rotors stopped on the ground: zeros, off the lattice
    assert rotor_quantum(stopped) == pytest.approx(350.0 / 262.5)
    # the floor: (2 k_T)^2 sum(w_i^2) q^2 / 12 at six rotors of 536 rad/s, q = 1 rad/s
    from types import SimpleNamespace

    from uavturb.gap.design import rounding_floor

    data = SimpleNamespace(S=np.full(10, 6 * 536.0**2))
    assert rounding_floor(data, 8.54858e-6, 1.0) == pytest.approx((2 * 8.54858e-6) ** 2 * 6 * 536.0**2 / 12)
    assert rounding_floor(data, 8.54858e-6, 0.0) == 0.0
    # the share of sum(w^2) a steady hover's rounding leaves: q / sqrt(3) / sqrt(sum(w_i^2)) at the median row
    from uavturb.numerics.stream_updates import rounding_share

    hover = np.full((50, 4), 500.0)
    assert rounding_share(hover, 1.0) == pytest.approx(1.0 / np.sqrt(3.0) / 1000.0)
    assert rounding_share(hover, 0.0) == 0.0
    # the same by simulation: speeds rounded once and held, the relative error of their sum of squares
    errs = [np.sum(np.round(w0) ** 2) / np.sum(w0**2) - 1 for w0 in rng.uniform(499.5, 500.5, size=(4000, 4))]
    assert np.std(errs) == pytest.approx(rounding_share(hover, 1.0), rel=0.05)


def test_an_output_that_would_replace_or_enter_an_input_is_refused(tmp_path, capsys, good):
    # `gap REC --out REC --overwrite` once replaced the recording it had just read with its report
    rec = _copy(good, tmp_path)
    before = sorted(p.relative_to(rec) for p in rec.rglob("*"))
    for out, extra, match in [
        (rec, [], f"{rec}: is an input of this command: --out would replace or change it"),
        (tmp_path, [], f"{tmp_path}: holds an input of this command ({rec})"),
        (rec / "report", [], f"lies inside an input of this command ({rec})"),
        (tmp_path / "report", ["--apply", str(tmp_path / "report" / "physics.yaml")],
         "physics.yaml: lies inside --out"),
        (tmp_path / "report", ["--apply", str(rec / "vehicle.yaml")],
         "vehicle.yaml: lies inside an input of this command"),
    ]:
        code = main(["gap", str(rec), "--out", str(out), "--overwrite", "--sim-effects", "none", "--no-mlflow", *extra])
        err = capsys.readouterr().err
        assert code == 2 and len(err.strip().splitlines()) == 1 and match in err, err
    assert sorted(p.relative_to(rec) for p in rec.rglob("*")) == before and not (tmp_path / "report").exists()
    # residuals: a file inside the recording it reads
    code = main(["residuals", str(rec), "--out", str(rec / "mav0" / "imu0" / "data.csv"), "--overwrite"])
    assert code == 2 and "lies inside an input of this command" in capsys.readouterr().err
    assert sorted(p.relative_to(rec) for p in rec.rglob("*")) == before


def test_values_no_flight_holds_are_named_by_line_and_column(tmp_path, capsys, good):
    rec = _copy(good, tmp_path)
    state = rec / "mav0" / "state_groundtruth_estimate0" / "data.csv"
    _rewrite_csv(state,
                 lambda i, l: l if i != 100 else ",".join(c if j != 8 else "1e300" for j, c in enumerate(l.split(","))))
    _gap_fails(tmp_path, capsys, [rec], match="data.csv: line 102, column 9: 1e+300 m/s, beyond the 1e+03 m/s of any "
                                              "multirotor's flight (1 value over it)")
    rec = _copy(good, tmp_path, "rec2")
    points = read_ply(rec / "mav0" / "pointcloud0" / "data.ply")
    points[0] = [3e38, 0.0, 0.0]
    write_ply(rec / "mav0" / "pointcloud0" / "data.ply", points)
    _gap_fails(tmp_path, capsys, [rec], match="PLY vertex 0 lies 3e+38 m from the origin")


def test_a_vehicle_file_giving_a_key_twice_or_a_mass_no_multirotor_has_is_refused(tmp_path, capsys, good):
    rec = _copy(good, tmp_path)
    text = (rec / "vehicle.yaml").read_text()
    (rec / "vehicle.yaml").write_text(text + "mass: 2.5\n")
    _gap_fails(tmp_path, capsys, [rec], match="vehicle.yaml: refused: gives key 'mass' twice")
    (rec / "vehicle.yaml").write_text(re.sub(r"(?m)^mass: .*$", "mass: 1.0e-09", text))
    _gap_fails(tmp_path, capsys, [rec], match="key 'mass' is 1e-09 kg, under 0.001 kg")



def test_a_vehicle_file_with_a_key_misspelt_or_a_rotor_plane_metres_away_is_refused(tmp_path, capsys, good):
    """The probe's typos (``thrust_coeficient``, ``rotor_plane_Z``) had been dropped without a word (k_T identified
    instead; the rotor plane taken at the origin), and a rotor_plane_z of 4 m blamed on the point cloud. A key that
    is not read and is not a near miss of one absent stays (a note for the reader of the file)."""
    rec = _copy(good, tmp_path)
    text = (rec / "vehicle.yaml").read_text()
    without_k_T = re.sub(r"(?m)^thrust_coefficient: .*\n", "", text)
    for typo, meant in (("thrust_coeficient: 8.5e-06", "thrust_coefficient"), ("rotor_plane_Z: 0.15", "rotor_plane_z")):
        (rec / "vehicle.yaml").write_text(without_k_T + typo + "\n")
        _gap_fails(tmp_path, capsys, [rec], match=f"vehicle.yaml: key '{typo.split(':')[0]}' is not a vehicle.yaml "
                                                  f"key: did you mean '{meant}'")
    (rec / "vehicle.yaml").write_text(text + "rotor_plane_z: 4.0\n")
    _gap_fails(tmp_path, capsys, [rec],
               match="vehicle.yaml: key 'rotor_plane_z' is 4 m: the rotor plane lies within 1 m")
    (rec / "vehicle.yaml").write_text(text + "notes: built in 2024\nframe: hex\n")
    (kept,) = load_recordings([rec])
    assert kept.vehicle.extra == {"notes": "built in 2024", "frame": "hex"}


def test_a_battery_stream_is_listed_but_sets_no_update_rate(good):
    rec = read_recording(good)
    plain = stream_limits(rec)
    t = rec.ground_truth.t_ns[::20]
    with_battery = stream_limits(replace(rec, battery=Battery(t_ns=t, voltage=np.linspace(16.4, 15.2, len(t)),
                                                              current=np.full(len(t), 9.0))))
    assert with_battery[0][:-1] == plain[0] and with_battery[1:] == plain[1:]  # the slowest rate: the same
    assert with_battery[0][-1].endswith("read by battery_voltage where the rotor speeds are commanded and it covers "
                                        "the flight")
    late = stream_limits(replace(rec, battery=Battery(t_ns=t + 10**12, voltage=np.full(len(t), 16.0),
                                                      current=np.full(len(t), 9.0))))
    assert "outside the ground truth in time" in late[0][-1]


def test_a_ground_truth_thinned_to_half_its_update_rate(good):
    """The stream rate term's input: a ground truth updating at 15 Hz comes back updating at 7.5 Hz, each kept
    update's values held through the next one's rows; too slow for a surface effect now, it is keyed for it."""
    rec = read_recording(good)
    gt = rec.ground_truth
    n = int(round(len(gt) / ((gt.t_ns[-1] - gt.t_ns[0]) * 1e-9) / 15.0))  # rows per update at 15 Hz
    src = (np.arange(len(gt)) // n) * n
    held = replace(rec, ground_truth=GroundTruth(t_ns=gt.t_ns, p=gt.p[src], q=gt.q[src], v=gt.v[src],
                                                 b_w=gt.b_w[src], b_a=gt.b_a[src]))
    thinned = state_thinned(held).ground_truth
    want = (np.arange(len(gt)) // (2 * n)) * (2 * n)
    assert np.array_equal(thinned.p, gt.p[want]) and np.array_equal(thinned.q, gt.q[want])
    assert np.array_equal(thinned.v, gt.v[want]) and np.array_equal(thinned.t_ns, gt.t_ns)
    assert "surface" not in stream_limits(held)[1]
    limits = stream_limits(replace(held, ground_truth=thinned))[1]
    assert "heights crossed in 0.2 s" in limits["surface"] and "motor_lag" not in limits


def test_a_thrust_leading_the_force_while_the_torques_keep_time_is_read_as_stamped(tmp_path, capsys, good):
    """Only the collective part of sum(w^2) 0.3 s ahead (a controller raising the thrust before a disturbance it
    expects; Neural-Swarm's downwash swaps led by 0.18-0.32 s): the thrust alone reads the stream 0.30 s early, as
    a stream on another clock would, but the roll and pitch torques keep time on the stamps, so the recording is
    read as stamped and the report says why. The whole stream 0.3 s off is still refused (above)."""
    rec = _copy(good, tmp_path)
    path = rec / "mav0" / "rotors0" / "data.csv"
    lines = path.read_text().splitlines()
    rows = np.array([[float(v) for v in line.split(",")] for line in lines[1:]])
    t = (rows[:, 0] - rows[0, 0]) * 1e-9
    w2 = rows[:, 1:] ** 2
    collective = w2.mean(axis=1)
    led = np.sqrt(np.maximum(w2 - collective[:, None] + np.interp(t + 0.3, t, collective)[:, None], 0.0))
    path.write_text("\n".join([lines[0]] + [",".join([str(int(r[0]))] + [repr(float(v)) for v in w])
                                            for r, w in zip(rows, led)]) + "\n")
    note = check_rotor_clock(read_recording(rec))
    assert re.search(r"the vertical thrust matches the motion capture's best 0\.(29|30|31) s early", note), note
    assert "the roll and pitch torques keep time on the stamps" in note and note.startswith(str(rec))
    out = tmp_path / "report"
    assert main(["gap", str(rec), "--out", str(out), "--sim-effects", "none", "--no-mlflow"]) == 0
    assert note in (out / "report.md").read_text()
    assert note in json.loads((out / "report.json").read_text())["streams"]["streams"]


def test_a_reader_that_stops_reading_ends_the_command_quietly(tmp_path, good):
    """``uavturb gap ... | head -0``: stdout's reader is gone before the summary is printed. The report is written,
    and the command stops as one killed by SIGPIPE would (141), with nothing on stderr (it had said "error: a file:
    Broken pipe")."""
    read, write = os.pipe()
    os.close(read)
    out = tmp_path / "report"
    done = subprocess.run([sys.executable, "-m", "uavturb.cli", "gap", str(good), "--out", str(out), "--sim-effects",
                           "none", "--no-mlflow"], stdout=write, stderr=subprocess.PIPE, text=True, timeout=300)
    os.close(write)
    assert done.returncode == 141 and done.stderr == ""
    assert (out / "report.json").exists() and (out / "report.md").exists()


def test_the_program_ends_at_once_after_gap_with_its_output_and_status(tmp_path, good):
    """``uavturb gap`` as a program (``cli.console``) ends without the interpreter's teardown (``cli.QUICK_EXIT``):
    its summary is printed whole (flushed first), its status kept, on success and on a bad input alike."""
    out = tmp_path / "report"
    done = subprocess.run([sys.executable, "-m", "uavturb.cli", "gap", str(good), "--out", str(out), "--sim-effects",
                           "none", "--no-mlflow"], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    lines = done.stdout.splitlines()
    assert lines[0].startswith("effects named:") and lines[-1].endswith(f"report in {out}")
    assert json.loads((out / "report.json").read_text())["recordings"] == [str(good)]
    bad = subprocess.run([sys.executable, "-m", "uavturb.cli", "gap", str(tmp_path / "missing"), "--out",
                          str(tmp_path / "bad")], capture_output=True, text=True, timeout=300)
    assert bad.returncode == 2 and bad.stdout == "" and len(bad.stderr.splitlines()) == 1
    assert "missing" in bad.stderr and not (tmp_path / "bad").exists()


def test_an_imu_logged_over_part_of_the_flight_is_said_and_cuts_only_what_reads_it(tmp_path, capsys, good):
    """imu0 over the middle half of the flight had cut ``identify``'s and ``residuals``' rows by half without a word,
    ``residuals --source mocap`` included, which does not read the IMU."""
    rec = _copy(good, tmp_path)
    imu = rec / "mav0" / "imu0" / "data.csv"
    lines = imu.read_text().splitlines()
    n = len(lines) - 1
    imu.write_text("\n".join([lines[0]] + lines[1 + n // 4: 1 + 3 * n // 4]) + "\n")
    mocap, _ = residuals_to_file(rec, tmp_path / "mocap.csv", source="mocap")
    said = capsys.readouterr().err
    assert "imu0 covers only t = 3.0-9.0 s of the ground truth's 0-12.0 s: an analysis that reads it covers that " \
           "span alone (50 % of the recording)" in said
    from_imu, _ = residuals_to_file(rec, tmp_path / "imu.csv", source="imu")
    n_gt = len((rec / "mav0" / "state_groundtruth_estimate0" / "data.csv").read_text().splitlines()) - 1
    assert len(mocap.t) >= 0.98 * n_gt  # the whole flight: the IMU is not read
    assert len(from_imu.t) == pytest.approx(n / 2, rel=0.02)
    assert not stream_span_notes(load_recordings([good])[0])  # a whole IMU says nothing


def _rotors_of(good, tmp_path, source: str):
    """A copy of ``good`` whose rotor speeds are ``source`` (``rotor_speed_source``): the copy, its rotors0 file and
    that file's lines."""
    rec = _copy(good, tmp_path, source)
    yaml_path = rec / "vehicle.yaml"
    yaml_path.write_text(yaml_path.read_text() + f"rotor_speed_source: {source}\n")
    csv = rec / "mav0" / "rotors0" / "data.csv"
    return rec, csv, csv.read_text().splitlines()


def test_measured_rotor_glitches_are_left_out_and_said(tmp_path, good):
    """ESC telemetry reading 0 or twice a rotor's speed for one row (a rotor cannot jump by a quarter and back in
    10 ms): with rotor_speed_source measured, those rows are left out and said; commanded speeds may jump (the
    rotors follow through their lag) and are read as written."""
    rng = np.random.default_rng(1)
    for source in ("measured", "commanded"):
        rec, csv, lines = _rotors_of(good, tmp_path, source)
        rows = np.sort(rng.choice(np.arange(200, len(lines) - 200), 12, replace=False))
        for k, row in enumerate(rows):
            cells = lines[row].split(",")
            c = 1 + k % (len(cells) - 1)
            cells[c] = "0" if k % 2 else f"{2 * float(cells[c]):.6g}"
            lines[row] = ",".join(cells)
        csv.write_text("\n".join(lines) + "\n")
        (loaded,) = load_recordings([rec])
        said = [n for n in loaded.read_notes if "telemetry glitches" in n]
        if source == "measured":
            assert len(loaded.rotors.t_ns) == len(lines) - 1 - 12
            assert said == [f"{source}/rotors0: 12 rows where one rotor's speed jumps by over 25 % for one update "
                            f"and back (first at line {rows[0] + 1}; no rotor turns that fast) left out: telemetry "
                            "glitches"]
        else:
            assert len(loaded.rotors.t_ns) == len(lines) - 1 and said == []


def test_stopped_rotor_rows_known_answers():
    """A rotor at 0 beside others near hover is a dropout; on the gear, one ESC not yet started beside others at
    idle (30 % of hover) is not, nor are all rotors at 0 (motors off); also where the vehicle idled on its gear for
    most of the log."""
    hover = np.full((10, 4), 500.0)
    x = np.vstack([np.zeros((3, 4)), [[0.0, 150.0, 150.0, 150.0]], hover, [[500.0, 0.0, 510.0, 490.0]],
                   [[0.0, 0.0, 320.0, 320.0]]])
    assert stopped_rotor_rows(x).tolist() == [False] * 4 + [False] * 10 + [True, True]
    idling = np.vstack([np.full((40, 4), 150.0), x])  # the median turning speed is the idle's
    assert stopped_rotor_rows(idling).tolist() == [False] * 44 + [False] * 10 + [True, True]
    assert not stopped_rotor_rows(np.zeros((5, 4))).any() and not stopped_rotor_rows(np.zeros((0, 4))).any()


def test_a_rotor_read_0_for_half_a_second_in_flight_is_left_out_and_said(tmp_path, good):
    """Measured speeds with one rotor at 0 for 0.5 s mid-flight (more than one update: no glitch) are left out and
    said with the first line; commanded speeds are read as written."""
    for source in ("measured", "commanded"):
        rec, csv, lines = _rotors_of(good, tmp_path, source)
        t = np.array([int(line.split(",")[0]) for line in lines[1:]]) * 1e-9
        rows = np.flatnonzero((t - t[0] > 6.0) & (t - t[0] < 6.5)) + 1
        for row in rows:
            cells = lines[row].split(",")
            cells[3] = "0"
            lines[row] = ",".join(cells)
        csv.write_text("\n".join(lines) + "\n")
        (loaded,) = load_recordings([rec])
        said = [n for n in loaded.read_notes if "dropouts written as 0" in n]
        if source == "measured":
            assert len(loaded.rotors.t_ns) == len(lines) - 1 - len(rows) and len(rows) > 40
            assert said == [f"{source}/rotors0: {len(rows)} rows where a rotor reads 0 while another turns at over "
                            f"60 % of the flying speed (first at line {rows[0] + 1}; no multirotor flies so) left "
                            "out: telemetry dropouts written as 0"]
        else:
            assert len(loaded.rotors.t_ns) == len(lines) - 1 and said == []


def test_a_clipped_accelerometer_axis_is_said_and_a_noisy_one_is_not():
    """Vibration of 4 m/s^2 rms on z (mean 9.81) clipped at +-16 m/s^2: the axis sits at 16 on about 6 % of its
    rows, said in one sentence; the same noise unclipped, and the x and y axes, say nothing."""
    rng = np.random.default_rng(2)
    acc = np.column_stack([rng.normal(0, 0.5, 20000), rng.normal(0, 0.5, 20000), rng.normal(9.81, 4.0, 20000)])
    assert clipped_axes(acc, "accelerometer", "m/s^2") == []
    (line,) = clipped_axes(np.clip(acc, -16.0, 16.0), "accelerometer", "m/s^2")
    share = float(np.mean(acc[:, 2] >= 16.0))
    assert 0.05 < share < 0.08
    assert line.startswith(f"the accelerometer's z axis reads its extreme 16 m/s^2 on {int(round(share * 20000))} rows")


def test_a_y_up_world_is_named_in_the_ground_truths_file(tmp_path, capsys, good):
    """Motion capture exported y-up (OptiTrack's default): the accelerometer disagrees with the motion capture by
    over a g, and would agree with the world's y up; the one line names the ground truth's file and that cause (it
    had named imu0, whose readings are right)."""
    rec = _copy(good, tmp_path)
    c = np.sqrt(0.5)
    to_y_up = np.array([c, -c, 0.0, 0.0])  # -90 deg about x: (x, y, z) -> (x, z, -y)

    def y_up(i, line):
        x = [float(v) for v in line.split(",")[1:]]
        p, q, v = np.array(x[0:3]), np.array(x[3:7]), np.array(x[7:10])
        q2 = quat.multiply(to_y_up, q)
        moved = [p[0], p[2], -p[1], *q2, v[0], v[2], -v[1], *x[10:]]
        return ",".join([line.split(",")[0]] + [f"{y:.9g}" for y in moved])
    _rewrite_csv(rec / "mav0" / "state_groundtruth_estimate0" / "data.csv", y_up)
    line = _gap_fails(tmp_path, capsys, [rec], match="state_groundtruth_estimate0/data.csv: the accelerometer and ")
    assert "with a world whose y axis points up (OptiTrack's default): the world's z must point up" in line
