"""Which camera saw each point, when a merged cloud lost that: the nearest camera position.  Computed a block of
points and one camera at a time (a running minimum), so memory stays O(N) whatever the count of cameras: an
N x K x 3 array of differences would take gigabytes for a large cloud seen by many cameras."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

#: Points handled at a time: the temporaries are a few arrays of this many rows (~1.5 MB in float64).
BLOCK_ROWS = 1 << 16


def nearest_camera(points: NDArray[np.floating], viewpoints: NDArray[np.floating]) -> NDArray[np.int32]:
    """Index of the closest camera (viewpoints (K,3), m) for each point (N,3): the first of equally close ones.
    The distances are those of np.linalg.norm in the arithmetic of the two arrays' common dtype, so the answer is
    the argmin of the full N x K distance table, without building it."""
    pts = np.asarray(points)
    cams = np.asarray(viewpoints).reshape(-1, 3)
    out = np.zeros(len(pts), np.int32)
    if len(cams) < 2:
        return out
    dtype = np.result_type(pts.dtype, cams.dtype)  # the arithmetic of points - viewpoints
    for start in range(0, len(pts), BLOCK_ROWS):
        block = pts[start:start + BLOCK_ROWS]
        columns = [np.ascontiguousarray(block[:, j], dtype) for j in range(3)]
        index = out[start:start + BLOCK_ROWS]
        best: NDArray[np.floating] | None = None
        for k in range(len(cams)):
            # (dx² + dy²) + dz², then the root: np.linalg.norm's own order, so equal rows tie as they did
            dx, dy, dz = (columns[j] - cams[k, j] for j in range(3))
            dist = np.sqrt(dx * dx + dy * dy + dz * dz)
            if best is None:
                best = dist
                continue
            closer = dist < best  # strictly: the first of equally close cameras keeps the point, as argmin does
            best[closer] = dist[closer]
            index[closer] = k
    return out
