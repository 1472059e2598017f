"""Pydantic models of the wire contract.  Array decoding, limits and field names come from
graspd_client (one definition); these models add validation and the OpenAPI documentation.

Frames and units: metres, right-handed, in the frame of the cloud the caller sends.  A grasp follows
gpd_ros GraspConfig: position = centre of the hand base, rotation columns [approach, binormal, axis]
(hand x, y, z), fingertips at position + hand_depth * approach.
"""

from __future__ import annotations

import base64
import binascii
import math
from collections.abc import Sequence
from typing import Annotated, Any, ClassVar, Literal

import numpy as np
from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    PlainValidator,
    PrivateAttr,
    StrictBool,
    ValidationInfo,
    WithJsonSchema,
    field_validator,
    model_validator,
)

from graspd.core.cloud import CloudError, CloudGrid, ViewpointCloud
from graspd.core.errors import FieldError
from graspd.core.frames import check_camera_source, check_points_frame, pose_matrix
from graspd.core.grasp import RANKING_RULE
from graspd.core.hand import HAND_PRESETS, HandGeometry
from graspd.core.limits import (
    MAX_COORDINATE,
    MAX_GRASPS,
    MAX_NUM_SAMPLES,
    MAX_OBJECT_ID,
    MAX_PER_OBJECT,
    MAX_POINTS,
    MAX_TARGET_INDICES,
    MAX_TARGET_POINTS,
    MAX_TARGET_RLE_CHARS,
    MAX_VIEWPOINTS,
)
from graspd.core.masks import rle_decode, rle_string_counts
from graspd.core.warning import WARNING_CODES, DetectionWarning
from graspd.gpd.detector import Detection, DetectionParams
from graspd.gpd.environment import Box, EnvironmentParams, Plane
from graspd.gpd.preprocess import DEFAULT_RANGE_WINDOW
from graspd.gpd.selection import DEFAULT_MAX_PER_OBJECT
from graspd.gpd.target import OrientedBox, Target, TargetKind
from graspd.io.inputs import CloudInput, apply_frames, check_shape, finite_rows, keep_finite
from graspd.io.png import check_image_size, decode_png_rgb, png_size
from graspd.templates import TemplateDetection
from graspd.templates.demonstration import check_hand_pose
from graspd_client import wire
from graspd_client.codec import WIRE_DTYPES, WireError, decode_array

#: What max_per_object does and why its default is what it is (bench/results/targets.md).
MAX_PER_OBJECT_TEXT = (
    f"most grasps one object gets before every other object with a grasp has one (0 = off: pure ranking).  The "
    f"best grasp always comes first; then rounds of up to max_per_object grasps per object, each round in ranked "
    f"order.  Default {DEFAULT_MAX_PER_OBJECT}: on tables of eight objects it covers the most objects in the top 10 "
    "(7.6 against 3.3 with the cap off) with the same first grasp and the same precision in the top 5 "
    "(bench/targets.py --tuning; held-out figures in bench/results/targets.md)"
)

#: How /detect orders its grasps (selection.select); the OpenAPI descriptions and the README say the same.
RANKING = (
    "best first.  Filters: workspace, width in [min_aperture, max_aperture], approach cone, min_score.  With "
    "selection (the default): by score (input order when unscored) times the utility J(h) in [0, 1] when up is "
    "known (gravity, else the support's normal) times a width preference.  With clustering true (GPD's "
    "selection): the 1000 best-scoring candidates are clustered (hand axes within 12 deg, positions within 5 mm "
    "of each other's axis line and 7 cm of each other), each cluster returns its best-scoring member, and "
    "clusters are ranked by the sum of their members' scores (their member count when unscored) times the same "
    "factors.  So a grasp's own score need not decrease down the list.  With selection false: random order "
    "(seeded)"
)


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


def _array(shape: tuple[int | None, ...], kind: str, dtype: str, finite: bool, description: str) -> Any:
    """An Annotated numpy field decoded by the client codec.  Its WireError names the sub-field relative to
    this one ("" or ".data", ".dtype", ...); problems.from_validation appends it to pydantic's path."""

    def validate(value: Any) -> np.ndarray:
        if isinstance(value, list) and not value and shape == (None, 3):
            raise ValueError("empty (0 rows); send at least one point")
        return decode_array(value, shape=shape, kind=kind, dtype=None if kind == "i" else dtype,
                            finite=finite, max_bytes=MAX_POINTS * 3 * 8)

    return Annotated[np.ndarray, PlainValidator(validate),
                     WithJsonSchema({**ENCODED_ARRAY_SCHEMA, "description": description})]


Points = _array((None, 3), "f", "float32", False,
                "cloud points (N,3), metres, in the caller's frame (or each camera's, points_frame 'camera'); "
                "float32 or float64; rows with a NaN or infinite coordinate are dropped and counted (warning "
                "non_finite_dropped), a cloud with no finite row is refused")
Normals = _array((None, 3), "f", "float32", False,
                 "optional unit surface normals (N,3), one per point, pointing toward the camera that saw it; rows "
                 "that are not finite are dropped with their points")
Viewpoints = _array((None, 3), "f", "float64", True,
                    "camera positions (K,3), metres, same frame as the points")
CameraSource = _array((None,), "i", "int64", False,
                      "per-point camera index (N,) into viewpoints (or camera_poses); default 0 for every point")
RGBImage = _array((None, None, 3), "i", "uint8", False, "RGB image (H,W,3) uint8, row-major, top row first")
Matrix4 = _array((4, 4), "f", "float64", True, "4x4 homogeneous transform, row-major")


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


