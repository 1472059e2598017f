"""PLY files: the header's counts checked against the caps and the data length before anything is allocated (a
reader that trusted them would reserve the declared count, or pad a short file with zeros), then the vertex
element's x, y, z read with numpy: `ascii` (graspd.io.text_numbers: C speed, one row a line),
`binary_little_endian` and `binary_big_endian` (records through a numpy dtype; `property list` rows too), with
normals, colours and scalars where the file has them (graspd.io.file_cloud)."""

from __future__ import annotations

import struct
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from graspd.core.cloud import CloudError
from graspd.core.limits import MAX_POINTS
from graspd.io.file_cloud import MAX_SCALARS, FileCloud, colours_from_channels, kept_scalar
from graspd.io.text_numbers import line_counts, line_start, parse_numbers

_PLY_SIZES = {"char": 1, "uchar": 1, "int8": 1, "uint8": 1, "short": 2, "ushort": 2, "int16": 2, "uint16": 2,
              "int": 4, "uint": 4, "int32": 4, "uint32": 4, "float": 4, "float32": 4, "double": 8, "float64": 8}
_PLY_KINDS = {"char": "i", "uchar": "u", "int8": "i", "uint8": "u", "short": "i", "ushort": "u", "int16": "i",
              "uint16": "u", "int": "i", "uint": "u", "int32": "i", "uint32": "u", "float": "f", "float32": "f",
              "double": "f", "float64": "f"}
_PLY_FORMATS = ("ascii", "binary_little_endian", "binary_big_endian")
_MAX_PLY_HEADER = 64 << 10  # bytes


@dataclass(frozen=True)
class PlyElement:
    """One `element` of a PLY header: its name, declared row count and properties (each `[type, name]` or
    `["list", count type, item type, name]`)."""

    name: str
    count: int
    properties: list[list[str]]

    def least_bytes(self) -> int:
        """The fewest bytes its binary rows take: the fixed-size properties plus each list's count."""
        return self.count * sum(_PLY_SIZES[p[1]] if p[0] == "list" else _PLY_SIZES[p[0]] for p in self.properties)


@dataclass(frozen=True)
class PlyHeader:
    """A checked PLY header: the format, the elements in file order, which is the vertex element, where the
    data starts."""

    format: str
    elements: list[PlyElement]
    vertex: int  # index in elements
    offset: int  # byte where the data starts

    def endian(self) -> str:
        """numpy's byte-order mark of the binary data."""
        return ">" if self.format == "binary_big_endian" else "<"


def _dtype(endian: str, ply_type: str) -> np.dtype[np.number]:
    return np.dtype(f"{endian}{_PLY_KINDS[ply_type]}{_PLY_SIZES[ply_type]}")


