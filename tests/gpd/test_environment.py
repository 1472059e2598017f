"""The environment model: grasps close on objects, never on the table, tray walls or declared boxes, and no
hand or approach path enters them.  Scenes are rendered from boxes and cylinders (known geometry) or the
real table_mug Kinect cloud."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import open3d as o3d
import pytest

from graspd.core.camera import sensing_cameras, tabletop_cameras
from graspd.core.cloud import ViewpointCloud
from graspd.core.hand import HandGeometry
from graspd.gpd.candidates import SamplingParams, search_hands
from graspd.gpd.classifier import load_model
from graspd.gpd.detector import Detection, DetectionParams, GraspDetector
from graspd.gpd.environment import Box, EnvironmentParams, Label, hand_hits_environment, model_environment
from graspd.gpd.environment.types import Plane
from graspd.gpd.environment.walls import _spans_between_walls
from graspd.gpd.preprocess import PreprocessParams, preprocess
from graspd.gpd.scene import Scene
from graspd.io.cloud_files import read_cloud
from graspd_lab.sim.object_sets import PANDA_LIKE
from graspd_lab.world.noise import DepthNoise
from graspd_lab.world.render import render_scene

HAND = HandGeometry()
MUG = Path(__file__).resolve().parents[3] / "shared" / "data" / "real" / "table_mug.pcd"


def box_mesh(bounds: tuple[float, float, float, float, float, float]) -> o3d.geometry.TriangleMesh:
    """A solid box [xmin, xmax, ymin, ymax, zmin, zmax] (m)."""
    x0, x1, y0, y1, z0, z1 = bounds
    mesh = o3d.geometry.TriangleMesh.create_box(x1 - x0, y1 - y0, z1 - z0)
    return mesh.translate((x0, y0, z0))


TRAY_WALLS = [(-0.19, -0.18, -0.15, 0.15, 0.0, 0.06), (0.18, 0.19, -0.15, 0.15, 0.0, 0.06),
              (-0.19, 0.19, -0.15, -0.14, 0.0, 0.06), (-0.19, 0.19, 0.14, 0.15, 0.0, 0.06)]


def render(meshes: list[o3d.geometry.TriangleMesh], seed: int = 0) -> ViewpointCloud:
    return render_scene(meshes, tabletop_cameras(2, distance=0.75), DepthNoise(), seed)


def detect(cloud: ViewpointCloud, **options: Any) -> Detection:
    return GraspDetector(None, HAND).detect(cloud, DetectionParams(num_samples=300, use_classifier=False, **options))


@pytest.fixture(scope="module")
def tray() -> ViewpointCloud:
    floor = box_mesh((-0.3, 0.3, -0.3, 0.3, -0.02, 0.0))
    objects = [box_mesh((-0.17, -0.13, -0.05, 0.03, 0.0, 0.05)),  # against the left wall
               box_mesh((0.02, 0.06, 0.02, 0.09, 0.0, 0.07))]
    cyl = o3d.geometry.TriangleMesh.create_cylinder(0.025, 0.08).translate((0.1, -0.08, 0.04))
    return render([floor, *[box_mesh(w) for w in TRAY_WALLS], *objects, cyl])


def test_table_mug_top_ten_close_on_the_mug_and_clear_the_table() -> None:
    cloud = read_cloud(MUG, viewpoints=np.zeros((1, 3), np.float32))
    det = GraspDetector(load_model("generic15"), HAND).detect(cloud, DetectionParams(num_samples=500))
    env = det.environment
    assert env is not None and env.support is not None, "the table is found with no gravity given"
    top = det.grasps[:10]
    assert len(top) == 10
    # every sample of the top ten stands clear above the table: on the mug
    assert (env.support.distance(top.samples) > 0.015).all()
    assert not hand_hits_environment(top.positions, top.rotations, HAND, env, 0.05).any()


def test_tray_walls_and_floor_are_never_grasped(tray: ViewpointCloud) -> None:
    det = detect(tray, max_grasps=1000, use_selection=False)
    env = det.environment
    assert env is not None and env.support is not None and len(env.walls) >= 3
    g = det.grasps
    assert len(g) > 20
    walls = tuple(Box.from_bounds(w) for w in TRAY_WALLS)
    on_wall = np.zeros(len(g), bool)
    for w in walls:
        on_wall |= w.contains(g.samples, margin=0.004)
    assert not on_wall.any(), "no grasp is sampled on a wall"
    assert (g.samples[:, 2] > 0.006).all(), "no grasp is sampled on the floor"
    truth = type(env)(labels=env.labels, support=env.support, boxes=walls)
    assert not hand_hits_environment(g.positions, g.rotations, HAND, truth, 0.0).any(), \
        "no finger or palm goes through a real wall or the floor"


def test_the_default_environment_changes_what_an_unmodelled_detector_grasps(tray: ViewpointCloud) -> None:
    none = detect(tray, max_grasps=1000, use_selection=False, environment=EnvironmentParams(mode="none"))
    assert none.environment is not None and none.environment.counts()["support"] == 0
    on_floor = np.abs(none.grasps.samples[:, 2]) < 0.006
    assert on_floor.sum() > 10, "without an environment (the old behaviour) the floor is sampled"


def test_a_declared_box_removes_the_grasps_inside_it(tray: ViewpointCloud) -> None:
    around = (0.0, 0.08, 0.0, 0.11, -0.01, 0.1)  # the second box
    plain = detect(tray, max_grasps=1000, use_selection=False)
    assert Box.from_bounds(around).contains(plain.grasps.samples).sum() > 5
    env = EnvironmentParams(boxes=(Box.from_bounds(around),))
    declared = detect(tray, max_grasps=1000, use_selection=False, environment=env)
    assert declared.environment is not None and declared.environment.counts()["declared"] > 0
    assert not Box.from_bounds(around).contains(declared.grasps.samples).any()
    assert len(declared.grasps) > 5


def test_an_object_in_the_air_without_any_plane_still_gets_grasps() -> None:
    cyl = o3d.geometry.TriangleMesh.create_cylinder(0.03, 0.1).translate((0.0, 0.0, 0.2))
    cloud = render([cyl])
    det = detect(cloud, max_grasps=50)
    assert det.environment is not None and det.environment.support is None
    assert det.environment.counts()["object"] == det.num_points
    assert len(det.grasps) > 5


def test_wall_points_are_labelled_as_environment(tray: ViewpointCloud) -> None:
    det = detect(tray, max_grasps=10)
    env = det.environment
    assert env is not None
    counts = env.counts()
    assert counts["support"] > counts["object"] and counts["wall"] > 100
    assert int(Label.OBJECT) == 0


def test_hands_stop_short_of_the_support_and_reach_down_to_it(tray: ViewpointCloud) -> None:
    """The support is a plane the hand search stops at in closed form: no part of any candidate's hand or
    approach path dips below the clearance, yet fingertips come down close to the floor beside objects."""

    pre = preprocess(tray, PreprocessParams(voxel_size=0.003))
    env = model_environment(pre, HAND, EnvironmentParams())
    assert env.support is not None
    plane = env.support
    params = SamplingParams(num_samples=200, seed=3, sample_pool=env.object_mask, clear_behind=0.05 + HAND.palm_depth,
                            obstacles=env.labels != Label.SUPPORT, support_clearance=env.clearance,
                            support=plane)
    grasps, _ = search_hands(Scene.build(pre, HAND), HAND, params)
    assert len(grasps) > 50
    corners = HAND.swept_boxes(0.05)  # (3 boxes, low/high, xyz) in the hand frame
    pts = np.array([[x, y, z] for box in corners for x in box[:, 0] for y in box[:, 1] for z in box[:, 2]])
    world = grasps.positions[:, None, :] + np.einsum("gij,kj->gki", grasps.rotations, pts)
    lowest = plane.distance(world.reshape(-1, 3)).reshape(len(grasps), -1).min(axis=1)
    assert lowest.min() >= env.clearance - 1e-6
    down = grasps.approach @ plane.normal < -0.95
    tips = plane.distance(grasps.positions[down] + HAND.hand_depth * grasps.approach[down])
    assert down.sum() >= 5 and tips.min() < 0.01, "top-down fingertips reach within 1 cm of the floor"


def test_the_same_cloud_and_seed_give_the_same_environment(tray: ViewpointCloud) -> None:
    """Plane fitting is seeded numpy, not multi-threaded open3d RANSAC: a request is reproducible."""
    pre = preprocess(tray, PreprocessParams(voxel_size=0.003))
    first, second = (model_environment(pre, HAND, EnvironmentParams(), seed=5) for _ in range(2))
    assert first.support is not None and second.support is not None
    assert np.array_equal(first.support.normal, second.support.normal)
    assert first.support.offset == second.support.offset
    assert np.array_equal(first.labels, second.labels)


def _lying_on_table(cylinders: list[tuple[float, float, float]], heading_deg: float) -> Detection:
    """Cylinders (radius, length, offset across their axis; m) lying side by side on a table, their axes heading_deg
    about the vertical, seen by the household benchmark's side camera with its noise: the detection of a
    Panda-like hand, 200 samples, unscored."""
    heading = np.radians(heading_deg)
    meshes = [o3d.geometry.TriangleMesh.create_box(0.6, 0.6, 0.02).translate((-0.3, -0.3, -0.02))]
    for radius, length, across in cylinders:
        m = o3d.geometry.TriangleMesh.create_cylinder(radius=radius, height=length, resolution=48)
        m.rotate(o3d.geometry.get_rotation_matrix_from_xyz((0.0, np.pi / 2, 0.0)), center=(0, 0, 0))
        m.rotate(o3d.geometry.get_rotation_matrix_from_xyz((0.0, 0.0, heading)), center=(0, 0, 0))
        meshes.append(m.translate((-np.sin(heading) * across, np.cos(heading) * across, radius)))
    cloud = render_scene(meshes, sensing_cameras("side"), DepthNoise.benchmark(), 0)
    p = DetectionParams(num_samples=200, use_classifier=False, workspace=(-0.2, 0.2, -0.2, 0.2, -0.005, 0.4))
    return GraspDetector(None, PANDA_LIKE).detect(cloud, p)


@pytest.mark.parametrize(("radius", "length", "heading_deg"), [(0.0225, 0.16, 60.0), (0.0175, 0.23, 60.0),
                                                               (0.0175, 0.23, 90.0), (0.03, 0.16, 0.0)])
def test_a_bottle_lying_on_the_table_is_an_object_not_a_container_rim(radius: float, length: float,
                                                                       heading_deg: float) -> None:
    """Its ridge is a long line of up-facing points, as a thin wall's top is; its flanks falling away beside the
    ridge tell it from one."""
    found = _lying_on_table([(radius, length, 0.0)], heading_deg)
    assert found.environment is not None
    assert [s.kind for s in found.environment.surfaces] == ["support"]
    assert len(found.grasps) >= 20


@pytest.mark.parametrize("heading_deg", [30.0, 90.0])
def test_two_bottles_lying_side_by_side_are_objects_not_two_walls(heading_deg: float) -> None:
    """Each bottle's flank seen from the side is a long steep patch with a level top, and the two together look
    like a container's walls; their normals turning upward with height tell a curved flank from a flat wall."""
    found = _lying_on_table([(0.02, 0.19, 0.03), (0.028, 0.16, -0.03)], heading_deg)
    assert found.environment is not None
    assert [s.kind for s in found.environment.surfaces] == ["support"]
    assert len(found.grasps) >= 50


