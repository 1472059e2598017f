"""The open hand's whole way in is checked by default: its path from the pre-grasp pose and the pre-grasp pose itself
against the cloud's points (a neighbour above the object), against space no camera saw far behind a seen surface
(the hidden end of a long object; with unknown_space "fallback", when no hand keeps out of it, those entering it
least, with a warning), and with a clearance from the points it would otherwise graze.

Clouds are rendered from boxes (graspd_lab.world.render), so where each object is, seen or hidden, is exact."""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import numpy as np
import open3d as o3d
import pytest

from graspd.core.camera import tabletop_cameras
from graspd.core.grasp import GraspSet
from graspd.core.hand import HandGeometry, hand_preset
from graspd.gpd.detector import DetectionParams, GraspDetector
from graspd.gpd.occlusion import hand_shadow_length
from graspd.gpd.scene import unobserved_grid
from graspd_lab.world.noise import DepthNoise
from graspd_lab.world.render import render_scene

HAND = HandGeometry()
APPROACH = DetectionParams().approach_distance
TABLE = (-0.3, 0.3, -0.3, 0.3, -0.02, 0.0)
OBJECT = (-0.02, 0.02, -0.02, 0.02, 0.0, 0.06)  # the object to grasp: a 4 cm block
OVERHANG = (-0.05, 0.05, 0.0, 0.03, 0.09, 0.1)  # a neighbour's ledge 3 cm above it, over half of it
CAMERAS = tabletop_cameras(2, distance=0.7, elevation_deg=50.0, azimuth_deg=-90.0)
LONG = (-0.1, 0.1, -0.02, 0.02, 0.0, 0.05)  # 20 cm long, seen end-on from +x: its far end hidden


def _box(b: tuple[float, ...]) -> o3d.geometry.TriangleMesh:
    x0, x1, y0, y1, z0, z1 = b
    return o3d.geometry.TriangleMesh.create_box(x1 - x0, y1 - y0, z1 - z0).translate((x0, y0, z0))


def _inside(points: np.ndarray, bounds: tuple[float, ...], grow: float = 0.0) -> np.ndarray:
    lo, hi = np.array(bounds[0::2]) - grow, np.array(bounds[1::2]) + grow
    return np.all((points > lo) & (points < hi), axis=1)


def _paths_through(grasps: GraspSet, points: np.ndarray, depth: float = 0.001) -> int:
    """How many hands' swept outlines (fingers and palm from the pre-grasp pose to the grasp) hold any of points
    at least depth (m) inside."""
    boxes = HAND.swept_boxes(APPROACH)
    count = 0
    for pos, rot in zip(grasps.positions, grasps.rotations, strict=True):
        local = (points - pos) @ rot
        count += int(any(np.all((local > lo + depth) & (local < hi - depth), axis=1).any() for lo, hi in boxes))
    return count


@pytest.fixture(scope="module")
def ledge_scene() -> Any:
    return render_scene([_box(TABLE), _box(OBJECT), _box(OVERHANG)], CAMERAS, DepthNoise(), 0)


@pytest.mark.parametrize("unknown_space", ["avoid", "allow"])
def test_no_hand_is_returned_whose_way_in_passes_through_a_neighbours_points(ledge_scene: Any,
                                                                             unknown_space: str) -> None:
    p = DetectionParams(num_samples=400, use_classifier=False, max_grasps=1000, use_selection=False,
                        unknown_space=unknown_space)  # type: ignore[arg-type]
    ledge = ledge_scene.points[_inside(ledge_scene.points, OVERHANG, 0.002)].astype(np.float64)
    assert len(ledge) > 50
    det = GraspDetector(None, HAND)
    found = det.detect(ledge_scene, p)
    on_object = _inside(found.grasps.samples, OBJECT, 0.004)
    assert on_object.sum() >= 5, "the block must be grasped, or the test tests nothing"
    assert _paths_through(found.grasps[on_object], ledge) == 0
    # without the ledge, hands on the block come in where the ledge is: the scene tempts the check
    bare = render_scene([_box(TABLE), _box(OBJECT)], CAMERAS, DepthNoise(), 0)
    free = det.detect(bare, p).grasps
    assert _paths_through(free[_inside(free.samples, OBJECT, 0.004)], ledge) >= 5


