"""Templates of a box on a table (the paper's Fig. 3): known heights and region types per tile."""

from __future__ import annotations

import numpy as np

from fixtures import box_top_grasp
from graspd.core.cloud import ViewpointCloud
from graspd.core.hand import HandGeometry
from graspd.templates.demonstration import demonstration_template
from graspd.templates.geometry import (
    BACKGROUND,
    OCCLUSION,
    SURFACE,
    VOID,
    TemplateGeometry,
    candidate_templates,
    height_axes,
    prepare_scene,
)
from graspd_lab.world.meshes import posed_box as box_mesh
from graspd_lab.world.meshes import table_mesh
from graspd_lab.world.render import render_cloud

GEOM = TemplateGeometry.for_hand(HandGeometry())
BOX = (0.05, 0.10, 0.08)


def test_geometry_is_sized_from_the_hand() -> None:
    assert GEOM.n == 30
    assert np.isclose(GEOM.size, 0.15) and np.isclose(GEOM.depth, 0.09)
    small = TemplateGeometry.for_hand(HandGeometry(hand_outer_diameter=0.08, hand_depth=0.03))
    assert small.size < GEOM.size and small.depth < GEOM.depth


def test_table_is_segmented_and_top_axis_found(render_box, box_pose) -> None:
    cloud = render_box(box_pose())
    scene = prepare_scene(cloud, GEOM)
    assert scene.table is not None
    assert np.allclose(scene.table.normal, [0, 0, 1], atol=1e-3) and abs(scene.table.offset) < 1e-3
    assert scene.object_points[:, 2].min() > 0.004  # only the box is left
    centres, normals = height_axes(scene)
    top = np.argmax(normals[:, 2])
    assert normals[top, 2] > 0.999
    assert np.allclose(centres[top], [0.02, 0.01, 0.08], atol=0.004)
    # the faces turned away from the camera (and the bottom) give no axis
    cam_dir = np.array([0.5, 0.1, 0.5]) - centres
    assert np.all(np.einsum("ij,ij->i", normals, cam_dir) > 0)


def test_box_top_template_heights_and_types(render_box, box_pose) -> None:
    pose = box_pose()
    scene = prepare_scene(render_box(pose), GEOM)
    heights, types, frame = demonstration_template(scene, box_top_grasp(pose, BOX), HandGeometry())
    assert np.allclose(frame[:3, 2], [0, 0, 1], atol=3e-3)  # height axis = top face normal
    h, t = heights.reshape(30, 30), types.reshape(30, 30)
    surf = t == SURFACE
    # the 5 x 10 cm top face over 5 mm tiles: 200 tiles, all at the template plane
    assert 185 <= surf.sum() <= 230
    assert np.abs(h[surf]).max() < 0.003
    # its footprint: template x is along the box's 5 cm side (the demonstrated binormal)
    ii, jj = np.nonzero(surf)
    assert 9 <= np.ptp(ii) + 1 <= 12 and 19 <= np.ptp(jj) + 1 <= 22
    # around it the table, 8 cm down, or the box's shadow away from the camera
    bg = t == BACKGROUND
    assert bg.sum() > 200
    assert np.allclose(h[bg], 0.08, atol=0.003)
    occ = t == OCCLUSION
    assert occ.sum() > 100
    assert np.all((h[occ] >= 0.0) & (h[occ] < 0.08))
    cam_x = (np.array([0.5, 0.1, 0.5]) - frame[:3, 3]) @ frame[:3, 0]  # camera side along template x
    centre_i = (ii.min() + ii.max()) / 2
    occ_i = np.nonzero(occ)[0]
    assert cam_x > 0.3  # the camera is toward +x: the shadow lies toward -x, none beyond the box toward +x
    assert occ_i.mean() < centre_i - 5 and occ_i.max() <= ii.max()
    # the shadow's upper bound drops away from the box (rays graze the top edge)
    mid = int(round((jj.min() + jj.max()) / 2))
    beside = [i for i in range(ii.min()) if occ[i, mid]]
    assert len(beside) >= 5
    depth = h[beside, mid][::-1]  # from the box edge outward
    assert np.all(np.diff(depth) >= -0.002) and depth[-1] - depth[0] > 0.02
    assert (t == VOID).sum() == 0  # the table is within the 9 cm box everywhere


def test_tall_box_leaves_void_beyond_the_gripper_box(render_box, box_pose) -> None:
    tall = (0.04, 0.04, 0.20)
    scene = prepare_scene(render_box(box_pose(extents=tall), extents=tall), GEOM)
    heights, types, frame = demonstration_template(scene, box_top_grasp(box_pose(extents=tall), tall),
                                                   HandGeometry())
    void = types == VOID
    assert void.sum() > 300  # the table is 20 cm down, beyond the 9 cm box
    assert np.allclose(heights[void], GEOM.depth)
    assert not np.any(types == BACKGROUND)


def test_candidates_cover_every_axis_and_rotation(render_box, box_pose) -> None:
    scene = prepare_scene(render_box(box_pose()), GEOM)
    origins, frames, heights, types = candidate_templates(scene, rotations=16)
    centres, _ = height_axes(scene)
    assert len(heights) == 16 * len(centres) == len(frames) == len(origins)
    assert heights.shape[1] == types.shape[1] == 900
    assert np.allclose(np.einsum("kij,kil->kjl", frames, frames), np.eye(3), atol=1e-9)
    assert np.allclose(np.linalg.det(frames), 1.0)
    # rotations of one axis see the same tiles in a different order: equal surface counts (+-10%)
    top = np.argmax(frames[::16, 2, 2])
    counts = (types[16 * top : 16 * top + 16] == SURFACE).sum(axis=1)
    assert counts.min() >= 0.85 * counts.max()


def test_separate_pieces_get_their_own_axes_and_outliers_are_dropped(render_box, box_pose) -> None:
    cams = np.array([[0.5, 0.1, 0.5]])
    left, right = box_pose(xy=(-0.06, 0.0)), box_pose(yaw=1.0, xy=(0.07, 0.02))
    cloud = render_cloud([table_mesh(), box_mesh(BOX, left), box_mesh(BOX, right)], cams, (0.0, 0.0, 0.04),
                         width=320, height=240)
    stray = np.array([[0.0, -0.1, 0.3], [0.01, -0.1, 0.31], [0.2, 0.2, 0.25]], np.float32)  # flying pixels
    noisy = ViewpointCloud(points=np.concatenate([cloud.points, stray]), viewpoints=cloud.viewpoints)
    scene = prepare_scene(noisy, GEOM)
    assert scene.segments.max() == 1  # two boxes, the stray points dropped
    assert scene.object_points[:, 2].max() < 0.085
    centres, normals = height_axes(scene)
    tops = centres[normals[:, 2] > 0.99]
    assert len(tops) == 2
    assert sorted(np.round(tops[:, 0], 2).tolist()) == [-0.06, 0.07]
