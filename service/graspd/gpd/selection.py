"""Step 6 of Algorithm 1: filter, cluster and rank scored candidates.

Filters: grasp positions inside a workspace box, object width inside [min_aperture, max_aperture],
approach direction within a cone.  Clustering follows GPD: two hands agree when their hand axes are
within axis_angle_deg and one's position lies within axis_distance of the other's axis line (and
within max_distance); each cluster keeps its best member (with its own classifier score) and is
ranked by the sum of its members' scores (or their count when unscored).  That rank is multiplied
by the utility J(h) of the IJRR paper when a gravity direction is given, by a width preference and by the share
of the hand in space the cameras saw (grasp.RANKING_RULE); the terms travel with the grasps (GraspSet.ranking).
The ranked list then covers the table (cover_order): the best grasp first, and no object gets more than
max_per_object grasps before every other object with a grasp has one.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from graspd.core.grasp import GraspSet, Ranking
from graspd.gpd.preprocess import Workspace

Vec3 = tuple[float, float, float]
WIDTH_FLOOR = 0.2
#: Grasps one object gets before every other graspable object has one (0 = off: pure key order).  Chosen on
#: tables of eight training objects (bench/targets.py --tuning, bench/results/targets-tuning.md): 1 covers 7.6
#: objects in the top 10 against 3.3 with the cap off, with the same P@1 (the first grasp never moves) and P@5;
#: 2 and 3 cover fewer at no better precision.  Held-out figures: bench/results/targets.md.
DEFAULT_MAX_PER_OBJECT = 1


@dataclass(frozen=True)
class SelectionParams:
    """Every step can be switched off (None or False) for ablations; lengths in metres, angles in degrees."""

    workspace: Workspace | None = None
    min_aperture: float | None = None
    max_aperture: float | None = None
    approach_direction: Vec3 | None = None
    approach_max_angle_deg: float | None = None
    min_score: float | None = None
    use_clustering: bool = False
    cluster_axis_angle_deg: float = 12.0
    cluster_axis_distance: float = 0.005
    cluster_max_distance: float = 0.07
    min_cluster_size: int = 1
    cluster_max_candidates: int = 1000
    gravity: Vec3 | None = None
    reference_position: Vec3 | None = None
    reference_max_distance: float = 1.0
    max_grasps: int | None = 100
    table_height: float | None = None
    width_margin: float | None = None
    max_per_object: int = 0


def feasible_mask(grasps: GraspSet, params: SelectionParams) -> NDArray[np.bool_]:
    """Grasps passing the workspace, aperture and approach-cone filters."""
    keep = np.ones(len(grasps), bool)
    if params.workspace is not None:
        lo = np.array(params.workspace[0::2])
        hi = np.array(params.workspace[1::2])
        keep &= np.all((grasps.positions >= lo) & (grasps.positions <= hi), axis=1)
    if params.min_aperture is not None:
        keep &= grasps.widths >= params.min_aperture
    if params.max_aperture is not None:
        keep &= grasps.widths <= params.max_aperture
    if params.approach_direction is not None and params.approach_max_angle_deg is not None:
        d = np.asarray(params.approach_direction, np.float64)
        d = d / max(float(np.linalg.norm(d)), 1e-12)
        keep &= grasps.approach @ d >= np.cos(np.radians(params.approach_max_angle_deg))
    return keep


def cluster(grasps: GraspSet, params: SelectionParams) -> tuple[GraspSet, NDArray[np.int64], NDArray[np.float64]]:
    """Greedy GPD-style clustering, best first: (representatives, cluster sizes, cluster scores = sum of
    member scores, or sizes when unscored)."""
    m = len(grasps)
    if m == 0:
        return grasps, np.zeros(0, np.int64), np.zeros(0)
    scored = not np.isnan(grasps.scores).all()
    order = np.argsort(-np.nan_to_num(grasps.scores, nan=0.0), kind="stable")
    g = grasps[order]
    axis, pos = g.axis, g.positions
    cos_min = np.cos(np.radians(params.cluster_axis_angle_deg))
    free = np.arange(m)  # not yet in a cluster, best first: the next representative is free[0]
    reps: list[int] = []
    sizes: list[int] = []
    sums: list[float] = []
    while len(free):
        # one row of the agreement matrix, only for a representative and only against the free hands:
        # O(representatives x m) work instead of m x m arrays
        i, rest = int(free[0]), free[1:]
        delta = pos[rest] - pos[i]
        along = np.einsum("jk,k->j", delta, axis[i])
        off_axis = np.linalg.norm(delta - along[:, None] * axis[i], axis=1)
        agree = ((np.abs(np.einsum("jk,k->j", axis[rest], axis[i])) >= cos_min)
                 & (off_axis <= params.cluster_axis_distance)
                 & (np.linalg.norm(delta, axis=1) <= params.cluster_max_distance))
        members = np.concatenate([[i], rest[agree]])
        free = rest[~agree]
        reps.append(i)
        sizes.append(len(members))
        sums.append(float(np.nansum(g.scores[members])))
    sizes_a = np.array(sizes, np.int64)
    ok = sizes_a >= params.min_cluster_size
    out = g[np.array(reps, np.int64)[ok]]
    cluster_scores = np.array(sums)[ok] if scored else sizes_a[ok].astype(np.float64)
    return out, sizes_a[ok], cluster_scores


def utility(grasps: GraspSet, params: SelectionParams, table_height: float | None = None) -> NDArray[np.float64]:
    """J(h) in [0, 1] (IJRR paper, eq. 1): top approaches and high grasps first, optionally near a
    reference position.  Gravity must be given (a unit vector, cloud frame); otherwise all ones."""
    if params.gravity is None or len(grasps) == 0:
        return np.ones(len(grasps))
    g = np.asarray(params.gravity, np.float64)
    g = g / max(float(np.linalg.norm(g)), 1e-12)
    top = 0.5 * (grasps.approach @ g + 1.0)  # 1 for a straight top-down approach, 0 from below
    height = -(grasps.positions @ g)
    base = float(height.min()) if table_height is None else table_height
    z = height - base
    z_max = max(float(z.max()), 1e-6)
    j = top * np.maximum(1.0 - (z_max - z) / (10.0 * z_max), 0.0)
    if params.reference_position is not None:
        dist = np.linalg.norm(grasps.positions - np.asarray(params.reference_position), axis=1)
        j = j * np.maximum(1.0 - dist / params.reference_max_distance, 0.0)
    return j


def width_preference(grasps: GraspSet, params: SelectionParams) -> NDArray[np.float64]:
    """A factor in [WIDTH_FLOOR, 1]: 1 when the grasp's width leaves at least width_margin (m) free on each
    side inside max_aperture, falling linearly to WIDTH_FLOOR when the object fills the opening (the seen
    width of a partly hidden object understates its real one).  All ones when off."""
    if params.width_margin is None or params.max_aperture is None or len(grasps) == 0:
        return np.ones(len(grasps))
    free = (params.max_aperture - grasps.widths) / (2.0 * params.width_margin)
    return WIDTH_FLOOR + (1.0 - WIDTH_FLOOR) * np.clip(free, 0.0, 1.0)


def cover_order(objects: NDArray[np.int64], cap: int) -> NDArray[np.int64]:
    """The order (a permutation) that puts ranked grasps (best first, their object ids (M,); -1 for none, which
    count as one more object) into rounds: each round takes up to cap grasps of every object, best first, and
    keeps their ranked order; cap 0 keeps the ranked order.  The first grasp never moves."""
    m = len(objects)
    if cap <= 0 or m == 0:
        return np.arange(m)
    _, group = np.unique(objects, return_inverse=True)
    group = group.reshape(-1)
    by_group = np.argsort(group, kind="stable")  # ranked order within each group
    starts = np.searchsorted(group[by_group], group[by_group], side="left")
    rank_in_group = np.empty(m, np.int64)
    rank_in_group[by_group] = np.arange(m) - starts
    return np.lexsort((np.arange(m), rank_in_group // cap))


def select(grasps: GraspSet, params: SelectionParams, use_selection: bool = True,
           rng: np.random.Generator | None = None,
           rescore: Callable[[GraspSet], NDArray[np.float64]] | None = None, rescore_top: int = 0) -> GraspSet:
    """The final ranked list.  With use_selection off (the paper's ablation), the feasible, positively
    scored grasps come back in random order instead of by score and utility.  rescore (a grasp's score
    averaged over moved copies, graspd.gpd.robustness) replaces the classifier term of the first rescore_top
    grasps by key, which are then ranked among themselves, ahead of the rest."""
    g = grasps[feasible_mask(grasps, params)]
    if params.min_score is not None:
        g = g[~(g.scores < params.min_score)]  # NaN (unscored) survives
    if not use_selection:
        order = (rng or np.random.default_rng(0)).permutation(len(g))
        return g[order][: params.max_grasps]
    rank = np.nan_to_num(g.scores, nan=1.0)
    if params.use_clustering:
        # Cluster the best candidates only: pairwise tests are O(n^2) in memory.
        top = np.argsort(-np.nan_to_num(g.scores, nan=0.0), kind="stable")[: params.cluster_max_candidates]
        g, _, rank = cluster(g[np.sort(top)], params)
    util, width = utility(g, params, params.table_height), width_preference(g, params)
    seen = 1.0 - np.clip(np.nan_to_num(g.unknown_share, nan=0.0), 0.0, 1.0)
    key = rank * util * width * seen
    order = np.argsort(-np.nan_to_num(key, nan=-np.inf), kind="stable")
    if rescore is not None and rescore_top > 0 and len(g):
        top = order[:rescore_top]
        own = np.nan_to_num(g.scores[top], nan=1.0)
        rank = np.asarray(rank, np.float64).copy()
        rank[top] = rank[top] * rescore(g[top]) / np.maximum(own, 1e-6)
        key = rank * util * width * seen
        order[: len(top)] = top[np.argsort(-np.nan_to_num(key[top], nan=-np.inf), kind="stable")]
    ranked = replace(g, ranking=Ranking(classifier=np.asarray(rank, np.float64), utility=util, width=width,
                                        unknown=seen, key=key))
    ranked = ranked[order]
    return ranked[cover_order(ranked.object_ids, params.max_per_object)][: params.max_grasps]
