"""Field names, limits and the request builder of the graspd wire contract, shared by
client and server so there is one definition.

Frames and units: metres, right-handed, everything in the frame of the cloud the caller sends;
viewpoints are camera positions in that frame.  Or, with camera_poses (one camera-to-robot transform per
camera, ROS TF's camera -> base_link) and points_frame ("camera": each point in its camera's frame, as a driver
gives it; "robot": already in the robot frame), the server moves the cloud into the robot frame and answers
there (the response's "frame" is "robot"); workspace, gravity and the other geometric options are then in the
robot frame too.  A grasp follows gpd_ros GraspConfig: rotation
columns [approach, binormal, axis], position = centre of the hand base.
"""

from __future__ import annotations

import base64
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .codec import WireError, encode_array

API_VERSION = "1"

#: Upper bounds the server enforces (requests beyond them get a 422 naming the field).
MAX_NUM_SAMPLES = 20_000
MAX_GRASPS = 1_000
MAX_VIEWPOINTS = 64
MAX_TARGET_INDICES = 5_000_000
MAX_TARGET_POINTS = 20_000
MAX_TARGET_RLE_CHARS = 1 << 22
MAX_OBJECT_ID = 100_000
MAX_PER_OBJECT = 1_000
MAX_ROBUST_COPIES = 16
#: The kinds of target a detect request may give (one of them).
TARGET_KINDS: tuple[str, ...] = ("indices", "mask", "box", "points", "object")
MIN_CROP_SIZE = 8
MAX_CROP_SIZE = 512
DEFAULT_CROP_SIZE = 120

#: Hand-geometry fields (GPD names, metres) a request may override.
HAND_FIELDS: tuple[str, ...] = ("finger_width", "hand_outer_diameter", "hand_depth", "hand_height", "init_bite",
                                "palm_depth")

#: Per-grasp fields of a detect response.
GRASP_FIELDS: tuple[str, ...] = (
    "id", "position", "approach", "binormal", "axis", "width", "score", "sample", "pose", "quat_xyzw",
)

#: Detectors a detect request may ask for ("method"): GPD, or grasp templates from demonstrations.
DETECT_METHODS: tuple[str, ...] = ("gpd", "templates")

#: Zenoh key suffixes under the configured prefix (default "graspd").
ZENOH_DETECT_KEY = "detect"
ZENOH_CLOUD_KEY = "cloud"
ZENOH_GRASPS_KEY = "grasps"
ZENOH_DEMONSTRATIONS_KEY = "demonstrations"  # the bodies and answers of POST /demonstrations,
ZENOH_FEEDBACK_KEY = "feedback"  # POST /feedback
ZENOH_LIBRARY_KEY = "library"  # and GET /library (empty payload)

#: Zenoh's twin of HTTP's `Authorization: Bearer <token>`: a server with GRASPD_TOKEN set answers a query
#: (and takes a streamed cloud) only when its attachment is exactly b"Bearer <token>" (UTF-8); otherwise it
#: sends an error reply with status 401 and does nothing.
ZENOH_AUTH_SCHEME = b"Bearer "


def zenoh_token_attachment(token: str) -> bytes:
    """The Zenoh attachment that carries token (b"Bearer <token>")."""
    return ZENOH_AUTH_SCHEME + token.encode()

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def _vec(value: ArrayLike, n: int, field: str) -> list[float]:
    arr = np.asarray(value, np.float64).reshape(-1)
    if arr.shape != (n,) or not np.isfinite(arr).all():
        raise WireError(field, f"{n} finite numbers expected, got {np.asarray(value).tolist()!r}")
    return [float(v) for v in arr]