class Cloud(BaseModel):
    """Points seen by one or more cameras, and where the cameras were: viewpoints (camera positions in the
    cloud's frame, metres), or camera_poses (camera-to-robot transforms) with points_frame (graspd.core.frames)."""

    model_config = ConfigDict(extra="forbid")
    points: Points  # type: ignore[valid-type]
    viewpoints: Viewpoints = Field(default_factory=lambda: np.zeros((1, 3)))  # type: ignore[valid-type]
    camera_poses: list[CameraPose] | None = Field(  # type: ignore[valid-type]
        None, min_length=1, max_length=MAX_VIEWPOINTS,
        description="one camera-to-robot transform per camera (ROS: the TF transform of the camera's frame into "
        "the base frame).  Replaces viewpoints: the cameras' positions are the translations; detection runs in the "
        "robot frame and the grasps come back in it (the response's frame is 'robot')")
    points_frame: Literal["camera", "robot"] | None = Field(
        None, description="with camera_poses, required: 'camera' (each point in the frame of the camera that saw "
        "it, camera_source picking the camera; graspd moves it into the robot frame) or 'robot' (already in the "
        "robot frame).  Every other geometric field of the request (workspace, gravity, approach, environment, "
        "crops.camera_pose) is then in the robot frame")
    camera_source: CameraSource | None = None  # type: ignore[valid-type]
    normals: Normals | None = None  # type: ignore[valid-type]
    shape: tuple[Annotated[int, Field(ge=1)], Annotated[int, Field(ge=1)]] | None = Field(
        None, description="[height, width] of an organised cloud (a depth image's grid): points are its pixels in "
        "row-major order, height * width of them, NaN where there is no depth.  Lets detection use image "
        "neighbours (mixed-pixel filter, normals); leave out for an unorganised cloud")
    _dropped: int = PrivateAttr(default=0)
    _kept: np.ndarray | None = PrivateAttr(default=None)
    _received: int = PrivateAttr(default=0)

    @field_validator("points")
    @classmethod
    def _points(cls, v: np.ndarray) -> np.ndarray:
        if len(v) == 0:
            raise ValueError("empty cloud (0 points); send at least one point")
        if len(v) > MAX_POINTS:
            raise ValueError(f"{len(v)} points exceeds the limit of {MAX_POINTS}")
        finite = finite_rows(v)  # the others are dropped (model validator): the bound is on what is kept
        kept = v if finite.all() else v[finite]
        if len(kept) and max(-float(kept.min()), float(kept.max())) > MAX_COORDINATE:
            raise ValueError(f"coordinates beyond +-{MAX_COORDINATE:g} m; send metres in a local frame")
        return v.astype(np.float32, copy=False)

    @field_validator("viewpoints")
    @classmethod
    def _viewpoints(cls, v: np.ndarray) -> np.ndarray:
        if not 1 <= len(v) <= MAX_VIEWPOINTS:
            raise ValueError(f"1 to {MAX_VIEWPOINTS} camera positions expected, got {len(v)}")
        return v

    @field_validator("camera_source")
    @classmethod
    def _camera_source(cls, v: np.ndarray | None, info: ValidationInfo) -> np.ndarray | None:
        if v is None:
            return None
        pts, poses = info.data.get("points"), info.data.get("camera_poses")
        refs, what = (poses, "camera pose") if poses is not None else (info.data.get("viewpoints"), "viewpoint")
        if pts is not None and len(v) != len(pts):
            raise ValueError(f"one index per point expected ({len(pts)}), got {len(v)}")
        if refs is not None and len(v) and (v.min() < 0 or v.max() >= len(refs)):
            raise ValueError(f"indices must lie in [0, {len(refs) - 1}] (one per {what}), "
                             f"got values in [{v.min()}, {v.max()}]")
        return v.astype(np.int32)

    @field_validator("normals")
    @classmethod
    def _normals(cls, v: np.ndarray | None, info: ValidationInfo) -> np.ndarray | None:
        pts = info.data.get("points")
        if v is not None and pts is not None and v.shape != pts.shape:
            raise ValueError(f"one normal per point expected, shape {pts.shape}, got {v.shape}")
        return v

    @model_validator(mode="after")
    def _frames_and_finite(self) -> Cloud:
        """Frames are consistent (graspd.core.frames.check_points_frame; poses replace viewpoints), then rows with a
        NaN or infinite coordinate are dropped and counted (graspd.io.inputs.keep_finite; none left: cloud.points)."""
        check_points_frame(self.points_frame, self.camera_poses is not None, ".points_frame")
        check_camera_source(self.points_frame, len(self.camera_poses or ()), self.camera_source is not None,
                            ".camera_source")
        if self.camera_poses is not None and "viewpoints" in self.model_fields_set:
            raise WireError(".viewpoints", "give camera_poses or viewpoints, not both (with camera poses the "
                            "viewpoints are the cameras' positions in the robot frame)")
        self._received = len(self.points)
        try:
            check_shape(self.shape, self._received, ".shape")
        except CloudError as exc:
            raise WireError(".shape", exc.message) from None
        keep, self._dropped = keep_finite(self.points, self.normals, ".points")
        self._kept = keep
        if keep is not None:
            self.points = np.asarray(self.points)[keep]
            self.camera_source = None if self.camera_source is None else self.camera_source[keep]
            self.normals = None if self.normals is None else self.normals[keep]
        return self

    def poses(self) -> np.ndarray | None:
        """The camera poses as one (K,4,4) array, None without them."""
        return None if self.camera_poses is None else np.stack(self.camera_poses)

    def to_input(self) -> CloudInput:
        """The detector's cloud in the frame detection runs in (graspd.io.inputs.apply_frames), with the count of
        non-finite rows dropped."""
        poses = self.poses()
        try:
            viewpoints = (np.zeros((len(poses), 3), np.float32) if poses is not None
                          else np.asarray(self.viewpoints, np.float32))
            grid = None if self.shape is None else CloudGrid.of_rows(self.shape[0], self.shape[1], self._kept)
            cloud = ViewpointCloud(points=self.points, viewpoints=viewpoints,
                                   camera_source=(np.zeros(0, np.int32) if self.camera_source is None
                                                  else self.camera_source), normals=self.normals, grid=grid)
            moved, frame = apply_frames(cloud, poses, self.points_frame)
        except CloudError as exc:  # the validators above check what ViewpointCloud does; kept as a 422
            raise WireError(exc.field or "cloud", exc.message) from None
        return CloudInput(moved, frame, self._dropped, self._received or len(self.points))

    def to_cloud(self) -> ViewpointCloud:
        """The detector's ViewpointCloud (points float32, viewpoints, one camera index per point), in the frame
        detection runs in (the robot frame with camera_poses)."""
        return self.to_input().cloud


Length = Annotated[float, Field(gt=0.0, le=1.0, allow_inf_nan=False)]


class Hand(BaseModel):
    """Two-finger hand geometry (GPD names, metres): a named preset, optionally with overrides."""

    model_config = ConfigDict(extra="forbid")
    #: The field a plain string fills ("panda" is {"preset": "panda"}): in JSON and as an upload query parameter.
    STRING_FORM: ClassVar[str] = "preset"
    preset: str | None = Field(None, description=f"one of {sorted(HAND_PRESETS)}; default 'gpd'")
    finger_width: Length | None = Field(None, description="finger thickness along the closing direction (m)")
    hand_outer_diameter: Length | None = Field(None, description="outer span of the open fingers (m)")
    hand_depth: Length | None = Field(None, description="finger length along the approach (m)")
    hand_height: Length | None = Field(None, description="hand thickness along the hand axis (m)")
    init_bite: Annotated[float, Field(ge=0.0, le=1.0, allow_inf_nan=False)] | None = Field(
        None, description="least depth past the surface the fingertips must reach (m)")
    palm_depth: Annotated[float, Field(ge=0.0, le=1.0, allow_inf_nan=False)] | None = Field(
        None, description="depth of the gripper body behind the finger roots (m); kept clear of points and "
        "environment like the fingers")

    @field_validator("preset")
    @classmethod
    def _preset(cls, v: str | None) -> str | None:
        if v is not None and v not in HAND_PRESETS:
            raise ValueError(f"unknown hand preset {v!r}; known: {sorted(HAND_PRESETS)}")
        return v

    @model_validator(mode="after")
    def _consistent(self) -> Hand:
        try:
            self.geometry()  # HandGeometry checks the combination (outer diameter > 2 finger widths, ...)
        except FieldError as exc:  # it names hand.<name>; a combination of overrides is the field hand
            raise ValueError(str(exc)) from None
        return self

    def geometry(self) -> HandGeometry:
        """The preset with the overrides applied (consistent: checked when the request was validated)."""
        base = HAND_PRESETS[self.preset or "gpd"]
        overrides = {k: v for k, v in self.model_dump(exclude={"preset"}).items() if v is not None}
        return base.with_overrides(**overrides) if overrides else base


