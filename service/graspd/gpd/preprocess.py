"""Step 1 of Algorithm 1: clean a viewpoint cloud and estimate camera-facing surface normals (numpy, scipy)."""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from graspd.core.cloud import CloudError, ViewpointCloud
from graspd.core.grid import clean_normals
from graspd.core.jit import kernel
from graspd.core.points import pca_normals, ransac_plane, statistical_inliers, voxel_sums

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


def _box(workspace: Workspace) -> NDArray[np.float64]:
    """The workspace as (2,3) [[xmin, ymin, zmin], [xmax, ymax, zmax]] (m), checked."""
    box = np.array([workspace[0::2], workspace[1::2]], np.float64)
    if np.any(box[1] < box[0]):
        raise CloudError("workspace", "each max must be >= its min ([xmin, xmax, ymin, ymax, zmin, zmax])")
    return box


def crop_mask(points: NDArray[np.floating], workspace: Workspace) -> NDArray[np.bool_]:
    """Points inside the axis-aligned box [xmin, xmax, ymin, ymax, zmin, zmax]."""
    box = _box(workspace)
    return np.all((points >= box[0]) & (points <= box[1]), axis=1)


@kernel
def _ranges(points: NDArray[np.floating], source: NDArray[np.int32], cams: NDArray[np.floating],
            out: NDArray[np.floating]) -> None:
    """out[i] = |points[i] - its camera| in the points' dtype, summed x, y, z in order (numpy's einsum)."""
    single = cams.shape[0] == 1
    for i in range(points.shape[0]):
        c = 0 if single else source[i]
        rx, ry, rz = points[i, 0] - cams[c, 0], points[i, 1] - cams[c, 1], points[i, 2] - cams[c, 2]
        out[i] = np.sqrt(rx * rx + ry * ry + rz * rz)


@kernel
def _region_pass(points: NDArray[np.floating], normals: NDArray[np.float32], box: NDArray[np.float64],
                 use_box: bool, keep: NDArray[np.bool_]
                 ) -> tuple[int, int, NDArray[np.floating], NDArray[np.floating], NDArray[np.floating],
                            NDArray[np.floating]]:
    """One pass over points (N,3) for the region: keep[i] = the point is finite, so are its normals (when normals
    is (N,3)), and it lies in box (2,3) when use_box.  Returns the finite points' count, the kept count, the
    finite points' bounds (lo, hi) and the kept ones' (in the points' dtype; +-inf when none)."""
    n = points.shape[0]
    with_normals = normals.shape[0] == n
    flo = np.full(3, np.inf, points.dtype)
    fhi = np.full(3, -np.inf, points.dtype)
    klo = np.full(3, np.inf, points.dtype)
    khi = np.full(3, -np.inf, points.dtype)
    finite = 0
    count = 0
    for i in range(n):
        x, y, z = points[i, 0], points[i, 1], points[i, 2]
        ok = np.isfinite(x) and np.isfinite(y) and np.isfinite(z)
        if ok:
            finite += 1
            flo[0], flo[1], flo[2] = min(flo[0], x), min(flo[1], y), min(flo[2], z)
            fhi[0], fhi[1], fhi[2] = max(fhi[0], x), max(fhi[1], y), max(fhi[2], z)
            if with_normals:
                ok = np.isfinite(normals[i, 0]) and np.isfinite(normals[i, 1]) and np.isfinite(normals[i, 2])
            if use_box:
                ok = ok and box[0, 0] <= x <= box[1, 0] and box[0, 1] <= y <= box[1, 1] and box[0, 2] <= z <= box[1, 2]
        keep[i] = ok
        if ok:
            count += 1
            klo[0], klo[1], klo[2] = min(klo[0], x), min(klo[1], y), min(klo[2], z)
            khi[0], khi[1], khi[2] = max(khi[0], x), max(khi[1], y), max(khi[2], z)
    return finite, count, flo, fhi, klo, khi