def _tray_with_a_box_before(wall_side: float) -> tuple[ViewpointCloud, Box]:
    """The tray (TRAY_WALLS) with a block 8 cm tall standing 1 cm in front of the middle of its y = wall_side wall,
    seen by the benchmark's passive cameras: the block hides that wall's middle from the camera that sees it."""
    sign = 1.0 if wall_side > 0 else -1.0
    face = 0.14 * sign
    block = (-0.03, 0.03, min(face - sign * 0.04, face - sign * 0.01), max(face - sign * 0.04, face - sign * 0.01),
             0.0, 0.08)
    floor = box_mesh((-0.3, 0.3, -0.3, 0.3, -0.02, 0.0))
    cloud = render_scene([floor, *[box_mesh(w) for w in TRAY_WALLS], box_mesh(block)], sensing_cameras("passive"),
                         DepthNoise.benchmark(), 0)
    wall = next(w for w in TRAY_WALLS if (w[2] + w[3]) / 2.0 * sign > 0.1)
    return cloud, Box.from_bounds(wall)


@pytest.mark.parametrize("wall_side", [0.145, -0.145])
def test_a_tray_wall_whose_middle_an_object_hides_is_still_a_wall(wall_side: float) -> None:
    """Both ends of the wall show, 10-14 cm each (under the 18 cm a wall must run unbroken), and meet the side
    walls at the corners: the gap is what stands in front of it, not the wall's end."""
    cloud, wall = _tray_with_a_box_before(wall_side)
    det = detect(cloud, max_grasps=1000, use_selection=False)
    env = det.environment
    assert env is not None
    found = [s.box for s in env.surfaces if s.kind == "wall" and s.box is not None]
    assert any(wall.contains(b.centre[None], margin=0.02)[0] and 2 * b.half_extents[1] > 0.3 for b in found), \
        "the hidden wall is found along its whole length"
    assert not np.any(wall.contains(det.grasps.samples, margin=0.004)), "no grasp is sampled on it"


