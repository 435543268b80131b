"""Recordings written by hand, independently of ``uavturb.io.writer``, read and identified through the CLI.

The files follow ``recordings.md`` the way another lab would write them: a hexarotor at 200 Hz,
realistic IMU noise, rotor speeds quantised to 1 rad/s at another rate, a ``vehicle.yaml`` with the
required keys only (mass given, everything else unknown), ``, `` separators in one file and ``,``
in another. Malformed copies give one line on stderr naming the file, exit status 2, no traceback
and no partial output.
"""

from __future__ import annotations

import json
import shutil

import numpy as np
import pandas as pd
import pytest
from synthetic import inverse_dynamics_flight

from uavturb.cli import main
from uavturb.gap.preparation import prepared
from uavturb.io.reader import load_recordings
from uavturb.physics.vehicle import HEXAROTOR

GT_HEADER = ("#timestamp, p_RS_R_x [m], p_RS_R_y [m], p_RS_R_z [m], q_RS_w [], q_RS_x [], q_RS_y [], q_RS_z [], "
             "v_RS_R_x [m s^-1], v_RS_R_y [m s^-1], v_RS_R_z [m s^-1], b_w_RS_S_x [rad s^-1], b_w_RS_S_y [rad s^-1], "
             "b_w_RS_S_z [rad s^-1], b_a_RS_S_x [m s^-2], b_a_RS_S_y [m s^-2], b_a_RS_S_z [m s^-2]")
IMU_HEADER = ("#timestamp [ns],w_RS_S_x [rad s^-1],w_RS_S_y [rad s^-1],w_RS_S_z [rad s^-1],"
              "a_RS_S_x [m s^-2],a_RS_S_y [m s^-2],a_RS_S_z [m s^-2]")
VEHICLE_YAML = """name: someone-elses-hex
mass: 1.5
rotor_count: 6
arm_length: 0.215
rotor_angles_deg: [30, 90, 150, -150, -90, -30]
rotor_directions: [1, -1, 1, -1, 1, -1]
rotor_radius: 0.1
"""


def _write(folder, fd, omega_true, *, rotor_rate=100.0):
    """Write ``fd`` by hand in the layout of recordings.md (no project writer involved)."""
    (folder / "mav0" / "state_groundtruth_estimate0").mkdir(parents=True)
    (folder / "mav0" / "imu0").mkdir(parents=True)
    (folder / "mav0" / "rotors0").mkdir(parents=True)
    (folder / "vehicle.yaml").write_text(VEHICLE_YAML)
    with open(folder / "mav0" / "state_groundtruth_estimate0" / "data.csv", "w") as f:
        f.write(GT_HEADER + "\n")
        for k in range(len(fd.t_ns)):
            row = [*fd.p[k], *fd.q[k], *fd.v[k], 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]
            f.write(f"{fd.t_ns[k]}, " + ", ".join(f"{x:.9g}" for x in row) + "\n")
    with open(folder / "mav0" / "imu0" / "data.csv", "w") as f:
        f.write(IMU_HEADER + "\n")
        for k in range(len(fd.t_ns)):
            f.write(f"{fd.t_ns[k] + 1_000_000}," + ",".join(f"{x:.9g}" for x in [*fd.w[k], *fd.acc[k]]) + "\n")
    # rotor speeds at another rate, interpolated from the truth, quantised to 1 rad/s
    t_rot = np.arange(fd.t_ns[0] + 3_000_000, fd.t_ns[-1], int(1e9 / rotor_rate))
    speeds = np.stack([np.interp(t_rot, fd.t_ns, omega_true[:, i]) for i in range(omega_true.shape[1])], 1)
    speeds = np.round(speeds)
    with open(folder / "mav0" / "rotors0" / "data.csv", "w") as f:
        f.write("#timestamp [ns]," + ",".join(f"w_{i} [rad s^-1]" for i in range(6)) + "\n")
        for k in range(len(t_rot)):
            f.write(f"{t_rot[k]}," + ",".join(f"{x:.0f}" for x in speeds[k]) + "\n")
    return folder


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    fd, truth = inverse_dynamics_flight(HEXAROTOR, duration=40.0, seed=21, rotor_quantum=0)
    return _write(tmp_path_factory.mktemp("independent") / "hex_flight", fd, truth["omega"])