class Approach(BaseModel):
    """Keep only grasps whose approach lies within max_angle_deg of direction (cloud frame)."""

    model_config = ConfigDict(extra="forbid")
    direction: list[Annotated[float, Field(allow_inf_nan=False)]] = Field(
        min_length=3, max_length=3, description="direction the hand should move along (need not be unit)")
    max_angle_deg: float = Field(45.0, ge=0.0, le=180.0, description="cone half-angle (degrees)")

    @field_validator("direction")
    @classmethod
    def _direction(cls, v: list[float]) -> list[float]:
        n = math.sqrt(sum(c * c for c in v))
        if n < 1e-9:
            raise ValueError("must be a non-zero vector")
        return [c / n for c in v]


class Intrinsics(BaseModel):
    """Pinhole intrinsics of the RGB camera (pixels): u = fx x/z + cx, v = fy y/z + cy."""

    model_config = ConfigDict(extra="forbid")
    fx: float = Field(gt=0, allow_inf_nan=False)
    fy: float = Field(gt=0, allow_inf_nan=False)
    cx: float = Field(allow_inf_nan=False)
    cy: float = Field(allow_inf_nan=False)


class CropsRequest(BaseModel):
    """Ask for one object-proposal crop per grasp (IJRR paper, combined grasp and object detection):
    a size x size window of the RGB image centred on the projection of the point between the fingers."""

    model_config = ConfigDict(extra="forbid")
    image: RGBImage | None = None  # type: ignore[valid-type]
    image_png: str | None = Field(None, description="the RGB image as base64 PNG (instead of image)")
    intrinsics: Intrinsics
    camera_pose: Matrix4 = Field(description="camera-to-cloud transform (4x4): optical frame, z forward, "  # type: ignore[valid-type]
                                 "x right, y down; maps camera coordinates into the cloud frame")
    size: int = Field(wire.DEFAULT_CROP_SIZE, ge=wire.MIN_CROP_SIZE, le=wire.MAX_CROP_SIZE,
                      description="crop side (pixels)")

    @field_validator("image")
    @classmethod
    def _image(cls, v: np.ndarray | None) -> np.ndarray | None:
        if v is None:
            return None
        if v.size and (v.min() < 0 or v.max() > 255):
            raise ValueError("values must lie in [0, 255] (uint8)")
        check_image_size(v.shape[1], v.shape[0])  # at least 2x2, at most 8 MP (as a PNG)
        return v.astype(np.uint8)

    @field_validator("image_png")
    @classmethod
    def _png(cls, v: str | None) -> str | None:
        if v is None:
            return None
        try:
            raw = base64.b64decode(v, validate=True)
        except (binascii.Error, ValueError) as exc:
            raise ValueError(f"invalid base64 ({exc})") from None
        if not raw.startswith(wire.PNG_MAGIC):
            raise ValueError("not a PNG (bad signature)")
        return v

    @model_validator(mode="after")
    def _one_image(self) -> CropsRequest:
        if (self.image is None) == (self.image_png is None):
            raise ValueError("give exactly one of image (array) or image_png (base64 PNG)")
        if self.image_png is not None:
            try:
                self.image = decode_png_rgb(self.image_png)  # type: ignore[assignment]
            except ValueError as exc:
                raise WireError(".image_png", str(exc)) from None  # relative to crops (problems.from_validation)
        assert self.image is not None
        h, w = self.image.shape[:2]
        if not (0 <= self.intrinsics.cx <= w and 0 <= self.intrinsics.cy <= h):
            raise WireError(".intrinsics", f"principal point ({self.intrinsics.cx:g}, {self.intrinsics.cy:g}) "
                            f"lies outside the {w}x{h} image; intrinsics and image do not match")
        return self

    @field_validator("camera_pose")
    @classmethod
    def _pose(cls, v: np.ndarray) -> np.ndarray:
        r = v[:3, :3]
        if not np.allclose(v[3], [0, 0, 0, 1], atol=1e-6) or not np.allclose(r @ r.T, np.eye(3), atol=1e-3):
            raise ValueError("must be a rigid transform (orthonormal rotation, last row 0 0 0 1)")
        return v


class EnvironmentSpec(BaseModel):
    """The environment stage: mode "auto" (detect support and walls, plus what is declared), "declared" (only
    what is declared here) or "none" (no environment model: every point is an object point)."""

    model_config = ConfigDict(extra="forbid")
    #: The field a plain string fills ("none" is {"mode": "none"}): in JSON and as an upload query parameter.
    STRING_FORM: ClassVar[str] = "mode"
    mode: Literal["auto", "declared", "none"] = "auto"
    support_plane: list[Annotated[float, Field(allow_inf_nan=False)]] | None = Field(
        None, min_length=4, max_length=4,
        description="[a, b, c, d]: the support a x + b y + c z + d = 0 (cloud frame), (a, b, c) pointing up")
    boxes: list[list[Annotated[float, Field(allow_inf_nan=False)]]] = Field(
        default_factory=list, max_length=64,
        description="static boxes the hand must not enter and whose points are never grasped, each "
                    "[xmin, xmax, ymin, ymax, zmin, zmax] (m, cloud frame)")

    @field_validator("support_plane")
    @classmethod
    def _plane(cls, v: list[float] | None) -> list[float] | None:
        if v is not None and math.sqrt(sum(c * c for c in v[:3])) < 1e-9:
            raise ValueError("(a, b, c) must be a non-zero normal")
        return v

    @field_validator("boxes")
    @classmethod
    def _boxes(cls, v: list[list[float]]) -> list[list[float]]:
        for k, b in enumerate(v):
            if len(b) != 6 or any(b[i + 1] < b[i] for i in (0, 2, 4)):
                raise ValueError(f"box {k}: [xmin, xmax, ymin, ymax, zmin, zmax] with each max >= its min expected")
        return v

    def params(self) -> EnvironmentParams:
        plane = None if self.support_plane is None else np.asarray(self.support_plane, np.float64)
        return EnvironmentParams(
            mode=self.mode,
            support=None if plane is None else Plane.from_coefficients(plane),
            boxes=tuple(Box.from_bounds(b) for b in self.boxes))


Finite = Annotated[float, Field(allow_inf_nan=False)]


def _png_mask_size(b64: str) -> tuple[int, int]:
    """(width, height) a base64 PNG mask declares, checked against the PNG limits before anything is decoded."""
    try:
        raw = base64.b64decode(b64[:64] + "=" * (-len(b64[:64]) % 4), validate=True)  # the IHDR is in 33 bytes
    except (binascii.Error, ValueError) as exc:
        raise ValueError(f"invalid base64 ({exc})") from None
    width, height = png_size(raw)
    check_image_size(width, height, MAX_POINTS)
    return width, height


