"""CDR bytes of a moveit_msgs/srv/GraspPlanning request -> the parts of its target graspd uses, read bounded.

Only the target (a moveit_msgs/CollisionObject) is read, up to its mesh poses: header, pose, id, each solid
primitive's type and dimensions, the primitive poses, each mesh's vertex bounds and the mesh poses.  Every
sequence length is checked against core.limits and against the bytes left before anything is read; triangles
and prism polygons are skipped (graspd never uses them), vertices are reduced to their bounds on a read-only
view of the message, and the rest of the request (planes, subframes, support_surfaces, candidate_grasps,
movable_obstacles) is never read.  A 61 MB request costs what its bounds cost, not a Python object per vertex.
Poses are position x y z then quaternion x y z w; everything is in the target's header.frame_id, metres.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from graspd.core.limits import (
    MAX_COORDINATE,
    MAX_TARGET_MESHES,
    MAX_TARGET_PRIMITIVES,
    MAX_TARGET_TRIANGLES,
    MAX_TARGET_VERTICES,
)
from graspd.core.types import F64
from graspd.io.ros.decode import RosDecodeError, _Reader
from graspd.io.ros.types import Header

#: Bytes of one geometry_msgs/Pose (7 float64), the least a shape_msgs/SolidPrimitive and a shape_msgs/Mesh take
#: (a type byte, two sequence lengths; two sequence lengths), a vertex and a triangle.
POSE_BYTES, PRIMITIVE_MIN_BYTES, MESH_MIN_BYTES, VERTEX_BYTES, TRIANGLE_BYTES = 56, 9, 8, 24, 12
#: Most dimensions of a shape_msgs/SolidPrimitive (float64[<=3]).
MAX_DIMENSIONS = 3


@dataclass(frozen=True)
class PlanTarget:
    """What graspd uses of a GraspPlanning target: its header and id, its pose (7,), per primitive the type and
    dimensions (P, 3; NaN where not given), the primitive poses (Q, 7), per mesh the min and max of its vertices
    ((M, 2, 3), mesh frame; NaN for a mesh without vertices) and the mesh poses (R, 7).  Arrays are copies: the
    message can be freed."""

    header: Header
    id: str
    pose: F64
    primitive_types: NDArray[np.uint8]
    primitive_dimensions: F64
    primitive_poses: F64
    mesh_bounds: F64
    mesh_poses: F64
    #: Vertices and triangles of all meshes together, as declared.
    vertices: int = 0
    triangles: int = 0


def _poses(r: _Reader, field: str, limit: int) -> F64:
    n = r.count(field, limit, POSE_BYTES)
    return np.array(r.array("f8", n, field, 7), np.float64).reshape(n, 7)


def _total(field: str, total: int, limit: int, what: str) -> None:
    if total > limit:
        raise RosDecodeError(field, f"the target's meshes have {total} {what} together, more than the limit of "
                                    f"{limit}")


def decode_plan_target(sample: bytes | bytearray | memoryview, skip: int = 0) -> PlanTarget:
    """The target of a CDR moveit_msgs/srv/GraspPlanning request; skip: bytes between the encapsulation and the
    request's fields (16: the rmw_cyclonedds request header of a service sample, read in place, no copy).
    RosDecodeError naming the field ("target.primitives", "target.meshes[0].vertices", ...) when a count passes
    core.limits or the bytes left, when the message is truncated, or when a vertex is not finite or beyond
    MAX_COORDINATE."""
    r = _Reader(sample)
    r._take(skip, 1, "request_header")
    r.string("group_name")
    header = r.header("target.header")
    pose = np.array(r.array("f8", 7, "target.pose"), np.float64)
    target_id = r.string("target.id")
    r.string("target.type.key")
    r.string("target.type.db")

    n = r.count("target.primitives", MAX_TARGET_PRIMITIVES, PRIMITIVE_MIN_BYTES)
    types = np.zeros(n, np.uint8)
    dims = np.full((n, MAX_DIMENSIONS), np.nan)
    for i in range(n):
        field = f"target.primitives[{i}]"
        types[i] = r.scalar("u1", f"{field}.type")
        k = r.count(f"{field}.dimensions", MAX_DIMENSIONS, 8)
        dims[i, :k] = r.array("f8", k, f"{field}.dimensions")
        r.array("f4", r.count(f"{field}.polygon.points", 2**32, 12), f"{field}.polygon.points", 3)  # skipped
    primitive_poses = _poses(r, "target.primitive_poses", MAX_TARGET_PRIMITIVES)

    m = r.count("target.meshes", MAX_TARGET_MESHES, MESH_MIN_BYTES)
    bounds = np.full((m, 2, 3), np.nan)
    vertices = triangles = 0
    for i in range(m):
        field = f"target.meshes[{i}]"
        nt = r.count(f"{field}.triangles", MAX_TARGET_TRIANGLES, TRIANGLE_BYTES)
        triangles += nt
        _total(f"{field}.triangles", triangles, MAX_TARGET_TRIANGLES, "triangles")
        r.array("u4", nt, f"{field}.triangles", 3)  # skipped: a view, never read
        nv = r.count(f"{field}.vertices", MAX_TARGET_VERTICES, VERTEX_BYTES)
        vertices += nv
        _total(f"{field}.vertices", vertices, MAX_TARGET_VERTICES, "vertices")
        if nv:
            v = r.array("f8", nv, f"{field}.vertices", 3)
            lo, hi = v.min(axis=0), v.max(axis=0)
            if not (np.abs(lo) <= MAX_COORDINATE).all() or not (np.abs(hi) <= MAX_COORDINATE).all():
                raise RosDecodeError(f"{field}.vertices", f"must be finite, within {MAX_COORDINATE:g} m")
            bounds[i] = lo, hi
    mesh_poses = _poses(r, "target.mesh_poses", MAX_TARGET_MESHES)
    return PlanTarget(header, target_id, pose, types, dims, primitive_poses, bounds, mesh_poses, vertices,
                      triangles)
