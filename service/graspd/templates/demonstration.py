"""Learning from demonstration (Herzog et al. 2012, Sec. II-C) and the GPD grasp image stored with feedback.

A demonstration is a cloud (table + object) and the demonstrated hand pose (4x4, rotation columns
[approach, binormal, axis], translation = hand base centre, cloud frame).  Its template is taken on the
front-facing convex-hull axis the hand approaches along (the facet whose normal is closest to -approach
among those whose axis passes within 40% of the template size of the grasp centre), rotated so that the
template x axis is the binormal projected into the template plane; the entry stores the hand pose
relative to that template frame, so a matched candidate frame reproduces it.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from graspd.core.cloud import ViewpointCloud
from graspd.core.grasp import GraspSet
from graspd.core.hand import HandGeometry
from graspd.core.types import F32, F64
from graspd.gpd.images import encode_images
from graspd.gpd.preprocess import PreprocessParams, preprocess
from graspd.gpd.scene import Scene
from graspd.templates.geometry import (
    TemplateError,
    TemplateScene,
    axis_frames,
    extract_templates,
    height_axes,
    reference_x,
    rotated_frames,
)

U8 = NDArray[np.uint8]


def check_hand_pose(hand_pose: object) -> F64:
    """The pose as a float64 4x4 with an orthonormal right-handed rotation; TemplateError naming hand_pose."""
    try:
        pose = np.asarray(hand_pose, np.float64)
    except (TypeError, ValueError):
        raise TemplateError("hand_pose", "must be a 4x4 matrix of numbers") from None
    if pose.shape != (4, 4):
        raise TemplateError("hand_pose", f"must be a 4x4 matrix, got shape {pose.shape}")
    if not np.isfinite(pose).all():
        raise TemplateError("hand_pose", "must be finite")
    if not np.allclose(pose[3], [0.0, 0.0, 0.0, 1.0], atol=1e-6):
        raise TemplateError("hand_pose", "the last row must be [0, 0, 0, 1]")
    rot = pose[:3, :3]
    if not np.allclose(rot.T @ rot, np.eye(3), atol=1e-3) or np.linalg.det(rot) < 0:
        raise TemplateError("hand_pose", "the rotation (columns approach, binormal, axis) must be "
                            "orthonormal and right-handed")
    return pose


def demonstration_template(scene: TemplateScene, hand_pose: F64, hand: HandGeometry,
                           merge_angle_deg: float = 20.0, max_angle_deg: float = 60.0
                           ) -> tuple[F32, U8, F64]:
    """The demonstrated grasp's template: heights (n*n,), types (n*n,), frame (4,4) in the cloud frame."""
    pose = check_hand_pose(hand_pose)
    approach, binormal = pose[:3, 0], pose[:3, 1]
    centre = pose[:3, 3] + 0.5 * hand.hand_depth * approach
    centres, normals = height_axes(scene, merge_angle_deg)
    cos_a = normals @ -approach
    d = centre - centres
    along = np.einsum("ij,ij->i", d, normals)  # height of the finger centre over each facet (m)
    off = np.linalg.norm(d - along[:, None] * normals, axis=1)
    half, depth = scene.geometry.size / 2.0, scene.geometry.depth
    ok = (cos_a >= np.cos(np.radians(max_angle_deg))) & (off <= 0.8 * half) & (np.abs(along) <= depth)
    if not ok.any():
        raise TemplateError("hand_pose", "the hand approaches no camera-facing side of the object closely "
                            f"enough (within {max_angle_deg:.0f} deg and {0.8 * half:.3f} m of a hull facet axis, "
                            f"fingers within {depth:.3f} m of the facet)")
    cost = np.where(ok, (1.0 - cos_a) + off / half, np.inf)
    a = int(np.argmin(cost))
    base = axis_frames(normals[a : a + 1], reference_x(normals[a : a + 1]))
    b = binormal - (binormal @ normals[a]) * normals[a]
    if np.linalg.norm(b) < 1e-6:
        b = pose[:3, 2] - (pose[:3, 2] @ normals[a]) * normals[a]
    angle = np.array([np.arctan2(b @ base[0, :, 1], b @ base[0, :, 0])])
    heights, types = extract_templates(scene, centres[a : a + 1], base, angle)
    frame = np.eye(4)
    frame[:3, :3] = rotated_frames(base, angle)[0]
    frame[:3, 3] = centres[a]
    return heights[0], types[0], frame


def grasp_image(cloud: ViewpointCloud, pose: F64, width: float, hand: HandGeometry,
                representation: str = "15") -> NDArray[np.uint8]:
    """The GPD grasp image (C, 60, 60) uint8 of one grasp pose (4,4) in cloud (graspd.gpd.images)."""
    pc = preprocess(cloud, PreprocessParams())
    scene = Scene.build(pc, hand)
    one = GraspSet(positions=pose[None, :3, 3], rotations=pose[None, :3, :3], widths=np.array([width]),
                   scores=np.array([np.nan]), samples=pose[None, :3, 3])
    return encode_images(scene, one, hand, representation)[0]


def cloud_from_arrays(arrays: dict[str, Any]) -> ViewpointCloud:
    """The cloud kept with a detection (see graspd.templates.detector.cloud_arrays)."""
    return ViewpointCloud(points=(arrays["offsets"].astype(np.float64) + arrays["centre"]).astype(np.float32),
                          viewpoints=arrays["viewpoints"], camera_source=arrays["camera_source"].astype(np.int32))
