"""GraspDetector: Algorithm 1 of the IJRR paper end to end, with a classifier passed in.

preprocess -> environment (support, walls, declared boxes, up) -> scene (kd-tree, unobserved volume)
-> sample hands on object points -> environment and feasibility filters -> encode grasp images -> score
-> select (utility J(h) with up from the support).  Without a classifier (or with use_classifier off) the pipeline
runs as the paper's "no classification" ablation and says so (scored = False).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field, replace
from typing import Any, Protocol

import numpy as np
from numpy.typing import NDArray

from graspd.core.cloud import ViewpointCloud
from graspd.core.grasp import GraspSet
from graspd.core.hand import HandGeometry
from graspd.core.limits import MAX_NUM_SAMPLES
from graspd.core.parallel import THREADS
from graspd.core.warning import DetectionWarning
from graspd.gpd.candidates import SUPPORT_BITE, SamplingParams, search_hands
from graspd.gpd.environment import Environment, EnvironmentParams, Label, hand_hits_environment, model_environment
from graspd.gpd.environment.coverage import unseen_floor_warning
from graspd.gpd.images import encode_batches, encode_images
from graspd.gpd.objects import SceneObject, Segmentation, segment_objects
from graspd.gpd.occlusion import (
    MAX_UNKNOWN_SHARE,
    UNKNOWN_FALLBACK_SHARE,
    UNKNOWN_SPACE_MODES,
    UnknownSpace,
    hand_shadow_length,
    unknown_share,
)
from graspd.gpd.preprocess import DEFAULT_RANGE_WINDOW, PreprocessParams, Workspace, preprocess, support_plane_mask
from graspd.gpd.robustness import MAX_ROBUST_COPIES, MAX_ROBUST_TOP, ROBUST_COPIES, ROBUST_TOP, robust_scores
from graspd.gpd.scene import ClosingRegionPoints, Scene
from graspd.gpd.selection import DEFAULT_MAX_PER_OBJECT, SelectionParams, Vec3, feasible_mask, select
from graspd.gpd.target import MIN_TARGET_POINTS, Target, TargetError, target_mask

#: Default clearance (m) of the hand's outline from the cloud's points (DetectionParams.clearance): the true
#: surface lies a millimetre or two beyond the points seen of it (noise, voxels, grazing views), and hands placed
#: flush against the points grazed it on the way in, by 1-3 mm (bench/approach.py).
HAND_CLEARANCE = 0.003


class Scorer(Protocol):
    """What the detector needs of a classifier (graspd.gpd.classifier.GraspClassifier satisfies it)."""

    name: str
    representation: str

    def score(self, images: NDArray[np.uint8]) -> NDArray[np.float32]: ...


@dataclass(frozen=True)
class DetectionParams:
    """Per-request knobs (metres, degrees).  workspace crops the cloud and the grasp positions; without one,
    range_window (m, 0 = off) keeps the points at most this far beyond the nearest surface the cameras see
    (preprocess.region_mask).

    environment: how objects are told from what holds them (default "auto": support plane and walls found
    in the cloud); "none" is the pipeline without an environment model.  approach_distance: the pre-grasp
    distance back along the approach over which the open hand's path must be free.  exclude_support_plane
    None follows the environment (samples on object points only); True/False override it.  width_margin
    (m): grasps whose width leaves less than this inside the opening rank lower (0 = off).  sample_points
    (K, 3; cloud frame, m): sample hands at the preprocessed point nearest each (those within frame_radius;
    gpd_ros CloudSamples / CloudIndexed) instead of num_samples random points.  early_stop (for requests that
    want few grasps; changes which grasps come back, so off by default): search the same seeded samples in
    rounds of early_stop_round and stop once 2 x max_grasps candidates in distinct 2 cm cells score at least
    min_score (else 0.5); deterministic for a seed.  cascade (with a detector that has a prefilter): a cheap
    first pass scores every candidate and only the best cascade_keep fraction (at least cascade_min) are
    encoded and scored by the full model; the rest are dropped.  unknown_space "avoid" (default): a hand with
    more than max_unknown (default none) of its fingers, palm or approach path in space no camera saw (behind a
    seen surface from every camera) is treated as colliding; "fallback" does the same, but when that leaves no
    hand returns those with at most unknown_fallback there, with a warning; "allow" checks the seen points only,
    as GPD does.
    target (graspd.gpd.target): sample on it only and keep the hands whose closing region holds no object point
    outside it; a target of sample points replaces sample_points.  max_per_object (0 = off): the ranked list gives
    no object more than this many grasps before every other object with a grasp has one (selection.cover_order).
    clearance (m): how far the open hand's outline, at the pre-grasp pose, along its path and at the grasp, keeps
    from the cloud's points except across its inner finger faces and its palm's face (what it grasps may touch
    them; candidates.SamplingParams.clearance; 0 places it flush against them, as GPD does).  flat_objects (off by
    default): an object lying flat, thinner than the hand's init_bite above the support's clearance (a packet 1 cm
    thick), gets hands whose fingertips stop above the support and hold its edges, candidates.SUPPORT_BITE deep;
    such grasps hold less often than deeper ones.  robust_copies (0 = off, the default): the first robust_top grasps
    by key are ranked by their classifier score averaged over the grasp and this many copies moved 2 mm and turned 3
    degrees (graspd.gpd.robustness): a grasp that a robot's or a camera's small error spoils ranks lower."""

    num_samples: int = 1000
    workspace: Workspace | None = None
    max_grasps: int = 100
    min_score: float | None = None
    approach_direction: Vec3 | None = None
    approach_max_angle_deg: float | None = None
    min_aperture: float | None = None
    max_aperture: float | None = None
    use_selection: bool = True
    use_clustering: bool = False
    use_classifier: bool = True
    gravity: Vec3 | None = None
    reference_position: Vec3 | None = None
    seed: int | None = 0
    voxel_size: float = 0.003
    remove_outliers: bool = False
    range_window: float = DEFAULT_RANGE_WINDOW
    exclude_support_plane: bool | None = None
    environment: EnvironmentParams = field(default_factory=EnvironmentParams)
    approach_distance: float = 0.05
    width_margin: float = 0.01
    num_orientations: int = 8
    num_finger_placements: int = 10
    frame_radius: float = 0.01
    score_batch: int = 512
    early_stop: bool = False
    early_stop_round: int = 100
    cascade: bool = True
    cascade_keep: float = 0.3
    cascade_min: int = 200
    unknown_space: UnknownSpace = "avoid"
    max_unknown: float = MAX_UNKNOWN_SHARE
    unknown_fallback: float = UNKNOWN_FALLBACK_SHARE
    sample_points: NDArray[np.float64] | None = field(default=None, compare=False, repr=False)
    target: Target | None = field(default=None, compare=False, repr=False)
    max_per_object: int = DEFAULT_MAX_PER_OBJECT
    clearance: float = HAND_CLEARANCE
    flat_objects: bool = False
    robust_copies: int = ROBUST_COPIES
    robust_top: int = ROBUST_TOP

    def __post_init__(self) -> None:
        if self.max_per_object < 0:
            raise ValueError(f"max_per_object must be >= 0 (0 = off), got {self.max_per_object}")
        if not 1 <= self.num_samples <= MAX_NUM_SAMPLES:
            raise ValueError(f"num_samples must be in [1, {MAX_NUM_SAMPLES}], got {self.num_samples}")
        if self.max_grasps < 0:
            raise ValueError(f"max_grasps must be >= 0, got {self.max_grasps}")
        if not 0.0 <= self.voxel_size <= 0.05:
            raise ValueError(f"voxel_size must be in [0, 0.05] m, got {self.voxel_size}")
        if not 1 <= self.num_orientations <= 64 or not 1 <= self.num_finger_placements <= 64:
            raise ValueError("num_orientations and num_finger_placements must be in [1, 64]")
        if not 0.0 <= self.approach_distance <= 0.5:
            raise ValueError(f"approach_distance must be in [0, 0.5] m, got {self.approach_distance}")
        if self.early_stop_round < 1:
            raise ValueError(f"early_stop_round must be >= 1, got {self.early_stop_round}")
        if not 0.0 < self.cascade_keep <= 1.0 or self.cascade_min < 1:
            raise ValueError(f"cascade_keep must be in (0, 1] and cascade_min >= 1, got {self.cascade_keep}, "
                             f"{self.cascade_min}")
        if self.unknown_space not in UNKNOWN_SPACE_MODES:
            raise ValueError(f"unknown_space must be one of {UNKNOWN_SPACE_MODES}, got {self.unknown_space!r}")
        if not 0.0 <= self.max_unknown <= 1.0:
            raise ValueError(f"max_unknown must be in [0, 1], got {self.max_unknown}")
        if not 0.0 <= self.unknown_fallback <= 1.0:
            raise ValueError(f"unknown_fallback must be in [0, 1], got {self.unknown_fallback}")
        if not 0.0 <= self.clearance <= 0.02:
            raise ValueError(f"clearance must be in [0, 0.02] m, got {self.clearance}")
        if not 0 <= self.robust_copies <= MAX_ROBUST_COPIES:
            raise ValueError(f"robust_copies must be in [0, {MAX_ROBUST_COPIES}] (0 = off), got {self.robust_copies}")
        if not 1 <= self.robust_top <= MAX_ROBUST_TOP:
            raise ValueError(f"robust_top must be in [1, {MAX_ROBUST_TOP}], got {self.robust_top}")
        if not 0.0 <= self.width_margin <= 0.1:
            raise ValueError(f"width_margin must be in [0, 0.1] m, got {self.width_margin}")

    def selection(self, hand: HandGeometry, env: Environment | None = None) -> SelectionParams:
        """Selection knobs; with an environment that knows "up", J(h) ranks by default (gravity = -up) with
        heights measured from the support, and the width margin applies."""
        gravity, table_height, margin = self.gravity, None, None
        if env is not None and env.mode != "none":
            margin = self.width_margin or None
            if gravity is None and env.up is not None:
                gravity = (float(-env.up[0]), float(-env.up[1]), float(-env.up[2]))
            if env.support is not None and env.up is not None and float(env.up @ env.support.normal) > 0.99:
                table_height = -env.support.offset
        return SelectionParams(
            workspace=self.workspace,
            min_aperture=self.min_aperture,
            max_aperture=hand.max_aperture if self.max_aperture is None else self.max_aperture,
            approach_direction=self.approach_direction,
            approach_max_angle_deg=self.approach_max_angle_deg,
            min_score=self.min_score,
            use_clustering=self.use_clustering,
            gravity=gravity,
            table_height=table_height,
            width_margin=margin,
            reference_position=self.reference_position,
            max_grasps=self.max_grasps,
            max_per_object=self.max_per_object,
        )


@dataclass(frozen=True)
class Detection:
    """Ranked grasps (best first) with what produced them and how long each stage took (s); objects: the scene's
    objects by id (graspd.gpd.objects), which the grasps' object ids refer to."""

    grasps: GraspSet
    timings: dict[str, float]
    model: str | None
    scored: bool
    num_candidates: int
    num_points: int
    hand: HandGeometry = field(default_factory=HandGeometry)
    environment: Environment | None = None
    warnings: tuple[DetectionWarning, ...] = ()
    objects: tuple[SceneObject, ...] = ()
    max_per_object: int = 0

    def object_grasps(self) -> list[list[int]]:
        """For each object (by id), the positions of its grasps in the ranked list."""
        out: list[list[int]] = [[] for _ in self.objects]
        for k, oid in enumerate(self.grasps.object_ids.tolist()):
            if 0 <= oid < len(out):
                out[oid].append(k)
        return out

    def warned(self, *more: DetectionWarning) -> Detection:
        """This detection with more warnings appended (codes already present are not repeated)."""
        have = {w.code for w in self.warnings}
        return replace(self, warnings=self.warnings + tuple(w for w in more if w.code not in have))

    def to_dict(self) -> dict[str, Any]:
        return {
            "grasps": [{**g, "object": oid if oid >= 0 else None}
                       for g, oid in zip(self.grasps.to_dicts(), self.grasps.object_ids.tolist(), strict=True)],
            "timings": dict(self.timings),
            "model": self.model,
            "scored": self.scored,
            "num_candidates": self.num_candidates,
            "num_points": self.num_points,
            "hand": self.hand.to_dict(),
            "environment": None if self.environment is None else self.environment.to_dict(),
            "warnings": [w.to_dict() for w in self.warnings],
            "objects": [{**o.to_dict(), "grasps": g} for o, g in zip(self.objects, self.object_grasps(), strict=True)],
            "max_per_object": self.max_per_object,
        }