def test_the_hidden_part_of_a_long_object_beyond_the_opening_is_unseen_space_to_the_hand() -> None:
    """Seen end-on from low down, the inside of a 20 cm object lies up to 20 cm behind its seen faces: what lies
    12 cm behind them is unseen space to the hand check (it reaches 15.5 cm: fingers, palm, path), though the
    images' volume, as deep as the opening (8 cm), calls it free."""
    hand = hand_preset("panda")
    cam = tabletop_cameras(1, distance=0.7, elevation_deg=12.0)
    cloud = render_scene([_box(TABLE), _box(LONG)], cam, DepthNoise(), 0)
    p = DetectionParams(num_samples=300, use_classifier=False, max_grasps=1000, use_selection=False)
    det = GraspDetector(None, hand)
    scene = det.prepare(cloud, p, hand).scene
    eye = np.asarray(cam[0].position)
    grid = np.stack(np.meshgrid([-0.025, -0.02, -0.015], [-0.01, 0.0, 0.01], [0.025, 0.03], indexing="ij"), -1)
    inside = grid.reshape(-1, 3)
    # each point's distance behind the object's surface along its camera ray (where the ray enters the box)
    lo, hi = np.array(LONG[0::2]), np.array(LONG[1::2])
    for q in inside:
        ray = (q - eye) / np.linalg.norm(q - eye)
        with np.errstate(divide="ignore"):
            t = np.where(ray != 0, (np.where(ray > 0, lo, hi) - eye) / ray, -np.inf).max()
        assert 0.10 < np.linalg.norm(q - eye) - t < 0.14
    deep = scene.unobserved_within(hand_shadow_length(hand, p.approach_distance))
    assert not scene.unobserved.contains(inside.astype(np.float32)).any()
    # marching rays on voxels leaves holes, and the lattice (from the cloud's bounds less the shadow's length)
    # decides where they fall: half or more of these 18 points, none without the hand's deeper volume
    assert deep.contains(inside.astype(np.float32)).mean() >= 0.5


def test_the_floor_a_deep_bins_wall_hides_is_unseen_space_to_the_hand_though_it_lies_past_the_hands_reach() -> None:
    """Seen over a 22 cm wall from 45 degrees up, the floor beside the wall's far face lies 16-25 cm behind the
    wall's near face along the camera's rays: past the 15.5 cm the hand reaches (fingers, palm, path), so only
    the shadow's floor (occlusion.MIN_SHADOW_LENGTH) makes a finger reaching down there meet unseen space."""
    hand = hand_preset("panda").with_overrides(hand_outer_diameter=0.095)
    wall = (-0.01, 0.0, -0.15, 0.15, 0.0, 0.22)
    cam = tabletop_cameras(1, distance=0.8, elevation_deg=45.0, azimuth_deg=180.0)  # on the -x side of the wall
    cloud = render_scene([_box(TABLE), _box(wall)], cam, DepthNoise(), 0)
    p = DetectionParams(num_samples=50, use_classifier=False)
    scene = GraspDetector(None, hand).prepare(cloud, p, hand).scene
    eye = np.asarray(cam[0].position)
    assert eye[0] < -0.3, "the camera must look over the wall from its near side"
    grid = np.stack(np.meshgrid([0.13, 0.15, 0.17], [-0.02, 0.0, 0.02], [0.01, 0.02], indexing="ij"), -1)
    hidden = grid.reshape(-1, 3)
    reach = hand.hand_depth + hand.palm_depth + p.approach_distance
    for q in hidden:  # each point's distance behind the wall's near face (x = -0.01) along its camera ray
        ray = (q - eye) / np.linalg.norm(q - eye)
        enter = eye + ray * (-0.01 - eye[0]) / ray[0]
        assert enter[2] < 0.22, "the ray must pass through the wall, not over it"
        assert reach < np.linalg.norm(q - enter) < hand_shadow_length(hand, p.approach_distance)
    assert not scene.unobserved_within(reach).contains(hidden.astype(np.float32)).any()
    deep = scene.unobserved_within(hand_shadow_length(hand, p.approach_distance))
    assert deep.contains(hidden.astype(np.float32)).mean() >= 0.6  # marching rays on voxels leaves holes


