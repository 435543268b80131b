"""EuRoC-style CSV files: the one reader and writer every stream of a recording uses.

A file is header line(s) starting with ``#`` (any text after it: EuRoC files are not
consistent), then one row per sample: an integer timestamp [ns] followed by numbers,
separated by ``,`` or ``, ``. The column order is fixed by the stream (``recordings.md``);
this module holds the exact EuRoC headers, :func:`read_csv`, :func:`read_frame_list` (the
``cam0`` frame list) and :func:`write_csv`.

Reading is bounded (files come from other people's loggers): at most :data:`MAX_COLUMNS`
columns (checked on the first row), :data:`MAX_LINE_BYTES` bytes a line and :data:`MAX_ROWS`
rows a file (estimated before parsing), parsed in blocks so memory stays a small multiple of
the numbers read. A UTF-8 byte order mark and any bytes in ``#`` lines are accepted.

Timestamps are parsed as exact ``int64`` (never through ``float``: EuRoC nanosecond
timestamps have 19 digits, more than a double holds).
"""

from __future__ import annotations

import io
import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator, NoReturn

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
#
# Files from other people's loggers are read within stated bounds, checked before the heavy
# work; each refusal is one line naming the file and the limit. The file is parsed in blocks
# of about BLOCK_BYTES, so memory stays a small multiple of the numbers it holds.

#: Columns of a row, timestamp included (``rotors0`` holds one a rotor, at most 32).
MAX_COLUMNS = 64
#: Bytes of one line (a header line included).
MAX_LINE_BYTES = 1 << 16
#: Rows of one file (7 hours at 200 Hz).
MAX_ROWS = 5_000_000
#: bytes of memory per ground-truth row that ``uavturb gap`` peaks at, the larger of two measurements: a blind probe's
#: 4.8 M-row recording, 2.0 GB (420 bytes a row); a 10^6-row hexarotor's at 200 Hz with its IMU, 809 MB above the
#: imports, as ``uavturb bench gap`` measures its analysis
ANALYSIS_BYTES_PER_ROW = 810
#: The file is read and parsed in blocks of about this many bytes. A block's text is held a few times over while it
#: is cut into rows and parsed: two 5-minute 200 Hz recordings read side by side peaked 150 MB above the imports
#: with 16 MB blocks, 93-95 MB with 2 MB blocks, in the same time (0.66-0.74 s)
BLOCK_BYTES = 2 << 20

_BOM = b"\xef\xbb\xbf"
_TIMESTAMP_BYTES = np.zeros(256, dtype=bool)  # what column 0 may hold: an integer (no '.', 'e', '_')
_TIMESTAMP_BYTES[list(b"0123456789+- \t")] = True
_ROW_STARTS_ODDLY = np.zeros(256, dtype=bool)  # '#' or a blank: maybe a comment or blank line
_ROW_STARTS_ODDLY[list(b"# \t\r\n\f\v")] = True


def _open(path: Path):
    if not path.is_file():
        raise InputError(path, "file not found")
    try:
        return path.open("rb")
    except OSError as e:
        raise InputError(path, f"cannot be read ({e.strerror})") from None


def _blocks(path: Path, f) -> Iterator[tuple[int, bytes]]:
    """(number of the block's first line, whole lines ending in ``\\n`` except maybe the last),
    a UTF-8 byte order mark dropped; a line longer than :data:`MAX_LINE_BYTES` is refused."""
    line, carry, first = 1, b"", True
    while True:
        try:
            chunk = f.read(BLOCK_BYTES)
        except OSError as e:
            raise InputError(path, f"cannot be read ({e.strerror})") from None
        if first and chunk.startswith(_BOM):
            chunk = chunk[len(_BOM):]
        first = False
        if not chunk:
            break
        data = carry + chunk
        cut = data.rfind(b"\n")
        if cut < 0:
            carry = data
            if len(carry) > MAX_LINE_BYTES:
                raise InputError(path, f"line {line} is longer than {MAX_LINE_BYTES} bytes (the limit of a line)")
            continue
        block, carry = data[:cut + 1], data[cut + 1:]
        yield line, block
        line += block.count(b"\n")
    if carry:
        if len(carry) > MAX_LINE_BYTES:
            raise InputError(path, f"line {line} is longer than {MAX_LINE_BYTES} bytes (the limit of a line)")
        yield line, carry


