"""PCD files (PCL's point cloud format): the header checked against itself, the caps and the data length before
anything is allocated (a small file cannot declare gigabytes), then x, y, z read with numpy from every layout PCL
writes: `ascii` (graspd.io.text_numbers: C speed), `binary` (records of FIELDS/SIZE/TYPE/COUNT, little-endian) and
`binary_compressed` (LZF, graspd.io.lzf; one block per field), with normals, colour and scalars where the file
has them (graspd.io.file_cloud).  Organised clouds keep their NaN pixels in pixel order (graspd.io.inputs drops
and counts them) and their (HEIGHT, WIDTH)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from graspd.core.cloud import CloudError
from graspd.core.limits import MAX_POINTS
from graspd.io.file_cloud import MAX_SCALARS, FileCloud, colours_from_packed, kept_scalar
from graspd.io.lzf import LzfError, lzf_decompress
from graspd.io.text_numbers import line_counts, parse_numbers

#: The most points a PCD or PLY file may declare.
MAX_FILE_POINTS = MAX_POINTS
#: A binary_compressed PCD may expand at most this much (PCL's LZF on real clouds gives ~1-4x; more is a bomb).
MAX_PCD_EXPANSION = 32
_MAX_PCD_HEADER = 64 << 10  # bytes: PCL's headers are a few hundred
_MAX_PCD_FIELDS = 256
_MAX_PCD_COUNT = 4096  # values per field (PCL descriptors such as FPFH use 33, SHOT 352)
_PCD_SIZES = {"F": (4, 8), "I": (1, 2, 4, 8), "U": (1, 2, 4, 8)}
_PCD_KINDS = {"F": "f", "I": "i", "U": "u"}  # TYPE -> numpy kind


def _pcd_header(data: bytes) -> tuple[dict[str, list[str]], int]:
    """PCD header fields and the byte offset where the data starts (the header is read up to 64 KiB)."""
    header: dict[str, list[str]] = {}
    offset = 0
    limit = min(len(data), _MAX_PCD_HEADER)
    while True:
        end = data.find(b"\n", offset, limit)
        if end < 0:
            raise CloudError("body", "pcd: header ends before DATA" if limit == len(data)
                             else f"pcd: no DATA line in the first {_MAX_PCD_HEADER} bytes")
        line = data[offset:end].decode("ascii", errors="replace").strip()
        offset = end + 1
        if not line or line.startswith("#"):
            continue
        key, *values = line.split()
        header[key.upper()] = values
        if key.upper() == "DATA":
            return header, offset


def _count(header: dict[str, list[str]], key: str, default: str | None = None) -> int:
    """A non-negative integer header value (WIDTH, HEIGHT, POINTS) within MAX_FILE_POINTS; CloudError otherwise."""
    values = header.get(key, [default] if default is not None else [])
    if len(values) != 1 or not values[0].isdigit():  # isdigit: no sign, no exponent, no fraction
        raise CloudError("cloud.points", f"pcd {key} must be one non-negative integer, got {' '.join(values)!r}")
    if len(values[0]) > 12 or int(values[0]) > MAX_FILE_POINTS:
        raise CloudError("cloud.points", f"pcd {key} {values[0]} exceeds the limit of {MAX_FILE_POINTS} points")
    return int(values[0])


@dataclass(frozen=True)
class PcdHeader:
    """A checked PCD header: what the data section must hold."""

    fields: list[str]
    record_size: int  # bytes per point (binary layouts)
    values_per_point: int  # numbers per ASCII row
    points: int
    kind: str  # ascii, binary or binary_compressed
    offset: int  # where the data starts
    viewpoint: NDArray[np.float32] | None
    sizes: tuple[int, ...] = ()  # bytes of one value of each field
    types: tuple[str, ...] = ()  # F, I or U of each field
    counts: tuple[int, ...] = ()  # values of each field
    width: int = 0
    height: int = 1

    def xyz(self) -> list[int]:
        """Index in fields of x, y and z (the first of each name)."""
        return [self.fields.index(a) for a in "xyz"]

    def dtype(self, i: int) -> np.dtype[np.number]:
        """numpy dtype of one value of field i (little-endian, as PCL writes on every platform it runs on)."""
        return np.dtype(f"<{_PCD_KINDS[self.types[i]]}{self.sizes[i]}")

    def field_offset(self, i: int) -> int:
        """Bytes before field i in a binary record (binary_compressed: in units of the point count)."""
        return sum(s * c for s, c in zip(self.sizes[:i], self.counts[:i], strict=True))

    def column(self, i: int) -> int:
        """Index of field i's first value in an ASCII row."""
        return sum(self.counts[:i])


