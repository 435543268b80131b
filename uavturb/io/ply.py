"""PLY point clouds (``mav0/pointcloud0/data.ply``): vertex positions in the world frame.

:func:`read_ply` reads ``ascii``, ``binary_little_endian`` and ``binary_big_endian`` files and
returns the ``x y z`` vertex properties as an ``(N, 3)`` float64 array; other vertex
properties (colours, normals, ...) and other elements (faces, ...) are skipped, whatever
their order. :func:`write_ply` writes vertices only, atomically.
"""

from __future__ import annotations

import io
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from uavturb.errors import InputError
from uavturb.io.euroc_csv import write_atomic

#: PLY scalar type names (and their sized aliases) to numpy type codes.
PLY_TYPES = {
    "char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1",
    "short": "i2", "int16": "i2", "ushort": "u2", "uint16": "u2",
    "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
    "float": "f4", "float32": "f4", "double": "f8", "float64": "f8",
}
FORMATS = {"ascii": None, "binary_little_endian": "<", "binary_big_endian": ">"}


@dataclass
class _Property:
    name: str
    type: str  # numpy code of the value (of the items for a list)
    count_type: str | None = None  # numpy code of the list length; None for a scalar


@dataclass
class _Element:
    name: str
    count: int
    properties: list[_Property]

    @property
    def has_lists(self) -> bool:
        return any(p.count_type is not None for p in self.properties)


def _parse_header(path: Path, data: bytes) -> tuple[str, list[_Element], int]:
    """Format name, elements in file order, and the byte offset where the body starts."""
    if not data.startswith(b"ply"):
        raise InputError(path, "not a PLY file (it does not start with 'ply')")
    end = data.find(b"end_header")
    if end < 0:
        raise InputError(path, "PLY header has no 'end_header' line")
    body = data.find(b"\n", end)
    body = len(data) if body < 0 else body + 1
    try:
        header = data[:end].decode("ascii")
    except UnicodeDecodeError:
        raise InputError(path, "PLY header is not ASCII text") from None
    fmt = None
    elements: list[_Element] = []
    for line_no, line in enumerate(header.splitlines(), 1):
        words = line.split()
        if not words or words[0] in ("ply", "comment", "obj_info"):
            continue
        try:
            if words[0] == "format":
                fmt = words[1]
                if fmt not in FORMATS:
                    raise InputError(path, f"header line {line_no}: unknown PLY format '{fmt}'")
            elif words[0] == "element":
                elements.append(_Element(words[1], int(words[2]), []))
                if elements[-1].count < 0:
                    raise ValueError(words[2])
            elif words[0] == "property":
                if not elements:
                    raise InputError(path, f"header line {line_no}: property before any element")
                if words[1] == "list":
                    prop = _Property(words[4], PLY_TYPES[words[3]], PLY_TYPES[words[2]])
                else:
                    prop = _Property(words[2], PLY_TYPES[words[1]])
                elements[-1].properties.append(prop)
            else:
                raise InputError(path, f"header line {line_no}: unknown keyword '{words[0]}'")
        except (IndexError, KeyError, ValueError):
            raise InputError(path, f"header line {line_no}: cannot parse '{line.strip()}'") from None
    if fmt is None:
        raise InputError(path, "PLY header has no 'format' line")
    return fmt, elements, body


def _vertex_element(path: Path, elements: list[_Element]) -> tuple[int, list[int]]:
    """Index of the vertex element and the property indices of x, y, z."""
    names = [e.name for e in elements]
    if "vertex" not in names:
        raise InputError(path, f"PLY has no 'vertex' element (elements: {', '.join(names) or 'none'})")
    k = names.index("vertex")
    vertex = elements[k]
    if vertex.count == 0:
        raise InputError(path, "PLY is empty (0 vertices)")
    props = [p.name for p in vertex.properties]
    missing = [c for c in "xyz" if c not in props]
    if missing:
        raise InputError(path, f"PLY vertex element has no {', '.join(missing)} "
                               f"propert{'y' if len(missing) == 1 else 'ies'}"
                               f" (found: {', '.join(props) or 'none'})")
    return k, [props.index(c) for c in "xyz"]


def _skip_binary(path: Path, data: bytes, offset: int, element: _Element, endian: str) -> int:
    """Byte offset after ``element`` in a binary body.

    Every step moves forward and stays inside ``data`` (a negative list count, or one that runs
    past the end, is an error), so the walk ends after at most ``len(data)`` steps.
    """
    truncated = f"PLY data is truncated (in element '{element.name}')"
    if not element.has_lists:
        size = sum(np.dtype(p.type).itemsize for p in element.properties)
        offset += element.count * size
        if offset > len(data):
            raise InputError(path, truncated)
        return offset
    for item in range(element.count):  # list properties: walk item by item
        for p in element.properties:
            if p.count_type is None:
                offset += np.dtype(p.type).itemsize
                continue
            ct = np.dtype(endian + p.count_type)
            if offset + ct.itemsize > len(data):
                raise InputError(path, truncated)
            n = int(np.frombuffer(data, ct, 1, offset)[0])
            if n < 0:
                raise InputError(path, f"PLY element '{element.name}' {item}: list '{p.name}' has a negative "
                                       f"length ({n})")
            offset += ct.itemsize + n * np.dtype(p.type).itemsize
        if offset > len(data):
            raise InputError(path, truncated)
    return offset