def build_detect_request(
    points: ArrayLike,
    viewpoints: ArrayLike = ((0.0, 0.0, 0.0),),
    camera_source: ArrayLike | None = None,
    *,
    workspace: Sequence[float] | None = None,
    hand: str | Mapping[str, Any] | None = None,
    model: str | None = None,
    num_samples: int | None = None,
    max_grasps: int | None = None,
    min_score: float | None = None,
    approach_direction: Sequence[float] | None = None,
    approach_max_angle_deg: float | None = None,
    selection: bool | None = None,
    seed: int | None = None,
    clustering: bool | None = None,
    use_classifier: bool | None = None,
    gravity: Sequence[float] | None = None,
    exclude_support_plane: bool | None = None,
    min_aperture: float | None = None,
    max_aperture: float | None = None,
    image: ArrayLike | bytes | None = None,
    intrinsics: Mapping[str, float] | Sequence[float] | None = None,
    camera_pose: ArrayLike | None = None,
    crop_size: int | None = None,
    method: str | None = None,
    environment: str | Mapping[str, Any] | None = None,
    approach_distance: float | None = None,
    camera_poses: Sequence[Any] | ArrayLike | None = None,
    points_frame: str | None = None,
    normals: ArrayLike | None = None,
    unknown_space: str | None = None,
    target: Mapping[str, Any] | None = None,
    max_per_object: int | None = None,
    flat_objects: bool | None = None,
    robust_copies: int | None = None,
) -> dict[str, Any]:
    """The JSON body of POST /detect (and of the Zenoh query) from numpy inputs.

    points (N,3) m, or an organised (H,W,3) cloud (sent with its shape); viewpoints (K,3) camera positions;
    camera_source (N,) index into viewpoints;
    image HxWx3 uint8 (or PNG bytes) with intrinsics (fx, fy, cx, cy) and camera_pose (4x4,
    camera-to-cloud) asks for one object-proposal crop per grasp.  method "templates" asks the grasp-template
    detector (it takes cloud, workspace, max_grasps and hand only).  gravity (3,) is the direction gravity
    pulls in the cloud frame (ranks by score x utility J(h)); use_classifier=False is the unscored ablation;
    min_aperture/max_aperture (m) bound the grasp width; exclude_support_plane overrides where samples go.
    environment "auto" (the server's default), "declared" or "none", or {"mode", "support_plane": [a, b, c, d],
    "boxes": [[xmin, xmax, ymin, ymax, zmin, zmax], ...]}; approach_distance (m) the pre-grasp distance.
    camera_poses: one camera-to-robot transform per camera (4x4, or {"position", "quat_xyzw"}, or 7 numbers x, y,
    z, qx, qy, qz, qw) with points_frame "camera" or "robot" (see the module's note on frames); viewpoints are
    then left out.  normals (N,3): optional unit normals pointing toward the cameras.  unknown_space "avoid" (the
    server's default: a hand reaching into space no camera saw collides), "fallback" (the same; when no hand is
    left, those reaching least into it come back with a warning) or "allow" (seen points only).
    target: what to grasp, one of {"indices": rows}, {"mask": PNG bytes, a boolean (H, W) image or COCO RLE
    {"size", "counts"}}, {"box": {"centre", "rotation" or "quat_xyzw", "half_extents"}}, {"points": (K, 3)} or
    {"object": id} (build_target).  max_per_object: most grasps per object before every other object has one
    (0 = pure ranking; default the server's).  flat_objects=True also grasps objects lying flat (a packet 1 cm
    thick) by their edges, the fingertips stopping above the table (off by default: such grasps hold less often).
    robust_copies: moved copies of each of the first grasps that the ranking averages their score over (0 = off;
    default the server's).
    """
    body: dict[str, Any] = {"cloud": build_cloud(points, viewpoints, camera_source, camera_poses=camera_poses,
                                                 points_frame=points_frame, normals=normals)}
    if method is not None:
        if method not in DETECT_METHODS:
            raise WireError("method", f"one of {DETECT_METHODS} expected, got {method!r}")
        body["method"] = method
    if workspace is not None:
        body["workspace"] = _vec(workspace, 6, "workspace")
    if hand is not None:
        body["hand"] = hand if isinstance(hand, str) else dict(hand)
    options = {"model": model, "num_samples": num_samples, "max_grasps": max_grasps, "min_score": min_score,
               "selection": selection, "seed": seed, "clustering": clustering, "use_classifier": use_classifier,
               "exclude_support_plane": exclude_support_plane, "min_aperture": min_aperture,
               "max_aperture": max_aperture, "approach_distance": approach_distance, "unknown_space": unknown_space,
               "max_per_object": max_per_object, "flat_objects": flat_objects, "robust_copies": robust_copies}
    body.update({k: v for k, v in options.items() if v is not None})
    if environment is not None:
        body["environment"] = environment if isinstance(environment, str) else dict(environment)
    if target is not None:
        body["target"] = build_target(target)
    if gravity is not None:
        body["gravity"] = _vec(gravity, 3, "gravity")
    if approach_direction is not None:
        body["approach"] = {"direction": _vec(approach_direction, 3, "approach.direction")}
        if approach_max_angle_deg is not None:
            body["approach"]["max_angle_deg"] = float(approach_max_angle_deg)
    if image is not None:
        if intrinsics is None or camera_pose is None:
            raise WireError("crops", "an image needs intrinsics and camera_pose")
        if isinstance(intrinsics, Mapping):
            intr = {k: float(intrinsics[k]) for k in ("fx", "fy", "cx", "cy")}
        else:
            intr = dict(zip(("fx", "fy", "cx", "cy"), _vec(intrinsics, 4, "crops.intrinsics"), strict=True))
        crops: dict[str, Any] = {
            "intrinsics": intr,
            "camera_pose": np.asarray(camera_pose, np.float64).reshape(4, 4).tolist(),
        }
        if isinstance(image, bytes | bytearray):
            crops["image_png"] = base64.b64encode(bytes(image)).decode("ascii")
        else:
            crops["image"] = encode_array(np.asarray(image, np.uint8))
        if crop_size is not None:
            crops["size"] = int(crop_size)
        body["crops"] = crops
    return body


