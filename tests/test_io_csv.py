"""File formats of a recording: EuRoC CSV, PLY point clouds and sensor.yaml."""

from __future__ import annotations


import numpy as np
import pytest

from uavturb.errors import InputError
from uavturb.io import euroc_csv, ply, sensor_yaml
from uavturb.io.recording import Camera

T0 = 1403636579763555584


def write(tmp_path, text, name="data.csv"):
    path = tmp_path / name
    path.write_text(text)
    return path


# --- CSV ------------------------------------------------------------------------------


@pytest.mark.parametrize("sep", [",", ", "])
def test_read_csv_both_separators_exact_timestamps(tmp_path, sep):
    path = write(tmp_path, f"#timestamp [ns]{sep}a{sep}b\n{T0}{sep}1.5{sep}-2e-3\n{T0 + 1}{sep}0.1{sep}3\n")
    t, x = euroc_csv.read_csv(path, 3, "test")
    assert t.dtype == np.int64 and t.tolist() == [T0, T0 + 1]  # exact: not through float
    np.testing.assert_array_equal(x, [[1.5, -2e-3], [0.1, 3.0]])


def test_read_csv_any_header_and_no_header(tmp_path):
    for header in ("#timestamp, p_RS_R_x [m]\n", "# whatever text\n#second line\n", ""):
        t, x = euroc_csv.read_csv(write(tmp_path, header + "10,1\n20,2\n\n"), 2)
        assert t.tolist() == [10, 20] and x[:, 0].tolist() == [1.0, 2.0]


def test_a_file_read_in_many_blocks_is_the_file_read_in_one(tmp_path, monkeypatch):
    """Blocks of whole lines (:data:`euroc_csv.BLOCK_BYTES`, 2 MB): with blocks of 100 bytes, rows cut at every
    block's end, a header, comments and blank lines between rows give the same rows and line numbers as one
    block, and a bad value in a later block is named at its line."""
    rows = [f"{T0 + 10 * k}, {0.25 * k:.6f}, {-1.5 * k:.3e}" for k in range(400)]
    rows[37:37] = ["# a comment in the middle", ""]
    path = write(tmp_path, "#timestamp [ns], a, b\n" + "\n".join(rows) + "\n")
    whole = euroc_csv.read_csv(path, 3, "test", return_lines=True)
    monkeypatch.setattr(euroc_csv, "BLOCK_BYTES", 100)
    cut = euroc_csv.read_csv(path, 3, "test", return_lines=True)
    assert len(whole[0]) == 400 and whole[2][[0, 36, 37, 399]].tolist() == [2, 38, 41, 403]
    for a, b in zip(whole, cut):
        np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(cut[1][:, 0], 0.25 * np.arange(400))
    bad = path.read_text().splitlines()
    bad[300] = bad[300].replace(", ", ", x", 1)
    path.write_text("\n".join(bad) + "\n")
    with pytest.raises(InputError, match="line 301, column 2: expected a number"):
        euroc_csv.read_csv(path, 3, "test")


def test_read_csv_infers_column_count(tmp_path):
    t, x = euroc_csv.read_csv(write(tmp_path, "#h\n1,2,3,4\n2,5,6,7\n"), None)
    assert x.shape == (2, 3)


@pytest.mark.parametrize("text, expected", [
    ("", "no data rows"),
    ("#timestamp,a,b\n", "no data rows"),
    ("#h\n1,2,3\n2,3\n", "line 3: expected 3 columns, found 2"),
    ("#h\n1,2,3\n2,3,4,5\n", "line 3: expected 3 columns, found 4"),
    ("#h\n1,2,3\n2,3,4,\n", "line 3: expected 3 columns, found 4 (the row ends with a comma: EuRoC rows do not)"),
    ("#h\n1,2,3\n2,abc,4\n", "line 3, column 2: expected a number, found 'abc'"),
    ("#h\n1,2,3\n2,,4\n", "line 3, column 2"),
    ("#h\n1.5e3,2,3\n", "line 2, column 1: expected a timestamp"),
    ("#h\n1,2,3\n2,nan,4\n", "line 3, column 2: value nan is not finite"),
    ("#h\n1,2,3\n2,4,-inf\n", "line 3, column 3: value -inf is not finite"),
    ("#h\n1,2,3\n1,3,4\n", "line 3: timestamp 1 is duplicated"),
    ("#h\n5,2,3\n6,3,4\n4,3,4\n", "line 4: timestamp 4 is out of order"),
])
def test_read_csv_malformed(tmp_path, text, expected):
    path = write(tmp_path, text, "bad.csv")
    with pytest.raises(InputError) as e:
        euroc_csv.read_csv(path, 3, "test")
    assert str(path) in str(e.value) and expected in str(e.value)


