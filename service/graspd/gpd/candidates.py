"""Step 3 of Algorithm 1 (Algorithm 2 of the IJRR paper): sample 6-DOF hand candidates on the cloud.

For each sampled point p: a Darboux frame from the eigenvectors of the summed normal outer products
in an r-ball (largest eigenvalue: smoothed normal; smallest: the curvature axis); then a grid over
finger placements y (along the binormal) and orientations phi (about the curvature axis); each hand is
pushed forward along its approach until a finger or the palm touches the cloud, and kept when the
fingertips reach at least init_bite past p (so the closing region holds p).  On request (a support_bite), a hand
at the top of an object lying flat, thinner than that, whose fingertips the support plane stops sooner, needs
reach only support_bite past p: it holds the object by its edges.

Collision checks are binned along the closing direction at a resolution of a quarter finger width:
a point within one bin of a finger counts as touching it, a conservative margin for sensor noise.  With a
clearance, the hand's outline is grown by it wherever it may not touch: the fingertips stop that short of the
first point ahead, the fingers' outer faces and the hand's top and bottom faces keep that far from points beside
them (the inner faces are where the object goes, and the palm may rest on it): a true surface lies a millimetre
or two beyond the points seen of it, and a hand placed flush against them grazes it on the way in.
Per (sample, orientation) the middle of the collision-free finger placements is taken, as GPD does, then the
hand moves to the collision-free placement nearest the middle of what lies between its fingers: a gripper
closes symmetrically, and an object off the middle would be pushed sideways.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from graspd.core.grasp import GraspSet
from graspd.core.hand import HandGeometry
from graspd.core.parallel import THREADS
from graspd.gpd.environment import Plane
from graspd.gpd.placement import place_hands, slab_coordinates, slab_neighbours
from graspd.gpd.scene import ClosingRegionPoints, Scene, ball_pairs

MIN_FRAME_POINTS = 3
#: The support_bite (m) of a request for flat objects (DetectionParams.flat_objects): a packet 0.7-1.3 cm thick
#: lying flat is held by its edges between fingertips that stop the support's clearance above the table, where
#: init_bite leaves it no hand (bench/results/liftability-household-training-flat*.md).
SUPPORT_BITE = 0.004
CHUNK = 128  # samples per task of the hand search: smaller tasks balance 2 cores better, in cache


@dataclass(frozen=True)
class SamplingParams:
    """num_samples points drawn uniformly (seeded) from the cloud (or from the points where sample_pool
    is True: the region of interest), or exactly sample_indices;
    |Phi| orientations in [-pi/2, pi/2) and |Y| finger placements; frame_radius r (m).  clear_behind (m):
    how far behind the finger roots the hand's body and approach path must be free of points (palm depth
    plus approach distance); None checks only the points within the hand's own reach, as GPD does.
    obstacles: the points the hands test against (default all); support (its normal toward the free side)
    stops each hand support_clearance (m) short of the plane in closed form, so the support's points need not
    be among the obstacles (most of a tabletop cloud is table); where it stops the fingertips of a hand at a sample
    less than init_bite above it, they need reach only support_bite (m; None: init_bite, as GPD) past the sample.
    centre_on_object: each hand moves to the collision-free finger placement nearest the middle of the points
    between its fingers (False: the middle of the collision-free placements, GPD's choice).  clearance (m): how far
    the hand's outline keeps from the obstacle points, except across its inner finger faces and its palm's face (0:
    flush against them, as GPD)."""

    num_samples: int = 1000
    num_orientations: int = 8
    num_finger_placements: int = 10
    frame_radius: float = 0.01
    seed: int | None = 0
    sample_indices: tuple[int, ...] | None = None
    sample_pool: NDArray[np.bool_] | None = None
    clear_behind: float | None = None
    obstacles: NDArray[np.bool_] | None = None
    support: Plane | None = None
    support_clearance: float = 0.0
    support_bite: float | None = None
    centre_on_object: bool = True
    clearance: float = 0.0


def darboux_frames(scene: Scene, sample_idx: NDArray[np.int64], radius: float
                   ) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
    """Frames (S,3,3), columns [approach = -normal, binormal, curvature axis], from the r-ball normals,
    and the number of points in each r-ball."""
    pts, nrm = scene.points, scene.normals
    sid, idx = ball_pairs(scene.tree, pts[sample_idx], radius)
    n = nrm[idx].astype(np.float64)
    m = np.zeros((len(sample_idx), 3, 3))
    for a in range(3):
        for b in range(a, 3):
            m[:, a, b] = m[:, b, a] = np.bincount(sid, n[:, a] * n[:, b], len(sample_idx))
    _, vecs = np.linalg.eigh(m)  # ascending eigenvalues
    normal = vecs[:, :, 2]
    flip = np.einsum("ij,ij->i", normal, nrm[sample_idx]) < 0.0
    normal[flip] *= -1.0
    axis = vecs[:, :, 0]
    # The eigenvector's sign is arbitrary: point the axis toward the observing camera, which moves
    # with the cloud, so frames are deterministic and equivariant under rigid motions.
    to_cam = scene.cloud.viewpoints[scene.cloud.camera_source[sample_idx]] - pts[sample_idx]
    axis[np.einsum("ij,ij->i", axis, to_cam) < 0.0] *= -1.0
    approach = -normal
    binormal = np.cross(axis, approach)
    return np.stack([approach, binormal, axis], axis=2), np.bincount(sid, minlength=len(sample_idx))


def finger_offsets(hand: HandGeometry, count: int) -> NDArray[np.float64]:
    """Hand-centre offsets along the binormal (m) at which the sampled point lies between the fingers."""
    half = 0.9 * hand.closing_half_width
    return np.linspace(-half, half, count) if count > 1 else np.zeros(1)


def orientations(count: int) -> NDArray[np.float64]:
    """Angles (rad) about the curvature axis, GPD's grid: count steps over [-pi/2, pi/2), 0 included
    (the hand approaching along the smoothed surface normal)."""
    return np.linspace(-np.pi / 2, np.pi / 2, count, endpoint=False)


def sample_point_indices(n_points: int, params: SamplingParams) -> NDArray[np.int64]:
    """Indices of the points to sample at: the given ones, or num_samples drawn without replacement."""
    if params.sample_indices is not None:
        idx = np.asarray(params.sample_indices, np.int64)
        if idx.size and (idx.min() < 0 or idx.max() >= n_points):
            raise ValueError(f"sample_indices must lie in [0, {n_points - 1}]")
        return idx
    rng = np.random.default_rng(params.seed)
    pool = np.arange(n_points) if params.sample_pool is None else np.flatnonzero(params.sample_pool)
    k = min(params.num_samples, len(pool))
    return np.sort(pool[rng.choice(len(pool), size=k, replace=False)]).astype(np.int64)


def sample_candidates(scene: Scene, hand: HandGeometry, params: SamplingParams | None = None) -> GraspSet:
    """Collision-free hands whose closing region holds cloud points (scores NaN), best placement per
    (sample, orientation)."""
    return search_hands(scene, hand, params)[0]


def search_hands(scene: Scene, hand: HandGeometry, params: SamplingParams | None = None
                 ) -> tuple[GraspSet, ClosingRegionPoints]:
    """sample_candidates, also returning the cloud points in each hand's closing region (for images)."""
    p = params or SamplingParams()
    empty = (GraspSet(), ClosingRegionPoints(np.zeros(0, np.int64), np.zeros((0, 3), np.float32),
                                             np.zeros(0, np.int64)))
    if len(scene.points) == 0 or (p.num_samples <= 0 and p.sample_indices is None):
        return empty
    sample_idx = sample_point_indices(len(scene.points), p)
    if len(sample_idx) == 0:
        return empty
    frames, support = darboux_frames(scene, sample_idx, p.frame_radius)
    # A frame needs a surface: a valid normal and a few neighbours (lone points have neither).
    ok = (support >= MIN_FRAME_POINTS) & (np.linalg.norm(scene.normals[sample_idx], axis=1) > 0.5)
    sample_idx, frames = sample_idx[ok], frames[ok]
    if len(sample_idx) == 0:
        return empty
    obstacles = _Obstacles.of(scene, p.obstacles)
    # Chunks of samples keep the neighbour arrays small: time stays linear in the number of samples; they run
    # on the process's thread budget (a lone request uses every core).
    parts = THREADS.map(lambda a: _search_chunk(scene, hand, p, sample_idx[a : a + CHUNK], frames[a : a + CHUNK],
                                                obstacles), range(0, len(sample_idx), CHUNK))
    offsets = np.cumsum([0] + [len(g) for g, _ in parts])
    region = ClosingRegionPoints(
        np.concatenate([r.grasp + off for (_, r), off in zip(parts, offsets, strict=False)]),
        np.concatenate([r.local for _, r in parts]),
        np.concatenate([r.index for _, r in parts]),
    )
    return GraspSet.concatenate([g for g, _ in parts]), region


@dataclass(frozen=True)
class _Obstacles:
    """The points the hands are tested against: scene indices (None = every scene point) and their coordinates
    (m, cloud frame, float32); what only slab_pairs' kd-tree and dense paths use (float64 coordinates, columns,
    the largest coordinate, a kd-tree) is made on first use, so a search that scans its pairs builds none of it."""

    index: NDArray[np.int64] | None
    points: NDArray[np.float32]
    scene_tree: cKDTree | None = None  # the scene's own tree, when the obstacles are every scene point

    @staticmethod
    def of(scene: Scene, mask: NDArray[np.bool_] | None) -> _Obstacles:
        if mask is None:
            return _Obstacles(None, scene.points, scene.tree)
        index = np.flatnonzero(mask)
        return _Obstacles(index, scene.points[index])

    @cached_property
    def points64(self) -> NDArray[np.float64]:
        return self.points.astype(np.float64)

    @cached_property
    def columns(self) -> NDArray[np.float32]:
        """(3, N): x, y and z rows, contiguous."""
        return np.ascontiguousarray(self.points.T)

    @cached_property
    def scale(self) -> float:
        """The largest absolute coordinate (m, at least 1)."""
        return max(float(np.abs(self.points).max()), 1.0) if len(self.points) else 1.0

    @cached_property
    def tree(self) -> cKDTree:
        if self.scene_tree is not None:
            return self.scene_tree
        return cKDTree(self.points, balanced_tree=False)  # counts, and pairs sorted after: the tree's shape is moot


#: The dense pair test (every obstacle point against every sample, by matrix products) runs when it tests at
#: most this many times the pairs a kd-tree ball query would return; else the kd-tree does.
DENSE_FACTOR = 12
#: Obstacle points x samples tested densely at once (bounds the temporaries: ~40 MB).
DENSE_BLOCK = 1 << 21
#: A chunk's hand search tests every (sample, obstacle point) pair in one compiled pass when there are at most this
#: many (~1 ns a pair); beyond, slab_pairs finds them.
SCAN_PAIRS = 1 << 24
#: Margin of the dense slab pre-test, relative to the largest coordinate (m/m): pairs this close to the slab's
#: border go on to the exact test, so the dense and the kd-tree paths find the same pairs.
DENSE_EPS = 1e-5


def slab_pairs(obstacles: _Obstacles, samples: NDArray[np.float32], axes: NDArray[np.float32], reach: float,
               half_height: float) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """(sample row, obstacle row) pairs closer than reach (m), in sample order then obstacle order, holding at
    least every pair within half_height (m) of the sample's plane normal to its axis (S,3): a kd-tree ball query
    when the balls hold few of the points, else a dense test by matrix products that keeps only pairs near the
    slab.  Either way the caller's exact slab test (|(p - s) . axis| <= half_height, float32) gives the same set."""
    n_s, n_p = len(samples), len(obstacles.points)
    if n_s == 0 or n_p == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    expected = int(np.sum(obstacles.tree.query_ball_point(samples, reach, return_length=True)))
    if n_s * n_p > DENSE_FACTOR * expected:
        sid, idx = ball_pairs(obstacles.tree, samples, reach)
        order = np.argsort(sid * n_p + idx)
        return sid[order], idx[order]
    cols = obstacles.columns
    # float32 products err by a few ulp of the coordinates: a margin well above that keeps every slab pair
    scale = max(obstacles.scale, float(np.abs(samples).max()))
    margin = np.float32(half_height + DENSE_EPS * scale)
    offsets = np.einsum("ij,ij->i", samples, axes)
    r2 = reach * reach
    rows = max(1, DENSE_BLOCK // n_p)
    sids, idxs = [], []
    for a in range(0, n_s, rows):
        ax = axes[a : a + rows]
        # (rows, N): height of each point along each sample's axis; elementwise, not a BLAS product, whose
        # threads would spin beside the process's own (graspd.core.parallel)
        z = ax[:, 0:1] * cols[0] - offsets[a : a + rows, None]
        z += ax[:, 1:2] * cols[1]
        z += ax[:, 2:3] * cols[2]
        np.abs(z, out=z)
        sid, idx = np.nonzero(z <= margin)
        d = obstacles.points64[idx] - samples[a : a + rows][sid].astype(np.float64)
        inside = np.einsum("ij,ij->i", d, d) <= r2  # the ball test, in float64 as the kd-tree's
        sids.append(sid[inside] + a)
        idxs.append(idx[inside])
    return np.concatenate(sids).astype(np.int64), np.concatenate(idxs).astype(np.int64)


def _support_limit(p: SamplingParams, hand: HandGeometry, height: NDArray[np.float64],
                   frames: NDArray[np.float64], phis: NDArray[np.float64], s_grid: NDArray[np.float64],
                   behind: float) -> NDArray[np.float64]:
    """(samples, orientations, placements) furthest fingertip depth (m past the sample) that keeps the whole
    hand, and its path back by `behind`, support_clearance above the support plane; -inf where no depth does.
    height (S,): each sample's height above the support less support_clearance (m)."""
    assert p.support is not None
    n = p.support.normal
    nf = frames.transpose(0, 2, 1) @ n  # (S, 3): n in each sample frame
    c, s_ = np.cos(phis)[None, :], np.sin(phis)[None, :]
    na = c * nf[:, 0:1] + s_ * nf[:, 1:2]  # (S, Phi): n . approach
    nb = -s_ * nf[:, 0:1] + c * nf[:, 1:2]  # n . binormal
    od, hd, hh = hand.hand_outer_diameter, hand.hand_depth, hand.hand_height
    y_lo, y_hi = s_grid - od / 2.0, s_grid + od / 2.0  # (Y,) the hand's extent across
    low_y = np.minimum(y_lo[None, None, :] * nb[:, :, None], y_hi[None, None, :] * nb[:, :, None])
    base = height[:, None, None] + low_y - (hh / 2.0) * np.abs(nf[:, 2])[:, None, None]  # lowest point at x = 0
    na3 = na[:, :, None]
    with np.errstate(divide="ignore", invalid="ignore"):
        toward = base / np.maximum(-na3, 1e-12)  # na < 0: the fingertips (x = tip) come down first
    # na >= 0: the back of the hand and its path (x = tip - hd - behind) is lowest; deeper only lifts it
    away_ok = base + (-(hd + behind)) * na3 >= 0.0
    return np.where(na3 < 0.0, toward, np.where(away_ok, np.inf, -np.inf))


def _low_bite(p: SamplingParams, hand: HandGeometry, height: NDArray[np.float64]) -> NDArray[np.float64] | None:
    """(S,) least fingertip depth (m past the sample) where the support stops the fingertips: support_bite at a
    sample less than init_bite above the support's clearance (height, as _support_limit takes it: the top of an
    object lying flat, which only its edges hold), else the hand's init_bite (a hand low on a taller object must
    bite as deep as anywhere); None without a support_bite."""
    if p.support_bite is None:
        return None
    return np.where(height < hand.init_bite, min(hand.init_bite, p.support_bite), hand.init_bite)


def _search_chunk(scene: Scene, hand: HandGeometry, p: SamplingParams, sample_idx: NDArray[np.int64],
                  frames: NDArray[np.float64], obstacles: _Obstacles) -> tuple[GraspSet, ClosingRegionPoints]:
    """Algorithm 2 steps 5-10 for a batch of samples with their frames, tested against the obstacle points."""
    s_grid = finger_offsets(hand, p.num_finger_placements)
    phis = orientations(p.num_orientations)
    od, fw, hd, hh = hand.hand_outer_diameter, hand.finger_width, hand.hand_depth, hand.hand_height
    clear = p.clearance
    y_max = float(np.abs(s_grid).max()) + od / 2.0 + clear
    samples = scene.points[sample_idx]

    # Neighbours that can touch any hand of this sample (its outline grown by the clearance), in the sample frame,
    # within the hand's height; pairs ordered by sample, then by point.
    behind = 0.0 if p.clear_behind is None else p.clear_behind
    half_h = hh / 2.0 + clear
    reach = float(np.sqrt(y_max**2 + (hd + behind) ** 2 + half_h**2))
    fr = frames.astype(np.float32)
    # the obstacle points within reach of the chunk's bounds (samples are in index order, which voxels keep in x
    # order, so a chunk spans a narrow slice of the scene), in their order: the pairs and their order are the same
    bound = np.float32(reach * (1.0 + 1e-6) + 1e-6)
    near = np.flatnonzero(np.all((obstacles.points >= samples.min(axis=0) - bound)
                                 & (obstacles.points <= samples.max(axis=0) + bound), axis=1))
    if len(sample_idx) * len(near) <= SCAN_PAIRS:  # every pair tested, in one compiled pass
        sid, idx, loc = slab_neighbours(obstacles.points[near], samples, fr, reach, half_h)
        idx = near[idx]
    else:  # a kd-tree or a dense pre-test finds the pairs near each slab
        sid, idx = slab_pairs(obstacles, samples, np.ascontiguousarray(fr[:, :, 2]), reach, half_h)
        slab, loc = slab_coordinates(obstacles.points, samples, fr, sid, idx, half_h)
        sid, idx, loc = sid[slab], idx[slab], loc[slab]
    if obstacles.index is not None:
        idx = obstacles.index[idx]
    local_x, local_y, z = (np.ascontiguousarray(loc[:, k]) for k in range(3))
    starts = np.zeros(len(sample_idx) + 1, np.int64)
    np.cumsum(np.bincount(sid, minlength=len(sample_idx)), out=starts[1:])

    # Binned minimum approach depth per (sample, orientation, y-bin): a point within a bin of a finger touches it.
    bin_w = min(fw / 4.0, 0.0025)
    n_bins = int(np.ceil(2 * y_max / bin_w)) + 1

    def bin_range(lo: float, hi: float) -> tuple[int, int]:
        first = max(int(np.floor((lo + y_max) / bin_w)), 0)
        return first, max(first, min(int(np.floor((hi + y_max) / bin_w)) + 1, n_bins))

    ranges = np.array([(*bin_range(s - od / 2 - clear, s - od / 2 + fw),  # left finger
                        *bin_range(s + od / 2 - fw, s + od / 2 + clear),  # right finger
                        *bin_range(s - od / 2 - clear, s + od / 2 + clear))  # palm
                       for s in s_grid], np.int64).reshape(-1, 6)
    support, low_bite = None, None
    if p.support is not None:  # each sample's height above the support's clearance, m
        height = p.support.distance(samples.astype(np.float64)) - p.support_clearance
        support = _support_limit(p, hand, height, frames, phis, s_grid, behind)
        low_bite = _low_bite(p, hand, height)
    si, pi, bj, tip, ymin, ymax, local, elem, cand = place_hands(
        starts, local_x, local_y, z, phis, s_grid, ranges, support, y_max=y_max, bin_w=bin_w, n_bins=n_bins, hd=hd,
        clear=clear, init_bite=hand.init_bite, low_bite=low_bite, half_w=hand.closing_half_width,
        half_h=hh / 2.0, centre=p.centre_on_object)
    t_star = tip.astype(np.float64)

    c, s_ = np.cos(phis[pi])[:, None], np.sin(phis[pi])[:, None]
    f = frames[si]
    approach = c * f[:, :, 0] + s_ * f[:, :, 1]
    binormal = -s_ * f[:, :, 0] + c * f[:, :, 1]
    rotations = np.stack([approach, binormal, f[:, :, 2]], axis=2)
    positions = samples[si].astype(np.float64) + approach * (t_star - hd)[:, None] + binormal * s_grid[bj][:, None]
    grasps = GraspSet(
        positions=positions,
        rotations=rotations,
        widths=ymax - ymin,
        scores=np.full(len(si), np.nan),
        samples=samples[si].astype(np.float64),
    )
    return grasps, ClosingRegionPoints(cand, local, idx[elem])
