"""Readers for viewpoint clouds: PCD (ascii, binary, binary_compressed; VIEWPOINT header honoured), PLY and
NPZ.  Headers are checked against themselves, the data length and the caps before anything is allocated, so
that a small file cannot declare gigabytes; then open3d reads the file."""

from __future__ import annotations

import io
import tempfile
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from .cloud import CloudError, ViewpointCloud

#: The most points a PCD or PLY file may declare (the /detect cloud cap, graspd.server.schemas.MAX_POINTS).
MAX_FILE_POINTS = 5_000_000
#: A binary_compressed PCD may expand at most this much (PCL's LZF on real clouds gives ~1-4x; more is a bomb).
MAX_PCD_EXPANSION = 32
_MAX_PCD_HEADER = 64 << 10  # bytes: PCL's headers are a few hundred
_MAX_PCD_FIELDS = 256
_MAX_PCD_COUNT = 4096  # values per field (PCL descriptors such as FPFH use 33, SHOT 352)
_PCD_SIZES = {"F": (4, 8), "I": (1, 2, 4, 8), "U": (1, 2, 4, 8)}


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
    return PcdHeader(fields, record, sum(counts), points, kind, offset, viewpoint)


def _check_pcd_data(data: bytes, head: PcdHeader) -> None:
    """The data section holds exactly what the header declares (open3d would read past, pad or stop short)."""
    body = memoryview(data)[head.offset:]
    n = head.points
    if head.kind == "binary":
        if len(body) != n * head.record_size:
            raise CloudError("cloud.points", f"pcd header declares {n} points of {head.record_size} bytes "
                             f"({n * head.record_size} bytes); the data holds {len(body)} bytes")
    elif head.kind == "binary_compressed":
        if len(body) < 8:
            raise CloudError("cloud.points", "pcd binary_compressed data lacks its two size words")
        compressed, uncompressed = np.frombuffer(body[:8], "<u4").tolist()
        if compressed != len(body) - 8:
            raise CloudError("cloud.points", f"pcd binary_compressed declares {compressed} compressed bytes; "
                             f"the data holds {len(body) - 8}")
        if uncompressed != n * head.record_size:
            raise CloudError("cloud.points", f"pcd binary_compressed declares {uncompressed} bytes uncompressed; "
                             f"{n} points of {head.record_size} bytes take {n * head.record_size}")
        if uncompressed > MAX_PCD_EXPANSION * max(compressed, 1):
            raise CloudError("cloud.points", f"pcd binary_compressed expands {compressed} bytes to {uncompressed} "
                             f"(more than {MAX_PCD_EXPANSION}x)")
    else:  # numpy's C reader checks every value is a number and every row has the same count
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", UserWarning)  # "input contained no data"
                table = np.loadtxt(io.BytesIO(body), dtype=np.float64, ndmin=2, comments=None)
        except ValueError as exc:
            raise CloudError("cloud.points", f"pcd ascii data unreadable ({exc})") from None
        if table.shape != (n, head.values_per_point):
            raise CloudError("cloud.points", f"pcd header declares {n} points of {head.values_per_point} values; "
                             f"the data holds {table.shape[0]} rows of {table.shape[1]}")


def parse_pcd(data: bytes) -> tuple[NDArray[np.float32], NDArray[np.float32] | None]:
    """Points (N,3) and the VIEWPOINT translation (3,) of a PCD file (ascii, binary or binary_compressed).

    The header and the data size are checked first (check_pcd_header), then open3d reads the file and its
    point count is checked again: a file whose header lies is refused with a CloudError, never read short.
    """
    head = check_pcd_header(data)
    _check_pcd_data(data, head)
    import open3d as o3d  # noqa: PLC0415

    o3d.utility.set_verbosity_level(o3d.utility.VerbosityLevel.Error)
    with tempfile.NamedTemporaryFile(suffix=".pcd") as tmp:
        tmp.write(data)
        tmp.flush()
        cloud = o3d.t.io.read_point_cloud(Path(tmp.name), format="pcd")
    if "positions" not in cloud.point:
        raise CloudError("cloud.points", f"open3d read no points from the {head.kind} pcd data")
    xyz = cloud.point.positions.numpy()
    if xyz.shape != (head.points, 3):
        raise CloudError("cloud.points", f"pcd header declares {head.points} points; open3d read {len(xyz)}")
    return xyz.astype(np.float32, copy=False), head.viewpoint


