"""Analytic label cases: the hand approaches along +x, closes along y, hand axis z (identity rotation)."""

from __future__ import annotations

import numpy as np
import open3d as o3d
import pytest
from scipy.spatial.transform import Rotation

from graspd.core.grasp import GraspSet
from graspd.core.hand import HandGeometry
from graspd_lab.training.labels import LabelParams, label_grasps
from graspd_lab.world.meshes import box_mesh, cylinder_mesh, sphere_mesh

HAND = HandGeometry()  # 0.10 m between the open fingers, 0.06 m deep


def hands(positions: list[list[float]], rotations: list[np.ndarray] | None = None) -> GraspSet:
    pos = np.asarray(positions, float)
    rot = np.stack(rotations) if rotations is not None else np.repeat(np.eye(3)[None], len(pos), axis=0)
    return GraspSet(positions=pos, rotations=rot, widths=np.zeros(len(pos)), scores=np.full(len(pos), np.nan),
                    samples=pos.copy())


def rotated(mesh: o3d.geometry.TriangleMesh, axis: str, deg: float) -> o3d.geometry.TriangleMesh:
    m = o3d.geometry.TriangleMesh(mesh)
    m.rotate(Rotation.from_euler(axis, deg, degrees=True).as_matrix(), center=np.zeros(3))
    m.compute_triangle_normals()
    return m


def palm_for_bite(front_x: float, bite: float = 0.03) -> float:
    """Hand-base x so the fingertips reach bite past a surface at front_x."""
    return front_x + bite - HAND.hand_depth


def test_box_across_parallel_faces_is_a_grasp() -> None:
    box = box_mesh(0.06, 0.04, 0.10)  # faces at y = +-0.02 face the fingers
    lab = label_grasps([box], hands([[palm_for_bite(-0.03), 0.0, 0.0]]), HAND)
    assert lab.grasp[0] and lab.antipodal[0] and not lab.collision[0]
    assert lab.width[0] == pytest.approx(0.04, abs=1e-4)
    assert lab.left_contact[0] == pytest.approx(0.03, abs=1e-4)


def test_box_across_a_corner_is_not_a_grasp() -> None:
    box = rotated(box_mesh(0.05, 0.05, 0.10), "z", 45.0)  # vertical edges face the fingers
    front = -0.05 / np.sqrt(2.0)
    lab = label_grasps([box], hands([[palm_for_bite(front), 0.0, 0.0]]), HAND)
    assert not lab.collision[0]
    assert np.isfinite(lab.left_contact[0]) and np.isfinite(lab.right_contact[0])
    assert not lab.antipodal[0] and not lab.grasp[0]


def test_small_tilt_within_tolerance_large_tilt_not() -> None:
    """A finger-pad-sized patch (1 cm) may tilt atan(2 mm / 1 cm) = 11.3 deg under the 1 mm vertex error."""
    base = box_mesh(0.05, 0.04, 0.10)
    for deg, expect in ((5.0, True), (10.0, True), (13.0, False), (20.0, False)):
        box = rotated(base, "z", deg)
        lab = label_grasps([box], hands([[palm_for_bite(-0.03), 0.0, 0.0]]), HAND)
        assert bool(lab.grasp[0]) is expect, deg


def test_friction_cone_accepts_what_frictionless_rejects() -> None:
    box = rotated(box_mesh(0.05, 0.04, 0.10), "z", 15.0)
    g = hands([[palm_for_bite(-0.03), 0.0, 0.0]])
    assert not label_grasps([box], g, HAND).grasp[0]
    assert label_grasps([box], g, HAND, LabelParams(mu=0.5)).grasp[0]  # atan 0.5 = 26.6 deg > 15 deg
    assert not label_grasps([box], g, HAND, LabelParams(mu=0.1)).grasp[0]  # 5.7 deg < 15 deg


def test_cylinder_across_its_axis_is_a_grasp_at_any_roll() -> None:
    cyl = cylinder_mesh(0.03, 0.12)  # axis z
    rolls = [rotated(cyl, "z", deg) for deg in (0.0, 2.0, 4.5, 7.0)]  # facets every 9 deg
    for mesh in rolls:
        lab = label_grasps([mesh], hands([[palm_for_bite(-0.03), 0.0, 0.0]]), HAND)
        assert lab.grasp[0]
        assert lab.width[0] == pytest.approx(0.06, abs=1.5e-3)


def test_cylinder_along_its_axis_too_long_for_the_hand_collides() -> None:
    cyl = rotated(cylinder_mesh(0.02, 0.16), "x", 90.0)  # axis along y: 16 cm between 10 cm fingers
    lab = label_grasps([cyl], hands([[palm_for_bite(-0.02), 0.0, 0.0]]), HAND)
    assert lab.collision[0] and not lab.grasp[0]


def test_finger_cutting_the_object_is_not_a_grasp() -> None:
    box = box_mesh(0.06, 0.04, 0.10)
    g = hands([[palm_for_bite(-0.03), 0.045, 0.0],  # right finger inside the box's y range
               [0.0, 0.0, 0.0]])  # palm inside the box
    lab = label_grasps([box], g, HAND)
    assert lab.collision.all() and not lab.grasp.any()


def test_sphere_through_its_centre_is_a_grasp_offset_is_not() -> None:
    sphere = sphere_mesh(0.03, resolution=40)
    g = hands([[palm_for_bite(-0.03), 0.0, 0.0], [palm_for_bite(-0.03), 0.0, 0.024]])
    lab = label_grasps([sphere], g, HAND)
    assert lab.grasp[0] and not lab.grasp[1]


def test_nothing_between_the_fingers_is_not_a_grasp() -> None:
    box = box_mesh(0.04, 0.04, 0.04)
    lab = label_grasps([box], hands([[0.2, 0.0, 0.0]]), HAND)
    assert not lab.grasp[0] and not lab.antipodal[0] and not np.isfinite(lab.left_contact[0])


def test_labels_are_vectorised_and_order_free() -> None:
    box = box_mesh(0.06, 0.04, 0.10)
    good = [palm_for_bite(-0.03), 0.0, 0.0]
    bad = [0.0, 0.0, 0.0]
    lab = label_grasps([box], hands([good, bad, good, bad] * 300), HAND, LabelParams(chunk=100))
    assert lab.grasp.tolist() == [True, False, True, False] * 300


def test_palm_may_touch_within_the_approach_tolerance() -> None:
    """The sampler places hands against a noisy cloud: a palm 2 mm into the face is a grasp (the hand stops
    2 mm short), 6 mm is a collision (default approach_tolerance 3 mm)."""
    box = box_mesh(0.04, 0.04, 0.10)  # front face at x = -0.02, 4 cm deep: fingertips pass beyond
    lab = label_grasps([box], hands([[-0.02 + 0.002, 0.0, 0.0], [-0.02 + 0.006, 0.0, 0.0]]), HAND)
    assert lab.grasp.tolist() == [True, False]
    assert lab.collision.tolist() == [False, True]
    strict = label_grasps([box], hands([[-0.02 + 0.002, 0.0, 0.0]]), HAND, LabelParams(approach_tolerance=0.0))
    assert strict.collision[0] and not strict.grasp[0]