@dataclass
class _Block:
    """Rows of one block of a file: their line numbers, the rows joined by ``\\n`` (``body``),
    and the byte offsets the vectorised checks use."""

    lines: np.ndarray  # (N,) int64, line number of each row in the file
    body: bytes
    buf: np.ndarray  # (len(body),) uint8, the bytes of body
    starts: np.ndarray  # (N,) offset where each row starts
    ends: np.ndarray  # (N,) offset one past its last byte
    commas: np.ndarray  # offsets of every ','

    @classmethod
    def of(cls, lines: np.ndarray | None, body: bytes) -> "_Block":
        """The block of ``body``'s rows (``lines``: their line numbers; None: numbered from 0)."""
        buf = np.frombuffer(body, dtype=np.uint8)
        nl = np.flatnonzero(buf == ord("\n"))
        if lines is None:
            lines = np.arange(len(nl) + 1 if len(buf) else 0, dtype=np.int64)
        return cls(lines, body, buf, np.concatenate(([0], nl + 1)), np.append(nl, len(buf)),
                   np.flatnonzero(buf == ord(",")))

    def after(self, k: int) -> "_Block":
        """The rows from the ``k``-th on (a header's lines dropped), sliced from this block's offsets."""
        a = int(self.starts[k])
        body = self.body[a:]
        return _Block(self.lines[k:], body, np.frombuffer(body, dtype=np.uint8), self.starts[k:] - a, self.ends[k:] - a,
                      self.commas[np.searchsorted(self.commas, a):] - a)


def _rows(first_line: int, block: bytes) -> _Block:
    """The data rows of a block of lines (``#`` and blank lines dropped, wherever they are)."""
    body = block[:-1] if block.endswith(b"\n") else block
    rows = _Block.of(None, body)
    rows.lines += first_line
    n = len(rows.lines)
    first = rows.buf[rows.starts[rows.starts < len(body)]]  # first byte of each non-empty row
    if body and len(first) == n and not _ROW_STARTS_ODDLY[first].any():  # the usual block: only rows
        return rows
    if body and len(first) == n:  # the usual first block: a header (or a few comments) above plain rows
        odd = np.flatnonzero(_ROW_STARTS_ODDLY[first])
        k = int(odd[-1]) + 1
        if k < n and len(odd) == k and k <= 64 and all(_droppable(body[a:b]) for a, b in zip(rows.starts[:k],
                                                                                          rows.ends[:k])):
            return rows.after(k)
    kept = [(i, s) for i, s in enumerate(body.split(b"\n"), first_line)
            if s.strip() and not s.lstrip().startswith(b"#")]
    lines = np.fromiter((i for i, _ in kept), dtype=np.int64, count=len(kept))
    return _Block.of(lines, b"\n".join(s for _, s in kept))


def _droppable(row: bytes) -> bool:
    """A blank or comment line (``#`` after any blanks)."""
    return not row.strip() or row.lstrip().startswith(b"#")


