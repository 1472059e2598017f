"""A deep bin seen over its near wall, and from straight above.  Over the wall, the floor beside it is hidden
from every camera: no grasp there is not an empty bin, and the answer says so (unseen_floor); a bin or tray whose
floor the cameras saw gets no such warning.  From above, the four thin walls show only their tops: all four are
rims (environment), and the grasps are on what the bin holds.  Scenes are boxes rendered with the benchmark's
noise, so which points each box gave is known exactly."""

from __future__ import annotations

import numpy as np
import open3d as o3d
import pytest

from graspd.core.camera import Camera, sensing_cameras
from graspd.core.cloud import ViewpointCloud
from graspd.core.hand import HandGeometry
from graspd.gpd.classifier import DEFAULT_CASCADE_MODEL, default_model_name, load_model
from graspd.gpd.detector import Detection, DetectionParams, GraspDetector
from graspd.gpd.environment.coverage import MIN_HIDDEN_WIDTH, floor_coverage
from graspd_lab.world.noise import DepthNoise
from graspd_lab.world.render import render_scene_with_ids

HAND = HandGeometry()
#: A box on the floor beside the near (-x) wall: 6 x 8 x 3 cm, what the cameras over that wall cannot see.
HIDDEN_BOX = (-0.125, -0.065, -0.04, 0.04, 0.0, 0.03)
#: The cameras' side is -x (the robot's); one camera straight above the bin's middle sees all of its floor.
ABOVE = [Camera((0.0, 0.0, 0.9), (0.0, 0.0, 0.0), fov_deg=45.0, fov_axis="vertical")]


def box_mesh(bounds: tuple[float, float, float, float, float, float]) -> o3d.geometry.TriangleMesh:
    """A solid box [xmin, xmax, ymin, ymax, zmin, zmax] (m)."""
    x0, x1, y0, y1, z0, z1 = bounds
    return o3d.geometry.TriangleMesh.create_box(x1 - x0, y1 - y0, z1 - z0).translate((x0, y0, z0))


def container(wall_height: float, half_x: float = 0.14, half_y: float = 0.12, thickness: float = 0.01
              ) -> list[o3d.geometry.TriangleMesh]:
    """A table slab and four walls round an open floor of 2 half_x by 2 half_y (m), the table its floor."""
    ox, oy, h = half_x + thickness, half_y + thickness, wall_height
    return [box_mesh((-0.4, 0.4, -0.4, 0.4, -0.02, 0.0)),
            box_mesh((-ox, -half_x, -oy, oy, 0.0, h)), box_mesh((half_x, ox, -oy, oy, 0.0, h)),
            box_mesh((-ox, ox, -oy, -half_y, 0.0, h)), box_mesh((-ox, ox, half_y, oy, 0.0, h))]


def look(meshes: list[o3d.geometry.TriangleMesh], cameras: list[Camera]) -> tuple[ViewpointCloud, np.ndarray]:
    return render_scene_with_ids(meshes, cameras, DepthNoise.benchmark(), 0)


def detect(cloud: ViewpointCloud) -> Detection:
    """The service's defaults: the default model and its cascade, the environment found in the cloud."""
    detector = GraspDetector(load_model(default_model_name()), HAND, prefilter=load_model(DEFAULT_CASCADE_MODEL))
    return detector.detect(cloud, DetectionParams(workspace=(-0.3, 0.3, -0.3, 0.3, -0.01, 0.4)))


def codes(det: Detection) -> list[str]:
    return [w.code for w in det.warnings]


@pytest.fixture(scope="module")
def bin_seen_over_its_wall() -> tuple[ViewpointCloud, np.ndarray]:
    return look([*container(0.20), box_mesh(HIDDEN_BOX)], sensing_cameras("passive"))


def test_a_box_beside_a_deep_bins_near_wall_gives_no_point(bin_seen_over_its_wall: tuple) -> None:
    _, ids = bin_seen_over_its_wall
    assert not np.any(ids == 5), "the scene must hide the box from both cameras, or the test below tests nothing"


def test_no_grasp_in_a_deep_bin_seen_over_its_wall_says_its_floor_went_unseen(bin_seen_over_its_wall: tuple) -> None:
    cloud, _ = bin_seen_over_its_wall
    det = detect(cloud)
    assert len(det.grasps) == 0
    assert "unseen_floor" in codes(det)
    message = next(w.message for w in det.warnings if w.code == "unseen_floor")
    assert "% of the floor" in message and "from above" in message and "the widest around (" in message


def test_the_hidden_part_is_the_floor_beside_the_near_wall(bin_seen_over_its_wall: tuple) -> None:
    cloud, _ = bin_seen_over_its_wall
    prep = GraspDetector(None, HAND).prepare(cloud, DetectionParams(workspace=(-0.3, 0.3, -0.3, 0.3, -0.01, 0.4)),
                                             HAND)
    cover = floor_coverage(prep.cloud.points, prep.environment)
    assert cover is not None
    assert 0.03 < cover.floor_area < 0.08  # the 28 x 24 cm floor, less the walls' margins
    assert 0.2 < cover.unseen_share < 0.8
    assert cover.hidden_width >= MIN_HIDDEN_WIDTH
    # where to look: on the floor (z = 0) beside the near wall (inner face at x = -0.14), inside the bin
    assert cover.hidden_centre is not None
    x, y, z = cover.hidden_centre
    assert -0.14 < x < -0.02 and abs(y) < 0.12 and abs(z) < 0.01


def test_the_same_bin_seen_from_above_gets_grasps_on_the_box_and_no_floor_warning() -> None:
    det = detect(look([*container(0.20), box_mesh(HIDDEN_BOX)], ABOVE)[0])
    assert len(det.grasps) > 0
    assert "unseen_floor" not in codes(det)
    x0, x1, y0, y1, _, z1 = HIDDEN_BOX
    top = det.grasps[:5].positions
    assert np.all((top[:, 0] > x0 - 0.05) & (top[:, 0] < x1 + 0.05) & (top[:, 1] > y0 - 0.05) & (top[:, 1] < y1 + 0.05))


def test_a_bins_four_wall_tops_seen_from_above_are_four_rims() -> None:
    cloud, ids = look(container(0.20), ABOVE)
    prep = GraspDetector(None, HAND).prepare(cloud, DetectionParams(workspace=(-0.3, 0.3, -0.3, 0.3, -0.01, 0.4)),
                                             HAND)
    env = prep.environment
    assert sorted(s.kind for s in env.surfaces) == ["rim", "rim", "rim", "rim", "support"]
    points_of_walls = np.isin(ids, [1, 2, 3, 4])
    high = prep.cloud.points[:, 2] > 0.15  # the wall tops (the preprocessed cloud is thinned: no ids for it)
    assert points_of_walls.any() and not np.any(env.object_mask & high)


def test_an_empty_bin_seen_from_above_is_no_grasp_without_a_floor_warning() -> None:
    det = detect(look(container(0.20), ABOVE)[0])
    assert len(det.grasps) == 0
    assert "unseen_floor" not in codes(det)


def test_an_empty_low_tray_seen_by_the_same_cameras_is_no_grasp_without_a_floor_warning() -> None:
    """A 5 cm wall hides only a strip at its foot, too narrow for an object to lie in unseen."""
    det = detect(look(container(0.05), sensing_cameras("passive"))[0])
    assert len(det.grasps) == 0
    assert "unseen_floor" not in codes(det)
