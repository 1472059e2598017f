"""Scripted grasps on synthetic scenes, for the template tests and benchmarks.

The scene geometry moved to graspd.world (issue 12): meshes (posed_box, posed_cylinder, table_mesh,
pose_from, rot_z), objects (sized_urdf_mesh, through the held-out guard) and render (render_cloud); the
names below re-export it for importers not yet updated.  box_top_grasp, box_side_grasp and
grasp_angle_deg are test fixtures: they move to tests/ once their importers (tests/templates,
tests/server, tests/client, tests/conftest.py) import them from there.  Metres, world frame, z up.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from ..world.meshes import pose_from, rot_z, table_mesh
from ..world.meshes import posed_box as box_mesh
from ..world.meshes import posed_cylinder as cylinder_mesh
from ..world.objects import sized_urdf_mesh as random_urdf_mesh
from ..world.render import render_cloud

F64 = NDArray[np.float64]

__all__ = ["box_mesh", "box_side_grasp", "box_top_grasp", "cylinder_mesh", "grasp_angle_deg", "pose_from",
           "random_urdf_mesh", "render_cloud", "rot_z", "table_mesh"]


def box_top_grasp(box_pose: F64, extents: tuple[float, float, float], hand_depth: float = 0.06,
                  bite: float = 0.02) -> F64:
    """A vertical hand pose on a box (pose 4x4, extents m) closing across its local x side, fingertips
    bite (m) below the top face; rotation columns [approach, binormal, axis] (DESIGN.md)."""
    approach = np.array([0.0, 0.0, -1.0])
    binormal = box_pose[:3, :3] @ np.array([1.0, 0.0, 0.0])
    rot = np.column_stack([approach, binormal, np.cross(approach, binormal)])
    top = box_pose[:3, 3] + box_pose[:3, :3] @ np.array([0.0, 0.0, extents[2] / 2])
    return pose_from(rot, top - approach * (hand_depth - bite))


def box_side_grasp(box_pose: F64, extents: tuple[float, float, float], hand_depth: float = 0.06,
                   bite: float = 0.03, height: float = 0.2) -> F64:
    """A horizontal hand pose approaching a box's local +x face along -x, closing along its local y,
    at `height` (fraction of the box height) above its centre."""
    approach = box_pose[:3, :3] @ np.array([-1.0, 0.0, 0.0])
    binormal = box_pose[:3, :3] @ np.array([0.0, 1.0, 0.0])
    rot = np.column_stack([approach, binormal, np.cross(approach, binormal)])
    face = box_pose[:3, 3] + box_pose[:3, :3] @ np.array([extents[0] / 2, 0.0, extents[2] * height])
    return pose_from(rot, face - approach * (hand_depth - bite))


def grasp_angle_deg(rot_a: F64, rot_b: F64) -> float:
    """Angle (deg) between two hand orientations, counting a half turn about the approach as no change
    (a parallel-jaw hand is symmetric under it)."""
    flip = np.diag([1.0, -1.0, -1.0])
    best = 180.0
    for b in (rot_b, rot_b @ flip):
        c = (np.trace(rot_a.T @ b) - 1.0) / 2.0
        best = min(best, float(np.degrees(np.arccos(np.clip(c, -1.0, 1.0)))))
    return best