def _check_columns(path: Path, rows: _Block, n_cols: int | None) -> int:
    """Every row has the same number of comma-separated fields (``n_cols`` if given, at most
    :data:`MAX_COLUMNS`); returns it."""
    found = int(np.searchsorted(rows.commas, rows.ends[0])) + 1
    if found > MAX_COLUMNS:  # checked on the first row, before anything is sized by it
        raise InputError(path, f"line {rows.lines[0]}: {found} columns, more than {MAX_COLUMNS} (the limit of a row)")
    long = np.flatnonzero(rows.ends - rows.starts > MAX_LINE_BYTES)
    if len(long):
        raise InputError(path, f"line {rows.lines[long[0]]} is longer than {MAX_LINE_BYTES} bytes "
                               f"(the limit of a line)")
    counts = np.diff(np.searchsorted(rows.commas, rows.ends), prepend=0) + 1
    expected = found if n_cols is None else n_cols
    bad = np.flatnonzero(counts != expected)
    if len(bad):
        k = bad[0]
        row = rows.body[rows.starts[k]:rows.ends[k]].rstrip()
        why = (" (the row ends with a comma: EuRoC rows do not)" if counts[k] == expected + 1 and row.endswith(b",")
               else "")
        raise InputError(path, f"line {rows.lines[k]}: expected {expected} columns, found {counts[k]}{why}")
    return expected


def _timestamps_are_integers(rows: _Block) -> bool:
    """Column 0 of every row holds only digits, signs and blanks, at most 40 bytes (pandas would
    read ``1.5e3`` as 1500). Needs a comma on every row (checked before)."""
    width = rows.commas[np.searchsorted(rows.commas, rows.starts)] - rows.starts
    if width.max() > 40:
        return False
    at = rows.starts[:, None] + np.arange(int(width.max()))
    inside = np.arange(int(width.max())) < width[:, None]
    return bool(_TIMESTAMP_BYTES[rows.buf[np.where(inside, at, 0)]][inside].all())


def _check_times(path: Path, lines: np.ndarray, t_ns: np.ndarray, allow_repeats: bool = False) -> None:
    """Timestamps strictly increasing (non-decreasing with ``allow_repeats``), else InputError naming the first
    bad line."""
    d = np.diff(t_ns)
    bad = np.flatnonzero(d < 0 if allow_repeats else d <= 0)
    if len(bad):
        k = bad[0] + 1
        if d[bad[0]] == 0:
            raise InputError(path, f"line {lines[k]}: timestamp {t_ns[k]} is duplicated (previous row has "
                                   f"{t_ns[k - 1]})")
        raise InputError(path, f"line {lines[k]}: timestamp {t_ns[k]} is out of order: {-d[bad[0]] * 1e-9:.4g} s "
                               f"before the previous row's, {t_ns[k - 1]} (a logger restarted, or rows stamped on "
                               "another clock)")


def _diagnose(path: Path, lines: np.ndarray, body: bytes, missing_ok: bool = False) -> NoReturn:
    """Slow pass run only when the fast parse of a block failed: raise an InputError naming the bad field
    (``missing_ok``: empty and not-a-number fields are not the fault)."""
    for line, raw in zip(lines, body.split(b"\n")):
        try:
            row = raw.decode("utf-8")
        except UnicodeDecodeError as e:
            raise InputError(path, f"line {line}: not text "
                                   f"(byte 0x{raw[e.start]:02x} at column {e.start + 1})") from None
        for col, field in enumerate(row.split(",")):
            field = field.strip()
            if missing_ok and col > 0 and field.lower() in MISSING_FIELDS:
                continue
            try:
                if "_" in field:
                    raise ValueError(field)
                if col == 0 and not -(2**63) <= int(field) < 2**63:
                    raise ValueError(field)
                if col > 0 and not math.isfinite(float(field)):
                    raise InputError(path, f"line {line}, column {col + 1}: value {field[:40]} is not finite")
            except ValueError:
                kind = "timestamp (integer nanoseconds)" if col == 0 else "number"
                shown = repr(field[:60]) + ("..." if len(field) > 60 else "") if field else "an empty field"
                raise InputError(path, f"line {line}, column {col + 1}: expected a {kind}, found {shown}") from None
    raise InputError(path, "could not be parsed as numbers")


