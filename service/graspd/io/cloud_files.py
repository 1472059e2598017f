"""Readers for viewpoint clouds: PCD (graspd.io.pcd: ascii, binary, binary_compressed; VIEWPOINT header honoured;
organised ones too, their NaN pixels dropped and counted by graspd.io.inputs), PLY (graspd.io.ply: ascii and both
binary byte orders), NPY/NPZ and depth images (graspd.io.depth).  Headers are checked against themselves, the
data length and the caps before anything is allocated, so that a small file cannot declare gigabytes; then numpy
(or Pillow) reads the data: no open3d in the server."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from graspd.core.camera import Intrinsics
from graspd.core.cloud import CloudError, ViewpointCloud
from graspd.io.calibration import CameraCalibration
from graspd.io.camera_source import nearest_camera
from graspd.io.depth import DEFAULT_DEPTH_SCALE, depth_metres, depth_pixels, depth_points, read_depth_png
from graspd.io.file_cloud import FileCloud
from graspd.io.inputs import CloudInput, cloud_input
from graspd.io.npy import NPY_MAGIC, parse_npy_bytes
from graspd.io.npz import MAX_NPZ_BYTES, NPZ_ARRAYS, ZIP_MAGIC, parse_npz
from graspd.io.pcd import MAX_FILE_POINTS, MAX_PCD_EXPANSION, PcdHeader, check_pcd_header, parse_pcd, read_pcd
from graspd.io.ply import PlyHeader, check_ply, check_ply_header, parse_ply, read_ply

__all__ = ["CLOUD_SUFFIXES", "MAX_FILE_POINTS", "MAX_NPY_VALUES", "MAX_NPZ_BYTES", "MAX_PCD_EXPANSION", "NPY_MAGIC",
           "NPZ_ARRAYS", "ZIP_MAGIC", "FileCloud", "PcdHeader", "PlyHeader", "array_cloud", "check_pcd_header",
           "check_ply", "check_ply_header", "depth_cloud", "file_arrays", "image_arrays", "nearest_camera", "parse_npy",
           "parse_npz", "parse_pcd", "parse_ply", "read_cloud", "read_input", "read_pcd", "read_ply", "save_npz"]


# ---- numpy files: .npy (one array, graspd.io.npy) and .npz (named arrays, graspd.io.npz) -----------------

#: The most values an .npy array may hold: an (N,3) cloud or an (H,W) depth image at the caps.
MAX_NPY_VALUES = 3 * MAX_FILE_POINTS


def parse_npy(data: bytes, field: str = "body") -> NDArray[Any]:
    """The array of .npy bytes: header checked first (numbers only, no pickles, at most MAX_NPY_VALUES values),
    the data length exact; CloudError naming field in plain words otherwise (graspd.io.npy)."""
    return parse_npy_bytes(data, MAX_NPY_VALUES, field)


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


def file_arrays(cloud: FileCloud) -> dict[str, Any]:
    """The detector's arrays of a PCD or PLY file: points, the header's camera position, the file's normals when
    they are usable (FileCloud.usable_normals: otherwise the detector estimates them), and an organised cloud's
    shape [height, width] (cloud.shape; absent when unorganised)."""
    arrays: dict[str, Any] = {"points": cloud.points, "normals": cloud.usable_normals(),
                              "viewpoints": None if cloud.viewpoint is None else cloud.viewpoint.reshape(1, 3)}
    if cloud.shape is not None:
        arrays["shape"] = cloud.shape
    return arrays


def depth_cloud(depth: NDArray[np.float32], intrinsics: Sequence[float] | CameraCalibration,
                field: str = "intrinsics") -> NDArray[np.float32]:
    """The points of a depth image (H,W, m) with intrinsics: 4 numbers fx, fy, cx, cy, or a camera's calibration
    (graspd.io.calibration: its size must be the image's)."""
    if isinstance(intrinsics, CameraCalibration):
        intrinsics.check_image(depth.shape[1], depth.shape[0], field)
        return depth_points(depth, intrinsics.intrinsics(field))
    return depth_points(depth, Intrinsics.parse(intrinsics, field))


def image_arrays(data: bytes, kind: str, intrinsics: Sequence[float] | CameraCalibration | None = None,
                 depth_scale: float = DEFAULT_DEPTH_SCALE) -> dict[str, Any]:
    """The cloud arrays of an .npy ("npy") or 16-bit depth PNG ("png") file: with intrinsics a depth image's points
    (camera frame, m; pixels without depth left out), its grid "shape" and each point's "pixel", and "depth": True;
    without, an .npy's (N,3) points or organised (H,W,3) cloud with its "shape".  CloudError naming what is wrong."""
    image = parse_npy(data) if kind == "npy" else None
    if intrinsics is None:
        if image is None:
            raise CloudError("intrinsics", "a depth PNG needs the camera's intrinsics fx, fy, cx, cy (pixels)")
        arrays: dict[str, Any] = {"points": array_cloud(image)}
        if image.ndim == 3:
            arrays["shape"] = image.shape[:2]
        return arrays
    depth = read_depth_png(data, depth_scale) if image is None else depth_metres(image, depth_scale)
    return {"points": depth_cloud(depth, intrinsics), "shape": depth.shape, "pixel": depth_pixels(depth),
            "depth": True}


def read_input(path: str | Path, viewpoints: NDArray[np.floating] | None = None, *,
               camera_poses: object = None, points_frame: str | None = None,
               intrinsics: Sequence[float] | CameraCalibration | None = None,
               depth_scale: float = DEFAULT_DEPTH_SCALE) -> CloudInput:
    """The detector's cloud from a file, as the service makes it of the same upload (graspd.io.inputs.cloud_input:
    non-finite rows dropped and counted, camera poses applied).

    .pcd, .ply: points; .npz: points plus optional viewpoints, camera_source, normals, camera_poses, shape;
    .npy: (N,3) points, an organised (H,W,3) cloud, or with intrinsics an (H,W) depth image (float: metres;
    integer: depth_scale units); .png: a 16-bit depth image (depth_scale metres a unit, default millimetres)
    with intrinsics (fx, fy, cx, cy, or the camera's calibration, graspd.io.calibration).  Organised inputs (PCD
    with HEIGHT > 1, (H,W,3), depth images) keep their grid (ViewpointCloud.grid).  A PCD's or PLY's normals are
    used when usable (FileCloud.usable_normals).  A depth image is in its camera's optical frame; a camera pose
    (one) makes it points_frame "camera".  Camera positions come, in order of precedence, from `viewpoints`,
    from the file (PCD VIEWPOINT header; NPZ viewpoints), else the origin (a camera-frame cloud)."""
    path = Path(path)
    suffix = path.suffix.lower()
    data = path.read_bytes()
    arrays: dict[str, Any] = {}
    if suffix in (".pcd", ".ply"):
        arrays = file_arrays(read_pcd(data) if suffix == ".pcd" else read_ply(data))
    elif suffix == ".npz":
        arrays = dict(parse_npz(data))
    elif suffix in (".npy", ".png"):
        arrays = image_arrays(data, suffix[1:], intrinsics, depth_scale)
        if arrays.get("depth"):
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
                       points_frame=points_frame, shape=_shape(arrays.get("shape")), pixel=arrays.get("pixel"))


def _shape(shape: Any) -> tuple[int, int] | None:
    """An organised cloud's (height, width) as two ints (an .npz member is an array), None when not given."""
    if shape is None:
        return None
    values = np.asarray(shape).reshape(-1)
    if len(values) != 2 or not np.all(values == np.round(values)):
        raise CloudError("cloud.shape", f"[height, width] expected, got {values.tolist()}")
    return int(values[0]), int(values[1])


def read_cloud(path: str | Path, viewpoints: NDArray[np.floating] | None = None) -> ViewpointCloud:
    """A ViewpointCloud from .pcd, .ply, .npz or .npy (read_input, without frames): rows with a NaN or infinite
    coordinate are dropped (read_input also counts them)."""
    return read_input(path, viewpoints).cloud


def save_npz(path: str | Path, cloud: ViewpointCloud) -> None:
    """Write a cloud as .npz (points, viewpoints, camera_source, optional normals; not the grid, whose shape
    counts the dropped pixels too)."""
    arrays = {"points": cloud.points, "viewpoints": cloud.viewpoints, "camera_source": cloud.camera_source}
    if cloud.normals is not None:
        arrays["normals"] = cloud.normals
    np.savez_compressed(path, **arrays)  # type: ignore[arg-type]