def build_target(target: Mapping[str, Any]) -> dict[str, Any]:
    """The JSON of a request's target from numpy inputs: indices (N,) ints; mask PNG bytes, base64 text, a
    boolean (H, W) image (sent as COCO RLE: column-major run lengths) or {"size", "counts"}; box {"centre",
    "rotation" (3x3) or "quat_xyzw", "half_extents"} (m, the request's frame); points (K, 3) m; object an id.
    Counts are checked against the server's limits before anything is sent."""
    given = [k for k in target if k in TARGET_KINDS]
    if len(given) != 1 or len(target) != 1:
        raise WireError("target", f"exactly one of {list(TARGET_KINDS)} expected, got {sorted(target)}")
    kind, value = given[0], target[given[0]]
    if kind == "indices":
        idx = np.asarray(value).reshape(-1)
        if len(idx) > MAX_TARGET_INDICES:
            raise WireError("target.indices", f"{len(idx)} rows exceeds the limit of {MAX_TARGET_INDICES}")
        if idx.dtype.kind not in "iu":
            raise WireError("target.indices", f"integer rows expected, got dtype {idx.dtype.name}")
        return {"indices": encode_array(idx.astype(np.int64))}
    if kind == "mask":
        if isinstance(value, bytes | bytearray):
            return {"mask": base64.b64encode(bytes(value)).decode("ascii")}
        if isinstance(value, str | Mapping):
            return {"mask": value if isinstance(value, str) else dict(value)}
        image = np.asarray(value).astype(bool)
        if image.ndim != 2:
            raise WireError("target.mask", f"a 2-D (height, width) image expected, got shape {image.shape}")
        return {"mask": {"size": list(image.shape), "counts": rle_counts(image)}}
    if kind == "box":
        box = dict(value)
        out: dict[str, Any] = {"centre": _vec(box["centre"], 3, "target.box.centre"),
                               "half_extents": _vec(box["half_extents"], 3, "target.box.half_extents")}
        if box.get("rotation") is not None:
            out["rotation"] = np.asarray(box["rotation"], np.float64).reshape(3, 3).tolist()
        if box.get("quat_xyzw") is not None:
            out["quat_xyzw"] = _vec(box["quat_xyzw"], 4, "target.box.quat_xyzw")
        return {"box": out}
    if kind == "points":
        pts = np.asarray(value, np.float64).reshape(-1, 3)
        if len(pts) > MAX_TARGET_POINTS:
            raise WireError("target.points", f"{len(pts)} points exceeds the limit of {MAX_TARGET_POINTS}")
        return {"points": encode_array(pts)}
    return {"object": int(value)}