def check_ply_header(data: bytes) -> PlyHeader:
    """The PLY header, after checking every declared count against the caps and the data length (before
    anything is allocated).  A `property list` row takes at least its count's bytes, so a list bomb is refused
    too; ASCII data must hold a line per declared row of every element, each vertex row its properties' values."""
    if not data.startswith(b"ply"):
        raise CloudError("cloud.points", "a PLY file must start with 'ply'")
    end = data.find(b"end_header", 0, _MAX_PLY_HEADER)
    if end < 0:
        raise CloudError("cloud.points", f"the PLY header has no end_header in its first {_MAX_PLY_HEADER} bytes")
    newline = data.find(b"\n", end)
    offset = newline + 1 if newline >= 0 else len(data)
    body = memoryview(data)[offset:]
    fmt = ""
    elements: list[PlyElement] = []
    for line in data[:end].decode("ascii", errors="replace").splitlines():
        parts = line.split()
        if parts[:1] == ["format"] and len(parts) > 1:
            fmt = parts[1]
        elif parts[:1] == ["element"]:
            if len(parts) != 3 or not parts[2].isdigit() or len(parts[2]) > 12:
                raise CloudError("cloud.points", f"PLY element line {line.strip()!r} needs a name and a "
                                 f"non-negative integer count")
            elements.append(PlyElement(parts[1], int(parts[2]), []))
        elif parts[:1] == ["property"] and elements:
            prop = parts[1:]
            known = (len(prop) == 2 and prop[0] in _PLY_SIZES) or (  # a list's count is an integer type
                len(prop) == 4 and prop[0] == "list" and _PLY_KINDS.get(prop[1]) in ("i", "u")
                and prop[2] in _PLY_SIZES)
            if not known:
                raise CloudError("cloud.points", f"PLY property line {line.strip()!r} is not understood")
            elements[-1].properties.append(prop)
    if fmt not in _PLY_FORMATS:
        raise CloudError("cloud.points", f"PLY format {fmt!r} is not one of {list(_PLY_FORMATS)}")
    vertex = next((i for i, e in enumerate(elements) if e.name == "vertex"), None)
    if vertex is None:
        raise CloudError("cloud.points", "the PLY header declares no vertex element")
    count, props = elements[vertex].count, elements[vertex].properties
    if count > MAX_POINTS:
        raise CloudError("cloud.points", f"the PLY header declares {count} vertices, more than the limit of "
                         f"{MAX_POINTS}")
    if count == 0:
        raise CloudError("cloud.points", "the PLY header declares 0 vertices; send at least one point")
    names = [p[-1] for p in props]
    if not {"x", "y", "z"} <= set(names):
        raise CloudError("cloud.points", f"the PLY vertex element lacks x, y or z (has {names})")
    for a in "xyz":
        if props[names.index(a)][0] == "list":
            raise CloudError("cloud.points", f"the PLY vertex property {a} is a list, not a number")
    if fmt != "ascii":  # binary: every element row takes at least its fixed-size properties plus each list's count
        least = sum(e.least_bytes() for e in elements)
        if len(body) < least:
            raise CloudError("cloud.points", f"the PLY header declares {count} vertices (with its other elements "
                             f"at least {least} bytes); the file holds {len(body)} bytes")
    return PlyHeader(fmt, elements, vertex, offset)


def check_ply(data: bytes) -> int:
    """The vertex count a PLY header declares, checked as check_ply_header does (and, for ASCII, the vertex
    rows' values counted, as parse_ply reads them)."""
    head = check_ply_header(data)
    if head.format == "ascii":
        _ascii_vertex_rows(memoryview(data)[head.offset:], head)
    return head.elements[head.vertex].count


def _ascii_vertex_rows(body: memoryview, head: PlyHeader) -> tuple[NDArray[np.floating], NDArray[np.intp]]:
    """The numbers of the ASCII vertex rows (one row a line, after the lines of the elements before it) and
    where each row starts among them; CloudError when the file holds fewer lines or values than declared."""
    element = head.elements[head.vertex]
    count, width = element.count, len(element.properties)
    text = bytes(body)
    lines = text.count(b"\n") + 1  # as many as text.split(b"\n") makes
    total = sum(e.count for e in head.elements)
    first = sum(e.count for e in head.elements[: head.vertex])
    fewer = CloudError("cloud.points", f"the PLY header declares {count} vertices of {width} values; "
                       f"the file holds fewer")
    if lines < total or lines < first + count:
        raise fewer
    begin = line_start(text, first)
    stop = line_start(text, first + count) - 1 if first + count < lines else len(text)  # the last vertex row's end
    rows = text[begin:stop]
    per_line = line_counts(rows)
    if per_line.size < count or (per_line < width).any():  # a blank or a short row
        raise fewer
    # float32 unless a list's counts must be read exactly (x y z come out the same: numpy rounds strtod's float64)
    dtype = np.float64 if any(p[0] == "list" for p in element.properties) else np.float32
    try:
        values = parse_numbers(rows, int(per_line.sum()), dtype)
    except ValueError as exc:
        raise CloudError("cloud.points", f"the PLY vertex rows are unreadable ({exc})") from None
    return values, np.cumsum(per_line) - per_line


