"""EuRoC-style CSV files: the one reader and writer every stream of a recording uses.

A file is header line(s) starting with ``#`` (any text after it: EuRoC files are not
consistent), then one row per sample: an integer timestamp [ns] followed by numbers,
separated by ``,`` or ``, ``. The column order is fixed by the stream (``recordings.md``);
this module holds the exact EuRoC headers, :func:`read_csv`, :func:`read_frame_list` (the
``cam0`` frame list) and :func:`write_csv`.

Timestamps are parsed as exact ``int64`` (never through ``float``: EuRoC nanosecond
timestamps have 19 digits, more than a double holds).
"""

from __future__ import annotations

import io
import math
import os
from pathlib import Path
from typing import NoReturn

import numpy as np
import pandas as pd

from uavturb.errors import InputError

#: ``mav0/state_groundtruth_estimate0/data.csv`` (17 columns).
GROUNDTRUTH_HEADER = (
    "#timestamp, p_RS_R_x [m], p_RS_R_y [m], p_RS_R_z [m], q_RS_w [], q_RS_x [], q_RS_y [], q_RS_z [], "
    "v_RS_R_x [m s^-1], v_RS_R_y [m s^-1], v_RS_R_z [m s^-1], b_w_RS_S_x [rad s^-1], b_w_RS_S_y [rad s^-1], "
    "b_w_RS_S_z [rad s^-1], b_a_RS_S_x [m s^-2], b_a_RS_S_y [m s^-2], b_a_RS_S_z [m s^-2]"
)
#: ``mav0/imu0/data.csv`` (7 columns).
IMU_HEADER = (
    "#timestamp [ns],w_RS_S_x [rad s^-1],w_RS_S_y [rad s^-1],w_RS_S_z [rad s^-1],"
    "a_RS_S_x [m s^-2],a_RS_S_y [m s^-2],a_RS_S_z [m s^-2]"
)
#: ``mav0/vicon0/data.csv`` (8 columns).
VICON_HEADER = (
    "#timestamp [ns], p_RS_R_x [m], p_RS_R_y [m], p_RS_R_z [m], q_RS_w [], q_RS_x [], q_RS_y [], q_RS_z []"
)
#: ``mav0/cam0/data.csv`` (timestamp, file name).
CAMERA_HEADER = "#timestamp [ns],filename"
BATTERY_HEADER = "#timestamp [ns],voltage [V],current [A]"
BATTERY_VOLTAGE_HEADER = "#timestamp [ns],voltage [V]"

GROUNDTRUTH_COLUMNS = 17
IMU_COLUMNS = 7
VICON_COLUMNS = 8


def rotors_header(n_rotors: int) -> str:
    """Header of ``mav0/rotors0/data.csv`` for ``n_rotors`` rotors (``vehicle.yaml`` order)."""
    return "#timestamp [ns]," + ",".join(f"w_{i} [rad s^-1]" for i in range(n_rotors))


# --- reading ---------------------------------------------------------------------------


def _data_rows(path: Path, what: str) -> tuple[np.ndarray, list[str], str]:
    """The data rows of a CSV file with their 1-based line numbers (``#`` and blank lines dropped).

    Returns
    -------
    lines : (N,) int64, line number of each row in the file
    rows : list of N str, the rows as they are in the file
    body : the rows joined by newlines (what the parser reads)
    """
    if not path.is_file():
        raise InputError(path, "file not found")
    try:
        text = path.read_text(encoding="utf-8")
    except UnicodeDecodeError:
        raise InputError(path, f"not a text CSV file ({what})") from None
    except OSError as e:
        raise InputError(path, f"cannot be read ({e.strerror})") from None
    all_lines = text.splitlines()
    h = 0  # leading header (and blank) lines
    while h < len(all_lines) and (not all_lines[h].strip() or all_lines[h].lstrip().startswith("#")):
        h += 1
    while all_lines and not all_lines[-1].strip():  # trailing blank lines
        all_lines.pop()
    rows = all_lines[h:]
    body = "\n".join(rows)
    if "#" in body or any(not s.strip() for s in rows):  # comment or blank lines between rows: drop them
        numbered = [(i, s) for i, s in enumerate(all_lines, 1) if s.strip() and not s.lstrip().startswith("#")]
        lines = np.fromiter((i for i, _ in numbered), dtype=np.int64, count=len(numbered))
        rows = [s for _, s in numbered]
        body = "\n".join(rows)
    else:  # the usual file: one header block, then only rows
        lines = np.arange(h + 1, h + 1 + len(rows), dtype=np.int64)
    if not rows:
        raise InputError(path, f"no data rows (empty {what} file)")
    return lines, rows, body


