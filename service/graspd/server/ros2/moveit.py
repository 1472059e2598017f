"""MoveIt's side of the node: finger postures of moveit_msgs/Grasp from the hand width, and the pieces of
moveit_msgs/srv/GraspPlanning (where to sample on the target object, the requested frame, the reply).

Postures: a two-finger hand whose finger joints each move one finger by half the opening (Panda, Robotiq-style
mimic grippers driven by one joint, most parallel-jaw grippers in MoveIt): pre_grasp_posture opens to the hand's
aperture (hand_outer_diameter - 2 finger_width), grasp_posture closes to the grasp's width less a squeeze, both
as one trajectory point reached after POSTURE_TIME_S.  Metres; joint names from the settings.

GraspPlanning: a CollisionObject names the target (primitives and meshes posed in target.header.frame_id).
graspd makes it one oriented box, the request's target box (graspd.gpd.target): with one shape, that shape's
bounding box (a box primitive itself; a sphere, cylinder or cone its enclosing box; a mesh the bounds of its
vertices in the mesh frame); with several, the bounds of all their boxes in the object's own frame
(CollisionObject.pose).  TARGET_MARGIN_M is added on every side (depth noise, a model posed a little off).
Hands are sampled on the object points within it and close on no object point outside it; the rest of the cloud
stays (the table and neighbours still stop hands that would collide).  A target without such geometry (only an
id, planes, prisms) is refused: graspd has no planning scene to look it up in.  The answer is in the target's frame
(target.header.frame_id): the detection frame itself, or the camera frame of a camera-frame cloud moved by the
configured camera pose; each grasp's id is "<target.id>/<rank>".  support_surfaces, candidate_grasps and
movable_obstacles are not used.  The target comes bounded (graspd.io.ros.planning: counts within core.limits, a
mesh as its vertex bounds) and its box is built vectorised.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from graspd.core.types import F64
from graspd.gpd.target import OrientedBox
from graspd.io.ros.planning import PlanTarget
from graspd.server.problems import Problem

#: Seconds after which a posture is reached (trajectory point time_from_start).
POSTURE_TIME_S = 0.5
#: Margin added on every side of the target's box (m): cloud points that far outside still count as its.
TARGET_MARGIN_M = 0.01
#: moveit_msgs/MoveItErrorCodes values used here.
SUCCESS, PLANNING_FAILED, UNABLE_TO_ACQUIRE_SENSOR_DATA, SENSOR_INFO_STALE = 1, -1, -5, -24
FRAME_TRANSFORM_FAILURE, INVALID_OBJECT_NAME, FAILURE, TIMED_OUT = -21, -19, 99999, -6
#: shape_msgs/SolidPrimitive types.
BOX, SPHERE, CYLINDER, CONE, PRISM = 1, 2, 3, 4, 5



class PlanningError(Problem):
    """A GraspPlanning request that cannot be answered with grasps: the MoveItErrorCodes value and why (a 422
    to the request's life: the caller's request cannot be planned for)."""

    def __init__(self, code: int, message: str) -> None:
        super().__init__(422, message)
        self.code = code


@dataclass(frozen=True)
class FingerPostures:
    """Finger joint targets of the open and closed hand: joint names, the open opening (m), the squeeze taken
    off the grasp width when closing (m) and the closing effort per joint (N; 0: none given)."""

    joints: tuple[str, ...]
    open_width: float
    squeeze: float = 0.01
    effort: float = 0.0

    def positions(self, opening: float) -> list[float]:
        """Each joint at half the opening (m), the opening clipped to [0, open_width]."""
        half = 0.5 * float(np.clip(opening, 0.0, self.open_width))
        return [half] * len(self.joints)

    def messages(self, store: Any, width: float) -> tuple[Any, Any]:
        """(pre_grasp_posture, grasp_posture) trajectory_msgs/JointTrajectory of a grasp of width (m), from the
        rosbags typestore store; empty trajectories when no joints are named."""
        t = store.types
        traj, point = t["trajectory_msgs/msg/JointTrajectory"], t["trajectory_msgs/msg/JointTrajectoryPoint"]
        header = t["std_msgs/msg/Header"](stamp=t["builtin_interfaces/msg/Time"](sec=0, nanosec=0), frame_id="")
        if not self.joints:
            empty = traj(header=header, joint_names=[], points=[])
            return empty, empty
        sec = int(POSTURE_TIME_S)
        when = t["builtin_interfaces/msg/Duration"](sec=sec, nanosec=int(round((POSTURE_TIME_S - sec) * 1e9)))
        zeros = np.zeros(0, np.float64)

        def one(opening: float, effort: float) -> Any:
            efforts = np.full(len(self.joints), effort, np.float64) if effort > 0 else zeros
            return traj(header=header, joint_names=list(self.joints), points=[point(
                positions=np.asarray(self.positions(opening), np.float64), velocities=zeros, accelerations=zeros,
                effort=efforts, time_from_start=when)])

        return one(self.open_width, 0.0), one(float(width) - self.squeeze, self.effort)


def pose_matrices(poses: NDArray[np.floating]) -> F64:
    """4x4 of each pose (B, 7: position m, quaternion x y z w; a zero or non-finite quaternion reads as
    identity), vectorised.  PlanningError when a position is not finite."""
    p = np.asarray(poses, np.float64).reshape(-1, 7)
    out = np.tile(np.eye(4), (len(p), 1, 1))
    q = p[:, 3:]
    with np.errstate(invalid="ignore", over="ignore"):
        norm = np.linalg.norm(q, axis=1)
    ok = np.isfinite(q).all(axis=1) & (norm > 1e-9)
    if ok.any():
        x, y, z, w = (q[ok] / norm[ok, None]).T
        out[ok, :3, :3] = np.stack([
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], axis=-1),
            np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], axis=-1),
            np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], axis=-1)], axis=1)
    out[:, :3, 3] = p[:, :3]
    if not np.isfinite(out).all():
        raise PlanningError(INVALID_OBJECT_NAME, "the target's poses must be finite")
    return out


@dataclass(frozen=True)
class Boxes:
    """Oriented boxes: poses (B, 4, 4) and half extents (B, 3), m."""

    poses: F64
    halves: F64

    def __len__(self) -> int:
        return len(self.halves)


def target_boxes(target: PlanTarget) -> Boxes:
    """Oriented bounding boxes of a GraspPlanning target's primitives and meshes (graspd.io.ros.planning), in
    the target's header frame, vectorised.  Planes, prisms, primitives without their dimensions and meshes
    without vertices bound nothing; primitives and meshes without a pose are left out."""
    base = pose_matrices(target.pose)[0]
    k = min(len(target.primitive_types), len(target.primitive_poses))
    types, d = target.primitive_types[:k], target.primitive_dimensions[:k]
    half = np.full((k, 3), np.nan)
    box, sphere, round_ = types == BOX, types == SPHERE, (types == CYLINDER) | (types == CONE)
    half[box] = d[box] / 2
    half[sphere] = d[sphere, :1]
    half[round_] = np.stack([d[round_, 1], d[round_, 1], d[round_, 0] / 2], axis=-1)
    keep = np.isfinite(half).all(axis=1)
    poses = [base @ pose_matrices(target.primitive_poses[:k][keep])]
    halves = [np.abs(half[keep])]
    m = min(len(target.mesh_bounds), len(target.mesh_poses))
    bounds = target.mesh_bounds[:m]
    has = np.isfinite(bounds).all(axis=(1, 2))
    if has.any():
        lo, hi = bounds[has, 0], bounds[has, 1]
        centre = np.tile(np.eye(4), (len(lo), 1, 1))
        centre[:, :3, 3] = (lo + hi) / 2
        poses.append(base @ pose_matrices(target.mesh_poses[:m][has]) @ centre)
        halves.append((hi - lo) / 2)
    return Boxes(np.concatenate(poses).reshape(-1, 4, 4), np.concatenate(halves).reshape(-1, 3))


def target_box(target: PlanTarget, to_detection: F64, margin: float = TARGET_MARGIN_M) -> OrientedBox:
    """The one oriented box of a GraspPlanning target in the detection frame (to_detection maps the target's
    frame into it): its one shape's box, or the bounds of all its shapes' boxes in the object's frame, grown by
    margin (m) on every side.  PlanningError INVALID_OBJECT_NAME when the target has no shape with a size."""
    boxes = target_boxes(target)
    if not len(boxes):
        raise PlanningError(INVALID_OBJECT_NAME, f"target {target.id!r} has no box, sphere, cylinder, cone or mesh "
                            "with vertices: graspd needs its geometry (it has no planning scene to look it up in)")
    if len(boxes) == 1:
        pose, half = boxes.poses[0], boxes.halves[0]
    else:
        frame = pose_matrices(target.pose)[0]
        local = np.linalg.inv(frame) @ boxes.poses  # each box in the object's frame
        reach = np.einsum("bij,bj->bi", np.abs(local[:, :3, :3]), boxes.halves)  # their axis-aligned half sizes
        lo, hi = (local[:, :3, 3] - reach).min(axis=0), (local[:, :3, 3] + reach).max(axis=0)
        pose = frame.copy()
        pose[:3, 3] = frame[:3, :3] @ ((lo + hi) / 2) + frame[:3, 3]
        half = (hi - lo) / 2
    m = np.asarray(to_detection, np.float64) @ pose
    return OrientedBox(centre=m[:3, 3].copy(), rotation=m[:3, :3].copy(), half_extents=np.abs(half) + margin)


def frame_transform(requested: str, detection_frame: str, cloud_frame: str, camera_poses: F64 | None,
                    points_frame: str | None) -> F64:
    """4x4 mapping the requested frame into the detection frame.  The requested frame may be the detection
    frame (or empty), or, for a camera-frame cloud moved by one configured camera pose, the cloud's own frame
    (camera_frame_id).  PlanningError FRAME_TRANSFORM_FAILURE otherwise (graspd has no TF tree)."""
    want = requested.lstrip("/")
    if not want or want == detection_frame.lstrip("/"):
        return np.eye(4)
    if camera_poses is not None and points_frame == "camera" and len(camera_poses) == 1 \
            and want == cloud_frame.lstrip("/"):
        return np.asarray(camera_poses[0], np.float64)
    raise PlanningError(FRAME_TRANSFORM_FAILURE, f"cannot express grasps in frame {requested!r}: graspd knows "
                        f"{detection_frame!r}" + (f" and {cloud_frame!r}" if camera_poses is not None else "") +
                        " (set camera_poses, camera_frame_id and robot_frame_id in GRASPD_ROS2_OPTIONS)")


def error_code(store: Any, code: int, message: str = "", source: str = "graspd") -> Any:
    """moveit_msgs/MoveItErrorCodes of the distro's store (message and source from Jazzy on)."""
    cls = store.types["moveit_msgs/msg/MoveItErrorCodes"]
    names = {f for f, _ in store.fielddefs["moveit_msgs/msg/MoveItErrorCodes"][1]}
    return cls(val=code, **({"message": message, "source": source} if "message" in names else {}))
