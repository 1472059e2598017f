"""Template detection end to end: a demonstrated grasp is recovered on the object moved and rotated, and
failure feedback lowers the rank of the candidate that failed."""

from __future__ import annotations

import json

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from fixtures import box_side_grasp, box_top_grasp, grasp_angle_deg
from graspd.templates import TemplateDetector, TemplateLibrary, TemplateParams
from graspd_lab.world.meshes import pose_from, rot_z

BOX = (0.05, 0.10, 0.08)


def _rot(axis_angle: np.ndarray) -> np.ndarray:
    return Rotation.from_rotvec(axis_angle).as_matrix()


@pytest.mark.parametrize("move", [
    (rot_z(1.1), np.array([-0.03, 0.05, 0.0])),
    (rot_z(-2.4), np.array([0.2, -0.1, 0.0])),
    (_rot(np.array([0.3, -0.5, 0.9])), np.array([0.1, 0.3, -0.2])),  # table, camera and all tilted
])
def test_demonstrated_grasp_is_recovered_on_the_moved_scene(render_box, box_pose, library_url, move) -> None:
    pose = box_pose()
    cloud = render_box(pose)
    demo = box_top_grasp(pose, BOX)
    lib = TemplateLibrary(library_url())
    lib.add_demonstration(cloud, demo, label="box top")
    rot, shift = move
    moved = cloud.transformed(rot, shift)  # object, table and camera move together
    det = TemplateDetector(lib).detect(moved, max_grasps=5)
    want = pose_from(rot, shift) @ demo
    g = det.grasps
    assert len(g) >= 1 and det.grasp_ids[0].endswith(".0")
    assert np.linalg.norm(g.positions[0] - want[:3, 3]) < 0.01
    # r = 16 rotations about the height axis: at most half a step (11.25 deg) off
    assert grasp_angle_deg(g.rotations[0], want[:3, :3]) < 12.0
    assert det.mismatch[0] < 0.2 and 0 < g.scores[0] <= 1


def test_demonstrated_grasp_is_recovered_on_the_object_moved_under_a_fixed_camera(render_box, box_pose,
                                                                                 library_url) -> None:
    lib = TemplateLibrary(library_url())
    pose = box_pose()
    lib.add_demonstration(render_box(pose), box_top_grasp(pose, BOX))
    moved = pose_from(rot_z(1.1), (-0.03, 0.05, 0.0)) @ pose
    det = TemplateDetector(lib).detect(render_box(moved), max_grasps=5)
    want = box_top_grasp(moved, BOX)
    assert np.linalg.norm(det.grasps.positions[0] - want[:3, 3]) < 0.01
    assert grasp_angle_deg(det.grasps.rotations[0], want[:3, :3]) < 12.0
    assert abs(det.grasps.widths[0] - 0.05) < 0.006  # across the box's 5 cm side


def test_failure_feedback_lowers_the_rank_of_the_failed_candidate(render_box, box_pose, library_url) -> None:
    pose = box_pose()
    cloud = render_box(pose)
    lib = TemplateLibrary(library_url())
    top = lib.add_demonstration(cloud, box_top_grasp(pose, BOX), label="top")
    side = lib.add_demonstration(cloud, box_side_grasp(pose, BOX), label="side")
    detector = TemplateDetector(lib)
    moved = pose_from(rot_z(0.7), (0.05, -0.02, 0.0)) @ pose
    first = detector.detect(render_box(moved, noise=0.001, seed=1), max_grasps=200)
    assert {int(e) for e in first.entry_ids} == {top, side}
    failed = 0
    fb = lib.add_feedback(first.grasp_ids[failed], success=False)
    assert fb.failure_added and fb.entry_id == first.entry_ids[failed] and fb.image_stored
    # the next attempt sees the object anew (other sensor noise): the candidate template like the failed
    # one is found again, now ranked lower with a much higher mismatch (its best match may be another entry)
    second = detector.detect(render_box(moved, noise=0.001, seed=2), max_grasps=200)
    f1, f2 = first.frames[failed], second.frames
    angles = np.degrees(np.arccos(np.clip((np.einsum("kij,ij->k", f2[:, :3, :3], f1[:3, :3]) - 1) / 2, -1, 1)))
    same = np.flatnonzero((np.linalg.norm(f2[:, :3, 3] - f1[:3, 3], axis=1) < 0.005) & (angles < 3.0))
    assert len(same) == 1 and same[0] > failed
    assert second.mismatch[same[0]] > 3 * first.mismatch[failed]
    assert second.entry_ids[0] != first.entry_ids[failed]  # the other demonstration is now preferred
    # a success stores the outcome but leaves F_l alone
    ok = lib.add_feedback(second.grasp_ids[0], success=True)
    assert not ok.failure_added
    summary = lib.summary()
    assert summary["num_failures"] == 1 and summary["num_outcomes"] == 2 and summary["num_successes"] == 1
    outcomes = list(lib.iter_outcomes(with_images_only=True))
    assert [o["success"] for o in outcomes] == [False, True]
    assert outcomes[0]["image"].shape == (15, 60, 60) and outcomes[0]["image"].any()


def test_empty_library_gives_no_grasps(render_box, box_pose, library_url) -> None:
    det = TemplateDetector(TemplateLibrary(library_url())).detect(render_box(box_pose()))
    assert len(det.grasps) == 0 and det.num_entries == 0 and det.num_candidates > 0
    assert det.to_dict()["grasps"] == []


def test_result_is_json_ready_with_ids(render_box, box_pose, library_url) -> None:
    pose = box_pose()
    lib = TemplateLibrary(library_url())
    entry = lib.add_demonstration(render_box(pose), box_top_grasp(pose, BOX))
    det = TemplateDetector(lib, TemplateParams(keep_cloud=False)).detect(render_box(pose), max_grasps=3)
    d = json.loads(json.dumps(det.to_dict()))
    assert d["method"] == "templates" and len(d["grasps"]) == len(det.grasps) <= 3
    g = d["grasps"][0]
    assert g["id"] == det.grasp_ids[0] and g["template_entry"] == entry
    assert {"position", "approach", "binormal", "axis", "width", "score", "pose", "quat_xyzw"} <= set(g)
    fb = lib.add_feedback(det.grasp_ids[0], success=False)  # no cloud kept: stored without an image
    assert fb.failure_added and not fb.image_stored
