"""Depth images as clouds: a 16-bit PNG in millimetres (what ROS depth drivers and OpenCV write, depth_scale
0.001 m a unit) or a float32 array in metres (an integer array: depth_scale units), with pinhole intrinsics (fx,
fy, cx, cy: ROS CameraInfo K, pixel centres at integer coordinates), back-projected by the project's one camera
model (graspd.core.camera.backproject) into the camera's optical frame (x right, y down, z forward; m).

Pixels without depth (0, the drivers' mark) are not points and are left out silently; NaN or infinite depths
become non-finite rows, dropped and counted like every other input's (graspd.io.inputs).  With a camera pose
(camera-to-robot) the cloud is a camera-frame cloud of one camera: the request's camera_poses with points_frame
"camera".
"""

from __future__ import annotations

import io

import numpy as np
from numpy.typing import NDArray

from graspd.core.camera import Intrinsics, backproject
from graspd.core.cloud import CloudError
from graspd.core.limits import MAX_POINTS

#: Most pixels a depth image may have (the cloud cap: one point a pixel).
MAX_DEPTH_PIXELS = MAX_POINTS
#: Metres per unit of a 16-bit depth PNG unless told otherwise (millimetres: ROS 16UC1, OpenCV, RealSense).
DEFAULT_DEPTH_SCALE = 0.001
PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def check_depth(depth: NDArray[np.generic], field: str = "body") -> NDArray[np.float32]:
    """A depth image (H,W) as float32 metres, checked: 2-D, numbers, at most MAX_DEPTH_PIXELS, some depth."""
    if depth.ndim != 2 or min(depth.shape) < 1:
        raise CloudError(field, f"a depth image (H, W) expected, got shape {depth.shape}")
    if depth.dtype.kind not in "fiu":
        raise CloudError(field, f"a numeric depth image expected, got dtype {depth.dtype}")
    if depth.size > MAX_DEPTH_PIXELS:
        raise CloudError(field, f"{depth.shape[1]}x{depth.shape[0]} pixels exceeds the limit of {MAX_DEPTH_PIXELS}")
    return np.asarray(depth, np.float32)


def depth_metres(image: NDArray[np.generic], depth_scale: float = DEFAULT_DEPTH_SCALE,
                 field: str = "body") -> NDArray[np.float32]:
    """A depth array (.npy) in metres: float values are metres already; integer values (a 16UC1 image saved as
    it is) are units of depth_scale metres (default millimetres), as in a depth PNG."""
    depth = check_depth(image, field)
    if image.dtype.kind in "iu":
        if not (np.isfinite(depth_scale) and depth_scale > 0):
            raise CloudError("depth_scale", f"a positive number of metres per unit expected, got {depth_scale!r}")
        return depth * np.float32(depth_scale)
    return depth


def read_depth_png(data: bytes, depth_scale: float = DEFAULT_DEPTH_SCALE, field: str = "body") -> NDArray[np.float32]:
    """A 16-bit single-channel PNG (or 32-bit integer) of depths in units of depth_scale metres -> (H,W) float32
    metres.  The size is checked before any pixel is decoded; an 8-bit or colour PNG is refused (it holds no
    depth)."""
    from PIL import Image  # noqa: PLC0415 - Pillow only when a PNG comes

    if not data.startswith(PNG_MAGIC):
        raise CloudError(field, "not a PNG (bad signature)")
    if not (np.isfinite(depth_scale) and depth_scale > 0):
        raise CloudError("depth_scale", f"a positive number of metres per unit expected, got {depth_scale!r}")
    try:
        with Image.open(io.BytesIO(data), formats=["PNG"]) as img:
            width, height = img.size
            if width * height > MAX_DEPTH_PIXELS:
                raise CloudError(field, f"{width}x{height} pixels exceeds the limit of {MAX_DEPTH_PIXELS}")
            if img.mode not in ("I;16", "I;16B", "I;16L", "I"):
                raise CloudError(field, f"a 16-bit single-channel depth PNG expected (millimetres), got mode "
                                 f"{img.mode!r}; colour and 8-bit images hold no depth")
            img.load()
            raw = np.asarray(img)
    except CloudError:
        raise
    except (OSError, SyntaxError, ValueError, Image.DecompressionBombError) as exc:
        raise CloudError(field, f"unreadable PNG ({exc})") from None
    return check_depth(raw, field) * np.float32(depth_scale)


def depth_points(depth: NDArray[np.floating], intrinsics: Intrinsics) -> NDArray[np.float32]:
    """The points (N,3) of a depth image (H,W, metres) in the camera's optical frame, row-major over the pixels
    that have depth (non-zero; NaN and infinite depths kept, as non-finite rows for graspd.io.inputs to count)."""
    z = check_depth(np.asarray(depth))
    has_depth = z != 0
    if not has_depth.any():
        raise CloudError("body", "the depth image has no pixel with depth (all 0)")
    points = backproject(z, intrinsics.fx, intrinsics.fy, intrinsics.cx, intrinsics.cy)
    return points[has_depth]


def depth_pixels(depth: NDArray[np.floating]) -> NDArray[np.int64]:
    """The row-major pixel index of each point depth_points gives (the pixels with depth, in its order): with the
    image's (H, W), the grid of the organised cloud (graspd.core.cloud.CloudGrid)."""
    return np.flatnonzero(np.asarray(depth).reshape(-1) != 0)
