"""``uavturb import ulog|csv``: a simulated flight written as a PX4 log and as loggers' CSVs in every
supported convention comes back as the same recording; bad maps and logs fail in one line naming the
key or column; a frame that contradicts the data is caught at import."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import yaml
from flight_logs import (ESC_REPORT, Topic, px4_topics, same_attitudes, write_csv_log, write_map, write_px4_log,
                         write_ulog)

from uavturb.cli import main
from uavturb.errors import InputError
from uavturb.commands.identify import identify_recordings
from uavturb.io import log_frames
from uavturb.io.csv_import import import_csv
from uavturb.io.log_import import flat_floor
from uavturb.io.reader import read_recording
from uavturb.io.recording import Battery
from uavturb.io.thrust_map import GRAM_FORCE, ThrustMap, held_voltage
from uavturb.io.ulog_import import import_ulog
from uavturb.io.writer import write_recording
from uavturb.physics import quaternion as quat
from uavturb.scene.heights import SurfaceIndex
from uavturb.sim.flights.simulate import generate_flight

PERMUTED = [2, 0, 3, 1]  # vehicle rotor i is log motor PERMUTED[i]


def _from_boot(rec, t0_ns=10_000_000_000):
    """``rec`` with its clock from boot, and no bias estimates in its ground truth (logs carry none)."""
    shift = int(rec.ground_truth.t_ns[0]) - t0_ns
    gt = rec.ground_truth
    zeros = np.zeros_like(gt.p)
    return replace(rec, ground_truth=replace(gt, t_ns=gt.t_ns - shift, b_w=zeros, b_a=zeros.copy()),
                   imu=replace(rec.imu, t_ns=rec.imu.t_ns - shift),
                   rotors=replace(rec.rotors, t_ns=rec.rotors.t_ns - shift))


@pytest.fixture(scope="module")
def flight(tmp_path_factory):
    """A simulated quadrotor flight with a battery stream at a tenth of the rate, written as a recording;
    its clock starts 10 s after boot, as a flight controller's does."""
    rec = _from_boot(generate_flight(vehicle="quad", effects="none", duration=12.0, kind="mixed", seed=3))
    t = rec.ground_truth.t_ns[::10]
    rec = replace(rec, battery=Battery(t_ns=t, voltage=np.linspace(4.1, 3.7, len(t)), current=np.full(len(t), 2.5)),
                  points=flat_floor(rec.ground_truth.p, 0.0))  # the room's floor, as `--floor-z 0` writes it
    path = tmp_path_factory.mktemp("flight") / "original"
    write_recording(rec, path)
    return read_recording(path)


def _same_recording(a, b, *, atol_p=0.0, atol_q=0.0, atol_w=0.0, atol_imu=0.0, atol_t_ns=0, velocity=True):
    for x, y in ((a.ground_truth, b.ground_truth), (a.rotors, b.rotors), (a.imu, b.imu), (a.battery, b.battery)):
        assert len(x.t_ns) == len(y.t_ns)
        assert np.max(np.abs(x.t_ns - y.t_ns)) <= atol_t_ns
    np.testing.assert_allclose(a.ground_truth.p, b.ground_truth.p, rtol=0, atol=atol_p)
    if velocity:
        np.testing.assert_allclose(a.ground_truth.v, b.ground_truth.v, rtol=0, atol=atol_p)
    assert same_attitudes(a.ground_truth.q, b.ground_truth.q) <= atol_q + 1e-7
    np.testing.assert_allclose(a.rotors.speeds, b.rotors.speeds, rtol=0, atol=atol_w)
    np.testing.assert_allclose(a.imu.gyro, b.imu.gyro, rtol=0, atol=atol_imu)
    np.testing.assert_allclose(a.imu.acc, b.imu.acc, rtol=0, atol=atol_imu)
    np.testing.assert_allclose(a.battery.voltage, b.battery.voltage, rtol=1e-6)


# --- frames: known attitudes ---------------------------------------------------------------------------


def test_level_vehicle_heading_north_is_the_identity_and_east_is_yaw_minus_90():
    north = np.array([[1.0, 0, 0, 0]])  # FRD to NED: level, nose north
    east = quat.from_euler(0.0, 0.0, np.pi / 2)[None]  # PX4 yaw +90 deg about down: nose east
    assert same_attitudes(log_frames.attitude_to_recording(north, "ned", "frd"), north) < 1e-12
    q_east = log_frames.attitude_to_recording(east, "ned", "frd")
    assert quat.yaw_of(q_east)[0] == pytest.approx(-np.pi / 2)
    np.testing.assert_allclose(quat.rotate(q_east, np.array([1.0, 0, 0])), [[0, -1, 0]], atol=1e-12)  # east = -y_W
    # position 2 m east and 1 m up in NED; an accelerometer at rest reads -g along FRD's z
    np.testing.assert_allclose(log_frames.world_vectors(np.array([[0.0, 2, -1]]), "ned"), [[0, -2, 1]])
    np.testing.assert_allclose(log_frames.body_vectors(np.array([[0.0, 0, -9.81]]), "frd"), [[0, 0, 9.81]])


def test_pitch_up_in_frd_is_nose_up_in_the_recording():
    q = quat.from_euler(0.0, 0.3, 0.0)[None]  # PX4 pitch +0.3 rad: nose up
    nose = quat.rotate(log_frames.attitude_to_recording(q, "ned", "frd"), np.array([1.0, 0, 0]))
    assert nose[0, 2] == pytest.approx(np.sin(0.3))


@pytest.mark.parametrize("sequence", ["zyx", "xyz"])
def test_euler_sequences_round_trip(sequence):
    rng = np.random.default_rng(0)
    rpy = rng.uniform([-1, -1.2, -3], [1, 1.2, 3], size=(50, 3))
    q = log_frames.euler_to_quaternion(rpy[:, 0], rpy[:, 1], rpy[:, 2], sequence)
    np.testing.assert_allclose(log_frames.euler_from_quaternion(q, sequence), rpy, atol=1e-12)
    R = quat.to_rotation_matrix(q[:1])[0]
    Rx, Ry, Rz = (quat.to_rotation_matrix(log_frames.euler_to_quaternion(*a, "zyx"))
                  for a in ([rpy[0, 0], 0, 0], [0, rpy[0, 1], 0], [0, 0, rpy[0, 2]]))
    np.testing.assert_allclose(R, Rz @ Ry @ Rx if sequence == "zyx" else Rx @ Ry @ Rz, atol=1e-12)