class GraspDetector:
    """Loads nothing itself: give it a classifier (or None for the unscored ablation) and a hand; prefilter is
    the cascade's cheap first pass (a classifier of a cheaper representation, e.g. 3 channels), or None."""

    def __init__(self, classifier: Scorer | None = None, hand: HandGeometry | None = None,
                 prefilter: Scorer | None = None) -> None:
        self.classifier = classifier
        self.hand = hand or HandGeometry()
        self.prefilter = prefilter

    def detect(self, cloud: ViewpointCloud, params: DetectionParams | None = None,
               hand: HandGeometry | None = None) -> Detection:
        p = params or DetectionParams()
        h = hand or self.hand
        timings: dict[str, float] = {}
        t0 = t = time.perf_counter()

        def lap(stage: str) -> None:
            nonlocal t
            now = time.perf_counter()
            timings[stage] = now - t
            t = now

        prep = self.prepare(cloud, p, h, lap)
        scene, env, sampling, sel = prep.scene, prep.environment, prep.sampling, prep.selection
        scorer = self.classifier if p.use_classifier else None

        def candidates_for(s: SamplingParams, q: DetectionParams = p) -> GraspSet:
            """Sample, filter (feasibility, environment) and score the hands of s; stage times add up."""
            t_start = time.perf_counter()
            cands, region = self.search(prep, s, q, h)
            t_batch = time.perf_counter()
            timings["sample"] = timings.get("sample", 0.0) + t_batch - t_start
            if scorer is None or not len(cands):
                return cands
            if self.prefilter is not None and p.cascade and len(cands) > p.cascade_min:
                keep = cascade_mask(self.prefilter, scene, cands, region, h, p)
                cands, region = cands[keep], region.subset(keep)
                now = time.perf_counter()
                timings["prefilter"] = timings.get("prefilter", 0.0) + now - t_batch
                t_batch = now
            # encode and score batch by batch: memory stays bounded however many candidates there are
            scores = np.empty(len(cands))
            for a, images in encode_batches(scene, cands, h, scorer.representation, region=region,
                                            batch=p.score_batch):
                t_encoded = time.perf_counter()
                scores[a : a + len(images)] = score_parallel(scorer, images)
                timings["encode"] = timings.get("encode", 0.0) + t_encoded - t_batch
                t_batch = time.perf_counter()
                timings["score"] = timings.get("score", 0.0) + t_batch - t_encoded
            return cands.with_scores(scores)

        timings.update(sample=0.0, encode=0.0, score=0.0)
        if p.early_stop and p.max_grasps > 0 and sampling.sample_indices is None and scorer is not None:
            candidates = GraspSet()
            for chunk in sample_rounds(len(scene.points), sampling, p.early_stop_round):
                candidates = GraspSet.concatenate([candidates, candidates_for(replace(sampling, sample_indices=chunk))])
                if enough_grasps(candidates, p):
                    break
        else:
            candidates = candidates_for(sampling)
        fallback = not len(candidates) and p.unknown_space == "fallback" and p.unknown_fallback > p.max_unknown
        if fallback:  # no hand keeps out of unseen space: those that enter it least, with a warning, not none
            candidates = candidates_for(sampling, replace(p, max_unknown=p.unknown_fallback))
        t = time.perf_counter()
        rng = np.random.default_rng(p.seed)
        rescore = None
        if scorer is not None and p.robust_copies > 0:
            def rescore(top: GraspSet, s: Scorer = scorer) -> NDArray[np.float64]:
                return robust_scores(top, lambda g: score_parallel(s, encode_images(scene, g, h, s.representation)),
                                     p.robust_copies, seed=0 if p.seed is None else p.seed)
        grasps = select(candidates, sel, use_selection=p.use_selection, rng=rng, rescore=rescore,
                        rescore_top=p.robust_top)
        warnings = list(env.warnings)
        if p.unknown_space == "allow" and len(grasps):
            top = grasps[:10]
            share = unknown_share(scene.unobserved_within(hand_shadow_length(h, p.approach_distance)), top.positions,
                                  top.rotations, h, p.approach_distance)
            if (share > p.max_unknown).any():
                warnings.append(DetectionWarning(
                    "unknown_space", f"{int((share > p.max_unknown).sum())} of the top {len(top)} grasps put "
                    f"up to {100 * float(share.max()):.0f}% of the hand into space no camera saw (unknown_space "
                    "is 'allow'); a hidden neighbour may be there"))
        if fallback and len(grasps):
            warnings.append(DetectionWarning(
                "unknown_space", f"no hand keeps out of space no camera saw; these grasps put up to "
                f"{100 * float(np.nanmax(grasps.unknown_share)):.0f}% of the hand and its approach path into it "
                f"(unknown_space 'fallback', at most {100 * p.unknown_fallback:.0f}%): a hidden neighbour may be "
                "there; a view from another side shows it"))
        if p.target is not None and not len(grasps):
            warnings.append(target_warning(prep, p.target, len(candidates)))
        hidden = None if len(grasps) or env.mode == "none" else unseen_floor_warning(prep.cloud.points, env)
        if hidden is not None:  # no grasp need not mean an empty container: say what no camera saw
            warnings.append(hidden)
        flat = None if len(grasps) or p.flat_objects else flat_objects_warning(prep, h)
        if flat is not None:  # objects the default bite leaves no hand on, and the option that tries them
            warnings.append(flat)
        lap("select")
        timings["total"] = time.perf_counter() - t0
        return Detection(
            grasps=grasps,
            timings=timings,
            model=None if scorer is None else scorer.name,
            scored=scorer is not None,
            num_candidates=len(candidates),
            num_points=len(prep.cloud),
            hand=h,
            environment=env,
            warnings=tuple(warnings),
            objects=prep.segmentation.objects,
            max_per_object=p.max_per_object if p.use_selection else 0,
        )

    def prepare(self, cloud: ViewpointCloud, p: DetectionParams, h: HandGeometry,
                lap: Callable[[str], None] | None = None) -> Prepared:
        """Preprocess, model the environment and build the scene of a request: everything before sampling."""
        pre = PreprocessParams(voxel_size=p.voxel_size, workspace=p.workspace, remove_outliers=p.remove_outliers,
                               range_window=p.range_window)
        prepared = preprocess(cloud, pre)
        if lap is not None:
            lap("preprocess")
        env = model_environment(prepared, h, p.environment, gravity=p.gravity, seed=p.seed)
        if lap is not None:
            lap("environment")
        scene = Scene.build(prepared, h)
        if lap is not None:
            lap("scene")
        modelled = env.mode != "none"
        segmentation = segment_objects(prepared.points, env.object_mask)
        if lap is not None:
            lap("objects")
        target = None
        if p.target is not None:
            target = target_mask(p.target, cloud, prepared, p.voxel_size, p.workspace, segmentation)
            if lap is not None:
                lap("target")
        if p.exclude_support_plane is False or (p.exclude_support_plane is None and not modelled):
            pool = None
        elif modelled:
            pool = segmentation.sampleable(env.object_mask)  # not on blobs of sensor artefacts
        else:
            pool = ~support_plane_mask(prepared.points)
        if target is not None:
            pool = target if pool is None else pool & target
            if np.count_nonzero(pool) < MIN_TARGET_POINTS:  # too small to grasp: no candidates, a warning says why
                pool = np.zeros_like(pool)
        # the support is a plane the hands stop short of in closed form, not thousands of points to test
        plane = env.support if modelled else None
        sampling = SamplingParams(num_samples=p.num_samples, num_orientations=p.num_orientations,
                                  num_finger_placements=p.num_finger_placements, frame_radius=p.frame_radius,
                                  seed=p.seed, sample_pool=pool, sample_indices=_nearest(scene, p),
                                  clear_behind=h.palm_depth + p.approach_distance,
                                  obstacles=None if plane is None else ~env.closed_form_mask(prepared.points),
                                  support=plane, support_clearance=env.clearance, clearance=p.clearance,
                                  support_bite=SUPPORT_BITE if p.flat_objects else None)
        scene = replace(scene, focus=hand_focus(prepared.points, sampling, h, p.approach_distance))
        return Prepared(cloud=prepared, environment=env, scene=scene, sampling=sampling,
                        selection=p.selection(h, env), segmentation=segmentation, target=target)

    @staticmethod
    def search(prep: Prepared, sampling: SamplingParams, p: DetectionParams, h: HandGeometry
               ) -> tuple[GraspSet, ClosingRegionPoints]:
        """The candidates of the sampling that pass the feasibility and environment filters, with their
        closing-region points: what the classifier scores (and what training data is labelled from)."""
        cands, region = search_hands(prep.scene, h, sampling)
        feasible = feasible_mask(cands, replace(prep.selection, min_score=None))
        if prep.environment.mode != "none":  # environment_conflicts of the feasible ones, without copying region
            env = prep.environment
            grasps_env = np.zeros(len(cands), bool)  # an environment point between the fingers
            grasps_env[region.grasp[env.labels[region.index] != Label.OBJECT]] = True
            feasible &= ~grasps_env
            feasible[feasible] = ~hand_hits_environment(cands.positions[feasible], cands.rotations[feasible], h, env,
                                                        p.approach_distance)
        if p.unknown_space != "allow" and feasible.any():
            share = np.full(len(cands), np.nan)
            unseen = prep.scene.unobserved_within(hand_shadow_length(h, p.approach_distance))
            share[feasible] = unknown_share(unseen, cands.positions[feasible],
                                            cands.rotations[feasible], h, p.approach_distance)
            feasible &= ~(share > p.max_unknown)
            cands = cands.with_unknown(share)
        if prep.target is not None and feasible.any():  # an object point outside the target between the fingers
            outside = ~prep.target[region.index]
            if prep.environment.mode != "none":
                outside &= prep.environment.labels[region.index] == Label.OBJECT
            feasible[region.grasp[outside]] = False
        kept, kept_region = cands[feasible], region.subset(feasible)
        return kept.with_objects(prep.segmentation.grasp_objects(kept_region, len(kept))), kept_region