def check_pcd_header(data: bytes) -> PcdHeader:
    """Validate a PCD header against itself and the caps before anything is allocated: FIELDS/SIZE/TYPE/COUNT
    agree, POINTS is a non-negative integer <= MAX_FILE_POINTS equal to WIDTH x HEIGHT, DATA is known."""
    header, offset = _pcd_header(data)
    try:
        fields = [f.lower() for f in header["FIELDS"]]
        sizes = [int(s) for s in header["SIZE"]]
        types = [t.upper() for t in header["TYPE"]]
        counts = [int(c) for c in header.get("COUNT", ["1"] * len(fields))]
        kind = header["DATA"][0].lower()
    except (KeyError, IndexError, ValueError) as exc:
        raise CloudError("body", f"pcd: malformed header ({type(exc).__name__}: {exc})") from None
    if not 1 <= len(fields) <= _MAX_PCD_FIELDS or not len(fields) == len(sizes) == len(types) == len(counts):
        raise CloudError("body", f"pcd: FIELDS, SIZE, TYPE and COUNT must list the same 1 to {_MAX_PCD_FIELDS} fields "
                         f"(got {len(fields)}, {len(sizes)}, {len(types)}, {len(counts)})")
    if not {"x", "y", "z"} <= set(fields):
        raise CloudError("body", "pcd: FIELDS must include x y z")
    for name, t, s, c in zip(fields, types, sizes, counts, strict=True):
        if s not in _PCD_SIZES.get(t, ()):
            raise CloudError("body", f"pcd: field {name!r} has TYPE {t} SIZE {s} (F is 4 or 8 bytes, I/U 1, 2, 4 or 8)")
        if not 1 <= c <= _MAX_PCD_COUNT:
            raise CloudError("body", f"pcd: field {name!r} has COUNT {c} (1 to {_MAX_PCD_COUNT})")
    for a in "xyz":
        if counts[fields.index(a)] != 1:
            raise CloudError("body", f"pcd: field {a} must have COUNT 1")
    points = _count(header, "POINTS")
    width, height = _count(header, "WIDTH"), _count(header, "HEIGHT", "1")
    if width * height != points:
        raise CloudError("cloud.points", f"pcd WIDTH x HEIGHT ({width} x {height}) differs from POINTS {points}")
    if points == 0:
        raise CloudError("cloud.points", "pcd POINTS is 0; send at least one point")
    if kind not in ("ascii", "binary", "binary_compressed"):
        raise CloudError("body", f"pcd: DATA {kind!r} is not supported (ascii, binary or binary_compressed)")
    viewpoint = None
    if "VIEWPOINT" in header:
        try:
            vp = np.array([float(v) for v in header["VIEWPOINT"]], np.float64)
        except ValueError:
            vp = np.zeros(0)
        if vp.shape != (7,) or not np.isfinite(vp).all():
            raise CloudError("body", f"pcd: VIEWPOINT must be 7 finite numbers (tx ty tz qw qx qy qz), "
                             f"got {' '.join(header['VIEWPOINT'])!r}")
        viewpoint = vp[:3].astype(np.float32)
    record = sum(s * c for s, c in zip(sizes, counts, strict=True))
    return PcdHeader(fields, record, sum(counts), points, kind, offset, viewpoint, tuple(sizes), tuple(types),
                     tuple(counts), width, height)


