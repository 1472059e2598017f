"""CDR bytes of a depth sensor_msgs/Image, its sensor_msgs/CameraInfo and tf2_msgs/TFMessage -> numpy, with the
bounded reader of graspd.io.ros.decode (every declared size checked against the bytes left before anything is
allocated; RosDecodeError naming the field).  A ROS 1 message is read once rosbags' ros1_to_cdr has made it the
ROS 2 message's CDR."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from graspd.core.camera import Intrinsics
from graspd.core.cloud import CloudError
from graspd.core.limits import MAX_POINTS
from graspd.io.ros.decode import CdrReader, RosDecodeError
from graspd.io.ros.types import Header

#: Depth encodings read (sensor_msgs/image_encodings): 16-bit millimetres, 32-bit float metres.
DEPTH_ENCODINGS = {"16UC1": "u2", "mono16": "u2", "32FC1": "f4"}
#: Most transforms one TFMessage may carry.
MAX_TRANSFORMS = 10_000


@dataclass(frozen=True)
class DepthImage:
    """A depth image (H,W) in metres (0: no depth) in header.frame_id, the camera's optical frame."""

    header: Header
    depth: NDArray[np.float32]


@dataclass(frozen=True)
class CameraInfo:
    """A CameraInfo's image size (pixels) and projection matrix P (3,4) and K (3,3)."""

    header: Header
    width: int
    height: int
    k: NDArray[np.float64]
    p: NDArray[np.float64]

    def intrinsics(self, field: str = "info_topic") -> Intrinsics:
        """fx, fy, cx, cy of P (depth_image_proc's choice for a rectified depth image), else of K when P is 0."""
        m = self.p if np.any(self.p[:, :3]) else self.k
        try:
            return Intrinsics.parse([m[0, 0], m[1, 1], m[0, 2], m[1, 2]], field)
        except CloudError as exc:
            raise RosDecodeError(field, f"the CameraInfo has no usable intrinsics ({exc.message})") from None


@dataclass(frozen=True)
class Transform:
    """One transform: the pose (4,4) of child_frame in parent_frame (p_parent = T p_child; m) at stamp (sec,
    nanosec: its header's)."""

    parent: str
    child: str
    matrix: NDArray[np.float64]
    stamp: tuple[int, int] = (0, 0)


def decode_depth_image(payload: bytes | bytearray | memoryview, depth_scale: float = 0.001,
                       field: str = "topic") -> DepthImage:
    """A depth sensor_msgs/Image (16UC1/mono16 in depth_scale metres a unit, default millimetres; 32FC1 in
    metres) -> (H,W) float32 metres."""
    r = CdrReader(payload)
    header = r.header("header")
    height, width = r.scalar("u4", "height"), r.scalar("u4", "width")
    encoding = r.string("encoding")
    bigendian = r.scalar("u1", "is_bigendian") != 0
    step = r.scalar("u4", "step")
    if encoding not in DEPTH_ENCODINGS:
        raise RosDecodeError(field, f"image encoding {encoding!r} is not depth (one of {sorted(DEPTH_ENCODINGS)})")
    if height * width > MAX_POINTS or height * width == 0:
        raise RosDecodeError(field, f"a {width}x{height} depth image (1 to {MAX_POINTS} pixels expected)")
    dt = np.dtype((">" if bigendian else "<") + DEPTH_ENCODINGS[encoding])
    if step < width * dt.itemsize:
        raise RosDecodeError(f"{field}.step", f"{step} < width x {dt.itemsize} bytes = {width * dt.itemsize}")
    n = r.count("data", 2**32, 1)
    if n < step * height:
        raise RosDecodeError(f"{field}.data", f"has {n} bytes; height x step = {height * step}")
    data = r.array("u1", n, "data")
    grid = np.ndarray((height, width), dt, buffer=data, strides=(step, dt.itemsize)).astype(np.float32)
    if dt.kind == "u":
        grid *= np.float32(depth_scale)
    return DepthImage(header, grid)


def decode_camera_info(payload: bytes | bytearray | memoryview) -> CameraInfo:
    """A sensor_msgs/CameraInfo -> its size, K and P."""
    r = CdrReader(payload)
    header = r.header("header")
    height, width = r.scalar("u4", "height"), r.scalar("u4", "width")
    r.string("distortion_model")
    r.array("f8", r.count("d", 64, 8), "d")
    k = np.array(r.array("f8", 9, "k"), np.float64).reshape(3, 3)
    r.array("f8", 9, "r")
    p = np.array(r.array("f8", 12, "p"), np.float64).reshape(3, 4)
    return CameraInfo(header, width, height, k, p)


def _quaternion_matrix(x: float, y: float, z: float, w: float) -> NDArray[np.float64]:
    """The rotation of a quaternion (normalised first; RosDecodeError when it is zero or not finite)."""
    q = np.array([x, y, z, w], np.float64)
    norm = float(np.linalg.norm(q))
    if not np.isfinite(norm) or norm < 1e-9:
        raise RosDecodeError("transforms.rotation", f"not a rotation quaternion: {q.tolist()}")
    x, y, z, w = (q / norm).tolist()
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def decode_tf_message(payload: bytes | bytearray | memoryview) -> list[Transform]:
    """A tf2_msgs/TFMessage -> its transforms (frame names without a leading '/', as tf2 has them)."""
    r = CdrReader(payload)
    n = r.count("transforms", MAX_TRANSFORMS, 4 + 8 + 4 + 4 + 56)
    out = []
    for i in range(n):
        header = r.header(f"transforms[{i}].header")
        child = r.string(f"transforms[{i}].child_frame_id")
        values = np.asarray(r.array("f8", 7, f"transforms[{i}].transform"), np.float64)
        if not np.isfinite(values).all():
            raise RosDecodeError(f"transforms[{i}].transform", "must be finite")
        matrix = np.eye(4)
        matrix[:3, :3] = _quaternion_matrix(*values[3:].tolist())
        matrix[:3, 3] = values[:3]
        out.append(Transform(header.frame_id.lstrip("/"), child.lstrip("/"), matrix, header.stamp))
    return out