def _check_columns(path: Path, lines: np.ndarray, body: str, n_cols: int | None) -> int:
    """Every row of ``body`` has the same number of comma-separated fields (``n_cols`` if given); returns it."""
    buf = np.frombuffer(body.encode("utf-8"), dtype=np.uint8)
    ends = np.append(np.flatnonzero(buf == ord("\n")), len(buf))  # one past the last byte of each row
    commas = np.searchsorted(np.flatnonzero(buf == ord(",")), ends)  # commas before the end of each row
    counts = np.diff(commas, prepend=0) + 1
    expected = int(counts[0]) if n_cols is None else n_cols
    bad = np.flatnonzero(counts != expected)
    if len(bad):
        k = bad[0]
        raise InputError(path, f"line {lines[k]}: expected {expected} columns, found {counts[k]}")
    return expected


def _check_times(path: Path, lines: np.ndarray, t_ns: np.ndarray) -> None:
    """Timestamps strictly increasing, else InputError naming the first bad line."""
    d = np.diff(t_ns)
    bad = np.flatnonzero(d <= 0)
    if len(bad):
        k = bad[0] + 1
        kind = "duplicated" if d[bad[0]] == 0 else "out of order"
        raise InputError(path, f"line {lines[k]}: timestamp {t_ns[k]} is {kind} (previous row has {t_ns[k - 1]})")


def _diagnose(path: Path, lines: np.ndarray, rows: list[str]) -> NoReturn:
    """Slow pass run only when the fast parse failed: raise an InputError naming the bad field."""
    for line, row in zip(lines, rows):
        for col, field in enumerate(row.split(",")):
            field = field.strip()
            try:
                if "_" in field:
                    raise ValueError(field)
                if col == 0 and not -(2**63) <= int(field) < 2**63:
                    raise ValueError(field)
                if col > 0 and not math.isfinite(float(field)):
                    raise InputError(path, f"line {line}, column {col + 1}: value {field} is not finite")
            except ValueError:
                kind = "timestamp (integer nanoseconds)" if col == 0 else "number"
                shown = field if field else "an empty field"
                raise InputError(path, f"line {line}, column {col + 1}: expected a {kind}, found {shown!r}") from None
    raise InputError(path, "could not be parsed as numbers")


def read_csv(path: str | Path, n_cols: int | None, what: str = "data", *,
             return_lines: bool = False) -> tuple[np.ndarray, ...]:
    """Read an EuRoC-style numeric CSV file.

    Parameters
    ----------
    path : file to read
    n_cols : expected number of columns including the timestamp, or ``None`` to accept any
        number (the same on every row)
    what : what the file holds, for messages (``"ground truth"``, ``"IMU"``, ...)

    Returns
    -------
    t_ns : (N,) int64, timestamps [ns], strictly increasing
    values : (N, K) float64, the other ``K = n_cols - 1`` columns, all finite
    lines : (N,) int64, the line number of each row in the file (only with ``return_lines``),
        for callers whose own checks name a line

    Raises
    ------
    InputError
        Naming ``path`` and the line: missing file, no data rows, wrong column count,
        non-numeric or non-finite value, timestamps duplicated or out of order.
    """
    path = Path(path)
    lines, rows, body = _data_rows(path, what)
    n = _check_columns(path, lines, body, n_cols)
    if n < 2:
        raise InputError(path, f"expected a timestamp and at least one value per row, found {n} column")
    try:
        # column 0 as text, then exact int64: pandas would accept "1.5e3" (through float) as an integer
        df = pd.read_csv(io.StringIO(body), header=None, skipinitialspace=True, na_filter=False,
                         dtype={0: str, **{k: np.float64 for k in range(1, n)}}, engine="c")
        if df.shape != (len(rows), n):  # rows merged or split (quotes etc.)
            raise ValueError("shape")
        t_ns = np.asarray(df[0].to_numpy(), dtype=str).astype(np.int64)
    except (ValueError, OverflowError, pd.errors.ParserError):
        _diagnose(path, lines, rows)
    values = df.iloc[:, 1:].to_numpy(np.float64)
    finite = np.isfinite(values)
    if not finite.all():
        k, c = np.argwhere(~finite)[0]
        raise InputError(path, f"line {lines[k]}, column {c + 2}: value {values[k, c]} is not finite")
    _check_times(path, lines, t_ns)
    return (t_ns, values, lines) if return_lines else (t_ns, values)


