"""Scene labels: a grasp is positive only with both contacts on one graspable object and a free way in.

Hand frame as in test_labels.py: approach +x, closing along y, hand axis z (identity rotation).
"""

from __future__ import annotations

import numpy as np
import open3d as o3d

from graspd.core.grasp import GraspSet
from graspd.core.hand import HandGeometry
from graspd_lab.training.labels import LabelParams, label_grasps
from graspd_lab.world.meshes import box_mesh

HAND = HandGeometry()


def hand_at(x: float, y: float = 0.0) -> GraspSet:
    pos = np.array([[x, y, 0.0]])
    return GraspSet(positions=pos, rotations=np.eye(3)[None], widths=np.zeros(1), scores=np.full(1, np.nan),
                    samples=pos.copy())


def moved(mesh: o3d.geometry.TriangleMesh, offset: tuple[float, float, float]) -> o3d.geometry.TriangleMesh:
    m = o3d.geometry.TriangleMesh(mesh)
    m.translate(offset)
    m.compute_triangle_normals()
    return m


def bite(front_x: float, depth: float = 0.03) -> float:
    return front_x + depth - HAND.hand_depth


def test_a_grasp_on_one_object_stays_positive_when_only_objects_are_graspable() -> None:
    box = box_mesh(0.06, 0.04, 0.10)
    wall = moved(box_mesh(0.02, 0.3, 0.3), (0.2, 0.0, 0.0))  # static geometry far away
    g = hand_at(bite(-0.03))
    assert label_grasps([wall, box], g, HAND, graspable=np.array([False, True])).grasp[0]


def test_a_static_mesh_between_the_fingers_is_never_a_grasp() -> None:
    slab = box_mesh(0.06, 0.04, 0.10)  # a tray wall the fingers would close on
    g = hand_at(bite(-0.03))
    assert label_grasps([slab], g, HAND).grasp[0]  # as an object it would be a grasp
    lab = label_grasps([slab], g, HAND, graspable=np.array([False]))
    assert not lab.grasp[0] and not lab.antipodal[0]


def test_two_touching_objects_closed_on_together_are_not_a_grasp() -> None:
    left = moved(box_mesh(0.06, 0.02, 0.10), (0.0, -0.01, 0.0))  # y in [-0.02, 0]
    right = moved(box_mesh(0.06, 0.02, 0.10), (0.0, 0.01, 0.0))  # y in [0, 0.02]
    g = hand_at(bite(-0.03))
    assert label_grasps([left, right], g, HAND).grasp[0]  # one contact on each box: antipodal as one body
    for params in (LabelParams(), LabelParams(mu=0.5)):
        lab = label_grasps([left, right], g, HAND, params, graspable=np.array([True, True]))
        assert not lab.grasp[0], params


def test_an_object_in_the_way_in_makes_the_grasp_negative_only_when_the_path_is_checked() -> None:
    box = box_mesh(0.06, 0.04, 0.10)
    x = bite(-0.03)
    lid = moved(box_mesh(0.01, 0.12, 0.04), (x - HAND.palm_depth - 0.03, 0.0, 0.0))  # 3 cm behind the palm
    g = hand_at(x)
    flags = np.array([True, True])
    no_path = LabelParams(palm_depth=None)
    assert label_grasps([box, lid], g, HAND, no_path, graspable=flags).grasp[0]
    with_path = LabelParams(palm_depth=None, approach_path=0.05)
    lab = label_grasps([box, lid], g, HAND, with_path, graspable=flags)
    assert not lab.grasp[0] and lab.collision[0]
