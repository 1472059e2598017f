"""The scene's objects (graspd.gpd.objects: the answer's objects list) as vision_msgs/Detection3DArray, the message
of ROS 2 Jazzy's vision_msgs 4.1, for the node's graspd/objects topic.

One Detection3D per object, in id order: id the object's id as text (a request's target.object names it; the same
for the same cloud), bbox the axis-aligned bounds of its points (center: their middle with the identity
orientation, size: their extent, m, the header's frame) and one result: class "object" with score 1 (graspd
segments by geometry and knows no classes) posed at the box centre, covariance zero (not estimated).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from graspd.gpd.objects import SceneObject
from graspd.io.ros import Header

from .interfaces import DETECTION3D_ARRAY

#: The class every object is reported as (graspd's segmentation has no classes) and its score.
OBJECT_CLASS = "object"
OBJECT_SCORE = 1.0


def detection3d_array(store: Any, objects: Sequence[SceneObject], header: Header) -> Any:
    """The vision_msgs/msg/Detection3DArray message (of store: ros_types) of objects, each with header."""
    t = store.types
    hdr = t["std_msgs/msg/Header"](stamp=t["builtin_interfaces/msg/Time"](sec=int(header.stamp[0]),
                                                                          nanosec=int(header.stamp[1])),
                                   frame_id=header.frame_id)
    point, quat, pose = t["geometry_msgs/msg/Point"], t["geometry_msgs/msg/Quaternion"], t["geometry_msgs/msg/Pose"]
    detections = []
    for obj in objects:
        c, e = np.asarray(obj.centre, np.float64).tolist(), np.asarray(obj.extent, np.float64).tolist()
        centre = pose(position=point(x=c[0], y=c[1], z=c[2]), orientation=quat(x=0.0, y=0.0, z=0.0, w=1.0))
        result = t["vision_msgs/msg/ObjectHypothesisWithPose"](
            hypothesis=t["vision_msgs/msg/ObjectHypothesis"](class_id=OBJECT_CLASS, score=OBJECT_SCORE),
            pose=t["geometry_msgs/msg/PoseWithCovariance"](pose=centre, covariance=np.zeros(36, np.float64)))
        bbox = t["vision_msgs/msg/BoundingBox3D"](center=centre,
                                                  size=t["geometry_msgs/msg/Vector3"](x=e[0], y=e[1], z=e[2]))
        detections.append(t["vision_msgs/msg/Detection3D"](header=hdr, results=[result], bbox=bbox, id=str(obj.id)))
    return t[DETECTION3D_ARRAY](header=hdr, detections=detections)


def encode_objects(store: Any, objects: Sequence[SceneObject], header: Header) -> bytes:
    """CDR of detection3d_array(store, objects, header)."""
    return bytes(store.serialize_cdr(detection3d_array(store, objects, header), DETECTION3D_ARRAY))