def rle_counts(image: NDArray[np.bool_]) -> list[int]:
    """COCO run lengths of a boolean (H, W) image: column-major, alternating runs of 0 and 1 from 0."""
    flat = np.asarray(image, bool).T.reshape(-1)
    change = np.flatnonzero(np.diff(flat.astype(np.int8))) + 1
    bounds = np.concatenate([[0], change, [flat.size]])
    counts = np.diff(bounds).tolist()
    return [0, *counts] if flat.size and flat[0] else counts


def camera_poses_json(poses: Sequence[Any] | ArrayLike) -> list[Any]:
    """The JSON form of camera poses: each a 4x4 nested list, or {"position", "quat_xyzw"} (from a mapping, or
    from 7 numbers x, y, z, qx, qy, qz, qw).  The server checks them (proper rotation, finite)."""
    if isinstance(poses, np.ndarray) and poses.ndim == 2:
        poses = [poses]
    out: list[Any] = []
    for k, pose in enumerate(poses):  # type: ignore[arg-type]
        if isinstance(pose, Mapping):
            out.append({"position": _vec(pose["position"], 3, f"cloud.camera_poses[{k}].position"),
                        "quat_xyzw": _vec(pose["quat_xyzw"], 4, f"cloud.camera_poses[{k}].quat_xyzw")})
            continue
        arr = np.asarray(pose, np.float64)
        if arr.size == 7:
            out.append({"position": arr.reshape(-1)[:3].tolist(), "quat_xyzw": arr.reshape(-1)[3:].tolist()})
        elif arr.size == 16:
            out.append(arr.reshape(4, 4).tolist())
        else:
            raise WireError(f"cloud.camera_poses[{k}]", f"a 4x4 matrix, {{position, quat_xyzw}} or 7 numbers "
                            f"expected, got shape {arr.shape}")
    return out


def build_cloud(points: ArrayLike, viewpoints: ArrayLike = ((0.0, 0.0, 0.0),),
                camera_source: ArrayLike | None = None, *, camera_poses: Sequence[Any] | ArrayLike | None = None,
                points_frame: str | None = None, normals: ArrayLike | None = None) -> dict[str, Any]:
    """The "cloud" object of a request: points (N,3) m, or an organised cloud (H,W,3) as a depth camera's driver
    gives it (sent row-major with its shape [H, W], so the server can use image neighbours), NaN rows dropped and
    counted by the server; camera positions (K,3) m, per-point camera index; or camera_poses and points_frame
    instead of the viewpoints (the default origin viewpoint is then left out).  Normals and camera_source of an
    organised cloud may come as (H,W,3) and (H,W)."""
    pts = np.asarray(points, np.float32)
    shape: list[int] | None = None
    if pts.ndim == 3 and pts.shape[2] == 3:
        shape = [int(pts.shape[0]), int(pts.shape[1])]
        pts = pts.reshape(-1, 3)
        normals = None if normals is None else np.asarray(normals, np.float32).reshape(-1, 3)
        camera_source = None if camera_source is None else np.asarray(camera_source).reshape(-1)
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise WireError("cloud.points", f"shape (N,3) or (H,W,3) expected, got {tuple(pts.shape)}")
    vps = np.asarray(viewpoints, np.float64).reshape(-1, 3)
    cloud: dict[str, Any] = {"points": encode_array(pts)}
    if shape is not None:
        cloud["shape"] = shape
    if camera_poses is None or not (vps.shape == (1, 3) and not vps.any()):
        cloud["viewpoints"] = vps.tolist()
    if camera_poses is not None:
        cloud["camera_poses"] = camera_poses_json(camera_poses)
    if points_frame is not None:
        cloud["points_frame"] = points_frame
    if camera_source is not None:
        cloud["camera_source"] = encode_array(np.asarray(camera_source).astype(np.int32))
    if normals is not None:
        cloud["normals"] = encode_array(np.asarray(normals, np.float32))
    return cloud


