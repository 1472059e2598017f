"""MoveIt's side of the node: finger postures of moveit_msgs/Grasp from the hand width, and the pieces of
moveit_msgs/srv/GraspPlanning (where to sample on the target object, the requested frame, the reply).

Postures: a two-finger hand whose finger joints each move one finger by half the opening (Panda, Robotiq-style
mimic grippers driven by one joint, most parallel-jaw grippers in MoveIt): pre_grasp_posture opens to the hand's
aperture (hand_outer_diameter - 2 finger_width), grasp_posture closes to the grasp's width less a squeeze, both
as one trajectory point reached after POSTURE_TIME_S.  Metres; joint names from the settings.

GraspPlanning: a CollisionObject names the target (primitives and meshes posed in target.header.frame_id);
graspd samples hands at the points of the newest cloud that lie within the target's bounding boxes (the rest of
the cloud stays: the table and neighbours still stop hands that would collide), and answers in the target's
frame (target.header.frame_id): the detection frame itself, or the camera frame of a camera-frame cloud moved by
the configured camera pose.  support_surfaces, candidate_grasps and movable_obstacles are not used.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from graspd.core.frames import quaternion_matrix

#: Seconds after which a posture is reached (trajectory point time_from_start).
POSTURE_TIME_S = 0.5
#: Margin around the target's bounding boxes within which cloud points count as the target's (m).
TARGET_MARGIN_M = 0.01
#: moveit_msgs/MoveItErrorCodes values used here.
SUCCESS, PLANNING_FAILED, UNABLE_TO_ACQUIRE_SENSOR_DATA, SENSOR_INFO_STALE = 1, -1, -5, -24
FRAME_TRANSFORM_FAILURE, INVALID_OBJECT_NAME, FAILURE, TIMED_OUT = -21, -19, 99999, -6
#: shape_msgs/SolidPrimitive types.
BOX, SPHERE, CYLINDER, CONE, PRISM = 1, 2, 3, 4, 5

F64 = NDArray[np.float64]


class PlanningError(Exception):
    """A GraspPlanning request that cannot be answered with grasps: the MoveItErrorCodes value and why."""

    def __init__(self, code: int, message: str) -> None:
        super().__init__(message)
        self.code = code
        self.message = message


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


def pose_matrix(pose: Any) -> F64:
    """4x4 of a geometry_msgs/Pose (position m, orientation x y z w; a zero quaternion reads as identity)."""
    q = pose.orientation
    quat = np.array([q.x, q.y, q.z, q.w], np.float64)
    out = np.eye(4)
    if np.isfinite(quat).all() and np.linalg.norm(quat) > 1e-9:
        out[:3, :3] = quaternion_matrix(quat)
    p = pose.position
    out[:3, 3] = [p.x, p.y, p.z]
    if not np.isfinite(out).all():
        raise PlanningError(INVALID_OBJECT_NAME, "the target's poses must be finite")
    return out


def target_boxes(target: Any) -> list[tuple[F64, F64]]:
    """Oriented bounding boxes of a moveit_msgs/CollisionObject's primitives and meshes, in the target's header
    frame: (4x4 box pose, half extents (3,) m) each.  Planes, and primitives without dimensions, bound nothing."""
    base = pose_matrix(target.pose)
    boxes: list[tuple[F64, F64]] = []
    for prim, pose in zip(target.primitives, target.primitive_poses, strict=False):
        d = np.asarray(prim.dimensions, np.float64)
        if prim.type == BOX and len(d) >= 3:
            half = d[:3] / 2
        elif prim.type == SPHERE and len(d) >= 1:
            half = np.full(3, d[0])
        elif prim.type in (CYLINDER, CONE) and len(d) >= 2:
            half = np.array([d[1], d[1], d[0] / 2])
        else:
            continue
        boxes.append((base @ pose_matrix(pose), np.abs(half)))
    for mesh, pose in zip(target.meshes, target.mesh_poses, strict=False):
        if not len(mesh.vertices):
            continue
        v = np.array([[p.x, p.y, p.z] for p in mesh.vertices], np.float64)
        lo, hi = v.min(axis=0), v.max(axis=0)
        centre = np.eye(4)
        centre[:3, 3] = (lo + hi) / 2
        boxes.append((base @ pose_matrix(pose) @ centre, (hi - lo) / 2))
    return boxes


def points_in_boxes(points: NDArray[np.floating], boxes: list[tuple[F64, F64]], to_points_frame: F64,
                    margin: float = TARGET_MARGIN_M) -> NDArray[np.bool_]:
    """Which points (N, 3, in the detection frame) lie within margin (m) of any box (posed in the target frame;
    to_points_frame maps the target frame into the detection frame)."""
    pts = np.asarray(points, np.float64)
    inside = np.zeros(len(pts), bool)
    for pose, half in boxes:
        m = to_points_frame @ pose
        local = (pts - m[:3, 3]) @ m[:3, :3]
        inside |= (np.abs(local) <= half + margin).all(axis=1)
    return inside


def sample_points_on_target(points: NDArray[np.floating], target: Any, to_points_frame: F64, num_samples: int,
                            seed: int = 0) -> F64 | None:
    """Where to sample hands for a GraspPlanning target: up to num_samples cloud points (detection frame, m)
    within its boxes, or None when the target has no geometry (the detector chooses on the whole cloud).
    PlanningError when the geometry covers no point of the cloud."""
    boxes = target_boxes(target)
    if not boxes:
        return None
    inside = np.flatnonzero(points_in_boxes(points, boxes, to_points_frame))
    if len(inside) == 0:
        raise PlanningError(PLANNING_FAILED, f"no point of the newest cloud lies within the geometry of target "
                            f"{target.id!r} (check its pose and header.frame_id)")
    if len(inside) > num_samples:
        inside = np.sort(np.random.default_rng(seed).choice(inside, num_samples, replace=False))
    return np.asarray(points, np.float64)[inside]


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