#: fields that mean "no value" where a stream may miss rows (motion capture that lost the vehicle writes them)
MISSING_FIELDS = ("", "nan", "-nan", "na", "n/a", "null")
_MISSING_SPELLINGS = sorted({f(x) for x in MISSING_FIELDS for f in (str.lower, str.upper, str.capitalize)}
                            | {"NaN", "-NaN"})


def _parse_block(path: Path, rows: _Block, n: int, missing_ok: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """(timestamps (N,) int64, values (N, n - 1) float64, all finite) of one block's rows; with ``missing_ok``,
    values may be NaN where a field is empty or not a number (:data:`MISSING_FIELDS`)."""
    try:
        lines, body = rows.lines, rows.body
        if not _timestamps_are_integers(rows):
            raise ValueError("timestamp")
        missing = {"na_filter": True, "keep_default_na": False, "na_values": _MISSING_SPELLINGS} if missing_ok \
            else {"na_filter": False}
        df = pd.read_csv(io.BytesIO(body), header=None, skipinitialspace=True, **missing,
                         dtype={0: np.int64, **{k: np.float64 for k in range(1, n)}}, engine="c")
        if df.shape != (len(lines), n):  # rows merged or split (quotes etc.)
            raise ValueError("shape")
    except (ValueError, OverflowError, UnicodeDecodeError, pd.errors.ParserError):
        _diagnose(path, lines, body, missing_ok)
    t_ns = df[0].to_numpy(np.int64)
    values = df.iloc[:, 1:].to_numpy(np.float64)
    finite = np.isfinite(values) | (np.isnan(values) if missing_ok else False)
    if not finite.all():
        k, c = np.argwhere(~finite)[0]
        raise InputError(path, f"line {lines[k]}, column {c + 2}: value {values[k, c]} is not finite")
    return t_ns, values


def _check_row_count(path: Path, rows: int, read: int, size: int, n: int) -> None:
    """Refuse a file of more than :data:`MAX_ROWS` rows (estimated from the share read so far)."""
    estimate = rows * size // max(read, 1)
    if estimate > MAX_ROWS:
        need = estimate * (n + 1) * 8 * 2 / 1e9  # values, timestamps and line numbers, twice while joined
        whole = estimate * ANALYSIS_BYTES_PER_ROW / 1e9
        raise InputError(path, f"holds about {estimate} rows, more than {MAX_ROWS} (the limit of a file); "
                               f"reading it would need about {need:.1f} GB of memory, analysing it about {whole:.1f} "
                               "GB: split the recording")


def _last_of_each_time(path: Path, lines: np.ndarray, t_ns: np.ndarray, values: np.ndarray
                       ) -> tuple[np.ndarray, str | None]:
    """(rows to keep: the last of each run of rows sharing a timestamp; a sentence on what was merged, or None).
    ``t_ns`` non-decreasing."""
    same = t_ns[1:] == t_ns[:-1]
    if not same.any():
        return np.ones(len(t_ns), bool), None
    keep = np.r_[~same, True]
    dropped = np.flatnonzero(~keep)
    copies = int(np.all(values[dropped] == values[dropped + 1], axis=1).sum())
    n = len(dropped)
    kinds = [f"{copies} exact {'copy' if copies == 1 else 'copies'}"] if copies else []
    kinds += [f"{n - copies} with other values"] if n - copies else []
    return keep, (f"{path}: {n} {'row repeats' if n == 1 else 'rows repeat'} the next row's timestamp "
                  f"({', '.join(kinds)}; first at line {lines[dropped[0]]}): the last row of each timestamp kept")


def read_csv(path: str | Path, n_cols: int | None, what: str = "data", *,
             return_lines: bool = False, repeated_times: list[str] | None = None,
             missing_rows: list[str] | None = None, lost: str = "tracking lost",
             then: str = "read as dropouts") -> tuple[np.ndarray, ...]:
    """Read an EuRoC-style numeric CSV file, in blocks, within this module's bounds.

    Parameters
    ----------
    path : file to read
    n_cols : expected number of columns including the timestamp, or ``None`` to accept any
        number (the same on every row, at most :data:`MAX_COLUMNS`)
    what : what the file holds, for messages (``"ground truth"``, ``"IMU"``, ...)

    Returns
    -------
    t_ns : (N,) int64, timestamps [ns], strictly increasing
    values : (N, K) float64, the other ``K = n_cols - 1`` columns, all finite
    lines : (N,) int64, the line number of each row in the file (only with ``return_lines``),
        for callers whose own checks name a line
    repeated_times : where given, rows sharing a timestamp (loggers write them: two messages stamped
        alike) are not refused: the last row of each timestamp is kept and one sentence saying how many
        rows went, and whether they were exact copies, is appended to this list. Rows whose timestamps go back
        are sorted into place where they are few (:data:`OUT_OF_ORDER_SHARE`, said in this list too), refused
        otherwise.
    missing_rows : where given, rows with a value missing (an empty field, NaN: motion capture that lost the
        vehicle) are left out, and one sentence saying how many, in how many stretches, is appended to this list
        (the stream then has a dropout there); a file with no complete row is refused.
    lost, then : what a missing value means in that sentence (motion capture: ``tracking lost``), and what comes of
        the rows left out (``read as dropouts``)

    Raises
    ------
    InputError
        Naming ``path`` and the line: missing file, no data rows, wrong column count,
        non-numeric or non-finite value, timestamps out of order (or repeated, without ``repeated_times``), a bound
        exceeded (:data:`MAX_COLUMNS`, :data:`MAX_LINE_BYTES`, :data:`MAX_ROWS`).
    """
    path = Path(path)
    parts: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []
    for rows, n in _row_blocks(path, n_cols):
        t_ns, values = _parse_block(path, rows, n, missing_rows is not None)
        parts.append((rows.lines, values, t_ns))
    if not parts:
        raise InputError(path, f"no data rows (empty {what} file)")
    lines, values, t_ns = (np.concatenate(p) if len(parts) > 1 else p[0] for p in zip(*parts))
    del parts
    if missing_rows is not None:
        lines, values, t_ns = _complete_rows(path, lines, values, t_ns, missing_rows, lost, then)
    if repeated_times is not None:
        lines, values, t_ns = _in_time_order(path, lines, values, t_ns, repeated_times)
    _check_times(path, lines, t_ns, allow_repeats=repeated_times is not None)
    if repeated_times is not None:
        keep, note = _last_of_each_time(path, lines, t_ns, values)
        if note is not None:
            lines, values, t_ns = lines[keep], values[keep], t_ns[keep]
            repeated_times.append(note)
    return (t_ns, values, lines) if return_lines else (t_ns, values)


#: share of a stream's rows whose timestamp goes back that are sorted into place (a logger writing from two threads
#: swaps a few neighbours); more is a file whose times mean something else, refused
OUT_OF_ORDER_SHARE = 0.01
#: the most a timestamp may go back, in the stream's median step, and still be sorted into place: two threads
#: swap neighbours a step or two apart; a block of rows stamped 0.3 s early (30 steps) overlaps 30 true rows, and a
#: logger restarted 10 s back interleaves two stretches of flight (sorted, the gyroscope was blamed)
OUT_OF_ORDER_STEPS = 5.0


def _in_time_order(path: Path, lines: np.ndarray, values: np.ndarray, t_ns: np.ndarray, notes: list[str]
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The rows sorted by time where under :data:`OUT_OF_ORDER_SHARE` of them go back (a sentence appended to
    ``notes``); as they are otherwise (:func:`_check_times` then names the first that goes back)."""
    d = np.diff(t_ns)
    back = int(np.sum(d < 0))
    if not back or back > OUT_OF_ORDER_SHARE * len(t_ns):
        return lines, values, t_ns
    step = float(np.median(d[d > 0])) if np.any(d > 0) else 0.0
    if -float(np.min(d)) > OUT_OF_ORDER_STEPS * step:
        return lines, values, t_ns  # a jump back, not neighbours swapped: _check_times names it
    first = int(lines[np.flatnonzero(d < 0)[0] + 1])
    order = np.argsort(t_ns, kind="stable")
    moved = int(np.sum(order != np.arange(len(order))))
    notes.append(f"{path}: {moved} rows out of time order, none by more than {OUT_OF_ORDER_STEPS:g} of the stream's "
                 f"steps (first at line {first}; a logger writing from two threads) put in time order")
    return lines[order], values[order], t_ns[order]


def _complete_rows(path: Path, lines: np.ndarray, values: np.ndarray, t_ns: np.ndarray, notes: list[str],
                   lost: str = "tracking lost", then: str = "read as dropouts"
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The rows with every value present; a sentence on those left out (a missing value meaning ``lost``, the rows
    then ``then``) appended to ``notes``."""
    complete = ~np.isnan(values).any(axis=1)
    if complete.all():
        return lines, values, t_ns
    if not complete.any():
        raise InputError(path, f"no row holds every value ({len(lines)} rows, each with a field empty or NaN)")
    gone = ~complete
    starts = np.flatnonzero(gone & ~np.r_[False, gone[:-1]])
    n = int(gone.sum())
    notes.append(f"{path}: {n} row{'s' if n > 1 else ''} with a value missing (empty or NaN: {lost}) "
                 f"left out, in {len(starts)} stretch{'es' if len(starts) > 1 else ''} from line "
                 f"{lines[starts[0]]}: {then}")
    return lines[complete], values[complete], t_ns[complete]


def _row_blocks(path: Path, n_cols: int | None):
    """The data rows of ``path`` block by block (:func:`_blocks`), each block checked for its column
    count (later blocks: as many as the first; at least a timestamp and one value) and the running row
    count against :data:`MAX_ROWS`: yields ``(rows, n_cols)``."""
    count, expected = 0, n_cols
    with _open(path) as f:
        size = os.fstat(f.fileno()).st_size
        for first_line, block in _blocks(path, f):
            rows = _rows(first_line, block)
            if not len(rows.lines):
                continue
            n = expected = _check_columns(path, rows, expected)
            if n < 2:
                raise InputError(path, f"expected a timestamp and at least one value per row, found {n} column")
            count += len(rows.lines)
            _check_row_count(path, count, f.tell(), size, n)
            yield rows, n


def read_frame_list(path: str | Path) -> tuple[np.ndarray, list[str]]:
    """Read a camera frame list (``cam0/data.csv``: ``timestamp [ns],filename``).

    Returns
    -------
    t_ns : (N,) int64, strictly increasing
    files : list of N file names (relative to ``cam0/data/``)
    """
    path = Path(path)
    stamps: list[int] = []
    files: list[str] = []
    all_lines: list[np.ndarray] = []
    for rows, _ in _row_blocks(path, 2):
        all_lines.append(rows.lines)
        for line, raw in zip(rows.lines.tolist(), rows.body.split(b"\n")):
            stamp, name = (x.strip() for x in raw.decode("utf-8", errors="replace").split(","))
            try:
                if "_" in stamp:
                    raise ValueError(stamp)
                stamps.append(int(stamp))
            except ValueError:
                raise InputError(path, f"line {line}, column 1: expected a timestamp (integer nanoseconds), "
                                       f"found {stamp[:60]!r}") from None
            if not name:
                raise InputError(path, f"line {line}, column 2: empty file name")
            files.append(name)
    if not files:
        raise InputError(path, "no data rows (empty camera frame list file)")
    try:
        t_ns = np.array(stamps, dtype=np.int64)
    except OverflowError:
        raise InputError(path, "a timestamp does not fit in 64 bits") from None
    _check_times(path, np.concatenate(all_lines), t_ns)
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