def hand_focus(points: NDArray[np.float32], sampling: SamplingParams, hand: HandGeometry, approach_distance: float
               ) -> tuple[NDArray[np.float64], NDArray[np.float64]] | None:
    """The box (lo, hi; m, cloud frame) every hand of the sampling, and its path back from the pre-grasp pose,
    lies in: the bounds of the points it samples at, grown by the farthest any part of such a hand reaches from
    its sample (which lies between the fingers).  None when it samples anywhere (no pool)."""
    if sampling.sample_indices is not None:
        at = points[np.asarray(sampling.sample_indices, np.int64)]
    elif sampling.sample_pool is not None:
        at = points[sampling.sample_pool]
    else:
        return None
    if len(at) == 0:
        return None
    along = hand.hand_depth + hand.palm_depth + approach_distance
    across = hand.hand_outer_diameter / 2.0 + hand.closing_half_width
    reach = float(np.sqrt(along**2 + across**2 + (hand.hand_height / 2.0) ** 2))
    return at.min(axis=0).astype(np.float64) - reach, at.max(axis=0).astype(np.float64) + reach


@dataclass(frozen=True)
class Prepared:
    """A request after preprocessing: the cloud, its environment and scene, and the sampling and selection
    parameters derived from them (GraspDetector.prepare)."""

    cloud: ViewpointCloud
    environment: Environment
    scene: Scene
    sampling: SamplingParams
    selection: SelectionParams
    segmentation: Segmentation = field(default_factory=lambda: Segmentation.empty(0))
    target: NDArray[np.bool_] | None = None


