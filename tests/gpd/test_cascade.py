"""The cascade: a cheap first pass keeps the best fraction of the candidates for the full model."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from graspd.gpd.classifier import load_model
from graspd.gpd.detector import DetectionParams, GraspDetector
from graspd_lab.world.scenes import cluttered_tabletop

SHIPPED = Path(__file__).resolve().parents[2] / "models"


@pytest.fixture(scope="module")
def cloud():  # type: ignore[no-untyped-def]
    return cluttered_tabletop(num_objects=4, seed=3, num_cameras=1, resolution_scale=0.5)


def test_the_cascade_scores_only_the_kept_fraction_with_the_full_model(cloud) -> None:  # type: ignore[no-untyped-def]
    full = load_model("generic15", SHIPPED)
    first = load_model("rep3-view", SHIPPED / "comparison")
    params = DetectionParams(num_samples=200, seed=1, cascade_keep=0.25, cascade_min=50, use_selection=False,
                             max_grasps=10_000)
    plain = GraspDetector(full).detect(cloud, params)
    cascaded = GraspDetector(full, prefilter=first).detect(cloud, params)
    assert plain.num_candidates > 200
    expected = max(50, int(np.ceil(0.25 * plain.num_candidates)))
    assert cascaded.num_candidates == expected
    assert "prefilter" in cascaded.timings
    # the kept candidates are scored by the full model exactly as without the cascade
    def keys(grasps):  # type: ignore[no-untyped-def]
        pairs = zip(grasps.positions, grasps.rotations, strict=True)
        return [tuple(np.round(np.r_[p, r.ravel()], 6)) for p, r in pairs]

    scored = dict(zip(keys(plain.grasps), plain.grasps.scores, strict=True))
    for k, score in zip(keys(cascaded.grasps), cascaded.grasps.scores, strict=True):
        assert scored[k] == pytest.approx(score, abs=1e-6)
    # and switching it off per request gives the plain answer
    off = GraspDetector(full, prefilter=first).detect(cloud, DetectionParams(
        num_samples=200, seed=1, cascade=False, use_selection=False, max_grasps=10_000))
    assert off.num_candidates == plain.num_candidates


def test_cascade_parameters_are_checked() -> None:
    with pytest.raises(ValueError, match="cascade_keep"):
        DetectionParams(cascade_keep=0.0)