@kernel
def _range_pass(points: NDArray[np.floating], source: NDArray[np.int32], cams: NDArray[np.floating], far: Any,
                keep: NDArray[np.bool_]) -> tuple[int, NDArray[np.floating], NDArray[np.floating]]:
    """keep[i] &= the point's range (_ranges' arithmetic) <= far (a scalar of the points' dtype: numpy compares an
    array with a Python float in the array's dtype); returns the kept count and bounds."""
    single = cams.shape[0] == 1
    lo = np.full(3, np.inf, points.dtype)
    hi = np.full(3, -np.inf, points.dtype)
    count = 0
    for i in range(points.shape[0]):
        if not keep[i]:
            continue
        c = 0 if single else source[i]
        x, y, z = points[i, 0], points[i, 1], points[i, 2]
        rx, ry, rz = x - cams[c, 0], y - cams[c, 1], z - cams[c, 2]
        if not np.sqrt(rx * rx + ry * ry + rz * rz) <= far:
            keep[i] = False
            continue
        count += 1
        lo[0], lo[1], lo[2] = min(lo[0], x), min(lo[1], y), min(lo[2], z)
        hi[0], hi[1], hi[2] = max(hi[0], x), max(hi[1], y), max(hi[2], z)
    return count, lo, hi


def range_limit(points: NDArray[np.floating], camera_source: NDArray[np.int32], viewpoints: NDArray[np.floating],
                window: float) -> tuple[NDArray[np.floating], float]:
    """Each point's range from the camera that saw it (N,) and the farthest range kept by a range window of
    `window` m beyond the near end of the scene (the NEAR_QUANTILE range): depth noise grows with range, so far,
    sparse points (a room behind the table) are the least reliable, and a hand rarely reaches them."""
    pts = np.asarray(points)
    pts = np.ascontiguousarray(pts if pts.dtype in (np.float32, np.float64) else pts.astype(np.float64))
    cams = np.ascontiguousarray(np.asarray(viewpoints, pts.dtype).reshape(-1, 3))
    ranges = np.empty(len(pts), pts.dtype)
    _ranges(pts, np.ascontiguousarray(camera_source, np.int32), cams, ranges)  # one compiled pass
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


@dataclass(frozen=True)
class Region:
    """The points a detection works on (region_mask): mask (N,), how many it keeps and their bounds lo, hi (3,
    the points' dtype; +-inf when none)."""

    mask: NDArray[np.bool_]
    count: int
    lo: NDArray[np.floating]
    hi: NDArray[np.floating]