def test_read_csv_merges_repeated_timestamps_where_asked(tmp_path):
    """Loggers stamp two messages alike: with ``repeated_times`` the last row of each timestamp is kept and one
    sentence says how many rows went and of which kind; a time going back is refused all the same."""
    path = write(tmp_path, "#h\n1,2,3\n1,2,3\n2,3,4\n3,5,6\n3,7,8\n3,9,9\n4,1,1\n", "rep.csv")
    notes: list[str] = []
    t, x, lines = euroc_csv.read_csv(path, 3, "test", return_lines=True, repeated_times=notes)
    assert t.tolist() == [1, 2, 3, 4] and x.tolist() == [[2, 3], [3, 4], [9, 9], [1, 1]]
    assert lines.tolist() == [3, 4, 7, 8]
    assert notes == [f"{path}: 3 rows repeat the next row's timestamp (1 exact copy, 2 with other values; first at "
                     "line 2): the last row of each timestamp kept"]
    t, x = euroc_csv.read_csv(write(tmp_path, "#h\n1,2,3\n2,3,4\n", "ok.csv"), 3, repeated_times=notes)
    assert t.tolist() == [1, 2] and len(notes) == 1  # nothing repeated, nothing said
    with pytest.raises(InputError, match="line 4: timestamp 4 is out of order"):
        euroc_csv.read_csv(write(tmp_path, "#h\n5,2,3\n5,3,4\n4,3,4\n", "back.csv"), 3, repeated_times=[])


def test_read_csv_sorts_a_few_rows_out_of_order_where_asked(tmp_path):
    """A logger writing from two threads swaps a few neighbours: under 1 % of the rows going back are put in time
    order and said where the caller takes notes; more are refused naming the first."""
    rows = [f"{10 * k},{k}" for k in range(300)]
    rows[100], rows[101] = rows[101], rows[100]
    rows[200], rows[201] = rows[201], rows[200]
    path = write(tmp_path, "#t,a\n" + "\n".join(rows) + "\n", "swapped.csv")
    with pytest.raises(InputError, match="line 103: timestamp 1000 is out of order"):
        euroc_csv.read_csv(path, 2)
    notes: list[str] = []
    t, x = euroc_csv.read_csv(path, 2, repeated_times=notes)
    assert t.tolist() == [10 * k for k in range(300)] and x[:, 0].tolist() == list(range(300))
    assert notes == [f"{path}: 4 rows out of time order, none by more than 5 of the stream's steps (first at line "
                     "103; a logger writing from two threads) put in time order"]
    many = rows[:]
    for k in range(0, 20, 2):
        many[k], many[k + 1] = many[k + 1], many[k]
    with pytest.raises(InputError, match="out of order"):
        euroc_csv.read_csv(write(tmp_path, "#t,a\n" + "\n".join(many) + "\n", "many.csv"), 2, repeated_times=[])
    # a block of rows stamped 0.3 s early (30 steps back) or a logger restarted 10 s back: refused, not interleaved
    for name, start, stop, shift in (("block.csv", 200, 250, 300), ("restart.csv", 150, 300, 1000)):
        moved = [f"{10 * k - shift * (start <= k < stop)},{k}" for k in range(300)]
        with pytest.raises(InputError, match=f"line {start + 2}: timestamp {10 * start - shift} is out of order: "
                                             f"{(shift - 10) * 1e-9:.4g} s before the previous row's"):
            euroc_csv.read_csv(write(tmp_path, "#t,a\n" + "\n".join(moved) + "\n", name), 2, repeated_times=[])