class MaskRLE(BaseModel):
    """A mask run-length encoded as COCO writes it (pycocotools): size [height, width]; counts the run lengths,
    column-major, alternating 0s and 1s from 0s: a list of integers or pycocotools' compressed string."""

    model_config = ConfigDict(extra="forbid")
    size: list[Annotated[int, Field(ge=1, le=MAX_POINTS)]] = Field(min_length=2, max_length=2,
                                                                   description="[height, width] (pixels)")
    counts: list[Annotated[int, Field(ge=0, le=MAX_POINTS)]] | Annotated[str, Field(max_length=MAX_TARGET_RLE_CHARS)]

    @field_validator("counts", mode="before")
    @classmethod
    def _counts(cls, v: Any) -> Any:
        if isinstance(v, list) and len(v) > MAX_POINTS + 1:  # counted before any element is checked
            raise ValueError(f"{len(v)} runs exceeds the limit of {MAX_POINTS + 1}")
        return v

    @model_validator(mode="after")
    def _image(self) -> MaskRLE:
        if self.size[0] * self.size[1] > MAX_POINTS:
            raise WireError(".size", f"{self.size[1]}x{self.size[0]} pixels exceeds the limit of {MAX_POINTS}")
        return self

    def decode(self) -> np.ndarray:
        """One flag per pixel, row-major (height * width,)."""
        try:
            counts = (rle_string_counts(self.counts) if isinstance(self.counts, str)
                      else np.asarray(self.counts, np.int64))
            return rle_decode(counts, self.size[0], self.size[1])
        except FieldError as exc:
            raise WireError(".counts", exc.message) from None


class TargetBox(BaseModel):
    """An oriented box in the request's frame (the robot frame with camera_poses), metres: centre, the rotation
    whose columns are the box axes (a 3x3 row-major matrix, or quat_xyzw as camera_poses takes it; default none)
    and the half extents along those axes."""

    model_config = ConfigDict(extra="forbid")
    centre: list[Finite] = Field(min_length=3, max_length=3, description="box centre (m)")
    rotation: list[list[Finite]] | None = Field(None, min_length=3, max_length=3,
                                                description="3x3 row-major; columns are the box axes")
    quat_xyzw: list[Finite] | None = Field(None, min_length=4, max_length=4,
                                           description="the rotation as a unit quaternion x, y, z, w")
    half_extents: list[Annotated[float, Field(ge=0.0, le=MAX_COORDINATE, allow_inf_nan=False)]] = Field(
        min_length=3, max_length=3, description="half sizes along the box axes (m)")

    @model_validator(mode="after")
    def _rotation(self) -> TargetBox:
        if self.rotation is not None and self.quat_xyzw is not None:
            raise WireError(".rotation", "give rotation or quat_xyzw, not both")
        self.oriented()
        return self

    def oriented(self) -> OrientedBox:
        """The checked box (graspd.core.frames.pose_matrix checks the rotation)."""
        if self.quat_xyzw is not None:
            value: Any = {"position": self.centre, "quat_xyzw": self.quat_xyzw}
            sub = ""
        else:
            rot = np.eye(3) if self.rotation is None else np.asarray(self.rotation, np.float64)
            if rot.shape != (3, 3):
                raise WireError(".rotation", f"a 3x3 matrix expected, got shape {rot.shape}")
            value = np.block([[rot, np.asarray(self.centre, np.float64)[:, None]], [np.zeros((1, 3)), np.ones((1, 1))]])
            sub = ".rotation"
        try:
            pose = pose_matrix(value, "")
        except FieldError as exc:
            raise WireError(sub + exc.field if exc.field.startswith(".") or not exc.field else exc.field,
                            exc.message) from None
        return OrientedBox(centre=pose[:3, 3].copy(), rotation=pose[:3, :3].copy(),
                           half_extents=np.asarray(self.half_extents, np.float64))


TargetIndices = _array((None,), "i", "int64", False, "rows of the cloud (0-based, as sent: NaN rows count)")
TargetPoints = _array((None, 3), "f", "float64", True, "sample points (K,3), m, in the request's frame")
TARGET_FIELDS = ("indices", "mask", "box", "points", "object")


class TargetSpec(BaseModel):
    """What to grasp, exactly one of: indices (rows of the cloud as sent, gpd_ros CloudIndexed), mask (one flag
    per row of an organised cloud or pixel of a depth image, height x width = the cloud's rows: a base64 PNG,
    nonzero = target, or COCO RLE), box (an oriented box), points (sample points, gpd_ros CloudSamples: hands are
    sampled at the cloud points nearest them) or object (an id from a previous answer's objects, for the same
    cloud).  Candidates are sampled on the target only and a grasp closes on no object point outside it;
    collisions, the environment and unseen space are checked against the whole cloud."""

    model_config = ConfigDict(extra="forbid")
    indices: TargetIndices | None = None  # type: ignore[valid-type]
    mask: MaskRLE | str | None = Field(None, description="a base64 PNG (any mode; nonzero pixels are the target) "
                                       "or {size: [height, width], counts} (COCO RLE, column-major)")
    box: TargetBox | None = None
    points: TargetPoints | None = None  # type: ignore[valid-type]
    object: int | None = Field(None, ge=0, le=MAX_OBJECT_ID, description="an object id (the answer's objects)")

    @field_validator("indices", "points", mode="before")
    @classmethod
    def _count(cls, v: Any, info: ValidationInfo) -> Any:
        limit = MAX_TARGET_INDICES if info.field_name == "indices" else MAX_TARGET_POINTS
        shape = v.get("shape") if isinstance(v, dict) else None  # an encoded array's {"shape": [n, ...]}
        n = len(v) if isinstance(v, list) else shape[0] if isinstance(shape, list) and shape else 0
        if isinstance(n, int) and n > limit:  # counted from the length sent, before an array is built
            raise ValueError(f"{n} {info.field_name} exceeds the limit of {limit}")
        return v

    @field_validator("mask")
    @classmethod
    def _png(cls, v: MaskRLE | str | None) -> MaskRLE | str | None:
        if isinstance(v, str):
            _png_mask_size(v)
        return v

    @model_validator(mode="after")
    def _one(self) -> TargetSpec:
        given = [name for name in TARGET_FIELDS if getattr(self, name) is not None]
        if len(given) != 1:
            raise ValueError(f"exactly one of {list(TARGET_FIELDS)} expected, got {given or 'none'}")
        if self.indices is not None and not len(self.indices):
            raise WireError(".indices", "selects no row (empty)")
        if self.points is not None and not len(self.points):
            raise WireError(".points", "no sample point given (empty)")
        return self

    def rows(self, received: int) -> np.ndarray | None:
        """One flag per row of the cloud as sent (received rows) for indices and masks, else None; WireError
        naming the field when an index lies outside the cloud or the mask is not the cloud's size."""
        if self.indices is not None:
            idx = self.indices
            if idx.min() < 0 or idx.max() >= received:
                raise WireError(".indices", f"rows must lie in [0, {received - 1}] (the cloud has {received} rows), "
                                f"got values in [{idx.min()}, {idx.max()}]")
            rows = np.zeros(received, bool)
            rows[idx] = True
            return rows
        if self.mask is None:
            return None
        if isinstance(self.mask, str):
            width, height = _png_mask_size(self.mask)
        else:
            height, width = self.mask.size
        if width * height != received:
            raise WireError(".mask", f"a {width}x{height} mask has {width * height} pixels, the cloud {received} "
                            "rows; send the mask of the organised cloud's (or depth image's) own image")
        if isinstance(self.mask, str):
            try:
                return np.asarray(decode_png_rgb(self.mask, MAX_POINTS).any(axis=2)).reshape(-1)
            except ValueError as exc:
                raise WireError(".mask", str(exc)) from None
        try:
            return self.mask.decode()
        except WireError as exc:
            raise WireError(".mask" + exc.field, exc.message) from None

    def target(self, received: int, kept: np.ndarray | None) -> Target:
        """The detector's target; rows of the cloud as sent are mapped onto the rows kept (kept: the finite rows'
        mask, None when all are)."""
        if self.box is not None:
            return Target("box", box=self.box.oriented())
        if self.points is not None:
            return Target("points", points=np.asarray(self.points, np.float64))
        if self.object is not None:
            return Target("object", object_id=self.object)
        rows = self.rows(received)
        assert rows is not None
        kind: TargetKind = "indices" if self.indices is not None else "mask"
        if kept is not None:
            rows = rows[kept]
        if not rows.any():
            raise WireError(f".{kind}", "selects no row of the cloud with finite coordinates" if kept is not None
                            else "selects no row of the cloud")
        return Target(kind, rows=rows)