def test_with_fallback_when_no_hand_keeps_out_of_unseen_space_those_entering_it_least_come_back_with_a_warning(
) -> None:
    """A block 2 cm beside an 8 cm wall, seen over the wall from one side: every hand on it dips into the wall's
    shadow, so "avoid" (the default) returns none, and "fallback" returns hands on the block that put a little of
    themselves there (at most unknown_fallback), and says so.  A second camera sees the floor behind the wall:
    then the hands keep out of unseen space, both modes answer alike and nothing is warned of."""
    hand = hand_preset("panda").with_opening(0.075)
    wall = (-0.01, 0.0, -0.15, 0.15, 0.0, 0.08)
    block = (0.02, 0.06, -0.02, 0.02, 0.0, 0.06)
    p = DetectionParams(num_samples=300, use_classifier=False, workspace=(-0.2, 0.2, -0.2, 0.2, -0.01, 0.3))
    det = GraspDetector(None, hand)
    one = render_scene([_box(TABLE), _box(wall), _box(block)],
                       tabletop_cameras(1, distance=0.8, elevation_deg=45.0, azimuth_deg=180.0), DepthNoise(), 0)
    assert len(det.detect(one, p).grasps) == 0
    found = det.detect(one, replace(p, unknown_space="fallback"))
    assert len(found.grasps) >= 20
    assert _inside(found.grasps.samples, block, 0.006).all()
    share = found.grasps.unknown_share
    assert (share > p.max_unknown).all() and (share <= p.unknown_fallback).all()
    assert [w.code for w in found.warnings] == ["unknown_space"]
    two = render_scene([_box(TABLE), _box(wall), _box(block)],
                       tabletop_cameras(2, distance=0.8, elevation_deg=45.0, azimuth_deg=180.0), DepthNoise(), 0)
    avoid, fallback = (det.detect(two, replace(p, unknown_space=mode)) for mode in ("avoid", "fallback"))
    assert len(avoid.grasps) >= 1 and (avoid.grasps.unknown_share == 0).all() and not avoid.warnings
    assert np.array_equal(fallback.grasps.positions, avoid.grasps.positions) and not fallback.warnings


def test_a_focused_unseen_volume_marks_the_whole_ones_cells_inside_its_focus_in_a_smaller_grid() -> None:
    """Where hands can reach (the focus box) the grid bounded by it marks the very cells the grid over the whole
    cloud marks, 30 cm shadows cast from a wall outside the focus included, in under half the cells."""
    wall = (-0.25, -0.24, -0.15, 0.15, 0.0, 0.22)
    cam = tabletop_cameras(2, distance=0.8, elevation_deg=45.0, azimuth_deg=180.0)
    cloud = render_scene([_box(TABLE), _box(LONG), _box(wall)], cam, DepthNoise(), 0)
    focus = (np.array([-0.15, -0.12, -0.02]), np.array([0.12, 0.12, 0.15]))
    whole = unobserved_grid(cloud.points, cloud.viewpoints, 0.004, 0.30)
    part = unobserved_grid(cloud.points, cloud.viewpoints, 0.004, 0.30, focus)
    assert part.voxel == whole.voxel and part.cells.size < whole.cells.size / 2
    first = np.ceil((focus[0] - whole.origin) / whole.voxel)  # the centres of the whole grid's cells in the focus
    last = np.floor((focus[1] - whole.origin) / whole.voxel) - 1
    axes = [whole.origin[i] + (np.arange(first[i], last[i] + 1) + 0.5) * whole.voxel for i in range(3)]
    inside = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3).astype(np.float32)
    marked = whole.contains(inside)
    assert marked.sum() > 1000, "the focus must hold unseen space, or this compares nothing"
    assert np.array_equal(part.contains(inside), marked)


def test_returned_hands_keep_their_clearance_from_the_points_they_would_graze(ledge_scene: Any) -> None:
    base = {"num_samples": 300, "use_classifier": False, "max_grasps": 1000, "use_selection": False}
    c = DetectionParams().clearance
    assert c >= 0.002
    det = GraspDetector(None, HAND)

    def grazing(params: DetectionParams) -> int:
        """Hands with a cloud point within c of a fingertip, an outer finger face or the top and bottom faces."""
        g = det.detect(ledge_scene, params).grasps
        pts = det.prepare(ledge_scene, params, HAND).cloud.points.astype(np.float64)
        pts = pts[pts[:, 2] > 0.006]  # the table is kept clear in closed form (environment clearance)
        od, fw, hd, hh = HAND.hand_outer_diameter, HAND.finger_width, HAND.hand_depth, HAND.hand_height
        bad = 0
        for pos, rot in zip(g.positions, g.rotations, strict=True):
            local = (pts - pos) @ rot
            x, ay, az = local[:, 0], np.abs(local[:, 1]), np.abs(local[:, 2])
            finger = (ay > od / 2 - fw) & (ay < od / 2 + 0.8 * c) & (x > 0) & (x < hd + 0.8 * c)
            bad += int((finger & (az < hh / 2 + 0.8 * c)).any())
        return bad

    assert grazing(DetectionParams(clearance=0.0, **base)) > 0, "flush hands must graze, or this tests nothing"
    assert grazing(DetectionParams(**base)) == 0