def _ascii_columns(body: memoryview, head: PlyHeader, wanted: frozenset[int]) -> dict[int, NDArray[np.floating]]:
    """The wanted vertex properties of ASCII rows (by property index), property by property over all rows at
    once: a list property's row holds its count then that many items, so the columns after it sit at a per-row
    position."""
    values, position = _ascii_vertex_rows(body, head)
    ends = np.append(position[1:], values.size)  # one past each row's last value
    props = head.elements[head.vertex].properties
    out: dict[int, NDArray[np.floating]] = {}
    for i, prop in enumerate(props):
        if (position >= ends).any():
            break
        if i in wanted:
            out[i] = values[position]
        if prop[0] == "list":
            length = values[position]
            if not (np.isfinite(length) & (length >= 0) & (length == np.round(length))).all():
                raise CloudError("cloud.points", f"the PLY vertex list {prop[-1]!r} has a count that is not a "
                                 "non-negative integer")
            position += 1 + np.minimum(length, ends - position).astype(np.intp)  # past the row: refused below
        else:
            position += 1
    else:
        if (position == ends).all():
            return out
    raise CloudError("cloud.points", "the PLY vertex rows do not hold the values their properties declare "
                     "(one row a line)")


def _binary_layout(body: memoryview, offset: int, element: PlyElement, endian: str) -> np.dtype[np.void] | None:
    """A numpy record dtype for every row of element when each list holds as many items as in the first row
    (triangle faces, fixed-size descriptors); None when the first row does not fit in the data."""
    fields: list[tuple[str, np.dtype[np.number]] | tuple[str, np.dtype[np.number], tuple[int]]] = []
    pos = offset
    for i, prop in enumerate(element.properties):
        if prop[0] != "list":
            fields.append((f"p{i}", _dtype(endian, prop[0])))
            pos += _PLY_SIZES[prop[0]]
            continue
        counter, item = _dtype(endian, prop[1]), _dtype(endian, prop[2])
        if pos + counter.itemsize > len(body):
            return None
        length = int(np.frombuffer(body, counter, 1, pos)[0])
        pos += counter.itemsize + length * item.itemsize
        if length < 0 or pos > len(body):
            return None
        fields += [(f"p{i}", counter), (f"p{i}_items", item, (length,))]
    return np.dtype(fields) if pos <= len(body) else None  # type: ignore[arg-type]


def _walk_rows(body: memoryview, offset: int, element: PlyElement, endian: str, wanted: frozenset[int]
               ) -> tuple[dict[int, NDArray[np.number]], int]:
    """Rows whose lists vary in length: each row's start depends on every row before it, so Python walks the
    lists' counts row by row (about 0.3 us a row), then numpy gathers the fixed-size properties of all rows at
    their offsets (the wanted ones).  Rare: point clouds' vertices have no lists, and a mesh's faces follow its
    vertices."""
    n, props = element.count, element.properties
    fewer = CloudError("cloud.points", f"the PLY header declares {n} {element.name} rows; the file holds fewer")
    segments = []  # per list: fixed bytes before it, its count's reader and size, its items' size
    gap = 0
    for prop in props:
        if prop[0] == "list":
            counter = struct.Struct(f"{endian}{_dtype(endian, prop[1]).char}")
            segments.append((gap, counter.unpack_from, counter.size, _PLY_SIZES[prop[2]]))
            gap = 0
        else:
            gap += _PLY_SIZES[prop[0]]
    starts = np.empty(n, np.int64)
    lengths = np.empty((n, len(segments)), np.int64)
    pos, size = offset, len(body)
    try:
        for row in range(n):
            starts[row] = pos
            for k, (before, unpack, counter_size, item_size) in enumerate(segments):
                pos += before
                length = unpack(body, pos)[0]
                if length < 0:
                    raise CloudError("cloud.points", f"a PLY {element.name} list has a negative count")
                lengths[row, k] = length
                pos += counter_size + length * item_size
            pos += gap
            if pos > size:
                raise fewer
    except struct.error:
        raise fewer from None
    raw = np.frombuffer(body, np.uint8)
    columns: dict[int, NDArray[np.number]] = {}
    at, k = starts.copy(), 0
    for i, prop in enumerate(props):
        if prop[0] == "list":
            at += segments[k][2] + lengths[:, k] * segments[k][3]
            k += 1
            continue
        dtype = _dtype(endian, prop[0])
        if i in wanted:
            column = np.empty((n, dtype.itemsize), np.uint8)
            for b in range(dtype.itemsize):  # byte by byte: temporaries of n, not n x itemsize, indices
                column[:, b] = raw[at + b]
            columns[i] = column.view(dtype).ravel()
        at += dtype.itemsize
    return columns, pos