def test_identify_json_on_an_independent_recording(recording, capsys):
    assert main(["identify", str(recording), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert {"thrust_coefficient", "moment_coefficient", "inertia", "theta"} <= set(out)
    assert out["thrust_coefficient"] == pytest.approx(HEXAROTOR.thrust_coefficient, rel=0.02)
    assert len(out["inertia"]) == 3 and len(out["theta"]) == 4
    J = np.array(HEXAROTOR.inertia)
    assert out["theta"][3] == pytest.approx(J[2] / J[0], rel=0.10)


def test_residuals_of_an_independent_recording(recording, tmp_path, capsys):
    out = tmp_path / "res.csv"
    assert main(["residuals", str(recording), "--out", str(out)]) == 0
    df = pd.read_csv(out)
    # a clean flight: the residual is sensor noise (m * 0.028 m/s^2 per axis), centred on zero
    fz = df[[c for c in df.columns if c.startswith("F_z")][0]].to_numpy()
    assert abs(np.mean(fz)) < 0.02 and np.std(fz) < 0.1


def test_residuals_take_the_accelerometer_s_bias_off(recording, tmp_path, capsys):
    """The same flight with its accelerometer reading 0.3 m/s^2 more along body x: a sensor's bias, not a force.
    Measured against the motion capture and taken off, the residual stays centred on zero (left in, it was a
    steady 0.45 N push on this 1.5 kg vehicle), and stderr says what was taken off."""
    biased = tmp_path / "biased"
    shutil.copytree(recording, biased)
    imu = biased / "mav0" / "imu0" / "data.csv"
    lines = imu.read_text().splitlines()
    sep = ", " if ", " in lines[1] else ","
    rows = [sep.join(x if i != 4 else repr(float(x) + 0.3) for i, x in enumerate(line.split(sep)))
            for line in lines[1:]]
    imu.write_text("\n".join([lines[0], *rows]) + "\n")
    out = tmp_path / "res.csv"
    assert main(["residuals", str(biased), "--out", str(out)]) == 0
    err = capsys.readouterr().err
    assert "accelerometer bias (0.3" in err and "taken off the IMU's specific force" in err
    fx = pd.read_csv(out)["F_Bx [N]"].to_numpy()
    assert abs(np.mean(fx)) < 0.02 and np.std(fx) < 0.1


def _corrupt_lines(path, fn):
    lines = path.read_text().splitlines()
    path.write_text("\n".join(fn(lines)) + "\n")


def _neighbours_swapped(lines):
    """Every other pair of neighbours swapped over 4 % of the rows after the 20th: 2 % of the rows go back in time,
    more than a logger's threads swap (a few are sorted into place)."""
    end = 20 + len(lines) // 25 // 2 * 2
    swapped = [x for k in range(20, end, 2) for x in (lines[k + 1], lines[k])]
    return lines[:20] + swapped + lines[end:]


CORRUPTIONS = {
    "missing ground truth": ("mav0/state_groundtruth_estimate0/data.csv",
                             lambda p: p.unlink()),
    "wrong column count": ("mav0/imu0/data.csv",
                           lambda p: _corrupt_lines(p, lambda l: l[:5] + [l[5].rsplit(",", 1)[0]] + l[6:])),
    "infinite value": ("mav0/rotors0/data.csv",  # NaN there is a dropout (left out and said), inf no measurement
                       lambda p: _corrupt_lines(p, lambda l: l[:9] + [l[9].rsplit(",", 1)[0] + ",inf"] + l[10:])),
    "non-numeric": ("mav0/imu0/data.csv",
                    lambda p: _corrupt_lines(p, lambda l: l[:7] + [l[7].replace(",", ",abc,", 1)[:-4]] + l[8:])),
    "timestamps out of order": ("mav0/state_groundtruth_estimate0/data.csv",  # 2 % of the rows go back
                                lambda p: _corrupt_lines(p, _neighbours_swapped)),
    "quaternion far from unit norm": ("mav0/state_groundtruth_estimate0/data.csv",
                                      lambda p: _corrupt_lines(p, lambda l: l[:40] + [
                                          ", ".join(x if i != 4 else "2.0" for i, x in enumerate(l[40].split(", ")))
                                      ] + l[41:])),
    "vehicle.yaml missing a key": ("vehicle.yaml",
                                   lambda p: p.write_text(VEHICLE_YAML.replace("rotor_radius: 0.1\n", ""))),
    "vehicle.yaml in millimetres": ("vehicle.yaml",
                                    lambda p: p.write_text(VEHICLE_YAML.replace(
                                        "arm_length: 0.215", "arm_length: 215"))),
    "vehicle.yaml list of the wrong length": ("vehicle.yaml",
                                              lambda p: p.write_text(VEHICLE_YAML.replace(
                                                  "[1, -1, 1, -1, 1, -1]", "[1, -1, 1, -1]"))),
    "rotor count differs from vehicle.yaml": ("mav0/rotors0/data.csv",
                                              lambda p: _corrupt_lines(p, lambda l: [",".join(x.split(",")[:-1])
                                                                                     for x in l])),
    "empty PLY": ("mav0/pointcloud0/data.ply",
                  lambda p: (p.parent.mkdir(parents=True, exist_ok=True), p.write_text(""))),
    "streams that do not overlap": ("mav0/rotors0/data.csv",
                                    lambda p: _corrupt_lines(p, lambda l: [l[0]] + [
                                        str(int(x.split(",")[0]) + 10**12) + "," + x.split(",", 1)[1]
                                        for x in l[1:]])),
}


def test_identify_says_when_k_T_disagrees_with_vehicle_yaml(recording, tmp_path, capsys):
    """vehicle.yaml's thrust coefficient a third of the vehicle's (a mass or coefficient copied wrong): the
    identified k_T is the flights' own and printed, with one line on stderr saying it is 3 times vehicle.yaml's and
    what to check; agreeing values say nothing of it. Rotor speeds in rpm where rad/s belong are refused by their tip
    speed before any fit (``io.reader.check_tip_speed``)."""
    off = tmp_path / "off"
    shutil.copytree(recording, off)
    (off / "vehicle.yaml").write_text(VEHICLE_YAML + f"thrust_coefficient: {HEXAROTOR.thrust_coefficient / 3}\n")
    agree = tmp_path / "agree"
    shutil.copytree(recording, agree)
    (agree / "vehicle.yaml").write_text(VEHICLE_YAML + f"thrust_coefficient: {HEXAROTOR.thrust_coefficient}\n")
    assert main(["identify", str(off), "--json"]) == 0
    k = json.loads(capsys.readouterr().out)["thrust_coefficient"]
    assert k == pytest.approx(HEXAROTOR.thrust_coefficient, rel=0.02)
    assert main(["identify", str(off)]) == 0
    err = capsys.readouterr().err.strip()
    assert err.startswith("uavturb identify: the identified k_T") and "is 3 times vehicle.yaml's" in err
    assert main(["identify", str(agree)]) == 0 and "the identified k_T" not in capsys.readouterr().err
    rpm = tmp_path / "rpm"
    shutil.copytree(agree, rpm)
    _corrupt_lines(rpm / "mav0/rotors0/data.csv", lambda l: [l[0]] + [
        ",".join([x.split(",")[0]] + [f"{float(w) * 60 / (2 * np.pi):.9g}" for w in x.split(",")[1:]]) for x in l[1:]])
    assert main(["identify", str(rpm)]) == 2
    assert "rotors0/data.csv: its rotor speeds put the blade tips at" in capsys.readouterr().err


def test_repeated_timestamps_are_merged_and_said(recording, tmp_path, capsys):
    """A logger's rows stamped alike (an exact copy in the IMU, two ground-truth rows with one timestamp) are
    no malformed file: the last of each is kept, identify runs on, and stderr names the file and the rows."""
    rep = tmp_path / "repeats"
    shutil.copytree(recording, rep)
    _corrupt_lines(rep / "mav0/imu0/data.csv", lambda l: l[:30] + [l[30], l[30]] + l[31:])
    gt = rep / "mav0/state_groundtruth_estimate0/data.csv"
    _corrupt_lines(gt, lambda l: l[:40] + [l[41].split(",", 1)[0] + "," + l[40].split(",", 1)[1]] + l[41:])
    assert main(["identify", str(rep)]) == 0
    err = capsys.readouterr().err
    assert f"{rep}/mav0/imu0/data.csv: 1 row repeats the next row's timestamp (1 exact copy; first at line 31)" in err
    assert f"{gt}: 1 row repeats the next row's timestamp (1 with other values; first at line 41)" in err
    rec = load_recordings([rep])[0]
    assert len(rec.read_notes) == 2 and np.all(np.diff(rec.ground_truth.t_ns) > 0)
    assert len(rec.imu.t_ns) == len(load_recordings([recording])[0].imu.t_ns)
    _, _, found = prepared([rec], [str(rep)])  # gap's report lists them with what the streams hold
    assert found["streams"][:2] == list(rec.read_notes)


@pytest.mark.parametrize("case", sorted(CORRUPTIONS))
@pytest.mark.parametrize("command", ["identify", "residuals"])
def test_malformed_recordings_give_one_line(recording, tmp_path, capsys, case, command):
    bad = tmp_path / "bad"
    shutil.copytree(recording, bad)
    rel, corrupt = CORRUPTIONS[case]
    corrupt(bad / rel)
    out = tmp_path / "out" / "res.csv"
    out.parent.mkdir()
    args = ["identify", str(bad)] if command == "identify" else ["residuals", str(bad), "--out", str(out)]
    assert main(args) == 2, case
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "Traceback" not in err, err
    named = rel.split("/")[-2] if rel.endswith("data.csv") else rel.split("/")[-1]
    assert named in err, (case, err)
    assert list(out.parent.iterdir()) == []  # nothing written, not even a temporary file