def test_read_csv_missing_file(tmp_path):
    with pytest.raises(InputError, match="nope.csv: file not found"):
        euroc_csv.read_csv(tmp_path / "nope.csv", 3)


def test_write_csv_round_trip_and_headers(tmp_path):
    rng = np.random.default_rng(0)
    t = T0 + np.arange(50, dtype=np.int64) * 5_000_001
    x = rng.normal(size=(50, 6)) * 10.0 ** rng.integers(-12, 12, size=(50, 6))
    path = tmp_path / "imu0" / "data.csv"
    euroc_csv.write_csv(path, euroc_csv.IMU_HEADER, t, x)
    assert path.read_text().splitlines()[0] == euroc_csv.IMU_HEADER
    t2, x2 = euroc_csv.read_csv(path, 7)
    assert np.array_equal(t2, t) and np.array_equal(x2, x)  # bit-exact
    assert [p.name for p in path.parent.iterdir()] == ["data.csv"]  # no temporary file left
    assert euroc_csv.rotors_header(3) == "#timestamp [ns],w_0 [rad s^-1],w_1 [rad s^-1],w_2 [rad s^-1]"
    assert euroc_csv.GROUNDTRUTH_HEADER.count(",") == 16 and euroc_csv.VICON_HEADER.count(",") == 7
    euroc_csv.write_csv(path, euroc_csv.IMU_HEADER, t, x, fmt="%.3f")
    assert euroc_csv.read_csv(path, 7)[1][0, 0] == pytest.approx(x[0, 0], abs=1e-3)
    with pytest.raises(InputError, match="non-finite"):
        euroc_csv.write_csv(path, euroc_csv.IMU_HEADER, t, np.full_like(x, np.nan))
    with pytest.raises(InputError, match="7-column header"):
        euroc_csv.write_csv(path, euroc_csv.IMU_HEADER, t, x[:, :5])


def test_frame_list_round_trip(tmp_path):
    path = tmp_path / "data.csv"
    t = T0 + np.arange(3) * 50_000_000
    euroc_csv.write_frame_list(path, t, [f"{x}.png" for x in t])
    assert path.read_text().startswith("#timestamp [ns],filename\n")
    t2, files = euroc_csv.read_frame_list(path)
    assert np.array_equal(t2, t) and files == [f"{x}.png" for x in t]
    with pytest.raises(InputError, match="line 3: timestamp 1 is out of order"):
        euroc_csv.read_frame_list(write(tmp_path, "#h\n2, a.png\n1, b.png\n", "f.csv"))


def test_read_csv_large_file_round_trips(tmp_path):
    n, pool = 100_000, np.random.default_rng(1).normal(size=(1000, 16))
    t = T0 + np.arange(n, dtype=np.int64) * 5_000_000
    rows = [", ".join(map(repr, r)) for r in pool.tolist()]
    path = tmp_path / "big.csv"
    path.write_text(euroc_csv.GROUNDTRUTH_HEADER + "\n" + "".join(
        f"{a}, {rows[k % 1000]}\n" for k, a in enumerate(t.tolist())))
    t2, x2 = euroc_csv.read_csv(path, 17)  # speed: `uavturb bench physics`, not a timed test
    assert np.array_equal(t2, t) and np.array_equal(x2, pool[np.arange(n) % 1000])


# --- PLY ------------------------------------------------------------------------------

PTS = np.array([[0.0, 1.0, 2.0], [-1.5, 2.25, 1e-3], [3.0, -4.0, 5.5]])


def ply_header(fmt, vertex_props, n=3, faces_first=False, n_faces=1):
    face = f"element face {n_faces}\nproperty list uchar int vertex_indices\n"
    vertex = f"element vertex {n}\n" + "".join(f"property {t} {name}\n" for t, name in vertex_props)
    body = (face + vertex) if faces_first else (vertex + face)
    return f"ply\nformat {fmt} 1.0\ncomment test\n{body}end_header\n".encode()