@pytest.mark.parametrize("wall_x", [0.185, -0.185])
def test_a_tray_wall_that_objects_standing_against_it_rise_above_is_still_a_wall(wall_x: float) -> None:
    """Three blocks 10 cm tall stand against the x = wall_x side of the 6 cm tray (TRAY_WALLS), seen by the
    benchmark's passive cameras: their sides rise above the wall's top along a third of its length, so its top
    is not level, yet it spans between the two side walls at their corners; its box keeps the wall's own top."""
    sign = 1.0 if wall_x > 0 else -1.0
    floor = box_mesh((-0.3, 0.3, -0.3, 0.3, -0.02, 0.0))
    blocks = [box_mesh((min(0.14 * sign, 0.18 * sign), max(0.14 * sign, 0.18 * sign), y, y + 0.03, 0.0, 0.10))
              for y in (-0.11, -0.02, 0.07)]
    cloud = render_scene([floor, *[box_mesh(w) for w in TRAY_WALLS], *blocks], sensing_cameras("passive"),
                         DepthNoise.benchmark(), 0)
    env = detect(cloud, max_grasps=10).environment
    assert env is not None
    wall = Box.from_bounds(next(w for w in TRAY_WALLS if (w[0] + w[1]) / 2.0 * sign > 0.1))
    found = [s.box for s in env.surfaces if s.kind == "wall" and s.box is not None]
    side = [b for b in found if wall.contains(b.centre[None], margin=0.02)[0]]
    assert side, "the side the blocks stand against is a wall"
    top = side[0].centre[2] + side[0].half_extents[2]
    assert 0.06 <= top <= 0.08, f"its box ends a little above the wall's 6 cm top, not at the blocks' 10 cm: {top}"


