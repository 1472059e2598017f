"""Readers for viewpoint clouds: PCD (ASCII/binary, VIEWPOINT header honoured), PLY and NPZ."""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from .cloud import CloudError, ViewpointCloud

_PCD_TYPES = {("F", 4): "<f4", ("F", 8): "<f8", ("I", 1): "<i1", ("I", 2): "<i2", ("I", 4): "<i4",
              ("I", 8): "<i8", ("U", 1): "<u1", ("U", 2): "<u2", ("U", 4): "<u4", ("U", 8): "<u8"}


def _pcd_header(data: bytes) -> tuple[dict[str, list[str]], int]:
    """PCD header fields and the byte offset where the data starts."""
    header: dict[str, list[str]] = {}
    offset = 0
    while True:
        end = data.find(b"\n", offset)
        if end < 0:
            raise CloudError("pcd: header ends before DATA")
        line = data[offset:end].decode("ascii", errors="replace").strip()
        offset = end + 1
        if not line or line.startswith("#"):
            continue
        key, *values = line.split()
        header[key.upper()] = values
        if key.upper() == "DATA":
            return header, offset


def parse_pcd(data: bytes) -> tuple[NDArray[np.float32], NDArray[np.float32] | None]:
    """Points (N,3) and the VIEWPOINT translation (3,) if the header gives a non-default one."""
    header, offset = _pcd_header(data)
    try:
        fields = [f.lower() for f in header["FIELDS"]]
        sizes = [int(s) for s in header["SIZE"]]
        types = header["TYPE"]
        counts = [int(c) for c in header.get("COUNT", ["1"] * len(fields))]
        npoints = int(header["POINTS"][0])
        kind = header["DATA"][0].lower()
    except (KeyError, IndexError, ValueError) as exc:
        raise CloudError(f"pcd: malformed header ({exc})") from None
    if not {"x", "y", "z"} <= set(fields):
        raise CloudError("pcd: FIELDS must include x y z")
    dtype = np.dtype([(f"{name}_{i}" if c > 1 else name, _PCD_TYPES[(t, s)], (c,) if c > 1 else ())
                      for i, (name, t, s, c) in enumerate(zip(fields, types, sizes, counts, strict=True))])
    if kind == "ascii":
        table = np.loadtxt(io.BytesIO(data[offset:]), dtype=np.float64, ndmin=2)
        cols = np.cumsum([0, *counts])
        xyz = np.stack([table[:, cols[fields.index(a)]] for a in "xyz"], axis=1)
    elif kind == "binary":
        raw = np.frombuffer(data, dtype=dtype, count=npoints, offset=offset)
        xyz = np.stack([raw[a].astype(np.float64) for a in "xyz"], axis=1)
    else:
        raise CloudError(f"pcd: DATA {kind!r} is not supported (use ascii or binary)")
    viewpoint = None
    if "VIEWPOINT" in header:
        vp = np.array([float(v) for v in header["VIEWPOINT"][:3]], np.float32)
        viewpoint = vp
    return xyz.astype(np.float32), viewpoint


_PLY_SIZES = {"char": 1, "uchar": 1, "int8": 1, "uint8": 1, "short": 2, "ushort": 2, "int16": 2, "uint16": 2,
              "int": 4, "uint": 4, "int32": 4, "uint32": 4, "float": 4, "float32": 4, "double": 8, "float64": 8}


def check_ply(data: bytes) -> int:
    """The vertex count a PLY header declares, after checking the body holds that many vertices
    (open3d silently pads a truncated file with zeros)."""
    if not data.startswith(b"ply"):
        raise CloudError("cloud.points: a PLY file must start with 'ply'")
    end = data.find(b"end_header")
    if end < 0:
        raise CloudError("cloud.points: the PLY header has no end_header")
    body = data[data.find(b"\n", end) + 1 :]
    fmt, count, props, element = "", -1, [], ""
    for line in data[:end].decode("ascii", errors="replace").splitlines():
        parts = line.split()
        if parts[:1] == ["format"] and len(parts) > 1:
            fmt = parts[1]
        elif parts[:1] == ["element"] and len(parts) == 3:
            element = parts[1]
            if element == "vertex":
                try:
                    count = int(parts[2])
                except ValueError:
                    break
        elif parts[:1] == ["property"] and element == "vertex":
            props.append(parts[1:])
    if count < 0:
        raise CloudError("cloud.points: the PLY header declares no vertex element")
    if fmt == "ascii":
        rows = [r for r in body.split(b"\n")[:count] if r.strip()]
        if len(rows) < count or any(len(r.split()) < len(props) for r in rows):
            raise CloudError(f"cloud.points: the PLY header declares {count} vertices of {len(props)} values; "
                             f"the file holds fewer")
    elif all(len(pr) == 2 and pr[0] in _PLY_SIZES for pr in props):
        size = sum(_PLY_SIZES[pr[0]] for pr in props)
        if len(body) < count * size:
            raise CloudError(f"cloud.points: the PLY header declares {count} vertices ({count * size} bytes); "
                             f"the file holds {len(body)} bytes")
    return count


def parse_ply(data: bytes) -> NDArray[np.float32]:
    """Vertex positions (N,3) of a PLY file (ASCII or binary), read with open3d; a file holding fewer
    vertices than its header declares is refused."""
    import tempfile

    import open3d as o3d

    declared = check_ply(data)

    with tempfile.NamedTemporaryFile(suffix=".ply") as tmp:
        tmp.write(data)
        tmp.flush()
        pcd = o3d.io.read_point_cloud(Path(tmp.name), format="ply")
    points = np.asarray(pcd.points, np.float32)
    if len(points) != declared:
        raise CloudError(f"cloud.points: the PLY header declares {declared} vertices, the file holds {len(points)}")
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
                raise CloudError("npz: needs an array named 'points'")
            points = z["points"]
            file_vp = z["viewpoints"] if "viewpoints" in z else None
            source = z["camera_source"] if "camera_source" in z else None
            normals = z["normals"] if "normals" in z else None
    else:
        raise CloudError(f"unsupported cloud file type {suffix!r} (use .pcd, .ply or .npz)")
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