#: Early stop: a round ends the search once this many times max_grasps candidates, each in its own
#: EARLY_STOP_SPACING cell, score at least min_score (else EARLY_STOP_SCORE).
EARLY_STOP_FACTOR = 2
EARLY_STOP_SCORE = 0.5
EARLY_STOP_SPACING = 0.02


def cascade_mask(prefilter: Scorer, scene: Scene, cands: GraspSet, region: ClosingRegionPoints, hand: HandGeometry,
                 p: DetectionParams) -> NDArray[np.bool_]:
    """The candidates the cascade's first pass keeps: the best cascade_keep fraction (at least cascade_min) by
    the prefilter's score on its own (cheap) images."""
    scores = np.empty(len(cands))
    for a, images in encode_batches(scene, cands, hand, prefilter.representation, region=region,
                                    batch=p.score_batch):
        scores[a : a + len(images)] = score_parallel(prefilter, images)
    k = min(len(cands), max(p.cascade_min, int(np.ceil(p.cascade_keep * len(cands)))))
    keep = np.zeros(len(cands), bool)
    keep[np.argsort(-scores, kind="stable")[:k]] = True
    return keep


def sample_rounds(n_points: int, sampling: SamplingParams, size: int) -> Iterator[tuple[int, ...]]:
    """The samples of sample_point_indices (the same seeded draw), in rounds of `size` taken in draw order
    (each round sorted): the first rounds are a uniform subsample, and all of them are every sample."""
    rng = np.random.default_rng(sampling.seed)
    pool = np.arange(n_points) if sampling.sample_pool is None else np.flatnonzero(sampling.sample_pool)
    drawn = pool[rng.choice(len(pool), size=min(sampling.num_samples, len(pool)), replace=False)]
    for a in range(0, len(drawn), max(1, size)):
        yield tuple(int(i) for i in np.sort(drawn[a : a + size]))