class DetectRequest(BaseModel):
    """POST /detect body and the Zenoh query payload (JSON)."""

    model_config = ConfigDict(extra="forbid")
    cloud: Cloud
    workspace: list[Annotated[float, Field(allow_inf_nan=False)]] | None = Field(
        None, min_length=6, max_length=6,
        description="[xmin, xmax, ymin, ymax, zmin, zmax] (m, cloud frame): crop points and grasp positions")
    range_window: float = Field(
        DEFAULT_RANGE_WINDOW, ge=0.0, le=MAX_COORDINATE, allow_inf_nan=False,
        description="with no workspace: keep the points at most this far (m) beyond the nearest surface the "
        "cameras see (depth noise grows with range; a room behind the table is sparse and noisy, and a hand "
        "rarely reaches it); the answer warns `range_window` when it left points out.  0: keep every point")
    hand: Hand | None = Field(None, description="hand geometry; a plain string is read as {\"preset\": string}")
    model: str | None = Field(None, max_length=200, description="classifier name (GET /models); default: the "
                              "server's default model, if any")
    num_samples: int = Field(1000, ge=1, le=MAX_NUM_SAMPLES, description="points sampled for candidates")
    max_grasps: int = Field(100, ge=0, le=MAX_GRASPS, description="most grasps returned")
    min_score: float | None = Field(None, allow_inf_nan=False, description="drop grasps scoring below this")
    approach: Approach | None = None
    selection: bool = Field(True, description="true: filter, cluster and rank best first (see `grasps` of the "
                            "response for the exact key); false: the paper's no-selection ablation, the grasps "
                            "passing the filters in random order (seeded)")
    clustering: bool = Field(False, description="GPD clustering of aligned hands: each cluster returns its "
                             "best-scoring member, ranked by the sum of its members' scores (off by default: "
                             "it favours large flat surfaces over the best grasp)")
    use_classifier: bool = Field(True, description="false: the paper's no-classification ablation (no CNN runs; "
                                 "scores null, scored false)")
    gravity: list[Annotated[float, Field(allow_inf_nan=False)]] | None = Field(
        None, min_length=3, max_length=3,
        description="direction gravity pulls (cloud frame, need not be unit; [0, 0, -1] when z is up): ranks by "
                    "score x utility J(h) (IJRR eq. 1), top-down approaches and high grasps first")
    exclude_support_plane: bool | None = Field(
        None, description="override: true samples no candidates on the support, false samples everywhere; default "
        "(null) follows the environment (samples on object points only)")
    environment: EnvironmentSpec | None = Field(
        None, description="how objects are told from what holds them; a plain string is read as {\"mode\": "
        "string}.  Default \"auto\": the support plane and container walls are found in the cloud; grasps close "
        "on objects only and no part of the hand or its approach path enters the environment")
    approach_distance: float = Field(0.05, ge=0.0, le=0.5, allow_inf_nan=False,
                                     description="pre-grasp distance (m) back along the approach over which the "
                                     "open hand's path must be free of points and environment")
    early_stop: bool = Field(False, description="search the seeded samples in rounds and stop once 2 x "
                             "max_grasps high-scoring grasps in distinct 2 cm cells are found: much faster for "
                             "requests that ask for few grasps, but the answer can differ from a full search")
    cascade: bool = Field(True, description="with the service's cascade model (GRASPD_CASCADE_MODEL, made for the "
                          "request's hand): a cheap first pass scores every candidate and the full model only the "
                          "best 30% (at least 200); false: the full model scores every candidate")
    unknown_space: Literal["avoid", "allow"] = Field(
        "avoid", description="space no camera saw (behind a seen surface from every camera): 'avoid' treats a "
        "hand with any of its fingers, palm or approach path there (beyond 4 mm) as colliding (a neighbour seen "
        "only in part may be there); 'allow' checks the seen points only, as GPD does, and warns when the best grasps "
        "reach into unseen space")
    min_aperture: float | None = Field(None, ge=0.0, le=1.0, allow_inf_nan=False,
                                       description="drop grasps whose width (object extent between the fingers) "
                                       "is below this (m)")
    max_aperture: float | None = Field(None, gt=0.0, le=1.0, allow_inf_nan=False,
                                       description="drop grasps whose width is above this (m); default the hand's "
                                       "hand_outer_diameter - 2 finger_width")
    seed: int | None = Field(0, ge=0, le=2**32 - 1, description="sampling seed (null: random)")
    crops: CropsRequest | None = Field(None, description="object-proposal crops, on request only")
    method: Literal["gpd", "templates"] = Field(
        "gpd", description="detector: 'gpd' (sampled candidates scored by the CNN) or 'templates' (grasp "
        "templates matched against the demonstration library, Herzog et al. 2012; uses cloud, workspace, "
        "max_grasps and the library's hand only)")
    target: TargetSpec | None = Field(None, description="what to grasp (one of indices, mask, box, points, object); "
                                      "default: every object")
    max_per_object: int = Field(DEFAULT_MAX_PER_OBJECT, ge=0, le=MAX_PER_OBJECT, description=MAX_PER_OBJECT_TEXT)
    _target: Target | None = PrivateAttr(default=None)

    @field_validator("workspace")
    @classmethod
    def _workspace(cls, v: list[float] | None) -> list[float] | None:
        if v is not None and any(v[i + 1] < v[i] for i in (0, 2, 4)):
            raise ValueError("each max must be >= its min ([xmin, xmax, ymin, ymax, zmin, zmax])")
        return v

    @field_validator("hand", mode="before")
    @classmethod
    def _hand(cls, v: Any) -> Any:
        return {Hand.STRING_FORM: v} if isinstance(v, str) else v

    @field_validator("environment", mode="before")
    @classmethod
    def _environment(cls, v: Any) -> Any:
        return {EnvironmentSpec.STRING_FORM: v} if isinstance(v, str) else v

    @field_validator("gravity")
    @classmethod
    def _gravity(cls, v: list[float] | None) -> list[float] | None:
        if v is None:
            return None
        n = math.sqrt(sum(c * c for c in v))
        if n < 1e-9:
            raise ValueError("must be a non-zero vector (the direction gravity pulls, cloud frame)")
        return [c / n for c in v]

    @field_validator("max_aperture")
    @classmethod
    def _max_aperture(cls, v: float | None, info: ValidationInfo) -> float | None:
        lo = info.data.get("min_aperture")
        if v is not None and lo is not None and v < lo:
            raise ValueError(f"must be >= min_aperture ({lo:g} m), got {v:g}")
        return v

    @model_validator(mode="after")
    def _target_on_cloud(self) -> DetectRequest:
        """The target checked against the cloud it points into (indices in range, a mask of its size) and mapped
        onto the rows kept (non-finite ones dropped); WireError naming target.<field>."""
        if self.target is None:
            return self
        if self.method == "templates":
            raise WireError("target", "method 'templates' takes no target; use method 'gpd'")
        try:
            self._target = self.target.target(self.cloud._received or len(self.cloud.points), self.cloud._kept)
        except WireError as exc:
            raise WireError("target" + exc.field, exc.message) from None
        return self

    def hand_geometry(self) -> HandGeometry | None:
        """The requested hand, None for the detector's own."""
        return None if self.hand is None else self.hand.geometry()

    def to_input(self) -> CloudInput:
        """The detector's cloud in the frame detection runs in, that frame's name and the non-finite rows dropped
        (graspd.io.inputs): its warnings go into the response."""
        return self.cloud.to_input()

    def to_cloud(self) -> ViewpointCloud:
        """The detector's ViewpointCloud of the request's cloud (in the robot frame with camera_poses)."""
        return self.to_input().cloud

    def workspace_bounds(self) -> tuple[float, float, float, float, float, float] | None:
        ws = self.workspace
        return None if ws is None else (ws[0], ws[1], ws[2], ws[3], ws[4], ws[5])

    def to_params(self) -> DetectionParams:
        """The detector's knobs (metres, degrees, cloud frame).  Every limit was checked by validation (the
        bounds in graspd_client.wire); WireError naming the body if DetectionParams still refuses."""
        approach, gravity = self.approach, self.gravity
        try:
            return DetectionParams(
                num_samples=self.num_samples,
                workspace=self.workspace_bounds(),
                range_window=self.range_window,
                max_grasps=self.max_grasps,
                min_score=self.min_score,
                approach_direction=None if approach is None else (approach.direction[0], approach.direction[1],
                                                                  approach.direction[2]),
                approach_max_angle_deg=None if approach is None else approach.max_angle_deg,
                min_aperture=self.min_aperture,
                max_aperture=self.max_aperture,
                use_selection=self.selection,
                use_clustering=self.clustering,
                use_classifier=self.use_classifier,
                gravity=None if gravity is None else (gravity[0], gravity[1], gravity[2]),
                exclude_support_plane=self.exclude_support_plane,
                environment=EnvironmentParams() if self.environment is None else self.environment.params(),
                approach_distance=self.approach_distance,
                early_stop=self.early_stop,
                cascade=self.cascade,
                unknown_space=self.unknown_space,
                seed=self.seed,
                target=self._target,
                max_per_object=self.max_per_object,
            )
        except ValueError as exc:
            raise WireError("body", str(exc)) from None


