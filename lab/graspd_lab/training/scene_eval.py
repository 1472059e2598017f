"""Precision at the top of the ranking on cluttered scenes, measured against the true meshes.

A robot executes the first grasp the service returns, so what counts is whether the top 1, 5 and 10 are
grasps.  For each evaluation scene (graspd_lab.training.scene_data.scene_views: the clutter benchmark's
scenes, cameras and noise), the detector runs with the service's defaults and the model under test, and
the returned grasps are labelled against the meshes exactly as the training data is (scene_labels:
contacts on one object within friction cones, nothing hit on the way in).  Two rankings are reported:
"service" (the answer a robot gets: selection and ranking included) and "score" (every candidate the
classifier scored, by score alone: the classifier's own precision at the top).

Scenes come from objects no training scene holds: the object split's test part of the training objects
("unseen"), or the held-out test objects 900-999 ("held-out": evaluation only, never used for training or
tuning, as in the clutter benchmark).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from graspd.core.hand import HandGeometry
from graspd.core.progress import track
from graspd.gpd.detector import DetectionParams, GraspDetector, Scorer, cascade_mask
from graspd.gpd.images import encode_images
from graspd_lab.training.labels import label_grasps
from graspd_lab.training.scene_data import SceneParams, SceneView, scene_spec, scene_views
from graspd_lab.world.objects import HELD_OUT_URDFS

TOP_K = (1, 5, 10)
#: Scene ids of evaluation scenes start here, far from any training scene id.
EVAL_SCENE_OFFSET = 1_000_000


@dataclass(frozen=True)
class SceneEvalParams:
    """Which evaluation scenes (how many, from which objects, the seed) and the detector's samples."""

    scenes: int = 30
    objects: str = "unseen"  # "unseen": the object split's test objects; "held-out": random_urdfs 900-999
    seed: int = 0
    num_samples: int = 1000
    data: SceneParams = field(default_factory=SceneParams)

    def __post_init__(self) -> None:
        if self.objects not in ("unseen", "held-out"):
            raise ValueError(f"objects must be 'unseen' or 'held-out', got {self.objects!r}")
        if self.scenes < 1:
            raise ValueError(f"scenes must be >= 1, got {self.scenes}")


def evaluation_views(params: SceneEvalParams) -> list[SceneView]:
    """One view of each evaluation scene (deterministic from the seed; clutter kinds only)."""
    parts = params.data.object_parts()
    pool = parts["test"] if params.objects == "unseen" else list(HELD_OUT_URDFS)
    views: list[SceneView] = []
    sid = EVAL_SCENE_OFFSET + 1000 * params.seed
    while len(views) < params.scenes:
        spec = scene_spec(sid, params.data, {"train": pool, "val": pool, "test": pool})
        sid += 1
        if spec["source"] == "single":
            continue
        seen = scene_views(spec["source"], spec["objects"], sid, 1, params.data.hand, params.data.noise,
                           params.data.sensing_mix, held_out_ok=params.objects == "held-out")
        views.extend(seen[:1])
    return views


def precision_at_k(labels_in_rank_order: np.ndarray, ks: tuple[int, ...] = TOP_K) -> dict[str, float]:
    """Fraction of grasps among the first k (fewer if fewer were returned; NaN if none) for each k."""
    out = {}
    for k in ks:
        top = labels_in_rank_order[:k]
        out[f"p@{k}"] = float(np.mean(top)) if len(top) else float("nan")
    return out


def evaluate_scenes(scorer: Scorer, views: list[SceneView], hand: HandGeometry | None = None,
                    num_samples: int = 1000, seed: int = 0, prefilter: Scorer | None = None) -> dict[str, Any]:
    """Per-scene and mean precision@1/5/10 of the service's ranking and of the classifier's score ranking,
    plus the scores and labels of every candidate scored (for calibration plots).  prefilter: the cascade's
    first pass (graspd.gpd.detector.cascade_mask), applied to both rankings."""
    h = hand or HandGeometry()
    det = GraspDetector(scorer, h, prefilter)
    labels_params = SceneParams().labels
    per_scene = []
    all_scores, all_labels = [], []
    for i, view in enumerate(track(views, f"scenes ({scorer.name if scorer is not None else 'unscored'})", "scene")):
        p = DetectionParams(num_samples=num_samples, workspace=view.workspace, seed=seed + i)
        answer = det.detect(view.cloud, p, h)
        served = label_grasps(view.truth, answer.grasps[:max(TOP_K)], h, labels_params, view.graspable).grasp
        prep = det.prepare(view.cloud, p, h)
        cands, region = det.search(prep, prep.sampling, p, h)
        if prefilter is not None and len(cands) > p.cascade_min:
            keep = cascade_mask(prefilter, prep.scene, cands, region, h, p)
            cands, region = cands[keep], region.subset(keep)
        row: dict[str, Any] = {"scene": i, "kind": view.kind, "sensing": view.sensing, "objects": view.num_objects,
                               "candidates": len(cands), "returned": len(answer.grasps)}
        row.update({f"service {k}": v for k, v in precision_at_k(served.astype(float)).items()})
        if len(cands):
            scores = np.asarray(scorer.score(encode_images(prep.scene, cands, h, scorer.representation, region=region)))
            truth = label_grasps(view.truth, cands, h, labels_params, view.graspable).grasp
            order = np.argsort(-scores, kind="stable")
            row.update({f"score {k}": v for k, v in precision_at_k(truth[order].astype(float)).items()})
            row["positive_rate"] = float(truth.mean())
            all_scores.append(scores)
            all_labels.append(truth)
        per_scene.append(row)
    keys = [f"{r} p@{k}" for r in ("service", "score") for k in TOP_K]
    mean = {k: float(np.nanmean([s.get(k, np.nan) for s in per_scene])) for k in keys}
    return {"scenes": per_scene, "mean": mean,
            "scores": np.concatenate(all_scores) if all_scores else np.zeros(0),
            "labels": np.concatenate(all_labels) if all_labels else np.zeros(0, bool)}