def _check_sizes(body: memoryview, head: PcdHeader) -> None:
    """The binary data section holds exactly what the header declares (a reader that trusted it would read past,
    pad or stop short); a binary_compressed block may be followed by bytes PCL's reader ignores (older PCL
    writers leave a few kB there)."""
    n = head.points
    if head.kind == "binary":
        if len(body) != n * head.record_size:
            raise CloudError("cloud.points", f"pcd header declares {n} points of {head.record_size} bytes "
                             f"({n * head.record_size} bytes); the data holds {len(body)} bytes")
    elif head.kind == "binary_compressed":
        if len(body) < 8:
            raise CloudError("cloud.points", "pcd binary_compressed data lacks its two size words")
        compressed, uncompressed = np.frombuffer(body[:8], "<u4").tolist()
        if compressed > len(body) - 8:  # as PCL's reader: the block must fit; bytes after it are ignored
            raise CloudError("cloud.points", f"pcd binary_compressed declares {compressed} compressed bytes; "
                             f"the data holds {len(body) - 8}")
        if uncompressed != n * head.record_size:
            raise CloudError("cloud.points", f"pcd binary_compressed declares {uncompressed} bytes uncompressed; "
                             f"{n} points of {head.record_size} bytes take {n * head.record_size}")
        if uncompressed > MAX_PCD_EXPANSION * max(compressed, 1):
            raise CloudError("cloud.points", f"pcd binary_compressed expands {compressed} bytes to {uncompressed} "
                             f"(more than {MAX_PCD_EXPANSION}x)")


def _ascii_table(body: memoryview, head: PcdHeader, dtype: type[np.floating]) -> NDArray[np.floating]:
    """The ASCII data as a (POINTS, values_per_point) table: every row must hold values_per_point numbers (blank
    lines skipped), POINTS rows."""
    n, width = head.points, head.values_per_point
    text = bytes(body)
    rows = line_counts(text)  # the table's shape first: a file of the wrong one is refused before parsing
    if rows.size and (rows != rows[0]).any():
        raise CloudError("cloud.points", f"pcd ascii data unreadable (its rows hold {rows.min()} to {rows.max()} "
                         "values)")
    if rows.size != n or (n and rows[0] != width):
        raise CloudError("cloud.points", f"pcd header declares {n} points of {width} values; the data holds "
                         f"{rows.size} rows of {rows[0] if rows.size else 0}")
    try:  # float32: numpy rounds strtod's float64 once more, as a float64 parse then a cast would
        values = parse_numbers(text, n * width, dtype)
    except ValueError as exc:
        raise CloudError("cloud.points", f"pcd ascii data unreadable ({exc})") from None
    return values.reshape(n, width)


class _Fields:
    """Per-field access to a PCD data section whatever its layout: field(i) is an (N, COUNT) view of field i's
    values (ascii: columns of the parsed table; binary: strided over the records; binary_compressed: field i's
    block of the LZF output)."""

    def __init__(self, body: memoryview, head: PcdHeader, wanted: list[int]) -> None:
        self.head = head
        self.table: NDArray[np.floating] | None = None
        self.raw: bytes | bytearray | memoryview = body
        if head.kind == "ascii":  # float64 when an integer or packed colour must come out exact
            exact = any(head.types[i] != "F" or head.fields[i] in _PACKED_COLOUR for i in wanted)
            self.table = _ascii_table(body, head, np.float64 if exact else np.float32)
        elif head.kind == "binary_compressed":
            try:
                compressed = int(np.frombuffer(body[:4], "<u4")[0])  # older PCL writers leave bytes after the block
                self.raw = lzf_decompress(bytes(body[8:8 + compressed]), head.points * head.record_size)
            except LzfError as exc:
                raise CloudError("cloud.points", f"pcd binary_compressed data unreadable ({exc})") from None

    def field(self, i: int, dtype: np.dtype[np.generic] | None = None) -> NDArray[np.generic]:
        """(N, COUNT) values of field i, in the field's type (dtype: the same bytes read as another type of the
        same size; binary layouts only)."""
        head, n, count = self.head, self.head.points, self.head.counts[i]
        if self.table is not None:
            column = head.column(i)
            return self.table[:, column:column + count]
        dt = head.dtype(i) if dtype is None else dtype
        if head.kind == "binary":
            return np.ndarray((n, count), dt, buffer=self.raw, offset=head.field_offset(i),
                              strides=(head.record_size, dt.itemsize))
        return np.frombuffer(self.raw, dt, count=n * count, offset=n * head.field_offset(i)).reshape(n, count)

    def packed_colour(self, i: int) -> NDArray[np.uint32]:
        """PCL's packed rgb/rgba word of every point (0xAARRGGBB): the 4 bytes of a binary field as uint32; in
        ASCII, PCL writes an F rgb as the integer of its bytes (Open3D writes the float): both are read."""
        if self.table is None:
            return self.field(i, np.dtype("<u4"))[:, 0].astype(np.uint32)
        values = self.field(i)[:, 0].astype(np.float64)
        if self.head.types[i] != "F":
            return np.clip(np.nan_to_num(values), 0, 2**32 - 1).astype(np.uint32)
        whole = np.isfinite(values) & (values >= 1) & (values == np.floor(values)) & (values < 2**32)
        bits = values.astype(np.float32).view(np.uint32)
        return np.where(whole, np.where(whole, values, 0).astype(np.uint32), bits).astype(np.uint32)