def enough_grasps(candidates: GraspSet, p: DetectionParams) -> bool:
    """Whether the candidates so far hold EARLY_STOP_FACTOR x max_grasps high-scoring, diverse grasps (scores
    >= min_score, else EARLY_STOP_SCORE; positions in distinct EARLY_STOP_SPACING cells)."""
    good = candidates.scores >= (EARLY_STOP_SCORE if p.min_score is None else p.min_score)
    cells = np.unique(np.floor(candidates.positions[good] / EARLY_STOP_SPACING).astype(np.int64), axis=0)
    return len(cells) >= EARLY_STOP_FACTOR * p.max_grasps


def _nearest(scene: Scene, p: DetectionParams) -> tuple[int, ...] | None:
    """Rows of the scene nearest the sample points (the target's, else p.sample_points; within p.frame_radius,
    each once), None without them.  TargetError when a target's points are all farther from the cloud."""
    points = p.target.points if p.target is not None and p.target.points is not None else p.sample_points
    if points is None:
        return None
    if len(points) == 0 or len(scene.points) == 0:
        return ()
    dist, idx = scene.tree.query(np.asarray(points, np.float64).reshape(-1, 3), distance_upper_bound=p.frame_radius)
    found = tuple(np.unique(idx[np.isfinite(dist)]).tolist())
    if not found and p.target is not None and p.target.points is not None:
        raise TargetError(p.target.field, f"none of its {len(points)} points lies within frame_radius "
                          f"({p.frame_radius:g} m) of the cloud (after the workspace crop)")
    return found


