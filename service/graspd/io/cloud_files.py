"""Readers for viewpoint clouds: PCD (graspd.io.pcd: ascii, binary, binary_compressed; VIEWPOINT header honoured;
organised ones too, their NaN pixels dropped and counted by graspd.io.inputs), PLY (graspd.io.ply: ascii and both
binary byte orders), NPY/NPZ and depth images (graspd.io.depth).  Headers are checked against themselves, the
data length and the caps before anything is allocated, so that a small file cannot declare gigabytes; then numpy
(or Pillow) reads the data: no open3d in the server."""

from __future__ import annotations

import io
from collections.abc import Sequence
from pathlib import Path
from typing import IO, Any

import numpy as np
from numpy.typing import NDArray

from graspd.core.camera import Intrinsics
from graspd.core.cloud import CloudError, ViewpointCloud
from graspd.io.depth import DEFAULT_DEPTH_SCALE, depth_metres, depth_points, read_depth_png
from graspd.io.inputs import CloudInput, cloud_input
from graspd.io.pcd import MAX_FILE_POINTS, MAX_PCD_EXPANSION, PcdHeader, check_pcd_header, parse_pcd
from graspd.io.ply import PlyHeader, check_ply, check_ply_header, parse_ply

__all__ = ["CLOUD_SUFFIXES", "MAX_FILE_POINTS", "MAX_NPY_VALUES", "MAX_PCD_EXPANSION", "NPZ_ARRAYS", "PcdHeader",
           "PlyHeader", "array_cloud", "check_pcd_header", "check_ply", "check_ply_header", "nearest_camera",
           "parse_npy", "parse_npz", "parse_pcd", "parse_ply", "read_cloud", "read_input", "save_npz"]


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
