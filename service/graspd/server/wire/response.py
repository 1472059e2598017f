"""The detect answer on the wire (POST /detect's 200 body, the Zenoh reply, the ROS 2 JSON output): grasps in
the gpd_ros GraspConfig convention (position = centre of the hand base, rotation columns [approach, binormal,
axis] = hand x, y, z, fingertips at position + hand_depth * approach), metres, in the answer's frame."""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import BaseModel, Field

from graspd.core.warning import MIN_DEPTH_SHARE, WARNING_CODES

from .detect import MAX_PER_OBJECT_TEXT, RANKING

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
                                     "with clustering, the sum of the cluster members' scores; with robust_copies, "
                                     "for the first 16 grasps by rank, averaged over that many copies of the grasp "
                                     "moved 2 mm and turned 3 degrees")
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


class DetectResponse(BaseModel):  # built by services.mapping.response (the docstring is in the OpenAPI document)
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
    num_points_received: int | None = Field(None, description="rows the request's cloud had (an organised cloud: "
                                            "its pixels)")
    num_points_dropped: int | None = Field(None, description="rows dropped for a NaN or infinite coordinate or "
                                           "normal: an organised cloud's pixels without depth (no warning unless "
                                           f"under {MIN_DEPTH_SHARE:.0%} have depth); an unorganised cloud's warn "
                                           "(non_finite_dropped)")
    num_points_out_of_range: int | None = Field(None, description="gpd: finite rows left out because they lie "
                                                "more than range_window (m) beyond the nearest surface the cameras "
                                                "see (only with no workspace: the room behind a table; 0 when "
                                                "none); give a workspace to choose the region yourself, or "
                                                "range_window 0 to keep every point")
    hand: dict[str, float] = Field(description="hand geometry used (m)")
    environment: EnvironmentOut | None = Field(None, description="gpd: what the environment stage found")
    warnings: list[WarningOut] = Field(default_factory=list, description="what the service could not do right "
                                       "for this request (empty for a correct request); the same on every "
                                       "transport")
    num_entries: int | None = Field(None, description="templates: library entries matched against")
    header: RosHeader | None = Field(None, description="Zenoh, CDR PointCloud2 input only: its ROS header")
    model_fits_hand: bool | None = Field(None, description="gpd with a model: whether the model serves the "
                                         "request's hand: trained on grasp images of it (finger width, outer "
                                         "diameter, depth, height), or chosen for it by the benchmarks (GET "
                                         "/models: measured_hands).  false: the hand and the model differ and the "
                                         "scores are less reliable (train one on a dataset of that hand: python -m "
                                         "graspd_lab.training.dataset --hand NAME, then graspd train)")
    ranking_rule: str | None = Field(None, description="gpd with selection: how each grasp's ranking terms combine "
                                     "into the key it was sorted by")
    objects: list[ObjectOut] | None = Field(None, description="gpd: the scene's objects by id, each with its grasps")
    max_per_object: int | None = Field(None, description="gpd: the max_per_object the list was ordered with (0: "
                                       "pure ranking; " + MAX_PER_OBJECT_TEXT + ")")

    def to_json(self) -> bytes:
        """The JSON bytes sent: compact, with the keys the mapping set (the others are not sent)."""
        return self.model_dump_json(exclude_unset=True).encode()