def region(cloud: ViewpointCloud, workspace: Workspace | None, range_window: float, finite_normals: bool = False
           ) -> Region:
    """region_mask with its count and bounds, in one compiled pass over the cloud (two with a range window that
    applies: the near range comes from a sample first); finite_normals also leaves out points whose normals are
    not finite (preprocess's selection)."""
    pts = cloud.points
    box = np.zeros((2, 3)) if workspace is None else _box(workspace)
    normals = cloud.normals if finite_normals and cloud.normals is not None else np.zeros((0, 3), np.float32)
    mask = np.empty(len(pts), np.bool_)
    finite, count, flo, fhi, lo, hi = _region_pass(pts, normals, box, workspace is not None, mask)
    if workspace is None and range_window > 0.0 and finite:
        diagonal = float(np.linalg.norm(np.asarray(fhi, np.float64) - flo))  # spans_window on the bounds
        if finite < len(pts) or not np.isfinite(diagonal) or diagonal > range_window:
            step = max(1, len(pts) // RANGE_SAMPLE)  # range_limit's sample: its ranges only
            sample = np.arange(0, len(pts), step)
            _, far = range_limit(pts[sample], cloud.camera_source[sample], cloud.viewpoints, range_window)
            count, lo, hi = _range_pass(pts, cloud.camera_source, cloud.viewpoints, pts.dtype.type(far), mask)
    return Region(mask, int(count), lo, hi)


def region_mask(cloud: ViewpointCloud, workspace: Workspace | None, range_window: float) -> NDArray[np.bool_]:
    """The points (finite ones) a detection works on: those inside the workspace box when one is given, else,
    with range_window > 0, those within the range window (range_limit, when spans_window says it could leave any
    out); else all finite points."""
    return region(cloud, workspace, range_window).mask


def voxelize(points: NDArray[np.float32], camera_source: NDArray[np.int32], voxel_size: float,
             normals: NDArray[np.float32] | None = None
             ) -> tuple[NDArray[np.float32], NDArray[np.int32], NDArray[np.float32] | None]:
    """Mean point per occupied voxel (graspd.core.points.voxel_groups' grid and order); the camera of a voxel is
    the one that saw most of its points (the lowest index on a tie); the mean normal, normalised, when normals are
    given.  One compiled pass over the points (graspd.core.points.voxel_sums)."""
    return _voxel_means(points, camera_source, voxel_size, normals)


def _voxel_means(points: NDArray[np.float32], camera_source: NDArray[np.int32], voxel_size: float,
                 normals: NDArray[np.float32] | None, keep: NDArray[np.bool_] | None = None
                 ) -> tuple[NDArray[np.float32], NDArray[np.int32], NDArray[np.float32] | None]:
    """voxelize of the points keep (N,) flags (all when None), without selecting them first."""
    rows, _ = voxel_sums(points, voxel_size, camera_source, normals, keep=keep)
    out_pts: NDArray[np.float32] = (rows[:, 1:4] / rows[:, :1]).astype(np.float32)
    votes = rows[:, 4 if normals is None else 7:]
    out_src = np.argmax(votes, axis=1).astype(np.int32) if votes.shape[1] else np.zeros(len(rows), np.int32)
    out_nrm = None
    if normals is not None:
        nsum = rows[:, 4:7]
        out_nrm = (nsum / np.maximum(np.linalg.norm(nsum, axis=1, keepdims=True), 1e-12)).astype(np.float32)
    return out_pts, out_src, out_nrm


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


def organised(cloud: ViewpointCloud, kept: Region, p: PreprocessParams) -> tuple[ViewpointCloud, Region]:
    """An organised cloud's region without its mixed (flying) pixels (graspd.core.grid.veil_points), and with
    normals from its image neighbours (graspd.core.grid.grid_normals, toward the camera; per point, so voxelize
    averages them) unless the cloud brought its own or recompute_normals is set; points with no usable image
    neighbour along a row or a column (isolated pixels) are left out with them.  The bounds stay the region's
    (a box around what is kept: preprocess asks only whether everything lies in one voxel)."""
    assert cloud.grid is not None
    estimate = cloud.normals is None or p.recompute_normals
    mixed, normals = clean_normals(cloud.points, cloud.camera_source, cloud.viewpoints, cloud.grid,
                                   p.normal_radius if estimate else None, kept.mask)
    mask = kept.mask & ~mixed
    if normals is not None:
        mask &= np.isfinite(normals[:, 0])
        cloud = replace(cloud, normals=normals)
    return cloud, Region(mask, int(np.count_nonzero(mask)), kept.lo, kept.hi)


def preprocess(cloud: ViewpointCloud, params: PreprocessParams | None = None) -> ViewpointCloud:
    """Keep the finite points of the region (region_mask: the workspace, else the range window) whose normals, if
    given, are finite too; voxelize, remove outliers, and give every point an oriented normal.  The selection is
    a mask voxelize reads through (region, one pass for the mask and the kept points' bounds): a 5M-point cloud
    is not copied first.  An organised cloud (one with a grid) loses its mixed pixels first and takes its normals
    from the grid (organised)."""
    p = params or PreprocessParams()
    kept = region(cloud, p.workspace, p.range_window, finite_normals=True)
    if cloud.grid is not None and kept.count:
        cloud, kept = organised(cloud, kept, p)
    if kept.count == 0:
        return cloud.__class__(points=np.zeros((0, 3), np.float32), viewpoints=cloud.viewpoints,
                               normals=np.zeros((0, 3), np.float32))
    keep = None if kept.count == len(cloud) else kept.mask
    if p.voxel_size > 0.0 and kept.count > 1 and bool(np.all(kept.hi - kept.lo < p.voxel_size)):
        first = int(np.argmax(kept.mask))  # every point in about one voxel (millions of zeros): one point, no grid
        pts, src = cloud.points[first:first + 1], cloud.camera_source[first:first + 1]
        nrm = None if cloud.normals is None else cloud.normals[first:first + 1]
    elif p.voxel_size > 0.0:
        pts, src, nrm = _voxel_means(cloud.points, cloud.camera_source, p.voxel_size, cloud.normals, keep)
    else:
        c = cloud if keep is None else cloud.select(keep)
        pts, src, nrm = c.points, c.camera_source, c.normals
    if p.remove_outliers and len(pts) > p.outlier_neighbors:
        keep_idx = statistical_inliers(pts, p.outlier_neighbors, p.outlier_std_ratio)
        pts, src = pts[keep_idx], src[keep_idx]
        nrm = None if nrm is None else nrm[keep_idx]
    if nrm is None or (p.recompute_normals and cloud.grid is None):
        nrm = estimate_normals(pts, p.normal_radius, p.normal_max_nn) if len(pts) >= 3 else np.zeros_like(pts)
    nrm = orient_toward_cameras(pts, nrm, src, cloud.viewpoints)
    return ViewpointCloud(points=pts, viewpoints=cloud.viewpoints, camera_source=src, normals=nrm)


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
