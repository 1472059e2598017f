"""PCD files (PCL's point cloud format): the header checked against itself, the caps and the data length before
anything is allocated (a small file cannot declare gigabytes), then x, y, z read with numpy from every layout PCL
writes: `ascii` (graspd.io.text_numbers: C speed), `binary` (records of FIELDS/SIZE/TYPE/COUNT, little-endian) and
`binary_compressed` (LZF, graspd.io.lzf; one block per field).  Organised clouds keep their NaN pixels in pixel
order: graspd.io.inputs drops and counts them."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from graspd.core.cloud import CloudError
from graspd.core.limits import MAX_POINTS
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

    def xyz(self) -> list[int]:
        """Index in fields of x, y and z (the first of each name)."""
        return [self.fields.index(a) for a in "xyz"]

    def dtype(self, i: int) -> np.dtype[np.number]:
        """numpy dtype of one value of field i (little-endian, as PCL writes on every platform it runs on)."""
        return np.dtype(f"<{_PCD_KINDS[self.types[i]]}{self.sizes[i]}")


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
                     tuple(counts))


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


def _ascii_xyz(body: memoryview, head: PcdHeader) -> NDArray[np.float32]:
    """x, y, z of ASCII data: every row must hold values_per_point numbers (blank lines skipped), POINTS rows."""
    n, width = head.points, head.values_per_point
    text = bytes(body)
    rows = line_counts(text)  # the table's shape first: a file of the wrong one is refused before parsing
    if rows.size and (rows != rows[0]).any():
        raise CloudError("cloud.points", f"pcd ascii data unreadable (its rows hold {rows.min()} to {rows.max()} "
                         "values)")
    if rows.size != n or (n and rows[0] != width):
        raise CloudError("cloud.points", f"pcd header declares {n} points of {width} values; the data holds "
                         f"{rows.size} rows of {rows[0] if rows.size else 0}")
    try:  # parsed as float32: numpy rounds strtod's float64 once more, as a float64 parse then a cast would
        values = parse_numbers(text, n * width, np.float32)
    except ValueError as exc:
        raise CloudError("cloud.points", f"pcd ascii data unreadable ({exc})") from None
    columns = [sum(head.counts[:i]) for i in head.xyz()]  # where each coordinate sits in a row
    return values.reshape(n, width)[:, columns].astype(np.float32, copy=False)


def _binary_xyz(body: memoryview, head: PcdHeader) -> NDArray[np.float32]:
    """x, y, z of binary data: POINTS records of record_size bytes, read through a dtype of the three fields."""
    offsets = [sum(s * c for s, c in zip(head.sizes[:i], head.counts[:i], strict=True)) for i in head.xyz()]
    layout = np.dtype({"names": ["x", "y", "z"], "formats": [head.dtype(i) for i in head.xyz()],
                       "offsets": offsets, "itemsize": head.record_size})
    records = np.frombuffer(body, layout, count=head.points)
    out = np.empty((head.points, 3), np.float32)
    for k, a in enumerate("xyz"):
        out[:, k] = records[a]
    return out


def _compressed_xyz(body: memoryview, head: PcdHeader) -> NDArray[np.float32]:
    """x, y, z of binary_compressed data: LZF expands to one block per field (all points' values of the first
    field, then the second's, ...)."""
    n = head.points
    try:
        compressed = int(np.frombuffer(body[:4], "<u4")[0])  # older PCL writers leave bytes after the block
        raw = lzf_decompress(bytes(body[8:8 + compressed]), n * head.record_size)
    except LzfError as exc:
        raise CloudError("cloud.points", f"pcd binary_compressed data unreadable ({exc})") from None
    out = np.empty((n, 3), np.float32)
    for k, i in enumerate(head.xyz()):
        start = n * sum(s * c for s, c in zip(head.sizes[:i], head.counts[:i], strict=True))
        out[:, k] = np.frombuffer(raw, head.dtype(i), count=n, offset=start)
    return out


def parse_pcd(data: bytes) -> tuple[NDArray[np.float32], NDArray[np.float32] | None]:
    """Points (N,3) float32 (metres, as the file holds them) and the VIEWPOINT translation (3,) of a PCD file
    (ascii, binary or binary_compressed).

    The header and the data size are checked first (check_pcd_header), then numpy reads x, y, z from the layout
    FIELDS/SIZE/TYPE/COUNT declare: a file whose header lies is refused with a CloudError, never read short.
    """
    head = check_pcd_header(data)
    body = memoryview(data)[head.offset:]
    _check_sizes(body, head)
    if head.kind == "ascii":
        points = _ascii_xyz(body, head)
    elif head.kind == "binary":
        points = _binary_xyz(body, head)
    else:
        points = _compressed_xyz(body, head)
    return points, head.viewpoint
