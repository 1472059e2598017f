"""Early stop (DetectionParams.early_stop): the same seeded samples in rounds, stopping once enough good,
diverse grasps are found; deterministic for a seed, and the whole search when never enough."""

from __future__ import annotations

import numpy as np
import pytest
from numpy.typing import NDArray

from graspd.gpd.candidates import SamplingParams, sample_point_indices
from graspd.gpd.detector import DetectionParams, GraspDetector, sample_rounds
from graspd.gpd.environment import EnvironmentParams
from graspd.server.services.warmup import warmup_cloud


class BrightScorer:
    """Deterministic stand-in classifier: 1 - the mean pixel (most candidates score above 0.5)."""

    name = "bright"
    representation = "15"

    def score(self, images: NDArray[np.uint8]) -> NDArray[np.float32]:
        return (1.0 - images.reshape(len(images), -1).mean(axis=1) / 255.0).astype(np.float32)


NO_ENV = EnvironmentParams(mode="none")  # open3d's RANSAC plane varies a little between runs


def test_rounds_are_the_seeded_samples() -> None:
    pool = np.zeros(5000, bool)
    pool[::3] = True
    s = SamplingParams(num_samples=450, seed=3, sample_pool=pool)
    rounds = list(sample_rounds(5000, s, 100))
    assert [len(r) for r in rounds] == [100, 100, 100, 100, 50]
    assert np.array_equal(np.sort(np.concatenate(rounds)), sample_point_indices(5000, s))


def test_early_stop_is_deterministic_and_searches_less() -> None:
    cloud = warmup_cloud()
    full = GraspDetector(BrightScorer()).detect(cloud, DetectionParams(num_samples=400, max_grasps=5,
                                                                       environment=NO_ENV))
    early = DetectionParams(num_samples=400, max_grasps=5, early_stop=True, early_stop_round=50, environment=NO_ENV)
    a = GraspDetector(BrightScorer()).detect(cloud, early)
    b = GraspDetector(BrightScorer()).detect(cloud, early)
    assert len(a.grasps) == 5 and a.num_candidates < full.num_candidates
    assert a.num_candidates == b.num_candidates and np.array_equal(a.grasps.positions, b.grasps.positions)
    assert np.all(a.grasps.scores >= 0.5)


@pytest.mark.parametrize("round_size", [70, 1000])
def test_never_enough_searches_every_sample(round_size: int) -> None:
    cloud = warmup_cloud()
    base = DetectionParams(num_samples=200, max_grasps=1000, environment=NO_ENV)
    full = GraspDetector(BrightScorer()).detect(cloud, base)
    early = GraspDetector(BrightScorer()).detect(cloud, DetectionParams(
        num_samples=200, max_grasps=1000, early_stop=True, early_stop_round=round_size, environment=NO_ENV))
    assert early.num_candidates == full.num_candidates
    key = np.lexsort(full.grasps.positions.T)
    key_e = np.lexsort(early.grasps.positions.T)
    assert np.array_equal(full.grasps.positions[key], early.grasps.positions[key_e])
    assert np.array_equal(full.grasps.scores[key], early.grasps.scores[key_e])