def _binary_rows(body: memoryview, offset: int, element: PlyElement, endian: str,
                 wanted: frozenset[int] = frozenset()) -> tuple[dict[int, NDArray[np.number]], int]:
    """The wanted fixed-size properties of a binary element's rows, by property index, and the byte where the
    next element starts: one numpy record read when every row's lists are as long as the first row's (checked:
    then each row's counts sit where the record puts them), else _walk_rows."""
    n = element.count
    layout = _binary_layout(body, offset, element, endian)
    if layout is None:
        raise CloudError("cloud.points", f"the PLY header declares {n} {element.name} rows; the file holds fewer")
    lists = [i for i, p in enumerate(element.properties) if p[0] == "list"]
    if offset + n * layout.itemsize <= len(body):
        rows = np.frombuffer(body, layout, n, offset)
        if all((rows[f"p{i}"] == layout[f"p{i}_items"].shape[0]).all() for i in lists):
            return {i: rows[f"p{i}"] for i in wanted}, offset + n * layout.itemsize
    if not lists:
        raise CloudError("cloud.points", f"the PLY header declares {n} {element.name} rows; the file holds fewer")
    return _walk_rows(body, offset, element, endian, wanted)


def _binary_columns(body: memoryview, head: PlyHeader, wanted: frozenset[int]) -> dict[int, NDArray[np.number]]:
    """The wanted vertex properties of binary rows (by property index), after the rows of the elements before
    them."""
    offset = 0
    for element in head.elements[: head.vertex]:
        _, offset = _binary_rows(body, offset, element, head.endian())
    columns, _ = _binary_rows(body, offset, head.elements[head.vertex], head.endian(), wanted)
    return columns


#: Vertex colour properties by the name writers give them: Open3D, CloudCompare and the RealSense viewer write
#: red/green/blue (uchar), some writers diffuse_red/... or r/g/b; floats are fractions 0-1.
_COLOUR_NAMES = (("red", "green", "blue"), ("diffuse_red", "diffuse_green", "diffuse_blue"), ("r", "g", "b"))
_NORMAL_NAMES = ("nx", "ny", "nz")


def read_ply(data: bytes) -> FileCloud:
    """Everything graspd uses of a PLY file's vertices (ascii, binary_little_endian or binary_big_endian): x, y, z
    (float32, m), normals nx/ny/nz, colours (red/green/blue, diffuse_*, r/g/b; uchar or float 0-1), the kept
    scalars (intensity, label, curvature, CloudCompare's scalar_*).  Other elements (faces, edges) are skipped:
    a mesh file gives its vertices.  A file holding fewer vertices, or fewer values in a row, than its header
    declares is refused with a CloudError."""
    head = check_ply_header(data)
    body = memoryview(data)[head.offset:]
    props = head.elements[head.vertex].properties
    index = {p[-1]: i for i, p in reversed(list(enumerate(props))) if p[0] != "list"}  # the first of each name
    normals = [index[a] for a in _NORMAL_NAMES] if all(a in index for a in _NORMAL_NAMES) else []
    colours = next(([index[a] for a in names] for names in _COLOUR_NAMES if all(a in index for a in names)), [])
    scalars = [name for name in index if kept_scalar(name)][:MAX_SCALARS]
    wanted = frozenset([*(index[a] for a in "xyz"), *normals, *colours, *(index[a] for a in scalars)])
    columns: dict[int, NDArray[np.generic]] = dict(
        _ascii_columns(body, head, wanted) if head.format == "ascii" else _binary_columns(body, head, wanted))
    if head.format == "ascii":  # text has no type: integer colour columns are integers
        for i in colours:
            if _PLY_KINDS[props[i][0]] != "f":
                columns[i] = np.asarray(columns[i]).astype(np.int64)

    def stack(which: list[int]) -> NDArray[np.float32]:
        out = np.empty((head.elements[head.vertex].count, 3), np.float32)
        for k, i in enumerate(which):
            out[:, k] = columns[i]
        return out

    return FileCloud(stack([index[a] for a in "xyz"]), stack(normals) if normals else None,
                     colours_from_channels([columns[i] for i in colours]) if colours else None,
                     {name: np.asarray(columns[index[name]]) for name in scalars})


def parse_ply(data: bytes) -> NDArray[np.float32]:
    """Vertex positions (N,3) float32 of a PLY file (read_ply without the other properties)."""
    return read_ply(data).points