_PLY_SIZES = {"char": 1, "uchar": 1, "int8": 1, "uint8": 1, "short": 2, "ushort": 2, "int16": 2, "uint16": 2,
              "int": 4, "uint": 4, "int32": 4, "uint32": 4, "float": 4, "float32": 4, "double": 8, "float64": 8}
_PLY_FORMATS = ("ascii", "binary_little_endian", "binary_big_endian")
_MAX_PLY_HEADER = 64 << 10  # bytes


def check_ply(data: bytes) -> int:
    """The vertex count a PLY header declares, after checking every declared count against the caps and the
    data length (before open3d allocates anything: it reserves the declared count, and pads a short file
    with zeros).  A `property list` row takes at least its count's bytes, so a list bomb is refused too."""
    if not data.startswith(b"ply"):
        raise CloudError("cloud.points", "a PLY file must start with 'ply'")
    end = data.find(b"end_header", 0, _MAX_PLY_HEADER)
    if end < 0:
        raise CloudError("cloud.points", f"the PLY header has no end_header in its first {_MAX_PLY_HEADER} bytes")
    newline = data.find(b"\n", end)
    body = memoryview(data)[newline + 1 :] if newline >= 0 else memoryview(b"")
    fmt = ""
    elements: list[tuple[str, int, list[list[str]]]] = []  # name, declared count, properties
    for line in data[:end].decode("ascii", errors="replace").splitlines():
        parts = line.split()
        if parts[:1] == ["format"] and len(parts) > 1:
            fmt = parts[1]
        elif parts[:1] == ["element"]:
            if len(parts) != 3 or not parts[2].isdigit() or len(parts[2]) > 12:
                raise CloudError("cloud.points", f"PLY element line {line.strip()!r} needs a name and a "
                                 f"non-negative integer count")
            elements.append((parts[1], int(parts[2]), []))
        elif parts[:1] == ["property"] and elements:
            prop = parts[1:]
            known = (len(prop) == 2 and prop[0] in _PLY_SIZES) or (
                len(prop) == 4 and prop[0] == "list" and prop[1] in _PLY_SIZES and prop[2] in _PLY_SIZES)
            if not known:
                raise CloudError("cloud.points", f"PLY property line {line.strip()!r} is not understood")
            elements[-1][2].append(prop)
    if fmt not in _PLY_FORMATS:
        raise CloudError("cloud.points", f"PLY format {fmt!r} is not one of {list(_PLY_FORMATS)}")
    vertex = [e for e in elements if e[0] == "vertex"]
    if not vertex:
        raise CloudError("cloud.points", "the PLY header declares no vertex element")
    count, props = vertex[0][1], vertex[0][2]
    if count > MAX_FILE_POINTS:
        raise CloudError("cloud.points", f"the PLY header declares {count} vertices, more than the limit of "
                         f"{MAX_FILE_POINTS}")
    if count == 0:
        raise CloudError("cloud.points", "the PLY header declares 0 vertices; send at least one point")
    names = [p[-1] for p in props]
    if not {"x", "y", "z"} <= set(names):
        raise CloudError("cloud.points", f"the PLY vertex element lacks x, y or z (has {names})")
    if fmt == "ascii":  # at least one line per declared row of every element; vertex rows checked value by value
        lines = bytes(body).split(b"\n")
        total = sum(e[1] for e in elements)
        start = sum(e[1] for e in elements[: elements.index(vertex[0])])
        rows = [r for r in lines[start : start + count] if r.strip()]
        if len(lines) < total or len(rows) < count or any(len(r.split()) < len(props) for r in rows):
            raise CloudError("cloud.points", f"the PLY header declares {count} vertices of {len(props)} values; "
                             f"the file holds fewer")
    else:  # binary: every element row takes at least its fixed-size properties plus each list's count
        least = sum(e[1] * sum(_PLY_SIZES[p[1]] if p[0] == "list" else _PLY_SIZES[p[0]] for p in e[2])
                    for e in elements)
        if len(body) < least:
            raise CloudError("cloud.points", f"the PLY header declares {count} vertices (with its other elements "
                             f"at least {least} bytes); the file holds {len(body)} bytes")
    return count