@pytest.mark.parametrize("binary", [True, False])
def test_ply_round_trip(tmp_path, binary):
    path = tmp_path / "data.ply"
    ply.write_ply(path, PTS, binary=binary)
    assert np.array_equal(ply.read_ply(path), PTS)


@pytest.mark.parametrize("endian, fmt", [("<", "binary_little_endian"), (">", "binary_big_endian")])
@pytest.mark.parametrize("faces_first", [False, True])
def test_ply_binary_any_property_order_and_types(tmp_path, endian, fmt, faces_first):
    props = [("uchar", "red"), ("float", "z"), ("int16", "label"), ("float", "x"), ("double", "nx"), ("float", "y")]
    dtype = np.dtype([("red", "u1"), ("z", "f4"), ("label", "i2"), ("x", "f4"), ("nx", "f8"), ("y", "f4")])
    arr = np.zeros(3, dtype=dtype.newbyteorder(endian))
    arr["x"], arr["y"], arr["z"] = PTS.T
    arr["red"], arr["label"] = 200, -7
    face = np.array([3], np.uint8).tobytes() + np.array([0, 1, 2], endian + "i4").tobytes()
    body = face + arr.tobytes() if faces_first else arr.tobytes() + face
    path = tmp_path / "data.ply"
    path.write_bytes(ply_header(fmt, props, faces_first=faces_first) + body)
    np.testing.assert_array_equal(ply.read_ply(path), PTS.astype(np.float32))


@pytest.mark.parametrize("faces_first", [False, True])
def test_ply_ascii_with_faces_and_extra_properties(tmp_path, faces_first):
    props = [("double", "y"), ("uchar", "red"), ("double", "x"), ("double", "z")]
    verts = "".join(f"{y!r} 7 {x!r} {z!r}\n" for x, y, z in PTS.tolist())
    faces = "4 0 1 2 0\n"
    path = tmp_path / "data.ply"
    path.write_bytes(ply_header("ascii", props, faces_first=faces_first)
                     + ((faces + verts) if faces_first else (verts + faces)).encode())
    assert np.array_equal(ply.read_ply(path), PTS)


@pytest.mark.parametrize("content, expected", [
    (None, "file not found"),
    (b"hello world\n", "not a PLY file"),
    (ply_header("ascii", [("float", "x"), ("float", "y"), ("float", "z")], n=0), "empty (0 vertices)"),
    (ply_header("ascii", [("float", "x"), ("float", "y"), ("float", "z")]) + b"1 2 3\n4 5 6\n",
     "truncated: expected 3 vertex lines, found 2"),
    (ply_header("ascii", [("float", "x"), ("float", "y"), ("float", "z")]) + b"1 2 3\n4 5 6\n7 8 9\n1 1 1\n2 2 2\n",
     "PLY body holds 1 more line(s) than its header declares (3 vertices and 1 other items)"),
    (ply_header("binary_little_endian", [("float", "x"), ("float", "y"), ("float", "z")]) + b"\0" * 20,
     "truncated: 3 vertices need 36 bytes, found 20"),
    (ply_header("ascii", [("float", "x"), ("float", "y"), ("float", "q")]) + b"1 2 3\n4 5 6\n7 8 9\n",
     "no z property"),
    (ply_header("ascii", [("float", "x"), ("float", "y"), ("float", "z")]) + b"1 2 3\n4 5\n7 8 9\n",
     "vertex 1: expected 3 values, found 2"),
    (ply_header("ascii", [("float", "x"), ("float", "y"), ("float", "z")]) + b"1 2 3\n4 a 6\n7 8 9\n",
     "not numeric"),
    (b"ply\nformat ascii 1.0\nelement face 0\nend_header\n", "no 'vertex' element"),
])
def test_ply_malformed(tmp_path, content, expected):
    path = tmp_path / "cloud.ply"
    if content is not None:
        path.write_bytes(content)
    with pytest.raises(InputError) as e:
        ply.read_ply(path)
    assert str(path) in str(e.value) and expected in str(e.value)