def test_objects_tops_side_by_side_at_one_height_are_no_board() -> None:
    """Four 5 cm blocks in a tray, 2 cm apart: their tops make one surface at one height wider than a level must
    be, with the blocks' sides seen beneath it between them; that is no board (a shelf's ceiling), and the blocks
    keep their grasps."""
    floor = box_mesh((-0.3, 0.3, -0.3, 0.3, -0.02, 0.0))
    blocks = [box_mesh((x, x + 0.07, y, y + 0.07, 0.0, 0.05)) for x in (-0.08, 0.01) for y in (-0.08, 0.01)]
    cloud = render_scene([floor, *[box_mesh(w) for w in TRAY_WALLS], *blocks], sensing_cameras("passive"),
                         DepthNoise.benchmark(), 0)
    det = detect(cloud, max_grasps=1000)
    assert det.environment is not None
    assert "board" not in [s.kind for s in det.environment.surfaces]
    assert len(det.grasps) >= 50


def test_a_shelf_ceiling_with_room_seen_beneath_is_a_board() -> None:
    """A shelf open toward the cameras, its ceiling 25 cm up over a block: room is seen under the ceiling itself,
    so it is a board, and the block beneath keeps its grasps."""
    floor = box_mesh((-0.3, 0.3, -0.3, 0.3, -0.02, 0.0))
    shelf = [box_mesh((-0.15, 0.15, -0.16, -0.145, 0.0, 0.27)), box_mesh((-0.15, 0.15, 0.145, 0.16, 0.0, 0.27)),
             box_mesh((0.145, 0.16, -0.16, 0.16, 0.0, 0.27)), box_mesh((-0.15, 0.16, -0.16, 0.16, 0.25, 0.27))]
    block = box_mesh((-0.05, 0.01, -0.03, 0.03, 0.0, 0.08))
    cloud = render_scene([floor, *shelf, block], sensing_cameras("passive"), DepthNoise.benchmark(), 0)
    det = detect(cloud, max_grasps=1000)
    assert det.environment is not None
    boards = [s for s in det.environment.surfaces if s.kind == "board"]
    assert len(boards) == 1 and boards[0].box is not None and boards[0].box.centre[2] > 0.15
    assert len(det.grasps) >= 20


