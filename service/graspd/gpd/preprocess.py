"""Step 1 of Algorithm 1: clean a viewpoint cloud and estimate camera-facing surface normals (numpy, scipy)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from graspd.core.cloud import CloudError, ViewpointCloud
from graspd.core.points import pca_normals, ransac_plane, statistical_inliers, voxel_groups

Workspace = tuple[float, float, float, float, float, float]


@dataclass(frozen=True)
class PreprocessParams:
    """voxel_size (m, 0 = off); workspace box [xmin, xmax, ymin, ymax, zmin, zmax] in the cloud frame;
    statistical outlier removal; normals from neighbours within normal_radius (m, at most max_nn); range_window
    (m, 0 = off): with no workspace, only points at most this much farther from their camera than the nearest
    surface the cameras see (region_mask)."""

    voxel_size: float = 0.003
    workspace: Workspace | None = None
    remove_outliers: bool = False
    outlier_neighbors: int = 20
    outlier_std_ratio: float = 2.0
    normal_radius: float = 0.01
    normal_max_nn: int = 30
    recompute_normals: bool = False
    range_window: float = 0.0


#: The range window a detection uses by default (m): points more than this beyond the nearest surface the cameras
#: see are left out when a request gives no workspace.  A tabletop seen from 0.5-1 m keeps its table and objects;
#: a room 1.6-2.5 m behind them goes (measured on the Kinect and stereo captures of bench/real.py).
DEFAULT_RANGE_WINDOW = 1.0
#: Share of the points (lowest ranges first) whose range defines the near end of the range window: robust to a
#: few stray points at the lens.
NEAR_QUANTILE = 0.01
#: Points whose ranges the near quantile is taken over, at most (every k-th point of a larger cloud).
RANGE_SAMPLE = 200_000
#: Points whose ranges one block computes.
RANGE_CHUNK = 262_144


def crop_mask(points: NDArray[np.floating], workspace: Workspace) -> NDArray[np.bool_]:
    """Points inside the axis-aligned box [xmin, xmax, ymin, ymax, zmin, zmax]."""
    lo = np.array(workspace[0::2], np.float64)
    hi = np.array(workspace[1::2], np.float64)
    if np.any(hi < lo):
        raise CloudError("workspace", "each max must be >= its min ([xmin, xmax, ymin, ymax, zmin, zmax])")
    return np.all((points >= lo) & (points <= hi), axis=1)


def range_limit(points: NDArray[np.floating], camera_source: NDArray[np.int32], viewpoints: NDArray[np.floating],
                window: float) -> tuple[NDArray[np.floating], float]:
    """Each point's range from the camera that saw it (N,) and the farthest range kept by a range window of
    `window` m beyond the near end of the scene (the NEAR_QUANTILE range): depth noise grows with range, so far,
    sparse points (a room behind the table) are the least reliable, and a hand rarely reaches them."""
    pts = np.asarray(points)
    cams = np.asarray(viewpoints, pts.dtype).reshape(-1, 3)
    ranges = np.empty(len(pts), pts.dtype if pts.dtype.kind == "f" else np.float64)
    for a in range(0, len(pts), RANGE_CHUNK):  # in blocks: no (N,3) temporary for a 5M-point cloud
        rel = pts[a:a + RANGE_CHUNK] - (cams[0] if len(cams) == 1 else cams[camera_source[a:a + RANGE_CHUNK]])
        ranges[a:a + RANGE_CHUNK] = np.sqrt(np.einsum("ij,ij->i", rel, rel))
    if len(ranges) == 0:
        return ranges, float("inf")
    sample = ranges[:: max(1, len(ranges) // RANGE_SAMPLE)]  # the quantile of every k-th point: a 5M cloud is
    sample = sample[np.isfinite(sample)]  # not sorted whole; non-finite points have no range
    if len(sample) == 0:
        return ranges, float("inf")
    return ranges, float(np.quantile(sample, NEAR_QUANTILE)) + window


def spans_window(points: NDArray[np.floating], window: float) -> bool:
    """Whether a range window of `window` m could leave any of points (N,3, m) out: only when their bounds'
    diagonal is longer than it (ranges from any camera differ by at most that); a tabletop cloud never pays for
    the ranges.  True when the bounds are not finite."""
    if len(points) == 0:
        return False
    lo, hi = np.min(points, axis=0), np.max(points, axis=0)
    diagonal = float(np.linalg.norm(np.asarray(hi, np.float64) - lo))
    return not np.isfinite(diagonal) or diagonal > window


def region_mask(cloud: ViewpointCloud, workspace: Workspace | None, range_window: float) -> NDArray[np.bool_]:
    """The points (finite ones) a detection works on: those inside the workspace box when one is given, else,
    with range_window > 0, those within the range window (range_limit); else all finite points."""
    mask = np.asarray(np.isfinite(cloud.points).all(axis=1), bool)
    if workspace is not None:
        return mask & crop_mask(cloud.points, workspace)
    if range_window > 0.0 and mask.any() and spans_window(cloud.points, range_window):
        ranges, far = range_limit(cloud.points, cloud.camera_source, cloud.viewpoints, range_window)
        mask &= ranges <= far  # a non-finite point's NaN range compares False
    return mask


def voxelize(points: NDArray[np.float32], camera_source: NDArray[np.int32], voxel_size: float,
             normals: NDArray[np.float32] | None = None
             ) -> tuple[NDArray[np.float32], NDArray[np.int32], NDArray[np.float32] | None]:
    """Mean point per occupied voxel (graspd.core.points.voxel_groups); the camera of a voxel is the one that saw
    most of its points."""
    inverse, counts = voxel_groups(points, voxel_size)
    m = counts.shape[0]
    sums = np.stack([np.bincount(inverse, points[:, k], m) for k in range(3)], axis=1)
    out_pts: NDArray[np.float32] = (sums / counts[:, None]).astype(np.float32)
    ncam = int(camera_source.max()) + 1 if camera_source.size else 1
    votes = np.bincount(inverse * ncam + camera_source, minlength=m * ncam).reshape(m, ncam)
    out_src = np.argmax(votes, axis=1).astype(np.int32)
    out_nrm = None
    if normals is not None:
        nsum = np.stack([np.bincount(inverse, normals[:, k], m) for k in range(3)], axis=1)
        out_nrm = (nsum / np.maximum(np.linalg.norm(nsum, axis=1, keepdims=True), 1e-12)).astype(np.float32)
    return out_pts, out_src.astype(np.int32), out_nrm


def estimate_normals(points: NDArray[np.float32], radius: float, max_nn: int) -> NDArray[np.float32]:
    """Unit surface normals (N,3) by local PCA over a hybrid radius/kNN neighbourhood (unoriented;
    graspd.core.points.pca_normals)."""
    return pca_normals(points, radius, max_nn)


def orient_toward_cameras(points: NDArray[np.float32], normals: NDArray[np.float32],
                          camera_source: NDArray[np.int32], viewpoints: NDArray[np.float32]) -> NDArray[np.float32]:
    """Flip each normal to point toward the camera that saw its point (outward for a visible surface)."""
    to_cam = viewpoints[camera_source] - points
    flip = np.einsum("ij,ij->i", normals, to_cam) < 0.0
    out = normals.copy()
    out[flip] *= -1.0
    return out


def preprocess(cloud: ViewpointCloud, params: PreprocessParams | None = None) -> ViewpointCloud:
    """Keep the finite points of the region (region_mask: the workspace, else the range window), voxelize,
    remove outliers, and give every point an oriented normal."""
    p = params or PreprocessParams()
    keep = region_mask(cloud, p.workspace, p.range_window)
    if cloud.normals is not None:
        keep &= np.asarray(np.isfinite(cloud.normals).all(axis=1), bool)
    c = cloud.select(keep) if not keep.all() else cloud
    if len(c) == 0:
        return c.__class__(points=np.zeros((0, 3), np.float32), viewpoints=c.viewpoints,
                           normals=np.zeros((0, 3), np.float32))
    pts, src, nrm = c.points, c.camera_source, c.normals
    if p.voxel_size > 0.0 and len(pts) > 1 and bool(np.all(np.ptp(pts, axis=0) < p.voxel_size)):
        pts, src = pts[:1], src[:1]  # every point in about one voxel (millions of zeros): one point, no grid
        nrm = None if nrm is None else nrm[:1]
    elif p.voxel_size > 0.0:
        pts, src, nrm = voxelize(pts, src, p.voxel_size, nrm)
    if p.remove_outliers and len(pts) > p.outlier_neighbors:
        keep_idx = statistical_inliers(pts, p.outlier_neighbors, p.outlier_std_ratio)
        pts, src = pts[keep_idx], src[keep_idx]
        nrm = None if nrm is None else nrm[keep_idx]
    if nrm is None or p.recompute_normals:
        nrm = estimate_normals(pts, p.normal_radius, p.normal_max_nn) if len(pts) >= 3 else np.zeros_like(pts)
    nrm = orient_toward_cameras(pts, nrm, src, c.viewpoints)
    return ViewpointCloud(points=pts, viewpoints=c.viewpoints, camera_source=src, normals=nrm)


def support_plane_mask(points: NDArray[np.float32], distance: float = 0.01, min_fraction: float = 0.2,
                       seed: int = 0) -> NDArray[np.bool_]:
    """Points within `distance` (m) of the dominant plane (RANSAC), if that plane holds at least
    min_fraction of the cloud; else all False.  Used to keep samples off the table."""
    mask = np.zeros(len(points), bool)
    if len(points) < 3:
        return mask
    model, inliers = ransac_plane(points, distance, iterations=200, seed=seed)
    if inliers >= min_fraction * len(points):
        # the least-squares plane of the best hypothesis' inliers: take every point within distance of it
        mask = np.abs(points.astype(np.float64) @ model[:3] + model[3]) <= distance
    return mask
