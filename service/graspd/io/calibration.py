"""A camera's calibration as the YAML ROS camera drivers write it (camera_calibration_parsers: image_width,
image_height, camera_name, camera_matrix, distortion_model, distortion_coefficients, rectification_matrix,
projection_matrix; each matrix as {rows, cols, data}), read with PyYAML's safe_load under a size cap.

A depth image is back-projected with the projection matrix P's fx, fy, cx, cy, as ROS's depth_image_proc does
(depth images are rectified; P equals K for a camera without distortion), or with K when P is absent or zero.
Pixels, with pixel centres at integer coordinates; the camera's optical frame (x right, y down, z forward)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import yaml
from numpy.typing import NDArray

from graspd.core.camera import Intrinsics
from graspd.core.cloud import CloudError

#: Largest calibration text read (bytes): drivers write under 1 kB.
MAX_CALIBRATION_BYTES = 64 << 10
#: Largest image side a calibration may declare (pixels).
MAX_IMAGE_SIDE = 1 << 16


@dataclass(frozen=True)
class CameraCalibration:
    """A camera's calibration: image size (pixels), name, K (3,3), distortion model and coefficients, R (3,3),
    P (3,4)."""

    width: int
    height: int
    name: str
    camera_matrix: NDArray[np.float64]
    distortion_model: str
    distortion: NDArray[np.float64]
    rectification: NDArray[np.float64]
    projection: NDArray[np.float64]

    def intrinsics(self, field: str = "intrinsics") -> Intrinsics:
        """fx, fy, cx, cy of P (depth_image_proc's choice for rectified depth), else of K when P is zero."""
        m = self.projection if np.any(self.projection[:, :3]) else self.camera_matrix
        return Intrinsics.parse([m[0, 0], m[1, 1], m[0, 2], m[1, 2]], field)

    def check_image(self, width: int, height: int, field: str = "intrinsics") -> None:
        """CloudError naming field unless a depth image of width x height pixels is this camera's (a calibration
        of 0 x 0, as some drivers write for an unknown size, fits any)."""
        if (self.width, self.height) != (0, 0) and (self.width, self.height) != (width, height):
            raise CloudError(field, f"the calibration is for {self.width}x{self.height} images; the depth image "
                             f"is {width}x{height}")


def _shown(value: object) -> str:
    """A YAML value for an error message: a scalar's repr (shortened), else only its type (a structure of
    aliases can expand exponentially when printed)."""
    return repr(value)[:40] if isinstance(value, int | float | str) or value is None else type(value).__name__


def _matrix(doc: dict[str, Any], key: str, shape: tuple[int, int], field: str, required: bool = True
            ) -> NDArray[np.float64]:
    """A {rows, cols, data} matrix of the YAML, checked against shape (a required one must be there)."""
    value = doc.get(key)
    if value is None and not required:
        return np.zeros(shape)
    if not isinstance(value, dict) or not isinstance(value.get("data"), list):
        raise CloudError(field, f"calibration {key} must be a mapping with rows, cols and a data list")
    if (value.get("rows"), value.get("cols")) != shape or len(value["data"]) != shape[0] * shape[1]:
        raise CloudError(field, f"calibration {key} must be {shape[0]}x{shape[1]} ({shape[0] * shape[1]} numbers), "
                         f"got rows {_shown(value.get('rows'))}, cols {_shown(value.get('cols'))}, "
                         f"{len(value['data'])} numbers")
    if not all(isinstance(v, int | float) for v in value["data"]):
        raise CloudError(field, f"calibration {key} data must be numbers")
    try:
        out = np.array([float(v) for v in value["data"]], np.float64).reshape(shape)
    except (TypeError, ValueError, OverflowError):
        raise CloudError(field, f"calibration {key} data must be numbers") from None
    if not np.isfinite(out).all():
        raise CloudError(field, f"calibration {key} data must be finite")
    return out


def parse_calibration(text: str | bytes, field: str = "intrinsics") -> CameraCalibration:
    """A CameraCalibration from camera_calibration_parsers YAML text; CloudError naming field when it is too
    large, not YAML, or lacks or garbles a key."""
    if len(text) > MAX_CALIBRATION_BYTES:
        raise CloudError(field, f"a calibration of {len(text)} bytes exceeds the limit of {MAX_CALIBRATION_BYTES}")
    try:
        doc = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise CloudError(field, f"calibration is not YAML ({type(exc).__name__}: "
                         f"{str(exc).splitlines()[0] if str(exc) else ''})") from None
    if not isinstance(doc, dict):
        raise CloudError(field, "calibration YAML must be a mapping (image_width, image_height, camera_matrix, ...)")
    sides = [doc.get("image_width", 0), doc.get("image_height", 0)]
    if not all(isinstance(v, int) and not isinstance(v, bool) and 0 <= v <= MAX_IMAGE_SIDE for v in sides):
        raise CloudError(field, f"calibration image_width and image_height must be integers 0 to {MAX_IMAGE_SIDE}, "
                         f"got {_shown(sides[0])} and {_shown(sides[1])}")
    texts = [doc.get("camera_name", ""), doc.get("distortion_model", "")]
    if not all(isinstance(v, str) for v in texts):
        raise CloudError(field, "calibration camera_name and distortion_model must be text")
    distortion = doc.get("distortion_coefficients") or {"rows": 1, "cols": 0, "data": []}
    cols = distortion.get("cols") if isinstance(distortion, dict) else None
    if not isinstance(cols, int) or not 0 <= cols <= 16:
        raise CloudError(field, "calibration distortion_coefficients must be 1 row of at most 16 numbers")
    return CameraCalibration(
        width=int(sides[0]), height=int(sides[1]), name=texts[0],
        camera_matrix=_matrix(doc, "camera_matrix", (3, 3), field),
        distortion_model=texts[1],
        distortion=_matrix({"distortion_coefficients": distortion}, "distortion_coefficients", (1, cols),
                           field).reshape(-1),
        rectification=_matrix(doc, "rectification_matrix", (3, 3), field, required=False),
        projection=_matrix(doc, "projection_matrix", (3, 4), field, required=False))


def looks_like_calibration(text: str) -> bool:
    """Whether an intrinsics value is calibration YAML rather than four numbers."""
    return ":" in text