def upload_params(params: Mapping[str, Any]) -> dict[str, Any]:
    """Query parameters of a file upload to POST /detect from Python values: vectors (viewpoint, intrinsics,
    workspace, gravity) as comma-separated numbers, camera_pose (one pose or a list of them: 4x4, 7 numbers or
    {position, quat_xyzw}) as repeated 'x,y,z,qx,qy,qz,qw' or 16 numbers, booleans as true/false."""
    out: dict[str, Any] = {}
    for name, value in params.items():
        if value is None:
            continue
        if name in ("camera_pose", "camera_poses"):
            poses = camera_poses_json(value if not _one_pose(value) else [value])
            out["camera_pose"] = [",".join(repr(float(v)) for v in (
                [*p["position"], *p["quat_xyzw"]] if isinstance(p, dict) else np.asarray(p).reshape(-1)))
                for p in poses]
        elif name == "viewpoint" and np.asarray(value).ndim == 2:
            out[name] = [",".join(repr(float(v)) for v in row) for row in np.asarray(value, np.float64)]
        elif isinstance(value, bool):
            out[name] = "true" if value else "false"
        elif isinstance(value, str | int | float):
            out[name] = value
        elif isinstance(value, Mapping) and name == "intrinsics":
            out[name] = ",".join(repr(float(value[k])) for k in ("fx", "fy", "cx", "cy"))
        else:
            out[name] = ",".join(repr(float(v)) for v in np.asarray(value, np.float64).reshape(-1))
    return out


def _one_pose(value: Any) -> bool:
    """Whether a camera_pose value is one pose (a mapping, a 4x4, 7 or 16 numbers), not a list of them."""
    if isinstance(value, Mapping):
        return True
    try:
        arr = np.asarray(value, np.float64)
    except (TypeError, ValueError):  # a list of mappings
        return False
    return arr.shape in ((4, 4), (7,), (16,))


def build_demonstration_request(
    points: ArrayLike,
    hand_pose: ArrayLike,
    viewpoints: ArrayLike = ((0.0, 0.0, 0.0),),
    camera_source: ArrayLike | None = None,
    *,
    label: str | None = None,
    hand: str | Mapping[str, Any] | None = None,
    workspace: Sequence[float] | None = None,
) -> dict[str, Any]:
    """The JSON body of POST /demonstrations: a cloud of the table and one object and the demonstrated hand
    pose (4x4, cloud frame, rotation columns [approach, binormal, axis], translation the hand-base centre)."""
    pose = np.asarray(hand_pose, np.float64)
    if pose.shape != (4, 4) or not np.isfinite(pose).all():
        raise WireError("hand_pose", f"a finite 4x4 matrix expected, got shape {pose.shape}")
    body: dict[str, Any] = {"cloud": build_cloud(points, viewpoints, camera_source), "hand_pose": pose.tolist()}
    if label is not None:
        body["label"] = label
    if hand is not None:
        body["hand"] = hand if isinstance(hand, str) else dict(hand)
    if workspace is not None:
        body["workspace"] = _vec(workspace, 6, "workspace")
    return body


def build_feedback_request(grasp_id: str, success: bool) -> dict[str, Any]:
    """The JSON body of POST /feedback: the id of a returned grasp and whether executing it succeeded."""
    if not isinstance(grasp_id, str) or not grasp_id:
        raise WireError("grasp_id", f"the id of a returned grasp (a string) expected, got {grasp_id!r}")
    return {"grasp_id": grasp_id, "success": bool(success)}


def decode_png_bytes(value: str | None) -> bytes | None:
    """PNG bytes from the base64 text of a response crop (None stays None)."""
    if value is None:
        return None
    raw = base64.b64decode(value)
    if not raw.startswith(PNG_MAGIC):
        raise WireError("grasps.crop.png", "not a PNG")
    return raw

