"""Selection: filters, GPD clustering, utility J(h), and the ablation switches."""

from __future__ import annotations

import numpy as np

from graspd.core.grasp import GraspSet
from graspd.gpd.selection import SelectionParams, cluster, feasible_mask, select, utility


def _grasps(positions, approaches, widths=None, scores=None) -> GraspSet:
    positions = np.asarray(positions, float)
    rots = []
    for a in np.asarray(approaches, float):
        a = a / np.linalg.norm(a)
        helper = np.array([0, 0, 1.0]) if abs(a[2]) < 0.9 else np.array([1.0, 0, 0])
        b = np.cross(helper, a)
        b /= np.linalg.norm(b)
        rots.append(np.stack([a, b, np.cross(a, b)], axis=1))
    m = len(positions)
    return GraspSet(positions=positions, rotations=np.array(rots),
                    widths=np.full(m, 0.05) if widths is None else np.asarray(widths, float),
                    scores=np.full(m, np.nan) if scores is None else np.asarray(scores, float),
                    samples=positions.copy())


def test_filters_keep_workspace_aperture_and_approach_cone() -> None:
    g = _grasps([[0, 0, 0], [1, 0, 0], [0, 0, 0], [0, 0, 0]], [[0, 0, -1], [0, 0, -1], [1, 0, 0], [0, 0, -1]],
                widths=[0.05, 0.05, 0.05, 0.11])
    p = SelectionParams(workspace=(-0.5, 0.5, -0.5, 0.5, -0.5, 0.5), max_aperture=0.1,
                        approach_direction=(0, 0, -1), approach_max_angle_deg=30)
    assert feasible_mask(g, p).tolist() == [True, False, False, False]


def test_clustering_merges_aligned_neighbours_and_sums_scores() -> None:
    g = _grasps([[0, 0, 0], [0, 0, 0.003], [0.2, 0, 0]], [[0, 0, -1]] * 3, scores=[0.9, 0.8, 0.7])
    reps, sizes, cluster_scores = cluster(g, SelectionParams())
    assert sizes.tolist() == [2, 1]
    assert np.allclose(cluster_scores, [1.7, 0.7])
    assert np.allclose(reps.scores, [0.9, 0.7])  # each representative keeps its own probability


def test_with_gpd_clustering_a_well_supported_cluster_outranks_a_lone_slightly_better_grasp() -> None:
    g = _grasps([[0.3, 0, 0], [0, 0, 0], [0, 0, 0.003], [0, 0, 0.006]], [[0, 0, -1]] * 4,
                scores=[0.95, 0.9, 0.85, 0.8])
    out = select(g, SelectionParams(use_clustering=True))
    assert np.allclose(out.scores[:2], [0.9, 0.95])


def test_by_default_the_best_scoring_grasp_ranks_first_however_many_neighbours_the_others_have() -> None:
    g = _grasps([[0.3, 0, 0], [0, 0, 0], [0, 0, 0.003], [0, 0, 0.006]], [[0, 0, -1]] * 4,
                scores=[0.95, 0.9, 0.85, 0.8])
    out = select(g, SelectionParams())
    assert np.allclose(out.scores, [0.95, 0.9, 0.85, 0.8])


def test_utility_prefers_top_grasps_and_high_ones() -> None:
    g = _grasps([[0, 0, 0.1], [0, 0, 0.1], [0, 0, 0.02]], [[0, 0, -1], [1, 0, 0], [0, 0, -1]])
    j = utility(g, SelectionParams(gravity=(0, 0, -1)))
    assert j[0] > j[2] > j[1]
    assert np.allclose(utility(g, SelectionParams()), 1.0)


def test_ranking_uses_scores_and_min_score_and_max_grasps() -> None:
    g = _grasps([[0, 0, 0], [0.2, 0, 0], [0.4, 0, 0]], [[0, 0, -1]] * 3, scores=[0.2, 0.9, 0.6])
    out = select(g, SelectionParams(min_score=0.5, max_grasps=5))
    assert np.allclose(out.scores, [0.9, 0.6])
    assert np.all((out.scores >= 0) & (out.scores <= 1))
    assert len(select(g, SelectionParams(max_grasps=1))) == 1


def test_no_selection_ablation_is_random_order_of_feasible() -> None:
    g = _grasps([[i * 0.2, 0, 0] for i in range(20)], [[0, 0, -1]] * 20, scores=np.linspace(0, 1, 20))
    out = select(g, SelectionParams(max_grasps=20), use_selection=False, rng=np.random.default_rng(1))
    assert len(out) == 20 and not np.all(np.diff(out.scores) <= 0)
