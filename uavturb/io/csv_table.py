"""A logger's CSV file read as the numeric columns a map asks for (``uavturb import csv``).

Self-contained and bounded, for files of unknown origin: lines are read one at a time up to
:data:`MAX_LINE_CHARS`, a file wider than :data:`MAX_COLUMNS` stops at once, and only the columns
the map names are converted to numbers (other columns may hold anything, text included).

* Header: ``auto`` (default) takes the first non-blank line as the column names when it is not all
  numbers (``#`` lines of one field before it are comments); a leading ``#`` is dropped (``# time[ms],x[m]``,
  EuRoC's ``#timestamp [ns]``). ``true`` always, ``false`` never (columns are then named by their 0-based index only).
* Lines starting with ``#`` after the header, and blank lines, are skipped.
* A last line with fewer fields than the header (a logger stopped mid-write) is left out and
  counted; such a line anywhere else is an error naming it.
* Fields may be quoted (``"x[m]"``); a UTF-8 byte-order mark (spreadsheets write one) is dropped.
* Empty fields and ``nan`` read as NaN (the importer leaves those rows out of the stream and counts them).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import TextIO

import numpy as np

from uavturb.errors import InputError

MAX_COLUMNS = 10_000
MAX_LINE_CHARS = 1_000_000


@dataclass
class Table:
    """The requested columns of a CSV file."""

    values: dict[str, np.ndarray]  # map key -> (N,) float64, NaN where empty or nan
    integers: dict[str, np.ndarray]  # map key -> (N,) int64, for exact keys whose every field is an integer
    lines: np.ndarray  # (N,) int, 1-based line number of each row
    names: list[str]  # header texts ([] without a header)
    truncated: int = 0  # last rows left out because they were cut short
    skipped_comments: int = 0


def _split(line: str, delimiter: str | None) -> list[str]:
    """Fields of a line, blanks and surrounding double quotes removed (no quoted delimiters: flight logs
    have none)."""
    return [f.strip().strip('"').strip() for f in (line.split() if delimiter is None else line.split(delimiter))]


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def _read_line(f: TextIO, path: Path, number: int) -> str:
    line = f.readline(MAX_LINE_CHARS + 1)
    if len(line) > MAX_LINE_CHARS:
        raise InputError(path, f"line {number} is longer than {MAX_LINE_CHARS} characters: not a flight log CSV")
    return line


def _resolve(wanted: dict[str, str | int], names: list[str], n_fields: int, path: Path) -> dict[str, int]:
    """Column index of every map key; a missing column names the key and the column."""
    index = {n: i for i, n in reversed(list(enumerate(names)))}
    out = {}
    for key, col in wanted.items():
        if isinstance(col, int):
            if col >= n_fields:
                raise InputError(path, f"map key {key}: column index {col} is beyond the file's {n_fields} columns")
            out[key] = col
        elif col in index:
            out[key] = index[col]
        else:
            shown = ", ".join(repr(n) for n in names[:12]) + (", ..." if len(names) > 12 else "")
            raise InputError(path, f"map key {key}: no column {col!r} in the header"
                                   + (f" (columns: {shown})" if names else " (the file has no header: use indices)"))
    return out


def read_table(path: str | Path, wanted: dict[str, str | int], *, delimiter: str | None = ",",
               header: str = "auto", exact: tuple[str, ...] = ()) -> Table:
    """Read the columns ``wanted`` (map key -> header text or 0-based index) of the CSV file ``path``.

    ``exact``: keys whose fields, when all are integers, are also kept as ``int64`` (timestamps in
    ns or µs beyond float64's 15-16 digits).

    Raises
    ------
    InputError
        Naming the file: missing, no data rows, too many columns, a missing column (naming the map
        key), a row of another width (not the last), or a field that is not a number.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError(path, "file not found")
    with open(path, encoding="utf-8-sig", errors="replace", newline=None) as f:  # -sig: a spreadsheet's BOM
        return _read(f, path, wanted, delimiter, header, exact)


def _read(f: TextIO, path: Path, wanted: dict[str, str | int], delimiter: str | None, header: str,
          exact: tuple[str, ...]) -> Table:
    names: list[str] = []
    cols: dict[str, int] | None = None
    n_fields = 0
    rows: dict[str, list[float]] = {k: [] for k in wanted}
    texts: dict[str, list[str]] = {k: [] for k in exact}
    lines: list[int] = []
    pending: tuple[int, list[str]] | None = None  # a short row, an error unless it is the last line
    skipped = 0
    number = 0
    while True:
        number += 1
        line = _read_line(f, path, number)
        if not line:
            break
        text = line.strip()
        if not text:
            continue
        if cols is None:
            fields = _split(text.lstrip("#"), delimiter)
            if text.startswith("#") and len(fields) < 2:  # a comment before the header ("# logger v1.2")
                skipped += 1
                continue
            if len(fields) > MAX_COLUMNS:
                raise InputError(path, f"line {number} has {len(fields)} columns (more than {MAX_COLUMNS}): "
                                       "not a flight log CSV")
            n_fields = len(fields)
            is_header = header == "true" or (header == "auto" and not all(map(_is_number, fields)))
            names = fields if is_header else []
            cols = _resolve(wanted, names, n_fields, path)
            if is_header:
                continue
        elif text.startswith("#"):
            skipped += 1
            continue
        if pending is not None:
            raise InputError(path, f"line {pending[0]} has {len(pending[1])} fields, expected {n_fields}")
        fields = text.split() if delimiter is None else text.split(delimiter)  # stripped only where read
        if len(fields) != n_fields:
            if len(fields) < n_fields:
                pending = (number, fields)
                continue
            raise InputError(path, f"line {number} has {len(fields)} fields, expected {n_fields}")
        for key, i in cols.items():
            rows[key].append(_number(fields[i], path, number, key))
        for key in exact:
            texts[key].append(fields[cols[key]].strip().strip('"'))
        lines.append(number)
    if not lines:
        raise InputError(path, "no data rows")
    return Table(values={k: np.asarray(v, dtype=np.float64) for k, v in rows.items()},
                 integers={k: np.asarray(v, dtype=np.int64) for k, v in texts.items() if _all_integers(v)},
                 lines=np.asarray(lines), names=names, truncated=int(pending is not None), skipped_comments=skipped)


def _all_integers(texts: list[str]) -> bool:
    """Every text an integer that fits int64 (19 digits: nanoseconds since 1970)."""
    return all((t.isdigit() or (t[:1] in "+-" and t[1:].isdigit())) and len(t) <= 20 and abs(int(t)) < 2**63
               for t in texts)


def _number(text: str, path: Path, line: int, key: str) -> float:
    """The field as a float (``float`` itself ignores surrounding blanks); quoted or empty fields handled."""
    try:
        return float(text)
    except ValueError:
        bare = text.strip().strip('"').strip()
    if not bare:
        return float("nan")
    try:
        return float(bare)
    except ValueError:
        raise InputError(path, f"line {line}: {bare[:40]!r} (map key {key}) is not a number") from None
