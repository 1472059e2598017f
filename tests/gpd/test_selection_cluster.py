"""Clustering on KD-tree neighbour pairs gives what the dense m x m version gave (graspd.gpd.selection.cluster)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from graspd.core.grasp import GraspSet
from graspd.gpd.selection import SelectionParams, cluster, select, utility, width_preference


def dense_cluster(grasps: GraspSet, params: SelectionParams) -> tuple[GraspSet, np.ndarray, np.ndarray]:
    """The former implementation: every pair tested in m x m arrays."""
    m = len(grasps)
    scored = not np.isnan(grasps.scores).all()
    order = np.argsort(-np.nan_to_num(grasps.scores, nan=0.0), kind="stable")
    g = grasps[order]
    axis = g.axis
    cos_axis = np.abs(axis @ axis.T) >= np.cos(np.radians(params.cluster_axis_angle_deg))
    delta = g.positions[None, :, :] - g.positions[:, None, :]
    along = np.einsum("ijk,ik->ij", delta, axis)
    off_axis = np.linalg.norm(delta - along[:, :, None] * axis[:, None, :], axis=2)
    near = (off_axis <= params.cluster_axis_distance) & (np.linalg.norm(delta, axis=2) <= params.cluster_max_distance)
    agree = cos_axis & near
    assigned = np.zeros(m, bool)
    reps, sizes, sums = [], [], []
    for i in range(m):
        if assigned[i]:
            continue
        members = agree[i] & ~assigned
        members[i] = True
        assigned |= members
        reps.append(i)
        sizes.append(int(members.sum()))
        sums.append(float(np.nansum(g.scores[members])))
    sizes_a = np.array(sizes, np.int64)
    ok = sizes_a >= params.min_cluster_size
    out = g[np.array(reps, np.int64)[ok]]
    return out, sizes_a[ok], (np.array(sums)[ok] if scored else sizes_a[ok].astype(np.float64))


def random_grasps(m: int, seed: int, scored: bool = True) -> GraspSet:
    """Hands bunched along a few lines (so that clusters form), with noisy axes."""
    rng = np.random.default_rng(seed)
    base = Rotation.random(6, random_state=seed).as_matrix()
    which = rng.integers(0, 6, m)
    tilt = Rotation.from_rotvec(rng.normal(0, 0.15, (m, 3))).as_matrix()
    rot = np.einsum("mij,mjk->mik", base[which], tilt)
    centres = rng.uniform(-0.05, 0.05, (6, 3))
    pos = centres[which] + base[which][:, :, 2] * rng.uniform(-0.04, 0.04, (m, 1)) + rng.normal(0, 0.003, (m, 3))
    scores = rng.uniform(0, 1, m) if scored else np.full(m, np.nan)
    return GraspSet(positions=pos, rotations=rot, widths=rng.uniform(0.01, 0.08, m), scores=scores, samples=pos)


@pytest.mark.parametrize(("m", "seed", "scored"), [(400, 0, True), (900, 1, True), (300, 2, False), (1, 3, True)])
def test_sparse_clustering_matches_dense(m: int, seed: int, scored: bool) -> None:
    g = random_grasps(m, seed, scored)
    params = SelectionParams(use_clustering=True, min_cluster_size=2 if seed == 1 else 1)
    got, want = cluster(g, params), dense_cluster(g, params)
    assert len(got[0]) == len(want[0]) and len(want[0]) < m or m == 1
    for a, b in zip(got, want, strict=True):
        x = a.positions if isinstance(a, GraspSet) else a
        y = b.positions if isinstance(b, GraspSet) else b
        assert np.array_equal(x, y)


def test_select_with_clustering_ranks_as_before() -> None:
    g = random_grasps(700, 4)
    params = SelectionParams(use_clustering=True, gravity=(0.0, 0.0, -1.0), max_grasps=20)
    got = select(g, params)
    reps, _, rank = dense_cluster(g, params)
    key = rank * utility(reps, params, None) * width_preference(reps, params)
    want = reps[np.argsort(-key, kind="stable")][:20]
    assert np.array_equal(got.positions, want.positions)
