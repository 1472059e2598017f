"""The detect request on the wire (POST /detect's body, the Zenoh query's JSON): its models and their checks of
what was sent (types, shapes, limits, frames), documented for OpenAPI.  Array decoding, limits and field names
come from graspd_client (one definition).  The detector's input, target and parameters are made from a request by
graspd.server.services.mapping.

Frames and units: metres, right-handed, in the frame of the cloud the caller sends (the robot frame with
camera_poses).
"""

from __future__ import annotations

import base64
import binascii
import math
from typing import Annotated, Any, ClassVar, Literal

import numpy as np
from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    ValidationInfo,
    field_validator,
    model_validator,
)

from graspd.core.errors import FieldError
from graspd.core.frames import check_camera_source, check_points_frame, pose_matrix
from graspd.core.hand import HAND_PRESETS, HandGeometry
from graspd.core.limits import (
    DEFAULT_ROBUST_COPIES,
    MAX_COORDINATE,
    MAX_GRASPS,
    MAX_NUM_SAMPLES,
    MAX_OBJECT_ID,
    MAX_PER_OBJECT,
    MAX_POINTS,
    MAX_ROBUST_COPIES,
    MAX_TARGET_INDICES,
    MAX_TARGET_POINTS,
    MAX_TARGET_RLE_CHARS,
    MAX_VIEWPOINTS,
)
from graspd.core.masks import rle_decode, rle_string_counts
from graspd_client import wire
from graspd_client.codec import WireError

from .arrays import CameraPose, CameraSource, Matrix4, Normals, Pixels, Points, RGBImage, Viewpoints, array_field

#: The default of range_window (m): the detector's (graspd.gpd.preprocess.DEFAULT_RANGE_WINDOW; a test keeps
#: them equal).
DEFAULT_RANGE_WINDOW = 1.0
#: The default of max_per_object: the detector's (graspd.gpd.selection.DEFAULT_MAX_PER_OBJECT; a test keeps them
#: equal).
DEFAULT_MAX_PER_OBJECT = 1
#: The most share of a hand in unseen space when unknown_space "fallback" falls back: the detector's
#: (graspd.gpd.occlusion.UNKNOWN_FALLBACK_SHARE; a test keeps them equal).
UNKNOWN_FALLBACK_SHARE = 0.05

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
    pixels: Pixels | None = None  # type: ignore[valid-type]

    @field_validator("points")
    @classmethod
    def _points(cls, v: np.ndarray) -> np.ndarray:
        if len(v) == 0:
            raise ValueError("empty cloud (0 points); send at least one point")
        if len(v) > MAX_POINTS:
            raise ValueError(f"{len(v)} points exceeds the limit of {MAX_POINTS}")
        finite = np.isfinite(v).all(axis=1)  # the others are dropped (services.mapping): the bound is on the kept
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

    @field_validator("pixels")
    @classmethod
    def _pixels(cls, v: np.ndarray | None, info: ValidationInfo) -> np.ndarray | None:
        if v is None:
            return None
        pts, shape = info.data.get("points"), info.data.get("shape")
        if shape is None:
            raise ValueError("pixel indices need the image's shape: give cloud.shape [height, width]")
        if pts is not None and len(v) != len(pts):
            raise ValueError(f"one pixel index per point expected ({len(pts)}), got {len(v)}")
        if len(v) and (int(v[0]) < 0 or int(v[-1]) >= shape[0] * shape[1] or bool((np.diff(v) <= 0).any())):
            raise ValueError(f"increasing pixel indices in [0, {shape[0] * shape[1] - 1}] expected (a "
                             f"{shape[0]}x{shape[1]} image, row-major)")
        return v.astype(np.int64, copy=False)

    @model_validator(mode="after")
    def _frames(self) -> Cloud:
        """Frames are consistent (graspd.core.frames.check_points_frame; poses replace viewpoints).  The rows with
        a NaN or infinite coordinate are dropped and counted, and shape checked against the rows sent, when the
        request is mapped to the detector's input (services.mapping.cloud_input)."""
        check_points_frame(self.points_frame, self.camera_poses is not None, ".points_frame")
        check_camera_source(self.points_frame, len(self.camera_poses or ()), self.camera_source is not None,
                            ".camera_source")
        if self.camera_poses is not None and "viewpoints" in self.model_fields_set:
            raise WireError(".viewpoints", "give camera_poses or viewpoints, not both (with camera poses the "
                            "viewpoints are the cameras' positions in the robot frame)")
        return self

    def poses(self) -> np.ndarray | None:
        """The camera poses as one (K,4,4) array, None without them."""
        return None if self.camera_poses is None else np.stack(self.camera_poses)


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
        return v.astype(np.uint8)  # its size is checked with a PNG's (services.mapping.crops_image)

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
        """One image; a PNG is decoded and the intrinsics checked against the image's size when the request is
        mapped (services.mapping.crops_image)."""
        if (self.image is None) == (self.image_png is None):
            raise ValueError("give exactly one of image (array) or image_png (base64 PNG)")
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