def _read_binary(path: Path, data: bytes, offset: int, elements: list[_Element], k: int, xyz: list[int],
                 endian: str) -> np.ndarray:
    for element in elements[:k]:
        offset = _skip_binary(path, data, offset, element, endian)
    vertex = elements[k]
    if vertex.has_lists:
        raise InputError(path, "PLY vertex element with list properties is not supported in binary files")
    dtype = np.dtype([(f"p{i}", endian + p.type) for i, p in enumerate(vertex.properties)])
    need = vertex.count * dtype.itemsize
    have = len(data) - offset
    if have < need:
        raise InputError(path, f"PLY data is truncated: {vertex.count} vertices need {need} bytes, "
                               f"found {max(have, 0)}")
    arr = np.frombuffer(data, dtype, vertex.count, offset)
    return np.stack([arr[f"p{i}"] for i in xyz], axis=1).astype(np.float64)


def _read_ascii(path: Path, data: bytes, offset: int, elements: list[_Element], k: int, xyz: list[int]) -> np.ndarray:
    try:
        text = data[offset:].decode("ascii")
    except UnicodeDecodeError:
        raise InputError(path, "ASCII PLY body holds non-ASCII bytes") from None
    lines = [s for s in text.splitlines() if s.strip()]
    start = sum(e.count for e in elements[:k])  # one line per item of each element before the vertices
    vertex = elements[k]
    block = lines[start:start + vertex.count]
    if len(block) < vertex.count:
        raise InputError(path, f"PLY data is truncated: expected {vertex.count} vertex lines, found {len(block)}")
    if vertex.has_lists:  # rare: walk each line
        out = np.empty((vertex.count, 3))
        for r, line in enumerate(block):
            words, i, vals = line.split(), 0, []
            for p in vertex.properties:
                if p.count_type is None:
                    vals.append(words[i] if i < len(words) else "")
                    i += 1
                else:
                    vals.append("")
                    i += 1 + (int(words[i]) if i < len(words) and words[i].isdigit() else 0)
            try:
                out[r] = [float(vals[j]) for j in xyz]
            except ValueError:
                raise InputError(path, f"PLY vertex {r}: cannot parse '{line.strip()}'") from None
        return out
    n_props = len(vertex.properties)
    try:
        df = pd.read_csv(io.StringIO("\n".join(block)), sep=r"\s+", header=None, dtype=np.float64,
                         na_filter=False, engine="c")
        ok = df.shape == (vertex.count, n_props) and not df.isna().to_numpy().any()
    except (ValueError, pd.errors.ParserError):
        ok = False
    if not ok:  # find the line at fault
        counts = np.fromiter((len(s.split()) for s in block), dtype=np.int64, count=len(block))
        bad = np.flatnonzero(counts != n_props)
        if len(bad):
            r = bad[0]
            raise InputError(path, f"PLY vertex {r}: expected {n_props} values, found {counts[r]}")
        raise InputError(path, "PLY vertex data is not numeric")
    return df[xyz].to_numpy(np.float64)


#: m, the farthest a scene point may lie from the origin (a room, a hall, a field: well under it; a scan in
#: micrometres, or 3e38, is not)
MAX_COORDINATE_M = 1e6


def read_ply(path: str | Path) -> np.ndarray:
    """Read the vertex positions of a PLY file.

    Parameters
    ----------
    path : ``.ply`` file (ascii, binary_little_endian or binary_big_endian)

    Returns
    -------
    (N, 3) float64 array, the ``x y z`` vertex properties [m]

    Raises
    ------
    InputError
        Naming ``path``: missing file, not a PLY, no vertices, no ``x``/``y``/``z``
        properties, truncated or non-numeric data, non-finite coordinates.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError(path, "file not found")
    data = path.read_bytes()
    fmt, elements, offset = _parse_header(path, data)
    k, xyz = _vertex_element(path, elements)
    endian = FORMATS[fmt]
    if endian is None:
        points = _read_ascii(path, data, offset, elements, k, xyz)
    else:
        points = _read_binary(path, data, offset, elements, k, xyz, endian)
    if not np.isfinite(points).all():
        r = int(np.flatnonzero(~np.isfinite(points).all(axis=1))[0])
        raise InputError(path, f"PLY vertex {r} has a non-finite coordinate")
    far = np.abs(points) > MAX_COORDINATE_M
    if far.any():
        r = int(np.flatnonzero(far.any(axis=1))[0])
        raise InputError(path, f"PLY vertex {r} lies {np.abs(points[r]).max():.3g} m from the origin, beyond the "
                               f"{MAX_COORDINATE_M:.0e} m of any scene a multirotor flies in (the scan's units?)")
    return points


def write_ply(path: str | Path, points: np.ndarray, binary: bool = True) -> None:
    """Write points as PLY vertices with ``double x y z`` properties, atomically.

    Parameters
    ----------
    path : file to write (its folder is created)
    points : (N, 3) positions [m]
    binary : ``binary_little_endian`` (default) or ``ascii``; both round-trip float64 exactly
    """
    path = Path(path)
    points = np.asarray(points, dtype=np.float64)
    if points.ndim != 2 or points.shape[1] != 3:
        raise InputError(path, f"points must have shape (N, 3), got {points.shape}")
    fmt = "binary_little_endian" if binary else "ascii"
    header = (f"ply\nformat {fmt} 1.0\ncomment uavturb scene points in W [m]\nelement vertex {len(points)}\n"
              "property double x\nproperty double y\nproperty double z\nend_header\n").encode("ascii")
    if binary:
        body = np.ascontiguousarray(points, dtype="<f8").tobytes()
    else:
        body = "".join(f"{x!r} {y!r} {z!r}\n" for x, y, z in points.tolist()).encode("ascii")
    write_atomic(path, header + body)
