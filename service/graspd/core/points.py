"""Point-set helpers shared by the renderers' consumers: one voxel downsampling."""

from __future__ import annotations

from typing import TypeVar

import numpy as np
from numpy.typing import NDArray

FloatArray = TypeVar("FloatArray", NDArray[np.float32], NDArray[np.float64])


def voxel_groups(points: NDArray[np.floating], voxel: float) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
    """The one voxel grid: for points (N,3, m, any frame, N > 0) the index of the occupied voxel of edge voxel
    (m) each falls in, voxels ordered by grid index (x, then y, then z; keyed in the points' dtype), and each
    voxel's point count (M,)."""
    grid = np.floor(points / voxel).astype(np.int64)
    grid -= grid.min(axis=0)
    dims = grid.max(axis=0) + 1
    keys = (grid[:, 0] * dims[1] + grid[:, 1]) * dims[2] + grid[:, 2]
    _, inverse, counts = np.unique(keys, return_inverse=True, return_counts=True)
    return inverse.reshape(-1), counts


def voxel_downsample(points: FloatArray, voxel: float) -> FloatArray:
    """One point (the mean) per occupied voxel of voxel_groups, in the input's dtype.  graspd.gpd.preprocess
    .voxelize is the same with cameras and normals; points (N,3) in any frame."""
    if len(points) == 0:
        return points
    inv, counts = voxel_groups(points, voxel)
    sums = np.stack([np.bincount(inv, points[:, k], len(counts)) for k in range(3)], axis=1)
    return np.asarray(sums / counts[:, None]).astype(points.dtype, copy=False)