Vec3Out = Annotated[list[float], Field(min_length=3, max_length=3)]


class ObjectOut(BaseModel):
    """One object of the scene (graspd.gpd.objects): the object points the environment stage kept, split where
    they are more than 6 mm apart (touching objects are one); ids count from 0 by position (x, then y, then z of
    the centre) and stay the same for the same cloud whatever num_samples, target or seed say."""

    id: int = Field(description="the object's id: a request's target.object names it")
    centre: Vec3Out = Field(description="centre of its points' axis-aligned bounds (m, the answer's frame)")
    extent: Vec3Out = Field(description="size of those bounds along x, y, z (m)")
    num_points: int = Field(description="its points after preprocessing (3 mm voxels by default)")
    grasps: list[int] = Field(description="positions of its grasps in this answer's grasps list, best first")


class CropOut(BaseModel):
    png: str | None = Field(description="base64 PNG (size x size RGB), null when the point is outside the image")
    pixel: list[float] | None = Field(description="[u, v] projection of the point between the fingers (px)")
    in_image: bool = Field(description="whether that point projects inside the image (in front of the camera)")


class RankingOut(BaseModel):
    """The terms a GPD grasp was ranked by (dimensionless; DetectResponse.ranking_rule says how they combine)."""

    classifier: float | None = Field(description="the classifier term: the model's probability (1 when unscored); "
                                     "with clustering, the sum of the cluster members' scores")
    utility: float | None = Field(description="utility J(h) of the IJRR paper in [0, 1]: top approaches and high "
                                  "grasps first, from the support up (1 when up is unknown)")
    width: float | None = Field(description="width preference in [0.2, 1]: lower when the object fills the opening")
    unknown: float | None = Field(description="1 - the share of the hand and its approach path in space no camera "
                                  "saw (1: all seen)")
    key: float | None = Field(description="the product of the terms: grasps are sorted by it, best first")


class GraspOut(BaseModel):
    """One grasp (gpd_ros GraspConfig), cloud frame, metres."""

    id: str = Field(description="unique id of this grasp (for feedback)")
    position: Vec3Out = Field(description="centre of the hand base (m)")
    approach: Vec3Out = Field(description="unit vector the hand moves along to reach the object (hand x)")
    binormal: Vec3Out = Field(description="unit closing direction of the fingers (hand y)")
    axis: Vec3Out = Field(description="approach x binormal (hand z)")
    width: float = Field(description="object extent between the fingers along binormal (m)")
    score: float | None = Field(description="gpd: classifier probability in [0, 1], null when unscored; "
                                "templates: match quality 1 / (1 + m) in (0, 1], m the eq. 2 mismatch")
    sample: Vec3Out = Field(description="cloud point the candidate was sampled at (m)")
    pose: list[list[float]] = Field(description="4x4 row-major; rotation columns [approach, binormal, axis], "
                                    "translation position")
    quat_xyzw: list[float] = Field(description="rotation as a unit quaternion x, y, z, w")
    crop: CropOut | None = Field(None, description="object-proposal crop, when crops were requested")
    template_entry: int | None = Field(None, description="templates: the library entry whose grasp this is")
    mismatch: float | None = Field(None, description="templates: eq. 2 mismatch m of the best match (lower is "
                                   "better)")
    ranking: RankingOut | None = Field(None, description="gpd with selection: the terms that ranked this grasp "
                                       "(the response's ranking_rule says how they combine)")
    object: int | None = Field(None, description="gpd: the id of the object it closes on (the answer's objects), "
                               "null when its closing region holds no object's points")


class PlaneOut(BaseModel):
    normal: Vec3Out = Field(description="unit normal, pointing up from the support")
    offset: float = Field(description="d of normal . p + d = 0 (m)")


class BoxOut(BaseModel):
    centre: Vec3Out = Field(description="box centre (m, cloud frame)")
    rotation: list[list[float]] = Field(description="3x3 row-major; columns are the box axes")
    half_extents: Vec3Out = Field(description="half sizes along the box axes (m)")