def read_frame_list(path: str | Path) -> tuple[np.ndarray, list[str]]:
    """Read a camera frame list (``cam0/data.csv``: ``timestamp [ns],filename``).

    Returns
    -------
    t_ns : (N,) int64, strictly increasing
    files : list of N file names (relative to ``cam0/data/``)
    """
    path = Path(path)
    lines, rows, body = _data_rows(path, "camera frame list")
    _check_columns(path, lines, body, 2)
    t_ns = np.empty(len(rows), dtype=np.int64)
    files = []
    for k, (line, row) in enumerate(zip(lines, rows)):
        stamp, name = (f.strip() for f in row.split(","))
        try:
            t_ns[k] = int(stamp)
        except ValueError:
            raise InputError(path, f"line {line}, column 1: expected a timestamp (integer nanoseconds), "
                                   f"found {stamp!r}") from None
        if not name:
            raise InputError(path, f"line {line}, column 2: empty file name")
        files.append(name)
    _check_times(path, lines, t_ns)
    return t_ns, files


# --- writing ---------------------------------------------------------------------------


def write_atomic(path: str | Path, data: str | bytes) -> None:
    """Write ``data`` (text as UTF-8, or bytes) to ``path`` through a temporary file and a rename.

    Every file writer of :mod:`uavturb.io` goes through it: a reader never sees half a file.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f"{path.name}.tmp-{os.getpid()}")
    try:
        tmp.write_bytes(data.encode("utf-8") if isinstance(data, str) else data)
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)


def write_csv(path: str | Path, header: str, t_ns: np.ndarray, values: np.ndarray, fmt: str | None = None) -> None:
    """Write an EuRoC-style CSV file atomically (temporary file, then rename).

    Parameters
    ----------
    path : file to write (its folder is created)
    header : the header line, starting with ``#`` (one of this module's constants)
    t_ns : (N,) integer timestamps [ns], strictly increasing
    values : (N, K) finite numbers, one column per header field after the timestamp
    fmt : printf format of one value (e.g. ``"%.9g"``); ``None`` writes the shortest text
        that reads back to the same float64 (exact round trip)

    Raises
    ------
    InputError
        Naming ``path``: shapes that do not match the header, non-finite values or timestamps
        that are not strictly increasing (the file would not read back).
    """
    path = Path(path)
    t_ns = np.asarray(t_ns)
    values = np.asarray(values, dtype=np.float64)
    if values.ndim == 1:
        values = values[:, None]
    n_header = header.count(",") + 1
    if t_ns.ndim != 1 or values.ndim != 2 or len(values) != len(t_ns) or values.shape[1] + 1 != n_header:
        raise InputError(path, f"cannot write timestamps of shape {t_ns.shape} and values of shape {values.shape} "
                               f"under a {n_header}-column header")
    if not np.issubdtype(t_ns.dtype, np.integer):
        raise InputError(path, "timestamps must be integer nanoseconds")
    if not np.isfinite(values).all():
        raise InputError(path, "refusing to write non-finite values")
    if len(t_ns) > 1 and np.any(np.diff(t_ns) <= 0):
        raise InputError(path, "refusing to write timestamps that are not strictly increasing")
    if fmt is None:
        body = [f"{t}," + ",".join(map(repr, row)) for t, row in zip(t_ns.tolist(), values.tolist())]
    else:
        row_fmt = "%d," + ",".join([fmt] * values.shape[1])
        body = [row_fmt % (t, *row) for t, row in zip(t_ns.tolist(), values.tolist())]
    write_atomic(path, header + "\n" + "".join(s + "\n" for s in body))


def write_frame_list(path: str | Path, t_ns: np.ndarray, files: list[str]) -> None:
    """Write a camera frame list (``cam0/data.csv``) atomically."""
    path = Path(path)
    t_ns = np.asarray(t_ns)
    if t_ns.ndim != 1 or len(t_ns) != len(files):
        raise InputError(path, f"{len(t_ns)} timestamps but {len(files)} file names")
    if len(t_ns) > 1 and np.any(np.diff(t_ns) <= 0):
        raise InputError(path, "refusing to write timestamps that are not strictly increasing")
    write_atomic(path, CAMERA_HEADER + "\n" + "".join(f"{int(t)},{f}\n" for t, f in zip(t_ns.tolist(), files)))