def target_warning(prep: Prepared, target: Target, num_candidates: int) -> DetectionWarning:
    """Why a target got no grasp: too few object points in it, or no hand that closes on it alone."""
    if prep.target is None:
        near = len(prep.sampling.sample_indices or ())
        return DetectionWarning("target_too_small", f"{target.field}: no collision-free hand at the {near} cloud "
                                f"points nearest its points ({num_candidates} candidates passed the checks); no "
                                "grasp returned")
    pool = prep.sampling.sample_pool
    on_objects = int(np.count_nonzero(pool)) if pool is not None else 0
    held = int(np.count_nonzero(prep.target))
    if pool is None or on_objects < MIN_TARGET_POINTS:
        why = (f"it covers {held} points of the cloud, {on_objects} of them on objects (the rest support, walls or "
               f"declared boxes); at least {MIN_TARGET_POINTS} object points are needed")
    else:
        pts = prep.cloud.points[pool]
        span = float(np.linalg.norm(pts.max(axis=0) - pts.min(axis=0)))
        why = (f"no collision-free hand closes on its {on_objects} object points ({100 * span:.1f} cm across) "
               "without taking in a point of another object")
    return DetectionWarning("target_too_small", f"{target.field}: {why}; no grasp returned")


def flat_objects_warning(prep: Prepared, hand: HandGeometry) -> DetectionWarning | None:
    """flat_objects when objects lie flatter than the hand's init_bite above the support's clearance (their tops,
    m, the 75th percentile of their points' heights: a packet's top face, above its noise): no hand reaches
    init_bite past such a top without touching the support, so the default leaves them none
    (candidates._low_bite gives them a shallower bite when the request asks for flat_objects)."""
    env, seg = prep.environment, prep.segmentation
    if env.support is None or not seg.objects:
        return None
    height = env.support.distance(prep.cloud.points.astype(np.float64))
    tops = np.array([np.percentile(height[seg.labels == o.id], 75.0) if o.num_points >= MIN_TARGET_POINTS
                     else np.inf for o in seg.objects])
    flat = tops - env.clearance < hand.init_bite
    if not flat.any():
        return None
    thickest = float(tops[flat].max())
    return DetectionWarning(
        "flat_objects", f"no grasp, and {int(flat.sum())} object(s) lie flat (their tops {100 * thickest:.1f} cm or "
        f"less above the support): a hand's fingertips must reach init_bite ({100 * hand.init_bite:.1f} cm) past "
        "an object's top and stop short of the support, which leaves them no hand; flat_objects: true holds them "
        "by their edges with a shallower bite (such grasps hold less often)")


