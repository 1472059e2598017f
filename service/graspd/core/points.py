"""Point-set helpers shared by the renderers' consumers: one voxel downsampling."""

from __future__ import annotations

from typing import TypeVar

import numpy as np
from numpy.typing import NDArray

FloatArray = TypeVar("FloatArray", NDArray[np.float32], NDArray[np.float64])


def voxel_downsample(points: FloatArray, voxel: float) -> FloatArray:
    """One point (the mean) per occupied voxel of edge voxel (m), in the input's dtype (voxels keyed in it
    too), ordered by voxel index (x, then y, then z).  Like graspd.gpd.preprocess.voxelize without cameras or
    normals; points (N,3) in any frame."""
    if len(points) == 0:
        return points
    keys = np.floor(points / voxel).astype(np.int64)
    _, inv, counts = np.unique(keys, axis=0, return_inverse=True, return_counts=True)
    inv = inv.reshape(-1)
    sums = np.stack([np.bincount(inv, points[:, k]) for k in range(3)], axis=1)
    return np.asarray(sums / counts[:, None]).astype(points.dtype, copy=False)