def _side_wall(y: float) -> Box:
    """A wall box along x at y (length on its second axis, as find_walls makes them), its ends at x = +-0.15."""
    rotation = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    return Box(np.array([0.0, y, 0.03]), rotation, np.array([0.007, 0.15, 0.03]))


def test_a_face_spans_between_walls_only_when_it_meets_them_at_its_two_ends() -> None:
    """A face square to two side walls, 1 cm from their ends, spans between them (a container's fourth side);
    one that meets a wall found twice at one end does not (objects' faces before a shelf's open front)."""
    face = Plane(np.array([1.0, 0.0, 0.0]), 0.14)  # x = -0.14
    up = np.array([0.0, 0.0, 1.0])
    assert _spans_between_walls(face, up, [_side_wall(-0.15), _side_wall(0.15)], min_length=0.15)
    assert not _spans_between_walls(face, up, [_side_wall(-0.15), _side_wall(-0.14)], min_length=0.15)


def test_object_faces_in_a_line_with_gaps_are_no_wall() -> None:
    """Three blocks in a row on a table, their faces in one plane with 5 cm gaps, are objects: no wall meets them."""
    floor = box_mesh((-0.3, 0.3, -0.3, 0.3, -0.02, 0.0))
    blocks = [box_mesh((x, x + 0.06, 0.0, 0.04, 0.0, 0.07)) for x in (-0.16, -0.05, 0.06)]
    cloud = render_scene([floor, *blocks], sensing_cameras("passive"), DepthNoise.benchmark(), 0)
    env = detect(cloud, max_grasps=10).environment
    assert env is not None
    assert [s.kind for s in env.surfaces] == ["support"]


def _tray_walls_found(inside: list[tuple[float, float, float, float, float, float]]) -> tuple[list[Box], Detection]:
    """The wall boxes found in the tray (TRAY_WALLS) with the given solids inside, seen by the benchmark's passive
    cameras, and the detection."""
    floor = box_mesh((-0.3, 0.3, -0.3, 0.3, -0.02, 0.0))
    cloud = render_scene([floor, *[box_mesh(w) for w in TRAY_WALLS], *[box_mesh(b) for b in inside]],
                         sensing_cameras("passive"), DepthNoise.benchmark(), 0)
    det = detect(cloud, max_grasps=1000)
    assert det.environment is not None
    return [s.box for s in det.environment.surfaces if s.kind == "wall" and s.box is not None], det


