"""The centring term: a grasp whose closing line passes far from its object's centre (where a heavy or long object
twists out when lifted) ranks below one through the middle, and every ranked grasp carries the term."""

from __future__ import annotations

import numpy as np

from graspd.core.grasp import GraspSet
from graspd.gpd.detector import DetectionParams, GraspDetector
from graspd.gpd.objects import SceneObject
from graspd.gpd.selection import CENTRING_FLOOR, SelectionParams, centring, select
from graspd.server.services.warmup import warmup_cloud

#: A 30 x 4 x 4 cm bar lying along x on a table (z up), its centre at the origin.
BAR = SceneObject(id=0, centre=np.array([0.0, 0.0, 0.02]), extent=np.array([0.30, 0.04, 0.04]), num_points=500)


def _top_grasps_on_bar(xs: list[float], scores: list[float]) -> GraspSet:
    """Top-down grasps closing across the bar (binormal along y) at positions x along it, sampled on its top."""
    m = len(xs)
    rot = np.array([[0.0, 0.0, -1.0], [0.0, 1.0, 0.0], [1.0, 0.0, 0.0]]).T  # columns: approach -z, binormal y, axis x
    samples = np.array([[x, 0.0, 0.04] for x in xs])
    return GraspSet(positions=samples + [0.0, 0.0, 0.05], rotations=np.repeat(rot[None], m, axis=0),
                    widths=np.full(m, 0.04), scores=np.asarray(scores, float), samples=samples,
                    objects=np.zeros(m, np.int64))


def test_an_end_grasp_on_a_bar_ranks_below_its_middle_grasp_even_when_scored_higher() -> None:
    grasps = _top_grasps_on_bar([0.13, 0.0], [0.9, 0.8])  # the end grasp scores higher
    ranked = select(grasps, SelectionParams(objects=(BAR,)))
    assert ranked.samples[0, 0] == 0.0  # the middle grasp first
    assert ranked.ranking is not None
    end = int(np.flatnonzero(ranked.samples[:, 0] == 0.13)[0])
    assert ranked.ranking.centring[end] < 0.65 < ranked.ranking.centring[1 - end]
    without = select(grasps, SelectionParams(objects=(BAR,), centring_floor=None))
    assert without.samples[0, 0] == 0.13  # with the term off, the score decides


def test_centring_falls_linearly_with_the_closing_line_offset_and_stops_at_the_floor() -> None:
    grasps = _top_grasps_on_bar([0.0, 0.05, 0.10, 0.5], [0.5] * 4)
    c = centring(grasps, SelectionParams(objects=(BAR,)))
    half = float(np.linalg.norm(BAR.extent)) / 2.0
    expected = 1.0 - (1.0 - CENTRING_FLOOR) * np.clip(np.hypot([0.0, 0.05, 0.10, 0.5], 0.02) / half, 0.0, 1.0)
    np.testing.assert_allclose(c, expected)
    assert c[-1] == CENTRING_FLOOR
    off_object = GraspSet(positions=grasps.positions, rotations=grasps.rotations, widths=grasps.widths,
                          scores=grasps.scores, samples=grasps.samples, objects=np.full(4, -1))
    np.testing.assert_array_equal(centring(off_object, SelectionParams(objects=(BAR,))), 1.0)


def test_every_ranked_grasp_of_a_detection_carries_the_centring_term() -> None:
    det = GraspDetector().detect(warmup_cloud(), DetectionParams(num_samples=150))
    assert len(det.grasps) > 5 and det.grasps.ranking is not None
    terms = det.grasps.ranking.to_dicts()
    assert all(0.5 <= t["centring"] <= 1.0 for t in terms)
    assert any(t["centring"] < 1.0 for t in terms)  # the scene's objects are found, and grasps off their middle
