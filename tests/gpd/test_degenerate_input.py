"""Degenerate clouds give a clear error or an empty result, never a crash."""

from __future__ import annotations

import numpy as np
import pytest

from graspd.core.cloud import CloudError, ViewpointCloud
from graspd.core.hand import HandGeometry
from graspd.gpd.detector import DetectionParams, GraspDetector
from graspd.gpd.preprocess import preprocess
from graspd.gpd.scene import Scene

VP = np.array([[0.5, 0.0, 0.5]], np.float32)


def _detect(points: np.ndarray, **kw) -> int:
    det = GraspDetector().detect(ViewpointCloud(points=points, viewpoints=kw.pop("viewpoints", VP)),
                                 DetectionParams(num_samples=50))
    assert det.scored is False and det.model is None
    return len(det.grasps)


def test_empty_cloud_gives_no_grasps() -> None:
    assert _detect(np.zeros((0, 3), np.float32)) == 0


def test_all_nan_cloud_gives_no_grasps() -> None:
    assert _detect(np.full((100, 3), np.nan, np.float32)) == 0


def test_infinite_points_are_dropped() -> None:
    pts = np.random.default_rng(0).uniform(-0.05, 0.05, (500, 3)).astype(np.float32)
    pts[::7] = np.inf
    assert preprocess(ViewpointCloud(points=pts, viewpoints=VP)).points.shape[0] < 500
    _detect(pts)


def test_one_point_gives_no_grasps() -> None:
    assert _detect(np.zeros((1, 3), np.float32)) == 0


def test_a_few_collinear_points_do_not_crash() -> None:
    pts = np.stack([np.linspace(0, 0.01, 5), np.zeros(5), np.zeros(5)], 1).astype(np.float32)
    assert _detect(pts) >= 0


def test_camera_inside_the_object_still_answers(cylinder_scene: ViewpointCloud) -> None:
    centre = np.array([[0.0, 0.0, 0.06]], np.float32)
    assert _detect(cylinder_scene.points, viewpoints=centre) >= 0


def test_scene_without_normals_is_refused_with_the_field_named() -> None:
    with pytest.raises(CloudError, match="normals"):
        Scene.build(ViewpointCloud(points=np.zeros((3, 3)), viewpoints=VP), HandGeometry())


@pytest.mark.parametrize(
    ("kwargs", "field"),
    [
        ({"points": np.zeros((4, 2))}, "cloud.points"),
        ({"points": np.zeros((4, 3)), "camera_source": np.array([0, 0, 3, 0])}, "cloud.camera_source"),
        ({"points": np.zeros((4, 3)), "camera_source": np.array([0, 0])}, "cloud.camera_source"),
        ({"points": np.zeros((4, 3)), "normals": np.zeros((3, 3))}, "cloud.normals"),
        ({"points": np.zeros((4, 3)), "viewpoints": np.full((1, 3), np.nan)}, "cloud.viewpoints"),
    ],
)
def test_malformed_clouds_name_the_field(kwargs: dict, field: str) -> None:
    kwargs.setdefault("viewpoints", VP)
    with pytest.raises(CloudError, match=field):
        ViewpointCloud(**kwargs)


@pytest.mark.parametrize(
    ("kwargs", "field"),
    [({"num_samples": 10**9}, "num_samples"), ({"num_samples": 0}, "num_samples"), ({"voxel_size": 1.0}, "voxel_size")],
)
def test_absurd_parameters_are_refused(kwargs: dict, field: str) -> None:
    with pytest.raises(ValueError, match=field):
        DetectionParams(**kwargs)


def test_impossible_hands_are_refused() -> None:
    with pytest.raises(ValueError, match="hand_outer_diameter"):
        HandGeometry(hand_outer_diameter=0.01, finger_width=0.01)
    with pytest.raises(ValueError, match="finger_width"):
        HandGeometry(finger_width=float("nan"))