MIN_SCORE_PIECE = 64  # images scored together at least: below this a second thread saves less than it costs


def score_parallel(scorer: Scorer, images: NDArray[np.uint8]) -> NDArray[np.float64]:
    """scorer.score(images) in pieces on the process's thread budget: a lone request scores on every core,
    concurrent ones on their share.  A scorer with intra-op threads of its own (its `threads`, 0 = all cores)
    gets fewer pieces.  Scores do not depend on the pieces (each image is scored on its own)."""
    own = int(getattr(scorer, "threads", 1))
    own = THREADS.cores if own <= 0 else own
    parts = min(max(1, THREADS.share() // own), max(1, len(images) // MIN_SCORE_PIECE))
    if parts <= 1:
        return np.asarray(scorer.score(images), np.float64)
    step = -(-len(images) // parts)
    pieces = THREADS.map(scorer.score, [images[a : a + step] for a in range(0, len(images), step)], threads=parts)
    return np.concatenate([np.asarray(x, np.float64) for x in pieces])


def environment_conflicts(candidates: GraspSet, region: ClosingRegionPoints, env: Environment, hand: HandGeometry,
                          approach_distance: float) -> NDArray[np.bool_]:
    """Candidates that grasp the environment (an environment point between the fingers) or whose hand or
    approach path enters it (see environment.hand_hits_environment)."""
    bad = np.zeros(len(candidates), bool)
    env_point = env.labels[region.index] != Label.OBJECT
    bad[region.grasp[env_point]] = True
    rest = ~bad
    bad[rest] = hand_hits_environment(candidates.positions[rest], candidates.rotations[rest], hand, env,
                                      approach_distance)
    return bad