def test_object_faces_in_a_line_inside_a_tray_are_no_wall() -> None:
    """Three 7 cm blocks in a row across the tray, 1 cm apart, their faces in one plane with a level top: inside
    the outline of the tray's four sides, they are objects, and keep their grasps."""
    row = [(x, x + 0.06, 0.0, 0.05, 0.0, 0.07) for x in (-0.11, -0.04, 0.03)]
    found, det = _tray_walls_found(row)
    assert len(found) == 4, [np.round(b.centre, 3).tolist() for b in found]
    assert all(any(Box.from_bounds(w).contains(b.centre[None], margin=0.02)[0] for w in TRAY_WALLS) for b in found)
    blocks = Box.from_bounds((-0.11, 0.09, 0.0, 0.05, 0.0, 0.07))
    assert np.count_nonzero(blocks.contains(det.grasps.positions, margin=0.05)) >= 10


def test_a_divider_running_from_wall_to_wall_inside_a_tray_is_a_wall() -> None:
    """A 1 cm board across the tray from side to side, as tall as its sides: it runs gap-free between the walls it
    meets at both ends, so it stays a wall although it stands inside the tray."""
    divider = (-0.18, 0.18, -0.005, 0.005, 0.0, 0.06)
    found, _ = _tray_walls_found([divider])
    assert any(Box.from_bounds(divider).contains(b.centre[None], margin=0.02)[0] for b in found)


def test_object_faces_in_a_line_on_a_platform_are_no_wall() -> None:
    """The same row of blocks standing on a 5 cm platform, no container around: inside the platform's outline,
    their faces are objects, and keep their grasps."""
    floor = box_mesh((-0.3, 0.3, -0.3, 0.3, -0.02, 0.0))
    platform = box_mesh((-0.15, 0.15, -0.12, 0.12, 0.0, 0.05))
    row = [box_mesh((x, x + 0.06, 0.0, 0.05, 0.05, 0.12)) for x in (-0.11, -0.04, 0.03)]
    cloud = render_scene([floor, platform, *row], sensing_cameras("passive"), DepthNoise.benchmark(), 0)
    det = detect(cloud, max_grasps=1000)
    assert det.environment is not None
    kinds = [s.kind for s in det.environment.surfaces]
    assert "platform" in kinds and "wall" not in kinds, kinds
    blocks = Box.from_bounds((-0.11, 0.09, 0.0, 0.05, 0.05, 0.12))
    assert np.count_nonzero(blocks.contains(det.grasps.positions, margin=0.05)) >= 10



def test_a_shelf_on_a_base_board_wider_than_it_keeps_its_sides() -> None:
    """A shelf open toward the cameras stands on a 1.5 cm board 10 cm wider than it on every side: the board is a
    raised level, but the shelf's own walls are its outline, so its sides standing well inside the board's are
    still walls."""
    floor = box_mesh((-0.3, 0.3, -0.3, 0.3, -0.02, 0.0))
    board = box_mesh((-0.22, 0.24, -0.26, 0.26, 0.0, 0.015))
    shelf = [(-0.12, 0.12, -0.165, -0.15, 0.015, 0.22), (-0.12, 0.12, 0.15, 0.165, 0.015, 0.22),
             (0.12, 0.135, -0.165, 0.165, 0.015, 0.22)]
    block = box_mesh((-0.04, 0.02, -0.03, 0.03, 0.015, 0.09))
    cloud = render_scene([floor, board, *[box_mesh(w) for w in shelf], block], sensing_cameras("passive"),
                         DepthNoise.benchmark(), 0)
    det = detect(cloud, max_grasps=1000)
    assert det.environment is not None
    found = [s.box for s in det.environment.surfaces if s.kind == "wall" and s.box is not None]
    for side in shelf:
        assert any(Box.from_bounds(side).contains(b.centre[None], margin=0.02)[0] for b in found), side
