"""Camera poses and the frames a cloud can come in, one way for every entrance (JSON, uploads, Zenoh, the ROS
streams, the CLI).

A robot knows each camera's pose in its base frame (ROS: the TF transform camera -> base_link).  A request may
give those poses (`camera_poses`: one camera-to-robot transform per camera, 4x4 or position + quaternion) and
say which frame its points are in (`points_frame`):

- "camera": each point is in the frame of the camera that saw it (camera_source picks the camera; ROS: the
  PointCloud2's frame_id, an optical frame); graspd moves it into the robot frame, p_robot = R_c p + t_c;
- "robot": the points are already in the robot frame; the poses only say where the cameras were.

Either way the viewpoints are the cameras' positions t_c in the robot frame, detection runs in the robot frame
and the grasps come back in it: the response's `frame` is "robot".  Without camera poses everything stays in
the frame of the cloud as sent (viewpoints in that frame) and the response's `frame` is "cloud".

Metres, right-handed; quaternions are x, y, z, w (ROS order).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray

from graspd.core.errors import FieldError
from graspd.core.limits import MAX_COORDINATE, MAX_VIEWPOINTS
from graspd.core.types import F64

PointsFrame = Literal["camera", "robot"]
#: What `points_frame` may say.
POINTS_FRAMES: tuple[str, ...] = ("camera", "robot")
#: The frame a response's grasps are in: the robot frame (camera poses given) or the cloud's own frame.
FRAME_ROBOT = "robot"
FRAME_CLOUD = "cloud"
#: Largest |translation| of a camera pose (m): the coordinate bound of graspd.core.limits.
MAX_TRANSLATION = MAX_COORDINATE
#: How far a rotation may be from orthonormal (max |R R^T - I|), and a quaternion's norm from 1: float32 TF
#: transforms and rounded printouts pass, a scaled or sheared matrix does not.
ORTHONORMAL_TOL = 1e-3
QUATERNION_TOL = 1e-2



def quaternion_matrix(quat_xyzw: Sequence[float] | NDArray[np.floating]) -> F64:
    """The 3x3 rotation of a unit quaternion (x, y, z, w); it is normalised first."""
    x, y, z, w = np.asarray(quat_xyzw, np.float64) / np.linalg.norm(quat_xyzw)
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def _numbers(value: Any, n: int, field: str, what: str) -> F64:
    try:
        arr = np.asarray(value, np.float64).reshape(-1)
    except (TypeError, ValueError):
        raise FieldError(field, f"{what}: {n} numbers expected, got {value!r}") from None
    if arr.shape != (n,):
        raise FieldError(field, f"{what}: {n} numbers expected, got {arr.size}")
    if not np.isfinite(arr).all():
        raise FieldError(field, f"{what}: must be finite (NaN or infinite values given)")
    return arr


def check_pose(matrix: NDArray[np.floating], field: str = "camera_poses") -> F64:
    """A checked camera-to-robot transform (4x4 float64): finite, last row 0 0 0 1, a proper rotation (orthonormal
    within ORTHONORMAL_TOL, determinant +1: a mirror is refused), translation within MAX_TRANSLATION m.  The
    rotation is snapped to the nearest exact one (SVD), so float32 round-off does not skew the cloud.
    FieldError naming field otherwise."""
    m = np.asarray(matrix, np.float64)
    if m.shape != (4, 4):
        raise FieldError(field, f"a 4x4 transform expected, got shape {m.shape}")
    if not np.isfinite(m).all():
        raise FieldError(field, "must be finite (NaN or infinite values given)")
    if not np.allclose(m[3], [0.0, 0.0, 0.0, 1.0], atol=1e-6):
        raise FieldError(field, f"last row must be 0 0 0 1, got {m[3].tolist()}")
    r = m[:3, :3]
    err = float(np.abs(r @ r.T - np.eye(3)).max())
    if err > ORTHONORMAL_TOL:
        raise FieldError(field, f"the rotation block is not orthonormal (|R R^T - I| = {err:.3g}); send a rigid "
                        "camera-to-robot transform (no scale or shear)")
    if np.linalg.det(r) < 0:
        raise FieldError(field, "the rotation block has determinant -1 (a mirror, not a rotation): a "
                        "right-handed camera-to-robot transform is expected")
    if np.abs(m[:3, 3]).max() > MAX_TRANSLATION:
        raise FieldError(field, f"translation beyond +-{MAX_TRANSLATION:g} m; send metres")
    u, _, vt = np.linalg.svd(r)
    out = np.eye(4)
    out[:3, :3] = u @ vt
    out[:3, 3] = m[:3, 3]
    return out


def pose_matrix(value: Any, field: str = "camera_poses") -> F64:
    """One camera-to-robot transform from what a caller may send: a 4x4 matrix (nested lists or an array,
    row-major), 16 numbers (row-major), {"position": [x, y, z], "quat_xyzw": [x, y, z, w]} (ROS TF order), or 7
    numbers x, y, z, qx, qy, qz, qw.  Checked with check_pose; FieldError naming field (or its sub-field)."""
    if isinstance(value, Mapping):
        extra = sorted(set(value) - {"position", "quat_xyzw"})
        if extra or "position" not in value or "quat_xyzw" not in value:
            raise FieldError(field, "{\"position\": [x, y, z], \"quat_xyzw\": [x, y, z, w]} or a 4x4 matrix "
                            f"expected, got keys {sorted(value)}")
        t = _numbers(value["position"], 3, f"{field}.position", "position")
        q = _numbers(value["quat_xyzw"], 4, f"{field}.quat_xyzw", "quaternion")
        return _from_position_quaternion(t, q, f"{field}.quat_xyzw", field)
    try:
        arr = np.asarray(value, np.float64)
    except (TypeError, ValueError):
        raise FieldError(field, "a 4x4 matrix or {position, quat_xyzw} expected (numbers only)") from None
    if arr.shape in ((16,), (4, 4)):
        return check_pose(arr.reshape(4, 4), field)
    if arr.shape == (7,):
        if not np.isfinite(arr).all():
            raise FieldError(field, "must be finite (NaN or infinite values given)")
        return _from_position_quaternion(arr[:3], arr[3:], field, field)
    raise FieldError(field, f"a 4x4 matrix, 16 numbers (row-major), {{position, quat_xyzw}} or 7 numbers "
                    f"(x, y, z, qx, qy, qz, qw) expected, got shape {arr.shape}")


def _from_position_quaternion(t: F64, q: F64, q_field: str, field: str) -> F64:
    norm = float(np.linalg.norm(q))
    if abs(norm - 1.0) > QUATERNION_TOL:
        raise FieldError(q_field, f"a unit quaternion (x, y, z, w) expected, got norm {norm:.4g}")
    m = np.eye(4)
    m[:3, :3] = quaternion_matrix(q)
    m[:3, 3] = t
    return check_pose(m, field)


def pose_matrices(values: Any, field: str = "camera_poses", max_cameras: int = MAX_VIEWPOINTS) -> F64:
    """(K, 4, 4) camera-to-robot transforms from a list of poses (each as pose_matrix takes it), or from one
    (K, 4, 4) array; 1 to max_cameras of them.  FieldError naming field[k] of a bad one."""
    if isinstance(values, np.ndarray) and values.ndim == 3:
        values = list(values)
    if isinstance(values, Mapping) or not isinstance(values, Sequence | np.ndarray) or isinstance(values, str):
        raise FieldError(field, "a list of camera poses expected (one per camera)")
    if not 1 <= len(values) <= max_cameras:
        raise FieldError(field, f"1 to {max_cameras} camera poses expected, got {len(values)}")
    return np.stack([pose_matrix(v, f"{field}[{k}]") for k, v in enumerate(values)])


def camera_positions(poses: F64) -> F64:
    """The cameras' positions in the robot frame (K, 3): the translations of their camera-to-robot poses."""
    return np.asarray(poses, np.float64)[:, :3, 3].copy()