def test_ply_million_points_round_trip(tmp_path):
    pts = np.random.default_rng(0).uniform(-5, 5, size=(1_000_000, 3))
    path = tmp_path / "big.ply"
    ply.write_ply(path, pts)
    assert np.array_equal(ply.read_ply(path), pts)


def _floor_mesh(path, fmt: str, quads: bool = False, extra: bytes = b""):
    """A 4 x 3 m floor at z = 0.1 as a PLY mesh: 4 corners and two triangles (or one quad), plus ``extra`` vertices."""
    corners = np.array([[0, 0, 0.1], [4, 0, 0.1], [4, 3, 0.1], [0, 3, 0.1]], float)
    faces = [[0, 1, 2, 3]] if quads else [[0, 1, 2], [0, 2, 3]]
    n_extra = len(extra.splitlines()) if fmt == "ascii" else len(extra) // 12
    header = (f"ply\nformat {fmt} 1.0\nelement vertex {4 + n_extra}\nproperty float x\nproperty float y\n"
              f"property float z\nelement face {len(faces)}\nproperty list uchar int vertex_indices\nend_header\n")
    if fmt == "ascii":
        body = "".join(f"{x} {y} {z}\n" for x, y, z in corners).encode() + extra
        body += "".join(f"{len(f)} {' '.join(map(str, f))}\n" for f in faces).encode()
    else:
        body = corners.astype("<f4").tobytes() + extra
        body += b"".join(np.array([len(f)], "u1").tobytes() + np.array(f, "<i4").tobytes() for f in faces)
    path.write_bytes(header.encode() + body)
    return path


@pytest.mark.parametrize("fmt, quads", [("binary_little_endian", False), ("ascii", False), ("ascii", True),
                                        ("binary_little_endian", True)])
def test_a_mesh_ply_is_read_as_its_surfaces(tmp_path, fmt, quads):
    path = _floor_mesh(tmp_path / "data.ply", fmt, quads)
    assert len(ply.read_ply(path)) == 4  # the vertices alone, as the contract reads a PLY
    np.testing.assert_array_equal(ply.read_ply_faces(path, 4), [[0, 1, 2], [0, 2, 3]])
    notes: list[str] = []
    pts = ply.scene_points(path, notes)
    assert len(pts) == 4 + int(np.ceil(12.0 / ply.FACE_SPACING_M**2))  # 12 m^2 at one point per 4 cm^2
    assert np.all(pts[:, 2] == pytest.approx(0.1)) and np.all((pts[:, 0] >= 0) & (pts[:, 0] <= 4))
    counts, _, _ = np.histogram2d(pts[:, 0], pts[:, 1], bins=(8, 6), range=((0, 4), (0, 3)))
    assert counts.min() > 0.8 * counts.mean()  # spread over the whole floor
    assert notes and "a mesh of 2 triangles (12 m^2)" in notes[0]


def test_non_finite_vertices_are_left_out_of_a_scene_and_said(tmp_path):
    nan = np.array([[np.nan, np.nan, np.nan], [1.0, np.inf, 0.0]], "<f4").tobytes()
    path = _floor_mesh(tmp_path / "data.ply", "binary_little_endian", extra=nan)
    with pytest.raises(InputError, match="PLY vertex 4 has a non-finite coordinate"):
        ply.read_ply(path)
    notes: list[str] = []
    pts = ply.scene_points(path, notes)
    assert np.isfinite(pts).all() and len(pts) == 4 + int(np.ceil(12.0 / ply.FACE_SPACING_M**2))
    assert "2 of 6 vertices have non-finite coordinates" in notes[0]
    only_nan = tmp_path / "nan.ply"
    only_nan.write_bytes(
        b"ply\nformat binary_little_endian 1.0\nelement vertex 2\nproperty float x\nproperty float y\n"
        b"property float z\nend_header\n" + np.full(6, np.nan, "<f4").tobytes())
    with pytest.raises(InputError, match="none of the PLY's 2 vertices has finite coordinates"):
        ply.scene_points(only_nan, [])


