"""The wire's array fields: numpy arrays decoded by the client codec (graspd_client.codec: base64 little-endian
C-order bytes, or nested lists), with their JSON schema, and the camera pose (a 4x4 matrix or position and
quaternion, checked by graspd.core.frames)."""

from __future__ import annotations

from typing import Annotated, Any

import numpy as np
from pydantic import PlainValidator, WithJsonSchema

from graspd.core.frames import pose_matrix
from graspd.core.limits import MAX_POINTS
from graspd_client.codec import WIRE_DTYPES, decode_array

ENCODED_ARRAY_SCHEMA: dict[str, Any] = {
    "oneOf": [
        {
            "type": "object",
            "title": "EncodedArray",
            "description": "base64 of the array's little-endian, C-order bytes",
            "properties": {
                "dtype": {"type": "string", "enum": list(WIRE_DTYPES)},
                "shape": {"type": "array", "items": {"type": "integer", "minimum": 0}},
                "data": {"type": "string", "contentEncoding": "base64"},
            },
            "required": ["dtype", "shape", "data"],
            "additionalProperties": False,
        },
        {"type": "array", "title": "NestedLists", "description": "plain nested lists of numbers (small inputs)"},
    ]
}


def array_field(shape: tuple[int | None, ...], kind: str, dtype: str, finite: bool, description: str) -> Any:
    """An Annotated numpy field decoded by the client codec.  Its WireError names the sub-field relative to
    this one ("" or ".data", ".dtype", ...); problems.from_validation appends it to pydantic's path."""

    def validate(value: Any) -> np.ndarray:
        if isinstance(value, list) and not value and shape == (None, 3):
            raise ValueError("empty (0 rows); send at least one point")
        return decode_array(value, shape=shape, kind=kind, dtype=None if kind == "i" else dtype,
                            finite=finite, max_bytes=MAX_POINTS * 3 * 8)

    return Annotated[np.ndarray, PlainValidator(validate),
                     WithJsonSchema({**ENCODED_ARRAY_SCHEMA, "description": description})]


Points = array_field((None, 3), "f", "float32", False,
                "cloud points (N,3), metres, in the caller's frame (or each camera's, points_frame 'camera'); "
                "float32 or float64; rows with a NaN or infinite coordinate are dropped and counted (warning "
                "non_finite_dropped), a cloud with no finite row is refused")
Normals = array_field((None, 3), "f", "float32", False,
                 "optional unit surface normals (N,3), one per point, pointing toward the camera that saw it; rows "
                 "that are not finite are dropped with their points")
Viewpoints = array_field((None, 3), "f", "float64", True,
                    "camera positions (K,3), metres, same frame as the points")
CameraSource = array_field((None,), "i", "int64", False,
                      "per-point camera index (N,) into viewpoints (or camera_poses); default 0 for every point")
Pixels = array_field((None,), "i", "int64", False,
                "with shape: the row-major pixel index of each point, increasing (a depth image's pixels that have "
                "depth); default: the points are every pixel in order")
RGBImage = array_field((None, None, 3), "i", "uint8", False, "RGB image (H,W,3) uint8, row-major, top row first")
Matrix4 = array_field((4, 4), "f", "float64", True, "4x4 homogeneous transform, row-major")


def _camera_pose(value: Any) -> np.ndarray:
    """One checked camera-to-robot transform (4,4) (graspd.core.frames.pose_matrix; its FieldError names the sub-field
    relative to this pose: "" or ".quat_xyzw", ...)."""
    return pose_matrix(value, "")


CameraPose = Annotated[np.ndarray, PlainValidator(_camera_pose), WithJsonSchema({
    "description": "camera-to-robot transform: a 4x4 row-major matrix or {\"position\": [x, y, z], "
                   "\"quat_xyzw\": [x, y, z, w]} (metres; a proper rotation: orthonormal, determinant +1)",
    "oneOf": [
        {"type": "array", "title": "Matrix4", "items": {"type": "array", "items": {"type": "number"},
                                                        "minItems": 4, "maxItems": 4}, "minItems": 4, "maxItems": 4},
        {"type": "object", "title": "PositionQuaternion", "additionalProperties": False,
         "required": ["position", "quat_xyzw"],
         "properties": {"position": {"type": "array", "items": {"type": "number"}, "minItems": 3, "maxItems": 3},
                        "quat_xyzw": {"type": "array", "items": {"type": "number"}, "minItems": 4,
                                      "maxItems": 4}}}]})]
