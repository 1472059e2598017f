"""Readers for viewpoint clouds: PCD (ascii, binary, binary_compressed; VIEWPOINT header honoured; organised ones
too, their NaN pixels dropped and counted by graspd.io.inputs), PLY, NPY/NPZ and depth images (graspd.io.depth).
Headers are checked against themselves, the data length and the caps before anything is allocated, so that a
small file cannot declare gigabytes; then open3d (or numpy, or Pillow) reads the file."""

from __future__ import annotations

import io
import tempfile
import warnings
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any

import numpy as np
from numpy.typing import NDArray

from graspd.core.camera import Intrinsics
from graspd.core.cloud import CloudError, ViewpointCloud
from graspd.core.limits import MAX_POINTS
from graspd.core.open3d_import import defer_plotly_drawing
from graspd.io.depth import DEFAULT_DEPTH_SCALE, depth_metres, depth_points, read_depth_png
from graspd.io.inputs import CloudInput, cloud_input

defer_plotly_drawing()  # open3d's dash/plotly drawing loads when used, not with open3d (~0.5 s of start-up)

#: The most points a PCD or PLY file may declare.
MAX_FILE_POINTS = MAX_POINTS
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


# ---- numpy files: .npy (one array) and .npz (named arrays) -------------------------------------------------

#: The arrays an .npz cloud may hold (others, such as colours, are ignored and never decompressed).
NPZ_ARRAYS = ("points", "viewpoints", "camera_source", "normals", "camera_poses")
NPY_MAGIC = b"\x93NUMPY"
ZIP_MAGIC = b"PK\x03\x04"
#: The most values an .npy array or an .npz member may hold: an (N,3) cloud or an (H,W) depth image at the caps.
MAX_NPY_VALUES = 3 * MAX_FILE_POINTS


def _npy_header(fp: io.BytesIO | IO[bytes], field: str) -> tuple[tuple[int, ...], np.dtype[Any]]:
    """(shape, dtype) of an .npy stream, checked before any data is read: numbers only (no pickled objects),
    at most MAX_NPY_VALUES values."""
    try:
        version = np.lib.format.read_magic(fp)
        if version == (1, 0):
            shape, fortran, dtype = np.lib.format.read_array_header_1_0(fp)
        else:
            shape, fortran, dtype = np.lib.format.read_array_header_2_0(fp)
    except Exception as exc:  # numpy's header parser raises ValueError, SyntaxError, tokenize.TokenError, ...
        raise CloudError(field, f"npy: unreadable header ({type(exc).__name__}: {exc})") from None
    if dtype.hasobject or dtype.kind not in "fiu" or dtype.fields is not None:
        raise CloudError(field, f"npy: numbers expected (float or integer), got dtype {dtype}")
    if int(np.prod(shape, dtype=np.float64)) > MAX_NPY_VALUES:
        raise CloudError(field, f"npy: shape {shape} exceeds the limit of {MAX_NPY_VALUES} values")
    return tuple(shape), dtype


def parse_npy(data: bytes, field: str = "body") -> NDArray[Any]:
    """The array of .npy bytes: header checked first (_npy_header), no pickles, the data length exact."""
    fp = io.BytesIO(data)
    shape, dtype = _npy_header(fp, field)
    need = int(np.prod(shape)) * dtype.itemsize
    if len(data) - fp.tell() != need:
        raise CloudError(field, f"npy: header declares {shape} {dtype} ({need} bytes); the file holds "
                         f"{len(data) - fp.tell()}")
    fp.seek(0)
    try:
        return np.asarray(np.load(fp, allow_pickle=False))
    except (ValueError, OSError, EOFError) as exc:
        raise CloudError(field, f"npy: unreadable ({exc})") from None


def parse_npz(data: bytes, field: str = "body") -> dict[str, NDArray[Any]]:
    """The NPZ_ARRAYS an .npz holds (each member's declared size and header checked before it is decompressed:
    a zip bomb is refused); 'points' is required."""
    import zipfile  # noqa: PLC0415
    import zlib  # noqa: PLC0415

    try:
        archive = zipfile.ZipFile(io.BytesIO(data))
    except (zipfile.BadZipFile, OSError, ValueError, NotImplementedError, RuntimeError) as exc:
        raise CloudError(field, f"npz: not a zip archive ({exc})") from None
    out: dict[str, NDArray[Any]] = {}
    with archive:
        members = {Path(info.filename).stem: info for info in archive.infolist() if info.filename.endswith(".npy")}
        if "points" not in members:
            raise CloudError("cloud.points", f"npz: needs an array named 'points' (has {sorted(members)})")
        for name in NPZ_ARRAYS:
            info = members.get(name)
            if info is None:
                continue
            if info.file_size > MAX_NPY_VALUES * 8 + 4096:
                raise CloudError(f"cloud.{name}", f"npz: {name} declares {info.file_size} bytes uncompressed, "
                                 "beyond the limit")
            try:
                raw = archive.read(info)
            except (zipfile.BadZipFile, OSError, ValueError, EOFError, NotImplementedError, RuntimeError,
                    zlib.error) as exc:  # corrupt, an unknown compression, encrypted
                raise CloudError(f"cloud.{name}", f"npz: {name} unreadable ({exc})") from None
            out[name] = parse_npy(raw, f"cloud.{name}")
    return out