class SurfaceOut(BaseModel):
    """One surface of the environment (graspd.gpd.environment.Surface)."""

    kind: Literal["support", "floor", "platform", "board", "wall", "rim", "declared"] = Field(
        description="support: the lowest support (a half-space the hand stays above); floor: a container's floor "
        "above it; platform: a raised top with no walls; board: a raised board with room beneath it (a shelf's "
        "ceiling); wall: a vertical face longer than any graspable object; "
        "rim: a thin wall's top seen as a long line; declared: a box of the request")
    plane: PlaneOut = Field(description="its plane, the normal toward the free side")
    box: BoxOut | None = Field(description="the solid the hand must not enter; null for the lowest support")
    extent: list[float] = Field(description="support, floor, platform: the two in-plane spans of its points (m); "
                                "wall: length and top height above the support (m); rim: length (m) and 0")
    num_points: int = Field(description="points labelled as this surface")
    confidence: float = Field(description="how clearly it passed the tests that made it environment, in [0, 1]")


class EnvironmentOut(BaseModel):
    """What the environment stage found (method gpd)."""

    mode: str = Field(description="auto, declared or none")
    support: PlaneOut | None = Field(description="the support plane, null when none was found or declared")
    walls: list[BoxOut] = Field(description="solids found in the cloud that the hand must not enter: walls, rims "
                                "and raised floors or platforms (see surfaces for which is which)")
    boxes: list[BoxOut] = Field(description="boxes the request declared")
    up: Vec3Out | None = Field(description="unit up direction (cloud frame), null when unknown")
    counts: dict[str, int] = Field(description="points per label (object, support, wall, box, ...)")
    surfaces: list[SurfaceOut] = Field(default_factory=list, description="every surface found or declared")
    confidence: float = Field(1.0, description="how sure the stage is of what holds the objects, in [0, 1]: the "
                              "least confidence of its surfaces, 0 when no support was found (then warnings say "
                              "so)")


class WarningOut(BaseModel):
    """Something the service could not do right, said instead of staying silent (graspd.core.warning)."""

    code: str = Field(description="stable code: " + "; ".join(f"{k}: {v}" for k, v in WARNING_CODES.items()))
    message: str = Field(description="what happened and what to do, for a person")


class RosStamp(BaseModel):
    sec: int
    nanosec: int


class RosHeader(BaseModel):
    """std_msgs/Header of a CDR sensor_msgs/PointCloud2 input (Zenoh only)."""

    frame_id: str
    stamp: RosStamp


def gpd_grasp_id(detection_id: str, k: int) -> str:
    """The id of the k-th GPD grasp of a detection ("<detection id>-<k>", the detection id 16 hex digits made
    by the server: the request id unless the client chose its own X-Request-ID; feedback parses it back)."""
    return f"{detection_id}-{k}"


class DetectResponse(BaseModel):
    """POST /detect answer and the Zenoh reply: built once, by from_detection, and serialised by to_json.  Keys
    that do not apply to a method (environment, num_entries, header, a grasp's crop or template fields) are
    left out of the JSON rather than sent as null."""

    request_id: str = Field(description="the request's id: the client's X-Request-ID when it sent a valid one (1 "
                            "to 128 letters, digits and . _ - : ; = + / @), else one the server made; the "
                            "X-Request-ID response header and every server log line of the request carry it")
    method: Literal["gpd", "templates"] = Field("gpd", description="the detector that answered")
    frame: Literal["robot", "cloud"] = Field("cloud", description="the frame every position and direction of "
                                             "this answer is in: 'robot' when the request gave camera_poses "
                                             "(the robot frame they map into), else 'cloud' (the frame of the "
                                             "cloud as sent)")
    grasps: list[GraspOut] = Field(description=RANKING)
    timings: dict[str, float] = Field(description="seconds per stage: decode, queue, preprocess, scene, sample, "
                                      "encode, score, select, crops; detect (the detector's wall time, stages "
                                      "included); total (decode to response, in the server)")
    model: str | None = Field(description="classifier used; null when unscored or method templates")
    scored: bool = Field(description="whether grasps carry scores: gpd, a classifier ran (else scores null); "
                         "templates, always (match quality)")
    num_candidates: int
    num_points: int = Field(description="points after preprocessing")
    hand: dict[str, float] = Field(description="hand geometry used (m)")
    environment: EnvironmentOut | None = Field(None, description="gpd: what the environment stage found")
    warnings: list[WarningOut] = Field(default_factory=list, description="what the service could not do right "
                                       "for this request (empty for a correct request); the same on every "
                                       "transport")
    num_entries: int | None = Field(None, description="templates: library entries matched against")
    header: RosHeader | None = Field(None, description="Zenoh, CDR PointCloud2 input only: its ROS header")
    model_fits_hand: bool | None = Field(None, description="gpd with a model: whether the model was trained on "
                                         "grasp images of the request's hand (finger width, outer diameter, "
                                         "depth, height).  false: the hand and the model differ and the scores "
                                         "are less reliable (train one on a dataset of that hand: python -m "
                                         "graspd_lab.training.dataset --hand NAME, then graspd train)")
    ranking_rule: str | None = Field(None, description="gpd with selection: how each grasp's ranking terms combine "
                                     "into the key it was sorted by")
    objects: list[ObjectOut] | None = Field(None, description="gpd: the scene's objects by id, each with its grasps")
    max_per_object: int | None = Field(None, description="gpd: the max_per_object the list was ordered with (0: "
                                       "pure ranking; " + MAX_PER_OBJECT_TEXT + ")")

    @classmethod
    def from_detection(cls, det: Detection | TemplateDetection, *, request_id: str, timings: dict[str, float],
                       hand: HandGeometry, crops: list[dict[str, Any]] | None = None,
                       header: dict[str, Any] | None = None, model_fits_hand: bool | None = None,
                       detection_id: str | None = None, frame: str = "cloud",
                       warnings: Sequence[DetectionWarning] = ()) -> DetectResponse:
        """The response to a detection, validated against this model (so what is sent cannot drift from what
        is documented).  Grasp ids are assigned here: gpd "<detection id>-<k>" (detection_id: the server's id
        of the detection, default request_id), templates the ids the library recorded.  crops: one
        CropOut-shaped dict per grasp; header: the ROS header of a CDR input (Zenoh); frame: the frame the grasps
        are in (graspd.core.frames); warnings: those of the input (graspd.io.inputs), before the detection's own.
        Cost at 100 grasps: ~1.2 ms to build, validate (pydantic-core) and serialise (to_json), against ~0.9 ms
        for the unvalidated dicts and orjson this replaced: a fraction of a percent of a detection."""
        g = det.grasps
        templates = isinstance(det, TemplateDetection)
        ids = det.grasp_ids if isinstance(det, TemplateDetection) else [gpd_grasp_id(detection_id or request_id, k)
                                                                        for k in range(len(g))]
        cols = (ids, g.positions.tolist(), g.approach.tolist(), g.binormal.tolist(), g.axis.tolist(),
                g.widths.tolist(), g.scores.tolist(), g.samples.tolist(), g.poses.tolist(), g.quat_xyzw.tolist())
        grasps: list[dict[str, Any]] = [
            {"id": gid, "position": pos, "approach": app, "binormal": bn, "axis": axis, "width": width,
             "score": None if score != score else score, "sample": sample, "pose": pose, "quat_xyzw": quat}
            for gid, pos, app, bn, axis, width, score, sample, pose, quat in zip(*cols, strict=True)]
        if crops is not None:
            for grasp, crop in zip(grasps, crops, strict=True):
                grasp["crop"] = crop
        out: dict[str, Any] = {"request_id": request_id, "method": "templates" if templates else "gpd",
                               "frame": frame, "grasps": grasps, "timings": timings,
                               "num_candidates": det.num_candidates,
                               "num_points": det.num_points, "hand": hand.to_dict(),
                               "warnings": [w.to_dict() for w in (*warnings, *getattr(det, "warnings", ()))]}
        if isinstance(det, TemplateDetection):
            for grasp, entry, m in zip(grasps, det.entry_ids.tolist(), det.mismatch.tolist(), strict=True):
                grasp.update(template_entry=entry, mismatch=m if math.isfinite(m) else None)
            out.update(model=None, scored=True, num_entries=det.num_entries)
        else:
            env = det.environment
            out.update(model=det.model, scored=det.scored, environment=None if env is None else env.to_dict(),
                       max_per_object=det.max_per_object,
                       objects=[{**o.to_dict(), "grasps": ks} for o, ks in zip(det.objects, det.object_grasps(),
                                                                                 strict=True)])
            for grasp, oid in zip(grasps, g.object_ids.tolist(), strict=True):
                grasp["object"] = oid if oid >= 0 else None
            if g.ranking is not None:  # the terms selection ranked by (graspd.core.grasp.Ranking); NaN goes as null
                for grasp, terms in zip(grasps, g.ranking.to_dicts(), strict=True):
                    grasp["ranking"] = {k: v if math.isfinite(v) else None for k, v in terms.items()}
                out["ranking_rule"] = RANKING_RULE
        if header is not None:
            out["header"] = header
        if model_fits_hand is not None:
            out["model_fits_hand"] = model_fits_hand
        return cls.model_validate(out)

    def to_json(self) -> bytes:
        """The JSON bytes sent: compact, with the keys from_detection set (the others are not sent)."""
        return self.model_dump_json(exclude_unset=True).encode()


