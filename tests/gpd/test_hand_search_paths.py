"""The hand search finds its slab neighbours by scanning every pair (small obstacle sets) or through slab_pairs
(kd-tree or dense pre-test, large ones): both give the same hands and closing regions, bit for bit."""

from __future__ import annotations

import numpy as np
import pytest

from graspd.core.hand import HandGeometry
from graspd.gpd import candidates
from graspd.gpd.detector import DetectionParams, GraspDetector
from graspd.gpd.environment import EnvironmentParams
from graspd.server.services.warmup import warmup_cloud


@pytest.mark.parametrize("mode", ["auto", "none"])
def test_scan_and_slab_pairs_give_the_same_hands(monkeypatch: pytest.MonkeyPatch, mode: str) -> None:
    hand = HandGeometry()
    params = DetectionParams(num_samples=150, environment=EnvironmentParams(mode=mode))
    prep = GraspDetector().prepare(warmup_cloud(), params, hand)
    scanned, scanned_region = candidates.search_hands(prep.scene, hand, prep.sampling)
    monkeypatch.setattr(candidates, "SCAN_PAIRS", 0)
    paired, paired_region = candidates.search_hands(prep.scene, hand, prep.sampling)
    assert len(scanned) > 100
    np.testing.assert_array_equal(scanned.positions, paired.positions)
    np.testing.assert_array_equal(scanned.rotations, paired.rotations)
    np.testing.assert_array_equal(scanned.widths, paired.widths)
    np.testing.assert_array_equal(scanned_region.grasp, paired_region.grasp)
    np.testing.assert_array_equal(scanned_region.index, paired_region.index)
    np.testing.assert_array_equal(scanned_region.local, paired_region.local)
