"""Checks of a request's setup that the detector cannot see for itself, each a plain numpy function that says,
with a DetectionWarning, what looks wrong and what to do (graspd.core.warning).  A correct request passes them all.

- viewpoint_warning: the viewpoints could not have seen the cloud (a camera behind the surface: normals, which
  preprocessing turns toward the cameras, then face the wrong way and the grasps come from the wrong side);
- few_points_warning: too few points left after the workspace crop;
- model_hand_warning: the model does not serve the requested hand (not trained on its images, not chosen for it);
- no_candidates_warning: no candidate survived, naming the stage that removed them.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from graspd.core.cloud import ViewpointCloud
from graspd.core.warning import DetectionWarning
from graspd.gpd.preprocess import Workspace, crop_mask, range_limit, region_mask, spans_window

if TYPE_CHECKING:  # no import at run time: the detector may call these checks itself
    from graspd.gpd.detector import Detection

#: Angular bin of the visibility test (rad): coarser than a depth camera's pixel (~0.0015 rad) so that a bin
#: holds several points of the surface it sees.
VISIBILITY_BIN_RAD = 0.01
#: A point lies behind another along a camera ray when it is farther by more than this (m): well above depth
#: noise and the voxel size.
VISIBILITY_MARGIN_M = 0.02
#: Share of the points no viewpoint could see above which the viewpoints are called wrong.  Measured (margin
#: 2 cm, bins 0.01 rad, 30k points): correct requests 0-0.9 % (table_mug.pcd from 0,0,0: 0.4 %; krylon.pcd
#: from its 0,0,0: 0 %; the clutter benchmark's pour, pile and packed scenes with their cameras: 0-0.9 %;
#: rendered two-camera tabletops: 0.1-0.3 %); wrong ones 7-43 % (table_mug.pcd from 0,0,3: 43 %, from 0,0,2:
#: 11 %; the benchmark scenes with cameras mirrored below the table: 8-31 %; two-camera scenes sent with one
#: camera: 7-18 %).
HIDDEN_SHARE_LIMIT = 0.05
#: Points the visibility test looks at, at most (every k-th point of a larger cloud; ~10 ms a camera).
VISIBILITY_MAX_POINTS = 30_000
#: Fewer points than this after the workspace crop and voxel filter make a detection unreliable (GPD samples
#: hands at points and needs the neighbourhood of each).
FEW_POINTS = 100


def _cube_bins(directions: NDArray[np.float64], bin_rad: float) -> NDArray[np.int64]:
    """A bin id per unit direction (M,3): the cube-map face it points through and a square cell of about bin_rad
    on that face (every direction has one, unlike a single perspective image)."""
    axis = np.argmax(np.abs(directions), axis=1)
    rows = np.arange(len(directions))
    major = directions[rows, axis]
    face = axis * 2 + (major < 0)
    others = np.stack([directions[rows, (axis + 1) % 3], directions[rows, (axis + 2) % 3]], axis=1)
    cells = np.floor(others / np.abs(major)[:, None] / bin_rad).astype(np.int64)  # |coord| <= 1: < 1/bin cells
    span = int(np.ceil(1.0 / bin_rad)) + 1
    return (face * (2 * span + 1) + cells[:, 0] + span) * (2 * span + 1) + cells[:, 1] + span


def hidden_share(points: NDArray[np.floating], viewpoints: NDArray[np.floating],
                 bin_rad: float = VISIBILITY_BIN_RAD, margin_m: float = VISIBILITY_MARGIN_M,
                 max_points: int = VISIBILITY_MAX_POINTS) -> float:
    """Share in [0, 1] of the points (N,3, m) that none of the viewpoints (K,3, m, same frame) could have seen:
    from each camera, a point is hidden when another point in about the same direction (within bin_rad) is
    nearer by more than margin_m.  A depth camera sees only the first surface along
    each ray, so a correct request scores near 0; a viewpoint behind the surface sees the scene's layers out of
    order and scores high.  0 for an empty cloud."""
    pts = np.asarray(points).reshape(-1, 3)
    if len(pts) > 2 * max_points:  # every k-th point first: a 5M-point cloud is not copied whole as float64
        pts = pts[:: len(pts) // max_points]
    pts = pts.astype(np.float64)
    pts = pts[np.isfinite(pts).all(axis=1)]
    if len(pts) == 0:
        return 0.0
    if len(pts) > max_points:
        pts = pts[:: -(-len(pts) // max_points)]
    seen = np.zeros(len(pts), bool)
    for v in np.asarray(viewpoints, np.float64).reshape(-1, 3):
        rel = pts - v
        r = np.linalg.norm(rel, axis=1)
        ok = r > 1e-9
        if not ok.any():  # every point at this camera: it sees none of them
            continue
        bins = _cube_bins(rel[ok] / r[ok, None], bin_rad)
        _, inverse = np.unique(bins, return_inverse=True)
        nearest = np.full(inverse.max() + 1, np.inf)
        np.minimum.at(nearest, inverse, r[ok])
        visible = np.zeros(len(pts), bool)
        visible[ok] = r[ok] <= nearest[inverse] + margin_m
        seen |= visible
    return float(1.0 - seen.mean())


def viewpoint_warning(points: NDArray[np.floating], viewpoints: NDArray[np.floating],
                      limit: float = HIDDEN_SHARE_LIMIT, share: float | None = None) -> DetectionWarning | None:
    """viewpoint_flipped when more than `limit` of the points could not have been seen from the viewpoints
    (hidden_share, unless `share` gives it); the points are those the detection used (after the workspace
    crop)."""
    share = hidden_share(points, viewpoints) if share is None else share
    if share <= limit:
        return None
    vps = "; ".join(", ".join(f"{c:.3g}" for c in v) for v in np.asarray(viewpoints, float).reshape(-1, 3))
    return DetectionWarning(
        "viewpoint_flipped",
        f"{100 * share:.0f}% of the points lie behind other points as seen from the viewpoints ({vps}): no camera "
        f"there could have seen them.  A viewpoint is probably on the wrong side of the surface (or a camera is "
        f"missing), so normals, turned toward the viewpoints, face away from the real camera and grasps may come "
        f"from the wrong side.  Give every camera's position in the cloud's frame (or camera_poses with "
        f"points_frame), with camera_source when several cameras' points are merged.")


@dataclass(frozen=True)
class RegionCheck:
    """What the request-level checks know of the region a detection worked on (preprocess.region_mask): the
    hidden_share of its points and how many finite points the range window left out (0 with a workspace; every
    answer counts them, num_points_out_of_range: the default doing its job is not a fault to warn of)."""

    hidden: float
    left_out: int = 0


def region_check(cloud: ViewpointCloud, workspace: Workspace | None, range_window: float) -> RegionCheck:
    """RegionCheck of a request's cloud (its frame, m): the region preprocess keeps, its hidden share, and what the
    range window left out."""
    if workspace is not None:
        return RegionCheck(_hidden_share_of(cloud, region_mask(cloud, workspace, 0.0)))
    if range_window <= 0.0 or not spans_window(cloud.points, range_window):
        return RegionCheck(_hidden_share_of(cloud, None))  # every point (hidden_share skips non-finite ones)
    ranges, far = range_limit(cloud.points, cloud.camera_source, cloud.viewpoints, range_window)
    near = ranges <= far  # NaN ranges (non-finite points) compare False: neither kept nor counted
    left_out = int(np.count_nonzero(ranges > far))
    return RegionCheck(_hidden_share_of(cloud, near), left_out)


def _hidden_share_of(cloud: ViewpointCloud, mask: NDArray[np.bool_] | None) -> float:
    """hidden_share of the masked points (None: all), every k-th row looked at before any copy (a 5M-point
    cloud)."""
    step = max(1, len(cloud) // (2 * VISIBILITY_MAX_POINTS))
    rows = cloud.points[::step] if mask is None else cloud.points[np.flatnonzero(mask[::step]) * step]
    return hidden_share(rows, cloud.viewpoints)


def few_points_warning(num_points: int, cropped: bool, limit: int = FEW_POINTS) -> DetectionWarning | None:
    """few_points when fewer than `limit` points are left after preprocessing (cropped: a workspace was set)."""
    if num_points >= limit:
        return None
    where = "after the workspace crop and the voxel filter" if cropped else "after the voxel filter"
    fix = ("check that the workspace is in the cloud's frame (or the robot frame, with camera_poses) and contains "
           "the objects" if cropped else "send a denser cloud")
    return DetectionWarning("few_points", f"only {num_points} points are left {where} (at least {limit} are "
                                          f"needed for reliable grasps): {fix}")


def model_hand_warning(model: str | None, fits: bool | None, hand: Mapping[str, float]) -> DetectionWarning | None:
    """model_hand_mismatch when the model does not serve the hand: neither trained on its grasp images nor chosen
    for it by the benchmarks (fits False, graspd.gpd.classifier.card_serves_hand; None: not known)."""
    if fits is not False or model is None:
        return None
    shown = ", ".join(f"{k} {v:g}" for k, v in hand.items() if k in ("finger_width", "hand_outer_diameter",
                                                                     "hand_depth", "hand_height"))
    return DetectionWarning("model_hand_mismatch",
                            f"model {model!r} was trained on grasp images of another hand than this request's "
                            f"({shown} m): its scores are less reliable.  Use a model made for this hand (GET "
                            f"/models lists each model's hand) or train one: python -m graspd_lab.training.dataset "
                            f"--hand NAME, then graspd train")


def no_candidates_warning(num_points: int, num_candidates: int, num_grasps: int,
                          counts: Mapping[str, int] | None = None) -> DetectionWarning | None:
    """no_candidates when a detection returns no grasp, naming the stage that removed them: preprocessing
    (no point left), the environment (no object point), candidate sampling (no collision-free hand), or
    selection (its filters: workspace, width, approach cone, min_score).  counts: points per environment label
    (Environment.counts), when known."""
    if num_grasps > 0:
        return None
    if num_points == 0:
        stage, why = "preprocess", "no point is left after the workspace crop and the outlier filter: check the " \
                                   "workspace and the cloud's frame"
    elif counts is not None and counts.get("object", num_points) == 0:
        labels = ", ".join(f"{k} {v}" for k, v in counts.items() if v)
        stage, why = "environment", f"every point belongs to the environment ({labels}), none to an object: is " \
                                    "anything on the support inside the workspace?"
    elif num_candidates == 0:
        stage, why = "candidates", "no sampled hand fits without colliding with the points, the environment or " \
                                   "unseen space: try more num_samples, a smaller hand, or unknown_space allow"
    else:
        stage, why = "selection", f"all {num_candidates} candidates were filtered out by selection (workspace, " \
                                  "width limits, approach cone, min_score): loosen them"
    return DetectionWarning("no_candidates", f"no grasp: the {stage} stage removed them; {why}")


def in_workspace(points: NDArray[np.floating], workspace: Sequence[float] | None) -> NDArray[np.floating]:
    """The points (N,3) inside workspace [xmin, xmax, ymin, ymax, zmin, zmax] (m; None: all of them)."""
    if workspace is None:
        return points
    w = tuple(float(v) for v in workspace)
    return points[crop_mask(points, (w[0], w[1], w[2], w[3], w[4], w[5]))]


def check_detection(det: Detection, cloud: ViewpointCloud, workspace: Workspace | None, range_window: float,
                    model_fits_hand: bool | None, region: RegionCheck | None = None) -> list[DetectionWarning]:
    """The request-level warnings of a GPD detection, in this order: viewpoint_flipped, few_points,
    model_hand_mismatch, no_candidates.  cloud, workspace and range_window: the cloud and region the detector was
    given, in its frame (m); model_fits_hand: whether the model serves the hand (None: not known); region:
    region_check of them if already known (the service computes it beside the detection)."""
    if region is None:
        region = region_check(cloud, workspace, range_window)
    found = [
        viewpoint_warning(cloud.points, cloud.viewpoints, share=region.hidden),
        few_points_warning(det.num_points, workspace is not None),
        model_hand_warning(det.model, model_fits_hand, det.hand.to_dict()),
        no_candidates_warning(det.num_points, det.num_candidates, len(det.grasps),
                              None if det.environment is None else det.environment.counts()),
    ]
    return [w for w in found if w is not None]
