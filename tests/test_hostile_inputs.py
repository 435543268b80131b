"""Recordings from strangers: every hostile input the test writes (small files: the bombs are tiny)
is refused in one line naming the file and the limit, in bounded time and memory, or read.

Memory is measured in this process with ``tracemalloc`` (numpy and Python allocations), or, for
the command line, by the kernel for the child process (its ``VmHWM``); limits are generous.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
import time
import tracemalloc
from pathlib import Path

import numpy as np
import pytest

from conftest import make_recording
from uavturb.cli import main
from uavturb.errors import InputError
from uavturb.io import euroc_csv, ply, yaml_mapping
from uavturb.io.reader import GROUNDTRUTH_CSV, IMU_YAML, POINTS_PLY, ROTORS_CSV, VEHICLE_YAML, read_recording
from uavturb.io.writer import write_recording

REPO = Path(__file__).resolve().parents[1]
MB = 1 << 20

#: 9 levels of 9 aliases: 9^9 (387 million) values once expanded, 836 bytes on disk
BOMB = "a: &a [x, x, x, x, x, x, x, x, x]\n" + "".join(
    f"{c}: &{c} [{', '.join(['*' + p] * 9)}]\n" for p, c in zip("abcdefgh", "bcdefghi"))


@pytest.fixture
def rec(tmp_path) -> Path:
    return write_recording(make_recording(), tmp_path / "rec")


def _refused(fn, *args, match: str, seconds: float = 30.0, megabytes: float = 300.0, **kw) -> str:
    """``fn(*args)`` raises one InputError line matching ``match`` within the time and memory given."""
    tracemalloc.start()
    t0 = time.perf_counter()
    try:
        with pytest.raises(InputError, match=match) as e:
            fn(*args, **kw)
    finally:
        _, peak = tracemalloc.get_traced_memory()
        tracemalloc.stop()
    took = time.perf_counter() - t0
    line = str(e.value)
    assert "\n" not in line and len(line) < 1200, line[:2000]
    assert took < seconds and peak < megabytes * MB, (took, peak / MB)
    return line


# --- YAML ----------------------------------------------------------------------------------


@pytest.mark.parametrize("key", ["mass", "name", "T_BS"])
def test_an_alias_bomb_in_vehicle_yaml_is_refused_at_once(rec, key):
    kept = [s for s in (rec / VEHICLE_YAML).read_text().splitlines() if not s.startswith(f"{key}:")]  # no T_BS here
    bomb = BOMB.replace("\n", "\n  ")
    (rec / VEHICLE_YAML).write_text("\n".join(kept) + f"\nbombs:\n  {bomb}\n{key}: *i\n")
    _refused(read_recording, rec, match=r"vehicle.yaml: refused: expands to more than 100000 values", seconds=5)


def test_an_alias_bomb_in_imu_sensor_yaml_is_refused(rec):
    (rec / IMU_YAML).write_text(BOMB + "rate_hz: *i\n")
    _refused(read_recording, rec, match=r"sensor.yaml: refused: expands to more than 100000 values", seconds=5)


@pytest.mark.parametrize("text, match", [
    ("a: " + "[" * 50_000 + "]" * 50_000 + "\n", "nested deeper than 64 levels"),
    ("mass: " + "9" * 5000 + "\n", "holds a value that cannot be read"),
    ("a: &a [1, *a]\n", "holds an alias that refers to itself"),
    ("a: 1\n" + "#" * (2 * MB) + "\n", "YAML files are read up to 1048576 bytes"),
    ("a: [1, 2\n", r"not valid YAML \(ParserError\)"),
    ("rate_hz: 2\x12\n", r"not valid YAML \(ReaderError: special characters are not allowed\)"),  # a control character
])
def test_yaml_bounds(tmp_path, text, match):
    path = tmp_path / "vehicle.yaml"
    path.write_text(text)
    _refused(yaml_mapping.read_yaml_mapping, path, match=match, seconds=10)


def test_yaml_1_2_exponents_are_numbers():
    d = yaml_mapping.parse_yaml_mapping("a: 1.0e308\nb: 1e5\nc: -2E-3\nd: 1.0e+3\ne: 12\nf: 1e5x\n", "t.yaml")
    assert d == {"a": 1e308, "b": 1e5, "c": -2e-3, "d": 1e3, "e": 12, "f": "1e5x"}
    assert isinstance(d["e"], int)


@pytest.mark.parametrize("count, match", [(100_000, "from 3 to 32, got 100000"), (10**400, "from 3 to 32")])
def test_rotor_count_is_bounded(rec, count, match):
    text = (rec / VEHICLE_YAML).read_text()
    (rec / VEHICLE_YAML).write_text("\n".join(f"rotor_count: {count}" if s.startswith("rotor_count:") else s
                                              for s in text.splitlines()))
    _refused(read_recording, rec, match=match, seconds=5)


def test_a_huge_number_in_vehicle_yaml_is_one_line(rec):
    text = (rec / VEHICLE_YAML).read_text()
    (rec / VEHICLE_YAML).write_text("\n".join("mass: " + "9" * 400 if s.startswith("mass:") else s
                                              for s in text.splitlines()))
    _refused(read_recording, rec, match="key 'mass' must be a finite number", seconds=5)


# --- CSV -----------------------------------------------------------------------------------


def test_a_state_stepping_by_minutes_is_refused_at_once(rec):
    # nanoseconds written from milliseconds: rows 5000 s apart (the position check's windows were once laid over
    # the whole span, 40 million of them, and the command never ended)
    lines = (rec / GROUNDTRUTH_CSV).read_text().splitlines()
    t0 = int(lines[1].split(",")[0])
    lines[1:] = [f"{t0 + k * 5_000 * 10**9},{line.split(',', 1)[1]}" for k, line in enumerate(lines[1:])]
    (rec / GROUNDTRUTH_CSV).write_text("\n".join(lines) + "\n")
    _refused(read_recording, rec, match=r"state_groundtruth_estimate0/data.csv: timestamps step by 5000 s "
                                        r"\(0.0002 Hz\)", seconds=5)


@pytest.mark.parametrize("value", ["1e308", "1e12"])
def test_a_rotor_speed_no_rotor_reaches_is_named(rec, value):
    # squared, 1e308 overflowed and the gap finder's least squares stopped inside LAPACK
    lines = (rec / ROTORS_CSV).read_text().splitlines()
    cells = lines[101].split(",")
    cells[2] = value
    lines[101] = ",".join(cells)
    (rec / ROTORS_CSV).write_text("\n".join(lines) + "\n")
    _refused(read_recording, rec,
             match=rf"rotors0/data.csv: line 102: rotor speed {re.escape(f'{float(value):.4g}')} for rotor 1 is "
                   r".* rad/s with rotor_speed_scale [0-9.]+, over the 1e\+05 rad/s no rotor reaches "
                   r"\(1 value over it\)")


def test_a_long_timestamp_field_is_refused_without_a_fixed_width_array(rec):
    path = rec / GROUNDTRUTH_CSV
    rows = path.read_text().splitlines()
    rows[5] = "7" * 60_000 + rows[5][rows[5].index(","):]  # a fixed-width array of 400 such rows: 96 MB
    path.write_text("\n".join(rows) + "\n")
    line = _refused(read_recording, rec, match="line 6, column 1: expected a timestamp", megabytes=30)
    assert len(line) < 800  # the field is not echoed whole


def test_a_line_longer_than_the_limit_is_refused(rec):
    path = rec / GROUNDTRUTH_CSV
    with path.open("a") as f:
        f.write("1," + "5" * (3 * MB) + "\n")
    _refused(read_recording, rec, match=r"is longer than 65536 bytes \(the limit of a line\)", megabytes=100)


def test_a_million_columns_are_refused_on_the_first_row(rec):
    path = rec / ROTORS_CSV
    path.write_text("#t\n1" + ",1" * 1_000_000 + "\n")
    _refused(read_recording, rec, match=r"line 2: 1000001 columns, more than 64 \(the limit of a row\)", seconds=10,
             megabytes=100)


def test_a_file_over_the_row_limit_is_refused_with_the_memory_it_would_need(rec, monkeypatch):
    monkeypatch.setattr(euroc_csv, "MAX_ROWS", 100)
    monkeypatch.setattr(euroc_csv, "ANALYSIS_BYTES_PER_ROW", 10**7)
    _refused(read_recording, rec, match=r"holds about 400 rows, more than 100 \(the limit of a file\); reading it "
                                        r"would need about 0\.0 GB of memory, analysing it about 4\.0 GB")


def test_headers_accept_any_text_a_bom_and_bytes_that_are_not_utf8(rec):
    path = rec / GROUNDTRUTH_CSV
    before = read_recording(rec).ground_truth.t_ns
    body = path.read_bytes()
    path.write_bytes(b"\xef\xbb\xbf#\xff\xfe caf\xe9 [m]\n" + body)
    assert np.array_equal(read_recording(rec).ground_truth.t_ns, before)


def test_a_byte_that_is_not_text_in_a_row_is_named(rec):
    path = rec / GROUNDTRUTH_CSV
    rows = path.read_bytes().split(b"\n")
    rows[3] = rows[3].replace(b",", b",\xff", 1)
    path.write_bytes(b"\n".join(rows))
    _refused(read_recording, rec, match=r"line 4: not text \(byte 0xff")


def test_comment_and_blank_lines_between_rows_keep_their_line_numbers(tmp_path):
    path = tmp_path / "d.csv"
    path.write_text("#h\n10,1\n\n# note\n20,2\n  \n30,x\n")
    _refused(euroc_csv.read_csv, path, 2, match="line 7, column 2: expected a number, found 'x'")


# --- PLY -----------------------------------------------------------------------------------


def _ply(count_type: str, count: int, tail: bytes = b"") -> bytes:
    header = (f"ply\nformat binary_little_endian 1.0\nelement face 1\nproperty list {count_type} int vertex_indices\n"
              "element vertex 1\nproperty float x\nproperty float y\nproperty float z\nend_header\n").encode()
    return header + np.array([count], dtype={"char": "i1", "int": "<i4", "uint": "<u4"}[count_type]).tobytes() + tail


@pytest.mark.parametrize("count_type, count, match", [
    ("char", -1, r"PLY element 'face' 0: list 'vertex_indices' has a negative length \(-1\)"),
    ("int", -2**31, "has a negative length"),
    ("uint", 2**32 - 1, r"PLY data is truncated \(in element 'face'\)"),
])
def test_ply_list_counts_are_validated(tmp_path, count_type, count, match):
    path = tmp_path / "cloud.ply"
    path.write_bytes(_ply(count_type, count, b"\0" * 12))
    _refused(ply.read_ply, path, match=match, seconds=5)


def test_a_ply_with_many_empty_list_items_ends(tmp_path):
    path = tmp_path / "cloud.ply"  # 10^12 faces announced, 200 bytes given: the walk stops at the end
    path.write_bytes(_ply("char", 0).replace(b"element face 1", b"element face 1000000000000") + b"\0" * 200)
    _refused(ply.read_ply, path, match="truncated", seconds=5)


# --- the command line: exit 2, one line, bounded time and memory, measured by the kernel -----


#: ``uavturb ARGS`` in a child that prints its own peak resident memory (``VmHWM``, kB) last on stdout
_CHILD = ("import sys\nfrom uavturb.cli import main\ncode = main(sys.argv[1:])\n"
          "print(open('/proc/self/status').read().split('VmHWM:')[1].split()[0])\nsys.exit(code)\n")


def _cli(args: list[str], cwd: Path) -> tuple[int, str, float, float]:
    """(exit status, stderr, seconds, peak memory in MB) of ``uavturb ARGS`` in a child process."""
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")])}
    t0 = time.perf_counter()
    res = subprocess.run([sys.executable, "-c", _CHILD, *args], cwd=cwd, env=env, capture_output=True, text=True,
                         timeout=120)
    return res.returncode, res.stderr, time.perf_counter() - t0, float(res.stdout.split()[-1]) / 1024


def test_cli_yaml_bomb_and_ply_hang_and_random_bag(rec, tmp_path):
    (rec / IMU_YAML).write_text(BOMB + "rate_hz: *i\n")
    code, err, took, mb = _cli(["identify", str(rec)], tmp_path)
    assert code == 2 and len(err.strip().splitlines()) == 1 and "refused: expands to more than" in err, err[-2000:]
    assert took < 30 and mb < 2048
    (rec / IMU_YAML).unlink()
    (rec / POINTS_PLY).write_bytes(_ply("char", -1, b"\0" * 200))
    code, err, took, mb = _cli(["identify", str(rec)], tmp_path)
    assert code == 2 and len(err.strip().splitlines()) == 1 and "negative length" in err, err[-2000:]
    assert took < 30 and mb < 2048
    bag = tmp_path / "random.bag"
    bag.write_bytes(np.random.default_rng(0).bytes(4000))
    code, err, took, mb = _cli(["import", "euroc", str(bag), "--out", str(tmp_path / "imported")], tmp_path)
    assert code == 2 and err.startswith(f"uavturb import euroc: error: {bag}: not a readable ROS1 bag"), err[-2000:]
    assert len(err.strip().splitlines()) == 1 and not (tmp_path / "imported").exists()


def test_the_last_guard_turns_any_failure_into_one_line(monkeypatch, capsys):
    from uavturb import cli

    for error, code, text in [(MemoryError(), 2, "out of memory"),
                              (RecursionError(), 2, "an input is nested too deeply"),
                              (OSError(28, "No space left on device", "/data/x.csv"), 2,
                               "/data/x.csv: no space left on the device"),
                              (FileNotFoundError(2, "No such file or directory", "/data/y.ckpt"), 2,
                               "/data/y.ckpt: No such file or directory"),
                              (FileNotFoundError(2, "No such file or directory", "/a.tmp", None, "/b.ckpt"), 2,
                               "/a.tmp -> /b.ckpt: No such file or directory"),
                              # Lightning's, its message only (it had been "a file: FileNotFoundError")
                              (FileNotFoundError("Checkpoint file not found: /runs/best-0.ckpt"), 2,
                               "Checkpoint file not found: /runs/best-0.ckpt (FileNotFoundError at "
                               "test_hostile_inputs.py:"),
                              (FileNotFoundError(), 2, "a file opened at test_hostile_inputs.py:"),
                              (KeyError("boom"), 1, "internal error (KeyError: 'boom') at test_hostile_inputs.py")]:
        def fail(args, error=error):
            raise error

        monkeypatch.setitem(cli.HANDLERS, "identify", fail)
        assert main(["identify", "x"]) == code
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and err[0].startswith(f"uavturb identify: error: {text}"), err


# --- links out of the recording folder ---------------------------------------------------------


def test_a_stream_linked_out_of_the_recording_is_followed_only_when_asked(rec, tmp_path, monkeypatch):
    outside = tmp_path / "elsewhere.csv"
    (rec / GROUNDTRUTH_CSV).rename(outside)
    (rec / GROUNDTRUTH_CSV).symlink_to(outside)
    _refused(read_recording, rec, match=r"data.csv: is a link out of the recording folder \(to .*elsewhere.csv\); "
                                        "it is not followed unless you set UAVTURB_FOLLOW_LINKS=1")
    monkeypatch.setenv("UAVTURB_FOLLOW_LINKS", "1")
    assert len(read_recording(rec).ground_truth.t_ns) == 400
    monkeypatch.delenv("UAVTURB_FOLLOW_LINKS")
    inside = rec / "gt_copy.csv"  # a link that stays inside the folder is fine
    outside.rename(inside)
    (rec / GROUNDTRUTH_CSV).unlink()
    (rec / GROUNDTRUTH_CSV).symlink_to(inside)
    assert len(read_recording(rec).ground_truth.t_ns) == 400


def test_a_loop_of_links_or_a_link_to_nothing_is_named(rec, tmp_path):
    loop = rec / GROUNDTRUTH_CSV
    loop.unlink()
    loop.symlink_to(loop)
    _refused(read_recording, rec, match=r"data.csv: is a loop of links \(.*data.csv\)")
    loop.unlink()
    loop.symlink_to(tmp_path / "gone.csv")
    _refused(read_recording, rec, match=r"data.csv: is a link to nothing \(.*gone.csv\)")
