"""graspd.gpd.sanity: the request-level checks on real and rendered clouds: a viewpoint that could not have seen
the cloud warns, the right one does not; too few points, a model made for another hand and an empty answer
each say what happened and what to do."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from graspd.gpd.preprocess import DEFAULT_RANGE_WINDOW, region_mask
from graspd.gpd.sanity import (
    HIDDEN_SHARE_LIMIT,
    few_points_warning,
    hidden_share,
    in_workspace,
    model_hand_warning,
    no_candidates_warning,
    viewpoint_warning,
)
from graspd.io.cloud_files import read_cloud
from graspd_lab.world.scenes import cluttered_tabletop


@pytest.fixture(scope="module")
def mug_points(real_data: Path) -> np.ndarray:
    return read_cloud(real_data / "table_mug.pcd").points


def test_table_mug_seen_from_its_camera_passes(mug_points: np.ndarray) -> None:
    assert hidden_share(mug_points, np.zeros((1, 3))) < 0.01
    assert viewpoint_warning(mug_points, np.zeros((1, 3))) is None


@pytest.mark.parametrize("viewpoint", [(0.0, 0.0, 3.0), (0.0, 0.0, 2.0)])
def test_table_mug_seen_from_behind_warns(mug_points: np.ndarray, viewpoint: tuple[float, float, float]) -> None:
    w = viewpoint_warning(mug_points, np.array([viewpoint]))
    assert w is not None and w.code == "viewpoint_flipped"
    assert "wrong side" in w.message and f"{viewpoint[2]:.3g}" in w.message


def test_krylon_from_its_own_viewpoint_passes(real_data: Path) -> None:
    can = read_cloud(real_data / "krylon.pcd")
    assert viewpoint_warning(can.points, can.viewpoints) is None


def test_rendered_tabletop_right_and_mirrored_cameras() -> None:
    cloud = cluttered_tabletop(num_objects=4, seed=3)
    assert hidden_share(cloud.points, cloud.viewpoints) < 0.01  # both cameras: every point explained
    mirrored = cloud.viewpoints.copy()
    mirrored[:, 2] *= -1  # the same cameras below the table (z = 0)
    assert hidden_share(cloud.points, mirrored) > HIDDEN_SHARE_LIMIT
    assert viewpoint_warning(cloud.points, mirrored) is not None


def test_in_workspace() -> None:
    pts = np.array([[0.0, 0.0, 0.0], [1.0, 1.0, 1.0], [0.5, 0.5, 2.0]])
    assert in_workspace(pts, None) is pts
    assert in_workspace(pts, [0, 1, 0, 1, 0, 1]).tolist() == [[0, 0, 0], [1, 1, 1]]


def test_few_points() -> None:
    assert few_points_warning(100, True) is None
    w = few_points_warning(7, True)
    assert w is not None and w.code == "few_points" and "only 7 points" in w.message and "workspace" in w.message
    w = few_points_warning(7, False)
    assert w is not None and "denser" in w.message


def test_model_hand_mismatch() -> None:
    hand = {"finger_width": 0.01, "hand_outer_diameter": 0.1, "hand_depth": 0.045, "hand_height": 0.02}
    assert model_hand_warning("scene15", True, hand) is None
    assert model_hand_warning("scene15", None, hand) is None
    assert model_hand_warning(None, False, hand) is None
    w = model_hand_warning("scene15", False, hand)
    assert w is not None and w.code == "model_hand_mismatch" and "'scene15'" in w.message and "0.045" in w.message


@pytest.mark.parametrize(("points", "candidates", "counts", "stage"), [
    (0, 0, None, "preprocess"),
    (500, 0, {"object": 0, "support": 500}, "environment"),
    (500, 0, {"object": 200, "support": 300}, "candidates"),
    (500, 40, {"object": 200, "support": 300}, "selection"),
])
def test_no_candidates_names_the_stage(points: int, candidates: int, counts: dict[str, int] | None,
                                       stage: str) -> None:
    assert no_candidates_warning(points, candidates, 3, counts) is None
    w = no_candidates_warning(points, candidates, 0, counts)
    assert w is not None and w.code == "no_candidates" and f"the {stage} stage removed them" in w.message


@pytest.mark.parametrize("name", ["milk_cartoon_all_small_clorox.pcd", "table_scene_mug_stereo_textured.pcd"])
def test_a_whole_room_frame_from_its_own_camera_is_not_flipped(real_data: Path, name: str) -> None:
    """An organised capture from the camera at the origin, the room out to 2.5 m behind the table: within the
    default range window nothing looks hidden; the same points seen from behind the table still warn."""
    cloud = read_cloud(real_data / name)
    region = cloud.points[region_mask(cloud, None, DEFAULT_RANGE_WINDOW)]
    assert np.linalg.norm(region, axis=1).max() < 1.7  # the room beyond the window is not part of it
    assert viewpoint_warning(region, np.zeros((1, 3))) is None
    assert viewpoint_warning(region, np.array([[0.0, 0.0, 3.0]])) is not None
