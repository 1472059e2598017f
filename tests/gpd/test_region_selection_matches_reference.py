"""preprocess selects its region by one compiled pass (preprocess.region: finite points and normals, the workspace
box or the range window, the kept points' bounds) and voxelizes through that mask instead of a copy.  Checked
here against the straightforward numpy selection written in the test (isfinite, the box, einsum ranges and their
near quantile, cloud.select) followed by the same voxelize and normals: the same points, cameras and normals,
bit for bit, on clouds with non-finite points and normals."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest
from numpy.typing import NDArray

from graspd.core.cloud import ViewpointCloud
from graspd.gpd.preprocess import (
    NEAR_QUANTILE,
    RANGE_SAMPLE,
    PreprocessParams,
    estimate_normals,
    orient_toward_cameras,
    preprocess,
    range_limit,
    region_mask,
    voxelize,
)


def numpy_ranges(cloud: ViewpointCloud) -> NDArray[np.float32]:
    rel = cloud.points - cloud.viewpoints[cloud.camera_source]
    return np.asarray(np.sqrt(np.einsum("ij,ij->i", rel, rel)))


def numpy_region(cloud: ViewpointCloud, workspace: Any, window: float) -> NDArray[np.bool_]:
    """The region as numpy computes it: finite rows, the box, else the ranges within window of the near quantile
    (over every k-th point's range) when the bounds' diagonal exceeds the window."""
    pts = cloud.points
    mask = np.isfinite(pts).all(axis=1)
    if workspace is not None:
        lo, hi = np.array(workspace[0::2]), np.array(workspace[1::2])
        return mask & np.all((pts >= lo) & (pts <= hi), axis=1)
    if window > 0.0 and mask.any():
        lo, hi = pts.min(axis=0), pts.max(axis=0)
        diagonal = float(np.linalg.norm(hi.astype(np.float64) - lo))
        if not np.isfinite(diagonal) or diagonal > window:
            ranges = numpy_ranges(cloud)
            sample = ranges[:: max(1, len(ranges) // RANGE_SAMPLE)]
            sample = sample[np.isfinite(sample)]
            far = float(np.quantile(sample, NEAR_QUANTILE)) + window
            mask &= ranges <= far
    return mask


def numpy_preprocess(cloud: ViewpointCloud, p: PreprocessParams) -> ViewpointCloud:
    """preprocess with the region selected by numpy and copied (cloud.select) before voxelize."""
    keep = numpy_region(cloud, p.workspace, p.range_window)
    if cloud.normals is not None:
        keep &= np.isfinite(cloud.normals).all(axis=1)
    c = cloud.select(keep)
    if len(c) == 0:
        return ViewpointCloud(points=np.zeros((0, 3), np.float32), viewpoints=c.viewpoints,
                              normals=np.zeros((0, 3), np.float32))
    pts, src, nrm = c.points, c.camera_source, c.normals
    if p.voxel_size > 0.0 and len(pts) > 1 and bool(np.all(np.ptp(pts, axis=0) < p.voxel_size)):
        pts, src, nrm = pts[:1], src[:1], None if nrm is None else nrm[:1]
    elif p.voxel_size > 0.0:
        pts, src, nrm = voxelize(pts, src, p.voxel_size, nrm)
    if nrm is None:
        nrm = estimate_normals(pts, p.normal_radius, p.normal_max_nn) if len(pts) >= 3 else np.zeros_like(pts)
    nrm = orient_toward_cameras(pts, nrm, src, c.viewpoints)
    return ViewpointCloud(points=pts, viewpoints=c.viewpoints, camera_source=src, normals=nrm)


def scene(n: int = 120_000, seed: int = 0, with_normals: bool = False) -> ViewpointCloud:
    """A table 0.7-0.9 m from two cameras, a box on it and a wall 2.5 m away; some rows NaN or inf, and (with
    normals) some NaN normals."""
    rng = np.random.default_rng(seed)
    k = n // 3
    table = np.c_[rng.uniform(-0.4, 0.4, k), rng.uniform(-0.3, 0.3, k), rng.uniform(0.7, 0.9, k)]
    box = np.c_[rng.uniform(-0.05, 0.05, k), rng.uniform(-0.05, 0.05, k), rng.uniform(0.6, 0.7, k)]
    wall = np.c_[rng.uniform(-1.5, 1.5, n - 2 * k), rng.uniform(-1.0, 1.0, n - 2 * k), np.full(n - 2 * k, 2.5)]
    pts = (np.concatenate([table, box, wall]) + rng.normal(0.0, 5e-4, (n, 3))).astype(np.float32)
    pts[rng.choice(n, 300, replace=False)] = np.nan
    pts[rng.choice(n, 50, replace=False), rng.integers(0, 3, 50)] = np.inf
    normals = None
    if with_normals:
        normals = rng.normal(size=(n, 3)).astype(np.float32)
        normals[rng.choice(n, 200, replace=False), 1] = np.nan
    return ViewpointCloud(points=pts, viewpoints=np.float32([[0.1, 0.0, 0.0], [-0.3, 0.1, -0.2]]),
                          camera_source=rng.integers(0, 2, n).astype(np.int32), normals=normals)


def assert_same(a: ViewpointCloud, b: ViewpointCloud) -> None:
    assert np.array_equal(a.points, b.points)
    assert np.array_equal(a.camera_source, b.camera_source)
    assert a.normals is not None and b.normals is not None and np.array_equal(a.normals, b.normals)
    assert np.array_equal(a.viewpoints, b.viewpoints)


@pytest.mark.parametrize("params", [
    PreprocessParams(),
    PreprocessParams(workspace=(-0.3, 0.3, -0.2, 0.2, 0.5, 0.85)),
    PreprocessParams(range_window=1.0),
    PreprocessParams(range_window=0.5, voxel_size=0.005),
    PreprocessParams(voxel_size=0.0, workspace=(-0.05, 0.05, -0.05, 0.05, 0.6, 0.7)),
])
@pytest.mark.parametrize("with_normals", [False, True])
def test_preprocess_matches_numpy_selection(params: PreprocessParams, with_normals: bool) -> None:
    cloud = scene(with_normals=with_normals)
    assert np.array_equal(region_mask(cloud, params.workspace, params.range_window),
                          numpy_region(cloud, params.workspace, params.range_window))
    assert_same(preprocess(cloud, params), numpy_preprocess(cloud, params))


def test_range_window_applies_and_ranges_match_numpy() -> None:
    cloud = scene(seed=1)
    ranges, far = range_limit(cloud.points, cloud.camera_source, cloud.viewpoints, 1.0)
    assert np.array_equal(ranges, numpy_ranges(cloud), equal_nan=True)
    mask = region_mask(cloud, None, 1.0)
    finite = np.isfinite(cloud.points).all(axis=1)
    assert 0 < mask.sum() < finite.sum()  # the wall goes
    assert np.array_equal(mask, finite & (ranges <= far))


def test_one_voxel_and_nothing_kept() -> None:
    rng = np.random.default_rng(2)
    pts = (np.float32([0.2, -0.1, 0.8]) + rng.uniform(0, 1e-4, (5000, 3))).astype(np.float32)
    pts[:3] = np.nan  # the first kept point is row 3
    cloud = ViewpointCloud(points=pts, viewpoints=np.zeros(3, np.float32))
    out = preprocess(cloud)
    assert np.array_equal(out.points, pts[3:4])
    assert_same(out, numpy_preprocess(cloud, PreprocessParams()))
    empty = preprocess(cloud, PreprocessParams(workspace=(1.0, 2.0, 1.0, 2.0, 1.0, 2.0)))
    assert len(empty) == 0 and empty.normals is not None and empty.normals.shape == (0, 3)


def test_all_non_finite_and_one_point() -> None:
    nan = ViewpointCloud(points=np.full((10, 3), np.nan, np.float32), viewpoints=np.zeros(3, np.float32))
    assert len(preprocess(nan, PreprocessParams(range_window=1.0))) == 0
    one = ViewpointCloud(points=np.float32([[0.1, 0.2, 0.7], [np.nan, 0, 0]]), viewpoints=np.zeros(3, np.float32))
    assert_same(preprocess(one), numpy_preprocess(one, PreprocessParams()))