Finite = Annotated[float, Field(allow_inf_nan=False)]


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
        self.pose()
        return self

    def pose(self) -> np.ndarray:
        """The box's pose (4x4: rotation columns the box axes, translation the centre), checked by
        graspd.core.frames.pose_matrix; WireError naming the sub-field."""
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
            return pose_matrix(value, "")
        except FieldError as exc:
            raise WireError(sub + exc.field if exc.field.startswith(".") or not exc.field else exc.field,
                            exc.message) from None


TargetIndices = array_field((None,), "i", "int64", False, "rows of the cloud (0-based, as sent: NaN rows count)")
TargetPoints = array_field((None, 3), "f", "float64", True, "sample points (K,3), m, in the request's frame")
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
        "rarely reaches it); the answer counts the points it left out (num_points_out_of_range).  0: keep every "
        "point")
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
    unknown_space: Literal["avoid", "fallback", "allow"] = Field(
        "avoid", description="space no camera saw (behind a seen surface from every camera): 'avoid' treats a "
        "hand with any of its fingers, palm or approach path there (beyond 4 mm) as colliding (a neighbour seen "
        "only in part may be there); 'fallback' does the same, but when that leaves no hand, those with at most "
        f"{UNKNOWN_FALLBACK_SHARE:.0%} there come back and the answer warns (unknown_space); 'allow' checks the "
        "seen points only, as GPD does, and warns when the best grasps reach into unseen space")
    flat_objects: bool = Field(False, description="grasp objects lying flat, thinner than the hand's init_bite "
                               "above the table (a packet 1 cm thick), by their edges: the fingertips stop above the "
                               "table and reach a few millimetres past its top.  Off by default: in the benchmark's "
                               "physics such grasps hold less often than deeper ones")
    robust_copies: int = Field(DEFAULT_ROBUST_COPIES, ge=0, le=MAX_ROBUST_COPIES,
                               description="the first 16 grasps are ranked by their classifier score "
                               "averaged over the grasp and this many copies moved 2 mm and turned 3 degrees (a "
                               "robot's and a camera's error): a grasp such an error spoils ranks lower.  Off (0) by "
                               "default: on the benchmark's held-out household objects 4 copies gained nothing")
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
    def _target_for_gpd(self) -> DetectRequest:
        """A target is for method gpd (its rows are checked against the cloud when the request is mapped:
        services.mapping.detection_target)."""
        if self.target is not None and self.method == "templates":
            raise WireError("target", "method 'templates' takes no target; use method 'gpd'")
        return self

    def hand_geometry(self) -> HandGeometry | None:
        """The requested hand, None for the detector's own."""
        return None if self.hand is None else self.hand.geometry()

    def workspace_bounds(self) -> tuple[float, float, float, float, float, float] | None:
        ws = self.workspace
        return None if ws is None else (ws[0], ws[1], ws[2], ws[3], ws[4], ws[5])