#: PCL's colour fields: one 4-byte word per point holding the colour (and alpha), packed.
_PACKED_COLOUR = ("rgb", "rgba")
_NORMALS = ("normal_x", "normal_y", "normal_z")


def _wanted(head: PcdHeader) -> dict[str, int]:
    """The fields read besides x, y, z, by name: normals (all three, COUNT 1), a packed colour (SIZE 4, COUNT 1),
    the kept scalars (COUNT 1; at most MAX_SCALARS).  Padding (`_`) and descriptors are skipped."""
    index = {name: head.fields.index(name) for name in dict.fromkeys(head.fields)}
    single = {name: i for name, i in index.items() if head.counts[i] == 1}
    out: dict[str, int] = {}
    if all(a in single for a in _NORMALS):
        out.update({a: single[a] for a in _NORMALS})
    colour = next((c for c in _PACKED_COLOUR if c in single and head.sizes[single[c]] == 4), None)
    if colour is not None:
        out[colour] = single[colour]
    scalars = [name for name in single if kept_scalar(name)][:MAX_SCALARS]
    out.update({name: single[name] for name in scalars})
    return out


def read_pcd(data: bytes) -> FileCloud:
    """Everything graspd uses of a PCD file (ascii, binary or binary_compressed) as PCL's reader takes it: x, y, z
    (float32, m), normal_x/y/z, the rgb/rgba colour, intensity/label/curvature, the VIEWPOINT position and, for
    an organised cloud (HEIGHT > 1), its (HEIGHT, WIDTH) with NaN pixels kept in pixel order.  Fields may come
    in any order, with padding (`_`) and COUNT > 1 (descriptors), which are skipped.

    The header and the data size are checked first (check_pcd_header), then numpy reads the fields from the
    layout FIELDS/SIZE/TYPE/COUNT declare: a file whose header lies is refused with a CloudError, never read short.
    """
    head = check_pcd_header(data)
    body = memoryview(data)[head.offset:]
    _check_sizes(body, head)
    wanted = _wanted(head)
    fields = _Fields(body, head, [*head.xyz(), *wanted.values()])
    points = np.empty((head.points, 3), np.float32)
    for k, i in enumerate(head.xyz()):
        points[:, k] = fields.field(i)[:, 0]
    normals = None
    if _NORMALS[0] in wanted:
        normals = np.empty((head.points, 3), np.float32)
        for k, name in enumerate(_NORMALS):
            normals[:, k] = fields.field(wanted[name])[:, 0]
    colour = next((c for c in _PACKED_COLOUR if c in wanted), None)
    colors = None if colour is None else colours_from_packed(fields.packed_colour(wanted[colour]))
    scalars = {name: np.array(fields.field(i)[:, 0]) for name, i in wanted.items()
               if name not in _NORMALS and name not in _PACKED_COLOUR}
    return FileCloud(points, normals, colors, scalars, head.viewpoint,
                     (head.height, head.width) if head.height > 1 else None)


def parse_pcd(data: bytes) -> tuple[NDArray[np.float32], NDArray[np.float32] | None]:
    """Points (N,3) float32 (metres, as the file holds them) and the VIEWPOINT translation (3,) of a PCD file
    (read_pcd without the other fields)."""
    cloud = read_pcd(data)
    return cloud.points, cloud.viewpoint