def to_robot(points: NDArray[np.floating], camera_source: NDArray[np.integer], poses: F64,
             normals: NDArray[np.floating] | None = None
             ) -> tuple[NDArray[np.float32], NDArray[np.float32] | None]:
    """Camera-frame points (N, 3) moved into the robot frame, each with the pose of the camera that saw it
    (poses[camera_source[i]]): p -> R p + t; normals are rotated.  float32 out, float64 arithmetic."""
    pts = np.asarray(points)
    src = np.asarray(camera_source)
    out = np.empty(pts.shape, np.float32)
    nrm_out = None if normals is None else np.empty(pts.shape, np.float32)
    cams = np.unique(src) if len(poses) > 1 else np.zeros(1, np.int64)
    for k in cams.tolist():
        rows = slice(None) if len(cams) == 1 else src == k
        r, t = poses[k, :3, :3], poses[k, :3, 3]
        out[rows] = np.asarray(pts[rows], np.float64) @ r.T + t
        if normals is not None and nrm_out is not None:
            nrm_out[rows] = np.asarray(normals[rows], np.float64) @ r.T
    return out, nrm_out


def frame_name(camera_poses: F64 | None) -> str:
    """The frame detection runs and answers in: "robot" with camera poses, else "cloud" (as sent)."""
    return FRAME_CLOUD if camera_poses is None else FRAME_ROBOT


def check_points_frame(points_frame: str | None, has_poses: bool, field: str = "points_frame") -> None:
    """points_frame is needed exactly when camera poses are given (the points' frame cannot be guessed safely:
    a wrong guess moves the whole cloud); FieldError naming the field otherwise."""
    if points_frame is not None and points_frame not in POINTS_FRAMES:
        raise FieldError(field, f"one of {list(POINTS_FRAMES)} expected, got {points_frame!r}")
    if has_poses and points_frame is None:
        raise FieldError(field, "required with camera_poses: 'camera' (each point in the frame of the camera that "
                        "saw it; graspd moves it into the robot frame) or 'robot' (already in the robot frame)")
    if not has_poses and points_frame is not None:
        raise FieldError(field, f"points_frame {points_frame!r} needs camera_poses (one camera-to-robot transform "
                        "per camera); without them everything stays in the cloud's own frame")


def check_camera_source(points_frame: str | None, num_poses: int, has_source: bool,
                        field: str = "cloud.camera_source") -> None:
    """Camera-frame points of several cameras need camera_source: which camera's pose moves each point (guessing
    would put one camera's points where another's belong).  FieldError naming the field otherwise."""
    if points_frame == "camera" and num_poses > 1 and not has_source:
        raise FieldError(field, f"required with {num_poses} camera poses and points_frame 'camera': the index of "
                        "the camera that saw each point (its pose moves the point into the robot frame)")