def test_a_face_outside_the_vertices_is_refused(tmp_path):
    path = _floor_mesh(tmp_path / "data.ply", "ascii")
    path.write_bytes(path.read_bytes().replace(b"3 0 2 3\n", b"3 0 2 9\n"))
    with pytest.raises(InputError) as e:
        ply.scene_points(path, [])
    assert str(path) in str(e.value) and "PLY face 1 refers to vertex 9, and the file has 4 vertices" in str(e.value)


# --- sensor.yaml ----------------------------------------------------------------------

EUROC_CAM0 = """%YAML:1.0
# General sensor definitions.
sensor_type: camera
comment: VI-Sensor cam0 (MT9M034)

# Sensor extrinsics wrt. the body-frame.
T_BS:
  cols: 4
  rows: 4
  data: [0.0148655429818, -0.999880929698, 0.00414029679422, -0.0216401454975,
         0.999557249008, 0.0149672133247, 0.025715529948, -0.064676986768,
        -0.0257744366974, 0.00375618835797, 0.999660727178, 0.00981073058949,
         0.0, 0.0, 0.0, 1.0]

# Camera specific definitions.
rate_hz: 20
resolution: [752, 480]
camera_model: pinhole
intrinsics: [458.654, 457.296, 367.215, 248.375] #fu, fv, cu, cv
distortion_model: radial-tangential
distortion_coefficients: [-0.28340811, 0.07395907, 0.00019359, 1.76187114e-05]
"""

EUROC_IMU0 = """sensor_type: imu
comment: VI-Sensor IMU (ADIS16448)
T_BS:
  cols: 4
  rows: 4
  data: [1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0]
rate_hz: 200
gyroscope_noise_density: 1.6968e-04
gyroscope_random_walk: 1.9393e-05
accelerometer_noise_density: 2.0000e-3
accelerometer_random_walk: 3.0000e-3
"""


def test_sensor_yaml_reads_euroc_and_round_trips(tmp_path):
    cam = sensor_yaml.read_camera_yaml(write(tmp_path, EUROC_CAM0, "cam.yaml"))
    assert cam.resolution == (752, 480) and cam.rate_hz == 20.0 and cam.distortion_model == "radial-tangential"
    assert cam.K[0, 2] == 367.215 and cam.T_BS[1, 3] == -0.064676986768 and cam.distortion[3] == 1.76187114e-05
    sensor_yaml.write_camera_yaml(tmp_path / "out" / "cam.yaml", cam)
    back = sensor_yaml.read_camera_yaml(tmp_path / "out" / "cam.yaml")
    assert np.array_equal(back.T_BS, cam.T_BS) and np.array_equal(back.intrinsics, cam.intrinsics)
    assert np.array_equal(back.distortion, cam.distortion) and back.resolution == cam.resolution
    imu = sensor_yaml.read_imu_yaml(write(tmp_path, EUROC_IMU0, "imu.yaml"))
    assert imu.rate_hz == 200.0 and imu.gyroscope_noise_density == 1.6968e-04
    assert np.array_equal(imu.T_BS, np.eye(4))
    sensor_yaml.write_imu_yaml(tmp_path / "out" / "imu.yaml", imu)
    again = sensor_yaml.read_imu_yaml(tmp_path / "out" / "imu.yaml")
    assert again.accelerometer_random_walk == 3e-3 and np.array_equal(again.T_BS, imu.T_BS)