def parse_ply(data: bytes) -> NDArray[np.float32]:
    """Vertex positions (N,3) of a PLY file (ASCII or binary), read with open3d; a file holding fewer
    vertices than its header declares is refused."""
    declared = check_ply(data)
    import open3d as o3d  # noqa: PLC0415 - after the check: nothing is allocated for a file that lies

    with tempfile.NamedTemporaryFile(suffix=".ply") as tmp:
        tmp.write(data)
        tmp.flush()
        pcd = o3d.io.read_point_cloud(Path(tmp.name), format="ply")
    points = np.asarray(pcd.points, np.float32)
    if len(points) != declared:
        raise CloudError("cloud.points", f"the PLY header declares {declared} vertices, the file holds {len(points)}")
    return points


def read_cloud(path: str | Path, viewpoints: NDArray[np.floating] | None = None) -> ViewpointCloud:
    """A ViewpointCloud from .pcd, .ply or .npz.

    Camera positions come, in order of precedence, from `viewpoints`, from the file (PCD VIEWPOINT
    header; NPZ `viewpoints` and `camera_source` arrays), else the origin (a camera-frame cloud).
    """
    path = Path(path)
    suffix = path.suffix.lower()
    source: NDArray[np.int32] | None = None
    normals = None
    file_vp: NDArray[np.float32] | None = None
    if suffix == ".pcd":
        points, file_vp = parse_pcd(path.read_bytes())
    elif suffix == ".ply":
        points = parse_ply(path.read_bytes())
    elif suffix == ".npz":
        with np.load(path) as z:
            if "points" not in z:
                raise CloudError("cloud.points", "npz: needs an array named 'points'")
            points = z["points"]
            file_vp = z["viewpoints"] if "viewpoints" in z else None
            source = z["camera_source"] if "camera_source" in z else None
            normals = z["normals"] if "normals" in z else None
    else:
        raise CloudError("cloud", f"unsupported cloud file type {suffix!r} (use .pcd, .ply or .npz)")
    vps = viewpoints if viewpoints is not None else file_vp
    if vps is None:
        vps = np.zeros((1, 3), np.float32)
    vps = np.asarray(vps, np.float32).reshape(-1, 3)
    if source is None and len(vps) > 1:
        source = nearest_camera(points, vps)
    return ViewpointCloud(
        points=points,
        viewpoints=vps,
        camera_source=np.zeros(0, np.int32) if source is None else source,
        normals=normals,
    )


def nearest_camera(points: NDArray[np.floating], viewpoints: NDArray[np.floating]) -> NDArray[np.int32]:
    """Index of the closest camera for each point: a stand-in when a merged cloud lost its sources."""
    d = np.linalg.norm(np.asarray(points)[:, None, :] - np.asarray(viewpoints)[None, :, :], axis=2)
    return np.argmin(d, axis=1).astype(np.int32)


def save_npz(path: str | Path, cloud: ViewpointCloud) -> None:
    """Write a cloud as .npz (points, viewpoints, camera_source, optional normals)."""
    arrays = {"points": cloud.points, "viewpoints": cloud.viewpoints, "camera_source": cloud.camera_source}
    if cloud.normals is not None:
        arrays["normals"] = cloud.normals
    np.savez_compressed(path, **arrays)  # type: ignore[arg-type]
