"""PLY point clouds (``mav0/pointcloud0/data.ply``): vertex positions in the world frame.

:func:`read_ply` reads ``ascii``, ``binary_little_endian`` and ``binary_big_endian`` files and
returns the ``x y z`` vertex properties as an ``(N, 3)`` float64 array; other vertex
properties (colours, normals, ...) and other elements (faces, ...) are skipped, whatever
their order. :func:`write_ply` writes vertices only, atomically.

A room is often exported as a *mesh*: a floor of two triangles has four vertices, at its corners,
and read as points it holds no floor under the vehicle. :func:`read_ply_faces` reads a mesh's
``face`` element (triangles, and polygons as fans of triangles) and :func:`surface_points`
samples its surfaces as a scan would (:data:`FACE_SPACING_M` apart), which is how recordings
read a mesh (:func:`scene_points`). Non-finite vertices (a scanner's no-return, written as NaN)
are left out there, and said.
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
    after = sum(e.count for e in elements[k + 1:])  # one line per item of each element after the vertices
    extra = len(lines) - start - vertex.count - after
    if extra > 0:  # a header that undercounts its vertices would drop the rest of the scan without a word
        raise InputError(path, f"PLY body holds {extra} more line(s) than its header declares ({vertex.count} "
                               f"vertices{f' and {after} other items' if after else ''}): the header's element counts "
                               "are wrong")
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


def read_ply(path: str | Path, allow_non_finite: bool = False) -> np.ndarray:
    """Read the vertex positions of a PLY file.

    Parameters
    ----------
    path : ``.ply`` file (ascii, binary_little_endian or binary_big_endian)
    allow_non_finite : non-finite coordinates are refused unless this is set (then they are returned as they are,
        for the caller to leave out: :func:`scene_points`)

    Returns
    -------
    (N, 3) float64 array, the ``x y z`` vertex properties [m]

    Raises
    ------
    InputError
        Naming ``path``: missing file, not a PLY, no vertices, no ``x``/``y``/``z``
        properties, truncated or non-numeric data, non-finite coordinates.
    """
    return _vertices(_opened(path), allow_non_finite)


@dataclass
class _Opened:
    """A PLY file read once: its bytes, format, elements and where its body starts."""
    path: Path
    data: bytes
    fmt: str
    elements: list[_Element]
    offset: int


def _opened(path: str | Path) -> _Opened:
    path = Path(path)
    if not path.is_file():
        raise InputError(path, "file not found")
    data = path.read_bytes()
    return _Opened(path, data, *_parse_header(path, data))


def _vertices(ply: _Opened, allow_non_finite: bool) -> np.ndarray:
    path = ply.path
    k, xyz = _vertex_element(path, ply.elements)
    endian = FORMATS[ply.fmt]
    if endian is None:
        points = _read_ascii(path, ply.data, ply.offset, ply.elements, k, xyz)
    else:
        points = _read_binary(path, ply.data, ply.offset, ply.elements, k, xyz, endian)
    if not allow_non_finite and not np.isfinite(points).all():
        r = int(np.flatnonzero(~np.isfinite(points).all(axis=1))[0])
        raise InputError(path, f"PLY vertex {r} has a non-finite coordinate")
    far = np.isfinite(points) & (np.abs(points) > MAX_COORDINATE_M)
    if far.any():
        r = int(np.flatnonzero(far.any(axis=1))[0])
        raise InputError(path, f"PLY vertex {r} lies {np.abs(points[r]).max():.3g} m from the origin, beyond the "
                               f"{MAX_COORDINATE_M:.0e} m of any scene a multirotor flies in (the scan's units?)")
    return points


def _face_element(elements: list[_Element]) -> tuple[int, int] | None:
    """Index of the ``face`` element and of its vertex-index list property (None: no such element)."""
    for k, e in enumerate(elements):
        if e.name != "face":
            continue
        for j, prop in enumerate(e.properties):
            if prop.count_type is not None and prop.name in ("vertex_indices", "vertex_index"):
                return k, j
    return None


def _fan(lists: list[np.ndarray]) -> np.ndarray:
    """(F, 3) int64 triangles of polygons given as index lists (fans from each polygon's first vertex)."""
    tri = [np.stack([poly[0].repeat(len(poly) - 2), poly[1:-1], poly[2:]], axis=1) for poly in lists if len(poly) >= 3]
    return np.concatenate(tri).astype(np.int64) if tri else np.empty((0, 3), np.int64)


def _binary_faces(path: Path, data: bytes, offset: int, elements: list[_Element], k: int, j: int,
                  endian: str) -> np.ndarray:
    for element in elements[:k]:
        offset = _skip_binary(path, data, offset, element, endian)
    face = elements[k]
    prop = face.properties[j]
    if len(face.properties) == 1:  # the common case, every face a triangle: one structured read
        dtype = np.dtype([("n", endian + prop.count_type), ("i", endian + prop.type, 3)])
        if offset + face.count * dtype.itemsize <= len(data):
            arr = np.frombuffer(data, dtype, face.count, offset)
            if np.all(arr["n"] == 3):
                return arr["i"].astype(np.int64)
    lists = []
    for item in range(face.count):  # any polygons and properties: item by item, every step forward
        for q in face.properties:
            if q.count_type is None:
                offset += np.dtype(q.type).itemsize
                continue
            ct, it = np.dtype(endian + q.count_type), np.dtype(endian + q.type)
            if offset + ct.itemsize > len(data):
                raise InputError(path, "PLY data is truncated (in element 'face')")
            n = int(np.frombuffer(data, ct, 1, offset)[0])
            if n < 0 or offset + ct.itemsize + n * it.itemsize > len(data):
                raise InputError(path, f"PLY face {item}: list '{q.name}' has a bad length ({n})")
            if q is prop:
                lists.append(np.frombuffer(data, it, n, offset + ct.itemsize).astype(np.int64))
            offset += ct.itemsize + n * it.itemsize
    return _fan(lists)


def _ascii_faces(path: Path, data: bytes, offset: int, elements: list[_Element], k: int, j: int) -> np.ndarray:
    lines = [s for s in data[offset:].decode("ascii", errors="replace").splitlines() if s.strip()]
    start = sum(e.count for e in elements[:k])
    face = elements[k]
    block = lines[start:start + face.count]
    if len(block) < face.count:
        raise InputError(path, f"PLY data is truncated: expected {face.count} face lines, found {len(block)}")
    lists = []
    for item, line in enumerate(block):
        words, i = line.split(), 0
        try:
            for q in face.properties:
                if q.count_type is None:
                    i += 1
                    continue
                n = int(words[i])
                if n < 0 or i + 1 + n > len(words):
                    raise ValueError(n)
                if q is face.properties[j]:
                    lists.append(np.array([int(w) for w in words[i + 1:i + 1 + n]], np.int64))
                i += 1 + n
        except (ValueError, IndexError):
            raise InputError(path, f"PLY face {item}: cannot parse '{line.strip()}'") from None
    return _fan(lists)


def read_ply_faces(path: str | Path, n_vertices: int) -> np.ndarray | None:
    """The triangles of a PLY mesh's ``face`` element.

    Parameters
    ----------
    path : ``.ply`` file, as :func:`read_ply` reads
    n_vertices : the file's vertex count (every index must be under it)

    Returns
    -------
    (F, 3) int64 array of vertex indices (polygons split into fans of triangles), or None where the file has
    no ``face`` element with a ``vertex_indices`` list

    Raises
    ------
    InputError
        Naming ``path``: a face list truncated or unparsable, or an index outside the vertices.
    """
    return _faces(_opened(path), n_vertices)


def _faces(ply: _Opened, n_vertices: int) -> np.ndarray | None:
    found = _face_element(ply.elements)
    if found is None:
        return None
    k, j = found
    endian = FORMATS[ply.fmt]
    faces = _ascii_faces(ply.path, ply.data, ply.offset, ply.elements, k, j) if endian is None \
        else _binary_faces(ply.path, ply.data, ply.offset, ply.elements, k, j, endian)
    bad = (faces < 0) | (faces >= n_vertices)
    if bad.any():
        f = int(np.flatnonzero(bad.any(axis=1))[0])
        raise InputError(ply.path, f"PLY face {f} refers to vertex {int(faces[f][bad[f]][0])}, and the file has "
                                   f"{n_vertices} vertices")
    return faces


#: m, the spacing a mesh's surfaces are sampled at (a scan's: several points in every 5 cm column of
#: :class:`uavturb.scene.heights.SurfaceIndex`)
FACE_SPACING_M = 0.02
#: the most points a mesh's surfaces are sampled into (160 MB); a larger area is sampled more coarsely, and said
MAX_FACE_POINTS = 20_000_000


def surface_points(triangles: np.ndarray, spacing: float, seed: int | None = 0) -> np.ndarray:
    """Points uniformly distributed over triangles' area, as a scan would hold them.

    Parameters
    ----------
    triangles : (F, 3, 3) float, the corners [m]
    spacing : float, mean point spacing [m]: ``ceil(area / spacing**2)`` points are drawn
    seed : int or None, the random generator's seed (deterministic for an int)

    Returns
    -------
    (P, 3) float array [m]. Random (Poisson-like), so, like a real scan, the cloud has small gaps.

    Raises
    ------
    InputError
        ``"mesh"`` when it has no area; ``"spacing"`` when not positive.
    """
    if not (np.isfinite(spacing) and spacing > 0):
        raise InputError("spacing", f"must be positive, got {spacing}")
    tri = np.asarray(triangles, dtype=float)
    if tri.ndim != 3 or len(tri) == 0:
        raise InputError("mesh", "no triangles")
    e1, e2 = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    area = 0.5 * np.linalg.norm(np.cross(e1, e2), axis=1)
    total = float(area.sum())
    if not (np.isfinite(total) and total > 0):
        raise InputError("mesh", "zero or undefined surface area")
    n = int(np.ceil(total / spacing**2))
    rng = np.random.default_rng(seed)
    cum = np.cumsum(area)
    face = np.minimum(np.searchsorted(cum, rng.random(n) * cum[-1], side="right"), len(tri) - 1)
    r = rng.random((n, 2))
    flip = r.sum(axis=1) > 1.0
    r[flip] = 1.0 - r[flip]
    return tri[face, 0] + r[:, :1] * e1[face] + r[:, 1:] * e2[face]


def scene_points(path: str | Path, notes: list[str]) -> np.ndarray:
    """A recording's scene points: the PLY's finite vertices and, for a mesh, its surfaces sampled.

    Parameters
    ----------
    path : ``mav0/pointcloud0/data.ply``
    notes : what was done to the file (non-finite vertices left out, a mesh's faces sampled) is appended here

    Returns
    -------
    (P, 3) float64 array [m] in W

    Raises
    ------
    InputError
        As :func:`read_ply` and :func:`read_ply_faces`, and where no vertex is finite.
    """
    ply = _opened(path)
    path = ply.path
    vertices = _vertices(ply, allow_non_finite=True)
    finite = np.isfinite(vertices).all(axis=1)
    if not finite.any():
        raise InputError(path, f"none of the PLY's {len(vertices)} vertices has finite coordinates")
    where = f"{path.parent.parent.parent.name}/pointcloud0"
    if not finite.all():
        notes.append(f"{where}: {int((~finite).sum())} of {len(vertices)} vertices have non-finite coordinates (a "
                     "scanner's no-returns) and are left out")
    faces = _faces(ply, len(vertices))  # the file read once
    if faces is None or len(faces) == 0:
        return vertices[finite]
    faces = faces[finite[faces].all(axis=1)]
    tri = vertices[faces]
    area = float(0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1).sum())
    if not area > 0:
        return vertices[finite]
    spacing = max(FACE_SPACING_M, float(np.sqrt(area / MAX_FACE_POINTS)))
    samples = surface_points(tri, spacing, seed=0)
    notes.append(f"{where}: a mesh of {len(faces)} triangles ({area:.3g} m^2): its surfaces are sampled every "
                 f"{100 * spacing:.2g} cm ({len(samples)} points) beside its {int(finite.sum())} vertices")
    return np.concatenate([vertices[finite], samples])


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