def array_cloud(array: NDArray[Any], field: str = "body") -> NDArray[np.float32]:
    """Points (N,3) from an .npy array: (N,3), or an organised (H,W,3) cloud (rows kept in pixel order, NaN
    pixels included: graspd.io.inputs drops and counts them).  An (H,W) array is a depth image: CloudError naming
    intrinsics (it needs them)."""
    if array.ndim == 2 and array.shape[1] == 3:
        return np.asarray(array, np.float32)
    if array.ndim == 3 and array.shape[2] == 3:
        return np.asarray(array, np.float32).reshape(-1, 3)
    if array.ndim == 2:
        raise CloudError("intrinsics", f"a {array.shape[1]}x{array.shape[0]} array is a depth image: give the "
                         "camera's intrinsics fx, fy, cx, cy (pixels) to back-project it (or send (N,3) points)")
    raise CloudError(field, f"points (N,3), an organised cloud (H,W,3) or a depth image (H,W) expected, got shape "
                     f"{array.shape}")


CLOUD_SUFFIXES = (".pcd", ".ply", ".npz", ".npy", ".png")


def read_input(path: str | Path, viewpoints: NDArray[np.floating] | None = None, *,
               camera_poses: object = None, points_frame: str | None = None,
               intrinsics: Sequence[float] | None = None, depth_scale: float = DEFAULT_DEPTH_SCALE) -> CloudInput:
    """The detector's cloud from a file, as the service makes it of the same upload (graspd.io.inputs.cloud_input:
    non-finite rows dropped and counted, camera poses applied).

    .pcd, .ply: points; .npz: points plus optional viewpoints, camera_source, normals, camera_poses; .npy: (N,3)
    points, an organised (H,W,3) cloud, or with intrinsics an (H,W) depth image (float: metres; integer:
    depth_scale units); .png: a 16-bit
    depth image (depth_scale metres a unit, default millimetres) with intrinsics (fx, fy, cx, cy).  A depth image
    is in its camera's optical frame; a camera pose (one) makes it points_frame "camera".  Camera positions come,
    in order of precedence, from `viewpoints`, from the file (PCD VIEWPOINT header; NPZ viewpoints), else the
    origin (a camera-frame cloud)."""
    path = Path(path)
    suffix = path.suffix.lower()
    data = path.read_bytes()
    arrays: dict[str, Any] = {}
    if suffix == ".pcd":
        points, file_vp = parse_pcd(data)
        arrays = {"points": points, "viewpoints": file_vp}
    elif suffix == ".ply":
        arrays = {"points": parse_ply(data)}
    elif suffix == ".npz":
        arrays = dict(parse_npz(data))
    elif suffix in (".npy", ".png"):
        image = parse_npy(data) if suffix == ".npy" else None
        if intrinsics is None:
            if image is None:
                raise CloudError("intrinsics", "a depth PNG needs the camera's intrinsics fx, fy, cx, cy (pixels)")
            arrays = {"points": array_cloud(image)}
        else:
            depth = read_depth_png(data, depth_scale) if image is None else depth_metres(image, depth_scale)
            arrays = {"points": depth_points(depth, Intrinsics.parse(intrinsics))}
            points_frame = points_frame or ("camera" if camera_poses is not None else None)
    else:
        raise CloudError("cloud", f"unsupported cloud file type {suffix!r} (use {', '.join(CLOUD_SUFFIXES)})")
    if viewpoints is not None:
        arrays["viewpoints"] = viewpoints
    if camera_poses is not None:
        if "viewpoints" in arrays and viewpoints is None:
            arrays.pop("viewpoints")  # the file's own (a PCD VIEWPOINT header) gives way to the poses
        arrays["camera_poses"] = camera_poses
    vps = arrays.get("viewpoints")
    return cloud_input(arrays["points"], None if vps is None else np.asarray(vps, np.float32).reshape(-1, 3),
                       arrays.get("camera_source"), arrays.get("normals"), camera_poses=arrays.get("camera_poses"),
                       points_frame=points_frame)


def read_cloud(path: str | Path, viewpoints: NDArray[np.floating] | None = None) -> ViewpointCloud:
    """A ViewpointCloud from .pcd, .ply, .npz or .npy (read_input, without frames): rows with a NaN or infinite
    coordinate are dropped (read_input also counts them)."""
    return read_input(path, viewpoints).cloud


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