def test_thrust_map_known_answers():
    tm = ThrustMap.from_dict({"unit": "g", "voltage_scale": 4.2, "command_range": [1000, 2000],
                              "terms": [[0, 0, 1.0], [1, 1, 2.0], [2, 0, 3.0]]}, "map")
    # u = 0.5, v = 3.78 / 4.2 = 0.9: 1 + 2 * 0.45 + 3 * 0.25 = 2.65 g
    assert tm.thrust(np.array([1500.0]), np.array([3.78]))[0] == pytest.approx(2.65 * GRAM_FORCE)
    w, negative = tm.rotor_speeds(np.array([1500.0, 0.0]), np.array([3.78, 3.78]), 1e-8)
    assert w[0] == pytest.approx(np.sqrt(2.65 * GRAM_FORCE / 1e-8))
    assert w[1] == 0 and negative == 1  # a command below the range (PWM 0): motor off


# --- CSV round trips -----------------------------------------------------------------------------------

CSV_CASES = {
    "enu-flu-quat-wxyz-s-rad/s": dict(world="enu", body="flu", time_unit="s"),
    "ned-frd-euler-deg-us-rpm-indices-noheader": dict(world="ned", body="frd", attitude="euler", time_unit="us",
                                                      rotor_unit="rpm", header=False, use_indices=True,
                                                      motor_order=PERMUTED),
    "neu-frd-quat-xyzw-ms-rpm-semicolon": dict(world="neu", body="frd", order="xyzw", time_unit="ms",
                                               rotor_unit="rpm", delimiter=";", motor_order=PERMUTED),
    "ned-flu-quat-world_to_body-s-tab": dict(world="ned", body="flu", direction="world_to_body", time_unit="s",
                                             delimiter="tab"),
    "enu-frd-euler-xyz-rad-ns-space-novelocity": dict(world="enu", body="frd", attitude="euler", euler_unit="rad",
                                                      sequence="xyz", time_unit="ns", delimiter="space"),
}


@pytest.mark.parametrize("case", list(CSV_CASES))
def test_csv_round_trip_in_every_convention(tmp_path, flight, case):
    kw = CSV_CASES[case]
    m = write_csv_log(flight, tmp_path / "log.csv", velocity="novelocity" not in case, **kw)
    rec, summary = import_csv(tmp_path / "log.csv", write_map(m, tmp_path / "map.yaml"), tmp_path / "rec",
                              vehicle=flight.vehicle)
    back = read_recording(tmp_path / "rec")
    exact = kw.get("time_unit") in ("s", "ns") and "euler" not in case and kw.get("rotor_unit") is None
    _same_recording(flight, back, atol_p=0.0 if exact else 1e-9, atol_q=0.0 if exact else 1e-9,
                    atol_w=0.0 if exact else 1e-9, atol_imu=1e-12, atol_t_ns=0 if kw["time_unit"] == "ns" else 500,
                    velocity="novelocity" not in case)
    if "novelocity" in case:  # velocity differentiated from the positions: close, not equal
        assert np.median(np.abs(back.ground_truth.v - flight.ground_truth.v)) < 0.02
    assert back.vehicle.rotor_speed_source == "commanded"
    assert f"ground truth {len(flight.ground_truth)} rows" in summary.line()


def test_csv_thrust_map_commands_with_battery_voltage(tmp_path, flight):
    c = 0.02  # N per unit command; the voltage term, of zero weight, makes the map need the battery
    tmap = {"type": "polynomial", "unit": "N", "voltage_scale": 4.0, "terms": [[1, 0, c], [1, 1, 0.0]]}
    m = write_csv_log(flight, tmp_path / "log.csv", rotor_unit="command", thrust_map=tmap, motor_order=PERMUTED,
                      time_unit="ns")
    _, summary = import_csv(tmp_path / "log.csv", write_map(m, tmp_path / "map.yaml"), tmp_path / "rec",
                            vehicle=flight.vehicle)
    back = read_recording(tmp_path / "rec")
    np.testing.assert_array_equal(back.rotors.t_ns, flight.rotors.t_ns)  # the battery's rows interpolated
    np.testing.assert_allclose(back.rotors.speeds, flight.rotors.speeds, rtol=1e-12)
    held = np.all(np.diff(flight.rotors.speeds, axis=0) == 0, axis=1)  # sample-and-hold, kept bit for bit
    np.testing.assert_array_equal(np.all(np.diff(back.rotors.speeds, axis=0) == 0, axis=1), held)
    assert "rotors 2401 rows (commanded, from command)" in summary.line()
    del m["battery"]
    with pytest.raises(InputError, match="rotors: thrust_map uses the battery voltage .* map battery.voltage"):
        import_csv(tmp_path / "log.csv", write_map(m, tmp_path / "map.yaml"), tmp_path / "rec2",
                   vehicle=flight.vehicle)


def test_csv_identify_same_as_original_in_every_convention(tmp_path, flight):
    ref = identify_recordings([flight.path]).to_dict()
    for k, case in enumerate(["ned-frd-euler-deg-us-rpm-indices-noheader", "neu-frd-quat-xyzw-ms-rpm-semicolon"]):
        m = write_csv_log(flight, tmp_path / f"{k}.csv", velocity=True, **CSV_CASES[case])
        import_csv(tmp_path / f"{k}.csv", write_map(m, tmp_path / f"{k}.yaml"), tmp_path / f"rec{k}",
                   vehicle=flight.vehicle, floor_z=0.0)
        got = identify_recordings([tmp_path / f"rec{k}"]).to_dict()
        for key in ("thrust_coefficient", "thrust_coefficient_stderr", "moment_coefficient", "inertia", "n_samples"):
            np.testing.assert_allclose(got[key], ref[key], rtol=1e-9, err_msg=key)  # nan where not determined