@pytest.mark.parametrize("change, expected", [
    (("intrinsics: [458.654, 457.296, 367.215, 248.375]", "intrinsics: [458.654, 457.296]"), "key 'intrinsics'"),
    (("resolution: [752, 480]", ""), "missing required key 'resolution'"),
    (("camera_model: pinhole", "camera_model: omni"), "key 'camera_model'"),
    (("0.0, 0.0, 0.0, 1.0]", "0.0, 0.0, 0.0]"), "key 'T_BS.data'"),
    (("0.0148655429818, -0.999880929698", "2.0148655429818, -0.999880929698"), "key 'T_BS' is not a rigid"),
    (("rate_hz: 20", "rate_hz: fast"), "key 'rate_hz'"),
])
def test_sensor_yaml_invalid(tmp_path, change, expected):
    path = write(tmp_path, EUROC_CAM0.replace(*change), "sensor.yaml")
    with pytest.raises(InputError) as e:
        sensor_yaml.read_camera_yaml(path)
    assert str(path) in str(e.value) and expected in str(e.value)


def test_sensor_yaml_missing_and_not_yaml(tmp_path):
    with pytest.raises(InputError, match="sensor.yaml: file not found"):
        sensor_yaml.read_imu_yaml(tmp_path / "sensor.yaml")
    with pytest.raises(InputError, match="not valid YAML"):
        sensor_yaml.read_imu_yaml(write(tmp_path, "a: [1, 2\n", "sensor.yaml"))
    assert isinstance(sensor_yaml.read_camera_yaml(write(tmp_path, EUROC_CAM0, "c.yaml")), Camera)


# --- YAML mappings (configs, vehicle.yaml, sensor.yaml, truth.yaml) ----------------------


def test_yaml_mapping_reads_a_mapping_and_fails_in_one_line(tmp_path):
    from uavturb.io.yaml_mapping import read_yaml_mapping

    assert read_yaml_mapping(write(tmp_path, "a: 1\nb: [2.5, x]\n", "m.yaml")) == {"a": 1, "b": [2.5, "x"]}
    assert read_yaml_mapping(write(tmp_path, "# only a comment\n", "empty.yaml")) == {}
    with pytest.raises(InputError, match=r"gone.yaml: config file not found$"):
        read_yaml_mapping(tmp_path / "gone.yaml", not_found="config file not found")
    with pytest.raises(InputError, match=r"bad.yaml: not valid YAML \(ParserError\)$"):
        read_yaml_mapping(write(tmp_path, "a: [1, 2\n", "bad.yaml"))
    with pytest.raises(InputError, match=r"list.yaml: expected a mapping of vehicle keys$"):
        read_yaml_mapping(write(tmp_path, "- 1\n- 2\n", "list.yaml"), expected="a mapping of vehicle keys")


def test_read_csv_leaves_rows_with_missing_values_out_where_asked(tmp_path):
    """A motion capture that lost the vehicle writes empty or NaN fields: refused by default (one line naming the
    field), left out with one sentence where the caller reads them as dropouts; a file with no complete row is
    refused."""
    path = tmp_path / "data.csv"
    rows = ["#timestamp,a,b"] + [f"{k * 10},{k}.5,{2 * k}" for k in range(10)]
    rows[3], rows[4], rows[8] = "20,,4", "30,NaN,6", "70,7.5,nan"
    path.write_text("\n".join(rows) + "\n")
    with pytest.raises(InputError, match=r"line 4, column 2: expected a number, found an empty field"):
        euroc_csv.read_csv(path, 3)
    notes: list[str] = []
    t, x = euroc_csv.read_csv(path, 3, missing_rows=notes)
    assert t.tolist() == [0, 10, 40, 50, 60, 80, 90] and np.isfinite(x).all()
    assert notes == [f"{path}: 3 rows with a value missing (empty or NaN: tracking lost) left out, in 2 "
                     "stretches from line 4: read as dropouts"]
    path.write_text("#t,a\n0,nan\n10,\n")
    with pytest.raises(InputError, match=r"no row holds every value \(2 rows, each with a field empty or NaN\)"):
        euroc_csv.read_csv(path, 2, missing_rows=[])
    path.write_text("#t,a\n0,1.0\n10,inf\n")  # an infinite value is no missing one
    with pytest.raises(InputError, match=r"line 3, column 2: value inf is not finite"):
        euroc_csv.read_csv(path, 2, missing_rows=[])