class FieldProblem(BaseModel):
    field: str
    message: str


class ErrorBody(BaseModel):
    """Every 4xx/5xx body: the first problem as text, its field, and all problems."""

    error: str
    field: str | None = None
    detail: list[FieldProblem] = Field(default_factory=list)


class ModelInfo(BaseModel):
    name: str
    representation: str
    default: bool
    card: dict[str, Any]


class InstanceJobOut(BaseModel):
    """An instance model being made (POST /models): a classifier fine-tuned for one uploaded mesh."""

    id: str = Field(description="the job's id")
    name: str = Field(description="the model's name: POST /detect selects it with model=name once state is done")
    category: Literal["box", "cylinder"] | None = Field(description="the object's category: the category model "
                                                         "was fine-tuned; none: the generic one")
    hand: str = Field(description="hand preset the grasp images are made for")
    base_model: str | None = Field(description="the model fine-tuned (None: trained from scratch)")
    state: Literal["queued", "running", "done", "failed"]
    stage: Literal["dataset", "training", "evaluating", "loading", "done"] | None = Field(
        description="while running: rendering and labelling views, fine-tuning, comparing, loading the model")
    view: int | None = Field(description="views rendered and labelled so far")
    views: int | None = Field(description="views to render")
    epoch: int | None = Field(description="fine-tuning epochs finished")
    epochs: int | None = Field(description="most epochs (training stops earlier at its time budget)")
    created_at: float = Field(description="UNIX time the job was queued (s)")
    elapsed_s: float = Field(description="running time so far, or until it finished (s)")
    error: str | None = Field(description="why it failed")
    field: str | None = Field(description="the request field at fault when it failed (e.g. mesh)")


class ModelsResponse(BaseModel):
    default: str | None
    cascade: str | None = Field(None, description="the cascade's first-pass model (GRASPD_CASCADE_MODEL), used "
                                "with the models made for its hand; null: no cascade")
    models: list[ModelInfo]
    jobs: list[InstanceJobOut] = Field(default_factory=list, description="instance models queued, being made "
                                       "or made by this server process (POST /models), oldest first")


def _check_hand_pose(v: np.ndarray) -> np.ndarray:
    """The templates' own check of a demonstrated pose (orthonormal, right-handed); field hand_pose."""
    try:
        return check_hand_pose(v)
    except FieldError as exc:  # a TemplateError naming hand_pose, the field pydantic reports it under
        raise ValueError(exc.message) from None


class DemonstrationRequest(BaseModel):
    """POST /demonstrations: a cloud of the table and one object, and the grasp demonstrated on it."""

    model_config = ConfigDict(extra="forbid")
    cloud: Cloud
    hand_pose: Matrix4 = Field(description="demonstrated hand pose (4x4, cloud frame, the grasp convention: "  # type: ignore[valid-type]
                               "rotation columns [approach, binormal, axis], translation the hand-base centre)")
    hand: Hand | None = Field(None, description="the demonstrating hand; must be the library's (GET /library)")
    label: str | None = Field(None, max_length=200, description="what was grasped, for people")
    workspace: list[Annotated[float, Field(allow_inf_nan=False)]] | None = Field(
        None, min_length=6, max_length=6, description="[xmin, xmax, ymin, ymax, zmin, zmax] (m, cloud frame): crop")

    _hand_pose = field_validator("hand_pose")(_check_hand_pose)
    _workspace = field_validator("workspace")(DetectRequest._workspace.__func__)  # type: ignore[attr-defined]
    _hand = field_validator("hand", mode="before")(DetectRequest._hand.__func__)  # type: ignore[attr-defined]


class FeedbackRequest(BaseModel):
    """POST /feedback: the outcome of executing a grasp this service returned."""

    model_config = ConfigDict(extra="forbid")
    grasp_id: str = Field(min_length=1, max_length=100, description="the grasp's id from a detect response")
    success: StrictBool = Field(description="whether the robot held the object")


class LibraryEntryOut(BaseModel):
    id: int
    label: str | None
    created_at: float = Field(description="UNIX time (s)")
    failures: int = Field(description="size of the entry's failure set F_l")
    outcomes: int = Field(description="outcomes reported for grasps from this entry")
    successes: int


class LibraryCounts(BaseModel):
    num_entries: int
    num_failures: int = Field(description="templates in all failure sets")
    num_outcomes: int = Field(description="outcomes stored (template and GPD grasps)")
    num_successes: int
    num_images: int = Field(description="outcomes stored with their GPD grasp image (for fine-tuning)")
    num_detections: int = Field(description="template detections whose grasps feedback can name")


class LibraryResponse(LibraryCounts):
    schema_version: int
    hand: dict[str, float] = Field(description="the hand the library is made for (m)")
    template: dict[str, Any] = Field(description="template geometry: n tiles a side, size (m), ...")
    entries: list[LibraryEntryOut]


class DemonstrationResponse(BaseModel):
    entry_id: int = Field(description="the new library entry")
    library: LibraryCounts


class FeedbackResponse(BaseModel):
    grasp_id: str
    method: Literal["gpd", "templates"] = Field(description="the detector that returned the grasp")
    success: bool
    outcome_id: int = Field(description="the stored outcome")
    entry_id: int | None = Field(description="templates: the library entry the grasp came from")
    failure_added: bool = Field(description="templates: the candidate's template joined F_l of that entry")
    image_stored: bool = Field(description="the outcome was stored with the grasp's 15-channel GPD image")
