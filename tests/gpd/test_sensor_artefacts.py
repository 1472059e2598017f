"""Sensor artefacts are not objects: a rendered box on a table with blobs of stereo speckle and mixed pixels added
near its silhouette (1-1.5 cm clumps of points floating 2 cm off it, as textured-light stereo leaves them):
the blobs get no object id, no hand is sampled on them, and no returned grasp holds only their points."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from graspd.core.cloud import ViewpointCloud
from graspd.core.hand import HandGeometry
from graspd.gpd.detector import DetectionParams, GraspDetector
from graspd.gpd.objects import segment_objects

WORKSPACE = (-0.2, 0.2, -0.2, 0.2, -0.01, 0.3)


def _with_blobs(cloud: ViewpointCloud, centres: np.ndarray, seed: int = 0) -> tuple[ViewpointCloud, np.ndarray]:
    """cloud plus a 60-point clump of about 1.2 cm around each centre (m); the mask of the added points."""
    rng = np.random.default_rng(seed)
    blobs = np.vstack([c + rng.uniform(-0.006, 0.006, (60, 3)) for c in centres]).astype(np.float32)
    points = np.vstack([cloud.points, blobs])
    added = np.zeros(len(points), bool)
    added[len(cloud.points):] = True
    return ViewpointCloud(points=points, viewpoints=cloud.viewpoints), added


def test_speckle_blobs_get_no_object_and_no_grasp(render_box: Callable[..., ViewpointCloud],
                                                  box_pose: Callable[..., np.ndarray]) -> None:
    pose = box_pose(yaw=0.0, xy=(0.0, 0.0))
    clean = render_box(pose)
    # beside the box's top edge and in front of its face toward the camera, 2 cm off its surfaces
    centres = np.array([[0.0, 0.0, 0.105], [0.055, 0.0, 0.06], [0.0, 0.075, 0.05]])
    cloud, added = _with_blobs(clean, centres)
    detector = GraspDetector()
    params = DetectionParams(num_samples=400, workspace=WORKSPACE)
    prepared = detector.prepare(cloud, params, HandGeometry())
    points = prepared.cloud.points
    near_blob = np.min(np.linalg.norm(points[:, None, :] - centres[None], axis=2), axis=1) < 0.008
    assert near_blob.sum() > 3 * 10  # the blobs survive preprocessing as objects' points would
    seg = segment_objects(points, prepared.environment.object_mask)
    assert len(seg.objects) == 1 and (seg.labels[near_blob] == -1).all()  # the box, and no blob
    pool = prepared.sampling.sample_pool
    assert pool is not None and not pool[near_blob].any() and pool.any()
    det = detector.detect(cloud, params)
    assert len(det.grasps) >= 10
    for k in range(10):  # every top grasp closes on the box
        assert det.grasps.object_ids[k] == 0

