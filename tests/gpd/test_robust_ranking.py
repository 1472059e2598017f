"""The first grasps are ranked by their classifier score averaged over copies moved 2 mm and turned 3 degrees
(graspd.gpd.robustness): the copies are that error, the same for a seed; a grasp whose copies score low falls
below those whose copies hold up, among the rescored grasps and ahead of the rest."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from numpy.typing import NDArray

from graspd.core.grasp import GraspSet
from graspd.gpd.classifier import default_model_name, load_model
from graspd.gpd.detector import DetectionParams, GraspDetector
from graspd.gpd.images import encode_images
from graspd.gpd.robustness import COPY_SHIFT, COPY_TURN_DEG, ROBUST_TOP, pose_copies, robust_scores
from graspd.gpd.selection import SelectionParams, select
from graspd.io.cloud_files import read_cloud


def _two_grasps() -> GraspSet:
    turn = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    return GraspSet(positions=np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]]), rotations=np.stack([np.eye(3), turn]),
                    widths=np.array([0.03, 0.04]), scores=np.array([0.9, 0.8]), samples=np.zeros((2, 3)))


def test_copies_are_moved_two_millimetres_and_turned_three_degrees_the_same_for_a_seed() -> None:
    grasps = _two_grasps()
    copies = pose_copies(grasps, 400, seed=5)
    assert len(copies) == 800
    own = np.repeat(np.arange(2), 400)  # grasp-major: grasp 0's copies first
    turned = np.einsum("nji,njk->nik", grasps.rotations[own], copies.rotations)
    angles = np.degrees(np.arccos(np.clip((np.trace(turned, axis1=1, axis2=2) - 1.0) / 2.0, -1.0, 1.0)))
    assert np.allclose(angles, COPY_TURN_DEG, atol=1e-6)
    shift = copies.positions - grasps.positions[own]
    assert abs(float(shift.std()) - COPY_SHIFT) < 0.1 * COPY_SHIFT and abs(float(shift.mean())) < 0.2e-3
    assert np.array_equal(copies.widths, grasps.widths[own])
    again = pose_copies(grasps, 400, seed=5)
    assert np.array_equal(again.positions, copies.positions) and np.array_equal(again.rotations, copies.rotations)
    assert not np.array_equal(pose_copies(grasps, 400, seed=6).positions, copies.positions)


def test_a_grasp_scores_the_mean_of_its_own_score_and_its_copies() -> None:
    grasps = _two_grasps()

    def by_height(g: GraspSet) -> NDArray[np.float64]:  # copies of grasp 0 score 0.5, of grasp 1 score 0.2
        return np.where(g.positions[:, 0] < 0.5, 0.5, 0.2)

    assert np.allclose(robust_scores(grasps, by_height, 4), [(0.9 + 4 * 0.5) / 5, (0.8 + 4 * 0.2) / 5])
    assert np.array_equal(robust_scores(grasps, by_height, 0), grasps.scores)


def test_a_rescored_grasp_that_falls_is_ranked_among_the_rescored_ahead_of_the_rest() -> None:
    n = 5
    grasps = GraspSet(positions=np.zeros((n, 3)), rotations=np.repeat(np.eye(3)[None], n, axis=0),
                      widths=np.full(n, 0.03), scores=np.array([0.9, 0.8, 0.7, 0.6, 0.5]),
                      samples=np.zeros((n, 3)))
    asked: list[int] = []

    def spoil_the_first(g: GraspSet) -> NDArray[np.float64]:
        asked.append(len(g))
        return np.where(g.scores > 0.85, 0.3, g.scores)

    params = SelectionParams(max_grasps=None)
    ranked = select(grasps, params, rescore=spoil_the_first, rescore_top=3)
    assert asked == [3]  # only the first three by key are rescored
    assert np.allclose(ranked.scores, [0.8, 0.7, 0.9, 0.6, 0.5])  # 0.3 < 0.6, but the rest stay behind
    assert ranked.ranking is not None
    assert np.allclose(ranked.ranking.classifier, [0.8, 0.7, 0.3, 0.6, 0.5])
    plain = select(grasps, params)
    assert np.allclose(plain.scores, grasps.scores) and plain.ranking is not None
    assert np.allclose(plain.ranking.classifier, grasps.scores)


@pytest.fixture(scope="module")
def mug(real_data: Path) -> tuple[GraspDetector, DetectionParams]:
    model = load_model(default_model_name())
    return GraspDetector(model), DetectionParams(num_samples=300, max_per_object=0, robust_copies=4)


def test_the_detectors_first_grasps_carry_their_mean_over_copies(mug: tuple[GraspDetector, DetectionParams],
                                                                  real_data: Path) -> None:
    detector, params = mug
    cloud = read_cloud(real_data / "table_mug.pcd")
    plain = detector.detect(cloud, replace(params, robust_copies=0))
    robust = detector.detect(cloud, params)
    assert DetectionParams().robust_copies == 0 and plain.num_candidates == robust.num_candidates
    assert plain.grasps.ranking is not None and robust.grasps.ranking is not None
    assert np.allclose(plain.grasps.ranking.classifier, plain.grasps.scores)

    # the plain ranking's first ROBUST_TOP grasps (copied in that order) are the rescored ones: recompute their
    # terms from their copies' images and find them, sorted by the new key, at the head of the robust ranking
    first = plain.grasps[:ROBUST_TOP]
    scene = detector.prepare(cloud, params, detector.hand).scene
    classifier = detector.classifier
    assert classifier is not None
    again = robust_scores(first, lambda g: np.asarray(
        classifier.score(encode_images(scene, g, detector.hand, classifier.representation)), np.float64), 4)
    assert not np.allclose(again, first.scores, atol=1e-3)  # the copies do score differently
    head = robust.grasps[:ROBUST_TOP]
    assert head.ranking is not None
    where = {tuple(np.round(p, 9)): i for i, p in enumerate(first.positions)}
    index = np.array([where[tuple(np.round(p, 9))] for p in head.positions])
    assert sorted(index) == list(range(ROBUST_TOP))
    assert np.allclose(head.ranking.classifier, again[index], atol=1e-5)
    assert np.all(np.diff(head.ranking.key) <= 1e-12)  # sorted among themselves