def test_csv_nan_rows_before_arming_truncated_row_and_repeats(tmp_path, flight):
    m = write_csv_log(flight, tmp_path / "log.csv")
    lines = (tmp_path / "log.csv").read_text().splitlines()
    header, rows = lines[0], lines[1:]
    n_cols = len(header.split(","))
    t0 = float(rows[0].split(",")[0])
    pre = [",".join([repr(t0 - (5 - k) * 0.01)] + ["nan"] * (n_cols - 1)) for k in range(5)]  # before arming
    held = rows[100].split(",")
    held[0] = repr((float(rows[100].split(",")[0]) + float(rows[101].split(",")[0])) / 2)  # a repeat, new time
    body = pre + rows[:101] + [",".join(held)] + rows[101:]
    truncated = body[-1][: len(body[-1]) // 2]
    (tmp_path / "log.csv").write_text("\n".join([header] + body[:-1] + [truncated]))
    _, summary = import_csv(tmp_path / "log.csv", write_map(m, tmp_path / "map.yaml"), tmp_path / "rec",
                            vehicle=flight.vehicle)
    line = summary.line()
    assert "5 ground-truth rows with nan" in line and "5 rotor rows with nan" in line
    assert "1 truncated last row" in line
    back = read_recording(tmp_path / "rec")
    assert len(back.ground_truth) == len(flight.ground_truth)  # + 1 repeat - 1 truncated
    k = np.searchsorted(back.ground_truth.t_ns, flight.ground_truth.t_ns[100])
    np.testing.assert_array_equal(back.ground_truth.p[k + 1], back.ground_truth.p[k])  # the repeat kept as it is


def test_csv_from_a_spreadsheet_bom_quotes_crlf(tmp_path, flight):
    m = write_csv_log(flight, tmp_path / "log.csv", time_unit="ns")
    lines = (tmp_path / "log.csv").read_text().splitlines()
    header = ",".join(f'"{n}"' for n in lines[0].split(","))
    text = "\r\n".join(["# written by a logger v1.2", header] + lines[1:]) + "\r\n"
    (tmp_path / "log.csv").write_bytes(("\ufeff" + text).encode("utf-8"))
    import_csv(tmp_path / "log.csv", write_map(m, tmp_path / "map.yaml"), tmp_path / "rec", vehicle=flight.vehicle)
    np.testing.assert_array_equal(read_recording(tmp_path / "rec").ground_truth.p, flight.ground_truth.p)


def test_csv_floor_and_rotor_plane(tmp_path, flight):
    m = write_csv_log(flight, tmp_path / "log.csv")
    import_csv(tmp_path / "log.csv", write_map(m, tmp_path / "map.yaml"), tmp_path / "rec", vehicle=flight.vehicle,
               floor_z=-0.05, rotor_plane_z=0.02)
    back = read_recording(tmp_path / "rec")
    assert back.vehicle.rotor_plane_z == 0.02
    assert np.all(back.points[:, 2] == -0.05)
    d_down = SurfaceIndex(back.points).d_down(back.ground_truth.p)
    np.testing.assert_allclose(d_down, back.ground_truth.p[:, 2] + 0.05, atol=1e-9)
    assert len(flat_floor(np.array([[0.0, 0, 1], [1e5, 1e5, 1]]), 0.0)) <= 2_000_000 + 20_000  # a wide flight


def test_a_floor_above_the_flight_is_said_in_the_summary(tmp_path, flight):
    # a floor given 10 cm over the lowest position: a drifting height (a PX4 log's barometer) reads the same
    m = write_csv_log(flight, tmp_path / "log.csv")
    low = float(flight.ground_truth.p[:, 2].min())
    _, summary = import_csv(tmp_path / "log.csv", write_map(m, tmp_path / "map.yaml"), tmp_path / "rec",
                            vehicle=flight.vehicle, floor_z=low + 0.1)
    note = [n for n in summary.notes if "under the floor" in n]
    assert len(note) == 1 and note[0].startswith("the position goes up to 0.10 m under the floor (--floor-z")
    assert "heights over the floor cannot be trusted" in summary.line()
    # the floor where it is: nothing said
    _, summary = import_csv(tmp_path / "log.csv", write_map(m, tmp_path / "map.yaml"), tmp_path / "rec2",
                            vehicle=flight.vehicle, floor_z=low - 0.01)
    assert not [n for n in summary.notes if "under the floor" in n]


# --- ULog round trips ----------------------------------------------------------------------------------


def test_ulog_round_trip_esc_rpm_motor_order_and_dropouts(tmp_path, flight):
    t_drop = int(flight.ground_truth.t_ns[600] // 1000)
    write_px4_log(flight, tmp_path / "log.ulg", motor_order=PERMUTED, dropouts=[(t_drop, 30)])
    rec, summary = import_ulog(tmp_path / "log.ulg", tmp_path / "rec", vehicle=flight.vehicle, motor_order=PERMUTED,
                               floor_z=0.0)
    np.testing.assert_allclose(read_recording(tmp_path / "rec").points, flight.points, rtol=0, atol=1e-6)
    back = read_recording(tmp_path / "rec")
    # float32 fields and integer rpm, as PX4 logs them; timestamps in µs
    _same_recording(flight, back, atol_p=2e-6, atol_q=1e-6, atol_w=np.pi / 60 + 1e-9, atol_imu=1e-5,
                    atol_t_ns=500)
    assert back.vehicle.rotor_speed_source == "measured"
    line = summary.line()
    assert "1 logging dropouts (30 ms) kept as gaps" in line and "the log lacks" not in line
    ref, got = identify_recordings([flight.path]).to_dict(), identify_recordings([tmp_path / "rec"]).to_dict()
    assert got["thrust_coefficient"] == pytest.approx(ref["thrust_coefficient"], rel=1e-3)  # rpm in whole rpm
    assert got["n_samples"] == ref["n_samples"]
    # inertia from differences of rotor speeds: whole rpm and float32 attitudes move it within its error
    ok = np.isnan(ref["inertia"]) | (np.abs(np.subtract(got["inertia"], ref["inertia"]))
                                     < np.array(ref["inertia_stderr"]))
    assert np.all(ok), (got["inertia"], ref["inertia"], ref["inertia_stderr"])


def test_ulog_height_from_dist_bottom_where_the_local_height_drifts(tmp_path, capsys, flight):
    # a barometer that sinks 0.5 m over the log: its local height goes under the floor; the range sensor's holds
    write_px4_log(flight, tmp_path / "log.ulg", height_drift_m=0.5, dist_bottom_invalid=range(20))
    drifting, summary = import_ulog(tmp_path / "log.ulg", tmp_path / "local", vehicle=flight.vehicle, floor_z=0.0)
    assert "under the floor (--floor-z 0)" in summary.line()
    ranged, summary = import_ulog(tmp_path / "log.ulg", tmp_path / "ranged", vehicle=flight.vehicle,
                                  height="dist_bottom")
    line = summary.line()
    assert "height from dist_bottom" in line and "floor z = 0 m" in line and "under the floor" not in line
    assert "20 vehicle_local_position rows without a valid dist_bottom" in line
    np.testing.assert_allclose(ranged.ground_truth.p[:, 2], flight.ground_truth.p[20:, 2], atol=1e-6)  # float32
    np.testing.assert_allclose(ranged.ground_truth.p[:, :2], drifting.ground_truth.p[20:, :2])
    # a log without a range sensor says so
    write_px4_log(flight, tmp_path / "plain.ulg")
    argv = ["import", "ulog", str(tmp_path / "plain.ulg"), "--vehicle", str(tmp_path / "vehicle.yaml"), "--out",
            str(tmp_path / "rec"), "--height", "dist_bottom"]
    (tmp_path / "vehicle.yaml").write_text(yaml.safe_dump(flight.vehicle.to_dict()))
    line = _import_fails(tmp_path, capsys, argv, "logs no dist_bottom in vehicle_local_position (no range sensor")
    assert line.startswith("uavturb import ulog: error: --height: dist_bottom: ")


def test_ulog_turning_rotors_the_vehicle_file_leaves_out_are_named(tmp_path, capsys, flight):
    # a hexarotor's log read with a quadrotor's vehicle.yaml once dropped two rotors' thrust without a word
    write_px4_log(flight, tmp_path / "log.ulg")  # the quadrotor's four ESCs
    quad = flight.vehicle
    tri = quad.with_params(rotor_angles_deg=quad.rotor_angles_deg[:3], rotor_directions=quad.rotor_directions[:3])
    (tmp_path / "vehicle.yaml").write_text(yaml.safe_dump(tri.to_dict()))
    argv = ["import", "ulog", str(tmp_path / "log.ulg"), "--vehicle", str(tmp_path / "vehicle.yaml"), "--out",
            str(tmp_path / "rec")]
    _import_fails(tmp_path, capsys, argv, "esc_status reports turning rotors on ESC 3, which the vehicle's 3 rotors "
                                          "(ESC 0, 1, 2) leave out")


def _outputs_log(tmp_path, flight, extra: dict[int, np.ndarray] | None = None) -> Path:
    """``flight`` as a ULog with ``actuator_outputs`` (0.4 N at full output), its channels ``extra`` replaced
    (index -> (N,) PWM), and the thrust map ``tm.yaml`` beside it."""
    c = 0.4
    topics = px4_topics(flight, rotors="outputs", thrust_per_command=c)
    out = next(t for t in topics if t.name == "actuator_outputs")
    for i, col in (extra or {}).items():
        out.rows[:] = [(*r[:2 + i], float(col[k]), *r[3 + i:]) for k, r in enumerate(out.rows)]
    write_ulog(tmp_path / "log.ulg", topics, nested={"esc_report": ESC_REPORT})
    (tmp_path / "tm.yaml").write_text(yaml.safe_dump({"command_range": [1000, 2000], "terms": [[1, 0, c]]}))
    return tmp_path / "log.ulg"


def test_ulog_outputs_that_drive_rotors_the_vehicle_file_leaves_out_are_named(tmp_path, capsys, flight):
    # the same as above for a vehicle without ESC telemetry: its fourth output drives a rotor
    log = _outputs_log(tmp_path, flight)
    quad = flight.vehicle
    tri = quad.with_params(rotor_angles_deg=quad.rotor_angles_deg[:3], rotor_directions=quad.rotor_directions[:3])
    (tmp_path / "vehicle.yaml").write_text(yaml.safe_dump(tri.to_dict()))
    argv = ["import", "ulog", str(log), "--vehicle", str(tmp_path / "vehicle.yaml"), "--out", str(tmp_path / "rec"),
            "--thrust-map", str(tmp_path / "tm.yaml")]
    _import_fails(tmp_path, capsys, argv, "actuator_outputs channel 3 follows the rotors' outputs at their level, "
                                          "outside the vehicle's 3 rotors (outputs 0, 1, 2)")
    assert not (tmp_path / "rec").exists()


def test_ulog_servo_and_unused_outputs_are_not_rotors(tmp_path, flight):
    # a gimbal servo sweeping about mid-travel and a channel held at the disarmed value are not rotors; the
    # rotors' own speeds come back as with no other channel
    n = len(flight.rotors)
    sweep = 1500.0 + 300.0 * np.sin(np.linspace(0.0, 9.0 * np.pi, n))
    log = _outputs_log(tmp_path, flight, {4: sweep, 5: np.full(n, 1500.0), 6: np.full(n, np.nan)})
    import_ulog(log, tmp_path / "rec", vehicle=flight.vehicle, thrust_map=tmp_path / "tm.yaml")
    np.testing.assert_allclose(read_recording(tmp_path / "rec").rotors.speeds, flight.rotors.speeds, rtol=1e-4,
                               atol=0.05)


@pytest.mark.parametrize("option, value, match", [
    ("--rotor-plane-z", "inf", "--rotor-plane-z: must be a finite height within +-5 m, got inf"),
    ("--rotor-plane-z", "50", "--rotor-plane-z: must be a finite height within +-5 m, got 50.0"),
    ("--floor-z", "1e300", "--floor-z: must be a finite height within +-1000 m, got 1e+300"),
])
def test_import_heights_out_of_range_are_refused(tmp_path, capsys, flight, option, value, match):
    write_px4_log(flight, tmp_path / "log.ulg")
    (tmp_path / "vehicle.yaml").write_text(yaml.safe_dump(flight.vehicle.to_dict()))
    argv = ["import", "ulog", str(tmp_path / "log.ulg"), "--vehicle", str(tmp_path / "vehicle.yaml"), "--out",
            str(tmp_path / "rec"), f"{option}={value}"]
    _import_fails(tmp_path, capsys, argv, match)


@pytest.mark.parametrize("value, match", [("-inf", "--floor-z: must be a finite height within +-1000 m, got -inf"),
                                          ("-2e3", "--floor-z: must be a finite height within +-1000 m, got -2000.0")])
def test_a_negative_value_in_exponent_form_reaches_its_option(tmp_path, capsys, flight, value, match):
    # argparse had read "-inf" and "-2e3" as options: "expected one argument" and a usage block
    write_px4_log(flight, tmp_path / "log.ulg")
    (tmp_path / "vehicle.yaml").write_text(yaml.safe_dump(flight.vehicle.to_dict()))
    argv = ["import", "ulog", str(tmp_path / "log.ulg"), "--vehicle", str(tmp_path / "vehicle.yaml"), "--out",
            str(tmp_path / "rec"), "--floor-z", value]
    _import_fails(tmp_path, capsys, argv, match)


def test_an_import_into_its_own_log_folder_is_refused(tmp_path, capsys, csv_log):
    m, vehicle = csv_log
    argv = _csv_argv(tmp_path, m, vehicle)
    argv[argv.index("--out") + 1] = str(tmp_path)
    code = main(argv)
    assert code == 2 and "holds an input of this command" in capsys.readouterr().err
    assert (tmp_path / "log.csv").exists()


def test_a_column_that_is_no_rotor_speed_is_named_at_import(tmp_path, capsys, flight):
    m = write_csv_log(flight, tmp_path / "log.csv", time_unit="ns")
    vehicle = tmp_path / "vehicle.yaml"
    vehicle.write_text(yaml.safe_dump(flight.vehicle.to_dict()))
    m["rotors"]["columns"][1] = m["time"]["column"]  # the time column, in ns, read as a rotor's speed
    _import_fails(tmp_path, capsys, _csv_argv(tmp_path, m, vehicle), f"rotor column {m['time']['column']!r} reads")


def test_ulog_a_wrong_motor_order_is_caught_or_changes_the_rotors(tmp_path, flight):
    write_px4_log(flight, tmp_path / "log.ulg", motor_order=PERMUTED)
    import_ulog(tmp_path / "log.ulg", tmp_path / "rec", vehicle=flight.vehicle)  # identity order: rotors swapped
    back = read_recording(tmp_path / "rec")
    np.testing.assert_allclose(back.rotors.speeds[:, PERMUTED], flight.rotors.speeds, atol=np.pi / 60 + 1e-9)


def test_ulog_actuator_outputs_through_a_thrust_map(tmp_path, flight):
    c = 0.4  # N at full output
    write_px4_log(flight, tmp_path / "log.ulg", rotors="outputs", thrust_per_command=c)
    (tmp_path / "tm.yaml").write_text(yaml.safe_dump({"command_range": [1000, 2000], "terms": [[1, 0, c]]}))
    _, summary = import_ulog(tmp_path / "log.ulg", tmp_path / "rec", vehicle=flight.vehicle,
                             thrust_map=tmp_path / "tm.yaml")
    back = read_recording(tmp_path / "rec")
    assert back.vehicle.rotor_speed_source == "commanded"
    np.testing.assert_allclose(back.rotors.speeds, flight.rotors.speeds, rtol=1e-4, atol=0.05)
    assert "the log lacks: esc_status" in summary.line()


def test_ulog_multi_instance_reads_the_lowest_and_says_so(tmp_path, flight):
    topics = px4_topics(flight)
    esc = next(t for t in topics if t.name == "esc_status")
    other = Topic("esc_status", esc.fields, [(r[0], *[0] * (len(r) - 1)) for r in esc.rows], multi_id=1)
    write_ulog(tmp_path / "log.ulg", [other, *topics], nested={"esc_report": ESC_REPORT})
    _, summary = import_ulog(tmp_path / "log.ulg", tmp_path / "rec", vehicle=flight.vehicle)
    assert "esc_status instance 0 of 2" in summary.line()
    np.testing.assert_allclose(read_recording(tmp_path / "rec").rotors.speeds, flight.rotors.speeds,
                               atol=np.pi / 60 + 1e-9)


def test_ulog_without_imu_and_battery_says_what_it_lacks(tmp_path, flight):
    bare = replace(flight, imu=None, battery=None)
    write_px4_log(bare, tmp_path / "log.ulg")
    _, summary = import_ulog(tmp_path / "log.ulg", tmp_path / "rec", vehicle=flight.vehicle)
    assert "the log lacks: sensor_combined, actuator_outputs, battery_status" in summary.line() or \
        "the log lacks: sensor_combined, battery_status" in summary.line(), summary.line()


# --- bad maps and logs: one line naming the key, column or convention ----------------------------------


def _import_fails(tmp_path, capsys, argv, match):
    code = main(argv)
    err = capsys.readouterr().err
    lines = [x for x in err.splitlines() if x.strip()]
    assert code == 2 and len(lines) == 1 and "Traceback" not in err, err
    assert match in lines[0], lines[0]
    assert lines[0].startswith(f"uavturb import {argv[1]}: error: "), lines[0]
    assert not (tmp_path / "rec").exists()
    return lines[0]


@pytest.fixture
def csv_log(tmp_path, flight):
    m = write_csv_log(flight, tmp_path / "log.csv", world="ned", body="frd")
    vehicle = tmp_path / "vehicle.yaml"
    vehicle.write_text(yaml.safe_dump(flight.vehicle.to_dict()))
    return m, vehicle


def _csv_argv(tmp_path, m, vehicle):
    return ["import", "csv", str(tmp_path / "log.csv"), "--map", str(write_map(m, tmp_path / "map.yaml")),
            "--vehicle", str(vehicle), "--out", str(tmp_path / "rec")]


def test_cli_import_csv_prints_one_summary_line(tmp_path, capsys, csv_log):
    assert main(_csv_argv(tmp_path, *csv_log)) == 0
    out = capsys.readouterr().out.strip().splitlines()
    assert len(out) == 1 and out[0].startswith(f"wrote {tmp_path / 'rec'}: ground truth")


@pytest.mark.parametrize("edit,match", [
    (lambda m: m["rotors"].update(columns=["m1", "m2", "motor3", "m4"]),
     "map key rotors.columns[2]: no column 'motor3' in the header"),
    (lambda m: m["time"].update(unit="fortnights"), "time.unit: unknown value 'fortnights'"),
    (lambda m: m.update(colour="red"), "colour: unknown key"),
    (lambda m: m["quaternion"].update(order="zyxw"), "quaternion.order: unknown value 'zyxw'"),
    (lambda m: m["rotors"].update(motor_order=[0, 0, 1, 2]), "rotors.motor_order: expected a permutation"),
    (lambda m: m["rotors"].update(unit="command"), "rotors.thrust_map: required when rotors.unit is command"),
    (lambda m: m.pop("world"), "world: required"),
    (lambda m: m["position"].update(columns=["px", "py"]), "position.columns: expected a list of 3 columns"),
])
def test_bad_maps_name_the_key(tmp_path, capsys, csv_log, edit, match):
    m, vehicle = csv_log
    edit(m)
    _import_fails(tmp_path, capsys, _csv_argv(tmp_path, m, vehicle), match)


@pytest.mark.parametrize("wrong,agree", [({"body": "flu"}, "body: flu looks wrong"),
                                         ({"world": "enu"}, "world: enu looks wrong"),
                                         ({"world": "enu", "body": "flu"}, "looks wrong")])
def test_a_frame_that_contradicts_the_data_fails_at_import(tmp_path, capsys, csv_log, wrong, agree):
    m, vehicle = csv_log
    m.update(wrong)
    line = _import_fails(tmp_path, capsys, _csv_argv(tmp_path, m, vehicle), agree)
    assert "the data agree with" in line and "body: frd" in line or "world: ned" in line, line


def test_a_frame_contradiction_is_caught_without_an_imu(tmp_path, capsys, flight):
    m = write_csv_log(replace(flight, imu=None), tmp_path / "log.csv", world="ned", body="frd")
    m.update(world="enu", body="flu")  # NED/FRD data read as ENU/FLU: level hover agrees, climbs do not
    vehicle = tmp_path / "vehicle.yaml"
    vehicle.write_text(yaml.safe_dump(flight.vehicle.to_dict()))
    _import_fails(tmp_path, capsys, _csv_argv(tmp_path, m, vehicle), "looks wrong")


def test_bad_csv_files_name_the_line(tmp_path, capsys, csv_log):
    m, vehicle = csv_log
    lines = (tmp_path / "log.csv").read_text().splitlines()
    lines[10] = lines[10].replace(",", ",oops,", 1).rsplit(",", 1)[0]  # same width, a word in the px column
    (tmp_path / "log.csv").write_text("\n".join(lines) + "\n")
    _import_fails(tmp_path, capsys, _csv_argv(tmp_path, m, vehicle), "line 11: 'oops' (map key position.columns[0])")
    (tmp_path / "log.csv").write_text(",".join(["c"] * 20_000) + "\n")
    _import_fails(tmp_path, capsys, _csv_argv(tmp_path, m, vehicle), "more than 10000")


def test_a_time_that_leaps_days_ahead_is_named(tmp_path, capsys, csv_log):
    # a timestamp centuries off (int64's maximum in ns) put the velocity's local fits through 2 distinct times
    m, vehicle = csv_log
    lines = (tmp_path / "log.csv").read_text().splitlines()
    first, rest = lines[-1].split(",", 1)
    lines[-1] = f"{float(first) + 2 * 86_400:.6f},{rest}"  # two days after the row before, in seconds
    (tmp_path / "log.csv").write_text("\n".join(lines) + "\n")
    _import_fails(tmp_path, capsys, _csv_argv(tmp_path, m, vehicle),
                  f"line {len(lines)}: the time leaps 1.73e+05 s past the row before")
    assert not (tmp_path / "rec").exists()


def test_nanoseconds_read_as_milliseconds_are_named(tmp_path, capsys, csv_log):
    # times past int64 nanoseconds once wrapped round silently into rows 5000 s apart
    m, vehicle = csv_log
    lines = (tmp_path / "log.csv").read_text().splitlines()
    lines[1:] = [f"{1403636579758555392 + 5_000_000 * k},{line.split(',', 1)[1]}" for k, line in enumerate(lines[1:])]
    (tmp_path / "log.csv").write_text("\n".join(lines) + "\n")
    m["time"]["unit"] = "ms"
    _import_fails(tmp_path, capsys, _csv_argv(tmp_path, m, vehicle),
                  "line 2: time 1.40364e+18 read in the map's time.unit is past what nanoseconds can count")


def test_bad_ulogs(tmp_path, capsys, flight):
    vehicle = tmp_path / "vehicle.yaml"
    vehicle.write_text(yaml.safe_dump(flight.vehicle.to_dict()))
    (tmp_path / "junk.ulg").write_bytes(b"not a log at all" * 10)
    argv = ["import", "ulog", str(tmp_path / "junk.ulg"), "--vehicle", str(vehicle), "--out", str(tmp_path / "rec")]
    _import_fails(tmp_path, capsys, argv, "not a readable ULog file")
    write_px4_log(flight, tmp_path / "log.ulg", rotors="outputs", thrust_per_command=0.4)
    argv[2] = str(tmp_path / "log.ulg")
    _import_fails(tmp_path, capsys, argv, "--thrust-map")
    _import_fails(tmp_path, capsys, argv + ["--motor-order", "0,1,1,2"], "--motor-order")
    topics = [t for t in px4_topics(flight) if t.name != "vehicle_attitude"]
    write_ulog(tmp_path / "noatt.ulg", topics, nested={"esc_report": ESC_REPORT})
    argv[2] = str(tmp_path / "noatt.ulg")
    _import_fails(tmp_path, capsys, argv, "no vehicle_attitude messages")


def test_import_euroc_old_spelling_still_works_and_says_so(tmp_path, capsys):
    code = main(["import-euroc", str(tmp_path / "missing.bag"), "--out", str(tmp_path / "rec")])
    err = capsys.readouterr().err
    assert code == 2
    assert "deprecated spelling, use `uavturb import euroc`" in err
    assert "missing.bag: file not found" in err
    assert main(["import", "euroc", str(tmp_path / "missing.bag"), "--out", str(tmp_path / "rec")]) == 2
    assert "deprecated" not in capsys.readouterr().err


def test_input_error_is_the_failure_type(tmp_path, flight):
    m = write_csv_log(flight, tmp_path / "log.csv")
    m["battery"]["voltage_unit"] = "kV"
    with pytest.raises(InputError, match="battery.voltage_unit: unknown value 'kV'"):
        import_csv(tmp_path / "log.csv", write_map(m, tmp_path / "map.yaml"), tmp_path / "rec", vehicle=flight.vehicle)


# --- the documented Neural-Swarm map, on a flight the test writes in that layout -------------------------

NS_HEADER = ("# time[ms],x[m],y[m],z[m],vx[m/s],vy[m/s],vz[m/s],ax[m/s^2],ay[m/s^2],az[m/s^2],qx,qy,qz,qw,"
             "u1[N],u2[N],u3[N],u4[N],u1[PWM],u2[PWM],u3[PWM],u4[PWM],Vbat[V],thrust_des[g],torquex[Nm],"
             "torquey[Nm],torquez[Nm],wx[rad/s],wy[rad/s],wz[rad/s]")


def _pwm_for_thrust(f_g, vbat, C):
    """The PWM (/ 65536) whose thrust [g] the map C00..C11 gives: the root of C20 p^2 + (C10 + C11 v) p + ...
    in [0, 1]."""
    v = vbat / 4.2
    a, b, c = C[3], C[1] + C[4] * v, C[0] + C[2] * v - f_g
    return (-b + np.sqrt(b * b - 4 * a * c)) / (2 * a)


def test_neural_swarm_map_reads_that_layout(tmp_path):
    docs = Path(__file__).resolve().parents[1] / "docs" / "maps"
    m = yaml.safe_load((docs / "neural_swarm.yaml").read_text())
    assert [t[2] for t in m["rotors"]["thrust_map"]["terms"]] == [None] * 5  # the dataset's own values go there
    C = [11.0, -39.0, -9.5, 20.5, 38.5]  # a thrust fit of the same form, made up for the test [g]
    for term, c in zip(m["rotors"]["thrust_map"]["terms"], C):
        term[2] = c
    (tmp_path / "map.yaml").write_text(yaml.safe_dump(m))
    rec = _from_boot(generate_flight(vehicle=str(docs / "crazyflie21.yaml"), effects="none", duration=10.0,
                                     kind="mixed", seed=2))
    vbat = np.linspace(3.9, 3.6, len(rec.ground_truth))  # V
    rec = replace(rec, points=flat_floor(rec.ground_truth.p, 0.0),
                  battery=Battery(t_ns=rec.ground_truth.t_ns, voltage=vbat))
    write_recording(rec, tmp_path / "original")
    gt, imu, n = rec.ground_truth, rec.imu, len(rec.ground_truth)
    assert np.array_equal(imu.t_ns, gt.t_ns) and np.array_equal(rec.rotors.t_ns, gt.t_ns)  # one row each, as logged
    f_g = rec.vehicle.thrust_coefficient * rec.rotors.speeds**2 / 0.00981  # grams, as the repository converts
    pwm = _pwm_for_thrust(f_g, held_voltage(rec.rotors.speeds, vbat)[:, None], C)  # a held command stays held
    acc_world = quat.rotate(gt.q, imu.acc)  # the firmware logs the specific force in the world frame
    cols = [gt.t_ns // 1000, gt.p, gt.v, acc_world, gt.q[:, [1, 2, 3, 0]], f_g * 0.00981, pwm, vbat,
            f_g.sum(axis=1), np.zeros((n, 3)), imu.gyro]
    table = np.column_stack([np.asarray(c, dtype=np.float64).reshape(n, -1) for c in cols])
    np.savetxt(tmp_path / "cf50_00.csv", table, delimiter=",", header=NS_HEADER[2:], fmt="%.18e")
    _, summary = import_csv(tmp_path / "cf50_00.csv", tmp_path / "map.yaml", tmp_path / "rec",
                            vehicle=str(docs / "crazyflie21.yaml"), floor_z=0.0)
    back = read_recording(tmp_path / "rec")
    np.testing.assert_allclose(back.rotors.speeds, rec.rotors.speeds, rtol=1e-9)
    np.testing.assert_allclose(back.imu.acc, imu.acc, atol=1e-9)
    assert back.vehicle.rotor_plane_z == -0.025 and back.vehicle.rotor_speed_source == "commanded"
    ref, got = identify_recordings([tmp_path / "original"]).to_dict(), identify_recordings([tmp_path / "rec"]).to_dict()
    held = np.all(np.diff(rec.rotors.speeds, axis=0) == 0, axis=1)
    assert held.mean() > 0.5  # the simulator's commands are held between updates, and stay held
    np.testing.assert_array_equal(np.all(np.diff(back.rotors.speeds, axis=0) == 0, axis=1), held)
    assert got["n_samples"] == ref["n_samples"]
    assert got["thrust_coefficient"] == pytest.approx(ref["thrust_coefficient"], rel=1e-9)
    np.testing.assert_allclose(got["accel_bias"], ref["accel_bias"], atol=1e-9)


def test_thrust_map_rest_and_newtons_per_unit():
    tm = ThrustMap.from_dict({"unit": "g", "newtons_per_unit": 0.00981, "terms": [[0, 0, 2.5], [1, 0, 10.0]]}, "m")
    w, rest = tm.rotor_speeds(np.array([0.0, -0.1, 0.5]), None, 1e-8)
    assert rest == 2 and w[0] == 0 and w[1] == 0  # motors off: the intercept (2.5 g) is no thrust
    assert w[2] == pytest.approx(np.sqrt(7.5 * 0.00981 / 1e-8))
    with pytest.raises(InputError, match="thrust_map.newtons_per_unit: expected a positive number"):
        ThrustMap.from_dict({"newtons_per_unit": -1, "terms": [[1, 0, 1.0]]}, "m")
    with pytest.raises(InputError, match=r"thrust_map.terms\[0\]: expected \[i, j, c\]"):
        ThrustMap.from_dict({"terms": [[1, 0]]}, "m")


def test_a_dead_rotor_column_is_named_by_its_log_column(tmp_path, capsys, flight):
    dead = replace(flight, rotors=replace(flight.rotors, speeds=flight.rotors.speeds * [1, 1, 0, 1]))
    m = write_csv_log(dead, tmp_path / "log.csv", motor_order=PERMUTED)  # vehicle rotor 2 is log column m4
    vehicle = tmp_path / "vehicle.yaml"
    vehicle.write_text(yaml.safe_dump(flight.vehicle.to_dict()))
    _import_fails(tmp_path, capsys, _csv_argv(tmp_path, m, vehicle),
                  "rotor column 'm4' (vehicle rotor 2) is 0 throughout the flight")


# --- the gap finder: the same report from the original and from its imports ----------------------------


def _gap_summary(path, out):
    from uavturb.commands.gap import gap

    r = gap([path], out, sim_effects="none", log_mlflow=False)
    return r["nominal"], {e["name"]: e["params"] for e in r["effects"]}


def test_gap_same_report_through_a_ned_csv(tmp_path, flight):
    m = write_csv_log(flight, tmp_path / "log.csv", world="ned", body="frd", time_unit="ns", motor_order=PERMUTED)
    import_csv(tmp_path / "log.csv", write_map(m, tmp_path / "map.yaml"), tmp_path / "rec", vehicle=flight.vehicle,
               floor_z=0.0)
    ref_nominal, ref_effects = _gap_summary(flight.path, tmp_path / "gap0")
    nominal, effects = _gap_summary(tmp_path / "rec", tmp_path / "gap1")
    assert effects == ref_effects
    for key in ("thrust_coefficient", "accel_bias"):
        np.testing.assert_allclose(nominal[key], ref_nominal[key], rtol=1e-9, atol=1e-12)


@pytest.mark.slow
def test_gap_names_the_same_wind_through_ulog_and_every_csv_convention(tmp_path):
    """A 45 s flight in a steady wind (the gap finder names it): the same effect and parameters from the
    original, its ULog and its CSVs in NED/FRD, ENU/FLU and north-east-up."""
    rec = _from_boot(generate_flight(vehicle="hex", effects="wind:f_x=0.2,f_y=-0.15", duration=45.0, kind="mixed",
                                     seed=32))
    rec = replace(rec, points=flat_floor(rec.ground_truth.p, 0.0))
    write_recording(rec, tmp_path / "original")
    _, ref = _gap_summary(tmp_path / "original", tmp_path / "gap_original")
    assert list(ref) == ["wind"] and ref["wind"]["f_x"] == pytest.approx(0.2, rel=0.15)
    write_px4_log(rec, tmp_path / "log.ulg", motor_order=[3, 0, 5, 1, 2, 4])
    paths = []
    for world, body in (("ned", "frd"), ("enu", "flu"), ("neu", "frd")):
        m = write_csv_log(rec, tmp_path / f"{world}.csv", world=world, body=body, time_unit="us", rotor_unit="rpm")
        import_csv(tmp_path / f"{world}.csv", write_map(m, tmp_path / f"{world}.yaml"), tmp_path / world,
                   vehicle=rec.vehicle, floor_z=0.0)
        paths.append(tmp_path / world)
    import_ulog(tmp_path / "log.ulg", tmp_path / "ulog", vehicle=rec.vehicle, floor_z=0.0,
                motor_order=[3, 0, 5, 1, 2, 4])
    for path in [*paths, tmp_path / "ulog"]:
        _, got = _gap_summary(path, tmp_path / f"gap_{path.name}")
        assert list(got) == ["wind"], path.name
        for k, v in ref["wind"].items():
            assert got["wind"][k] == pytest.approx(v, rel=0.01, abs=1e-3), (path.name, k)


def test_ulog_vehicle_imu_and_invalid_positions(tmp_path, flight):
    write_px4_log(flight, tmp_path / "log.ulg", imu="vehicle_imu", invalid_rows=range(100, 110))
    _, summary = import_ulog(tmp_path / "log.ulg", tmp_path / "rec", vehicle=flight.vehicle)
    back = read_recording(tmp_path / "rec")
    np.testing.assert_allclose(back.imu.gyro, flight.imu.gyro, atol=1e-5)  # delta angle / dt, float32
    np.testing.assert_allclose(back.imu.acc, flight.imu.acc, atol=1e-4)
    assert len(back.ground_truth) == len(flight.ground_truth) - 10
    assert "10 vehicle_local_position rows invalid or outside the attitudes" in summary.line()
    assert "sensor_combined" not in summary.line()


def test_ulog_cut_short_still_imports_what_it_holds(tmp_path, capsys, flight):
    write_px4_log(flight, tmp_path / "log.ulg")
    data = (tmp_path / "log.ulg").read_bytes()
    (tmp_path / "cut.ulg").write_bytes(data[: int(len(data) * 0.6)])  # the logger stopped mid-message
    vehicle = tmp_path / "vehicle.yaml"
    vehicle.write_text(yaml.safe_dump(flight.vehicle.to_dict()))
    assert main(["import", "ulog", str(tmp_path / "cut.ulg"), "--vehicle", str(vehicle), "--out",
                 str(tmp_path / "rec")]) == 0
    out = capsys.readouterr().out.strip().splitlines()
    assert len(out) == 1 and out[0].startswith(f"wrote {tmp_path / 'rec'}")
    back = read_recording(tmp_path / "rec")
    assert 0.4 * len(flight.ground_truth) < len(back.ground_truth) < 0.8 * len(flight.ground_truth)
