"""Point-set geometry every layer shares, numpy and scipy only: the one voxel grid, PCA normals, statistical
outlier removal, a seeded RANSAC plane and distance clusters."""

from __future__ import annotations

from typing import TypeVar

import numpy as np
from numpy.typing import NDArray
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from graspd.core.parallel import THREADS

FloatArray = TypeVar("FloatArray", NDArray[np.float32], NDArray[np.float64])


#: Grids of at most this many cells are counted densely by voxel_groups (8 bytes a cell, transiently), larger
#: ones by sorting the points' cell keys.
DENSE_VOXEL_CELLS = 1 << 22


def voxel_groups(points: NDArray[np.floating], voxel: float) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
    """The one voxel grid: for points (N,3, m, any frame, N > 0) the index of the occupied voxel of edge voxel
    (m) each falls in, voxels ordered by grid index (x, then y, then z; keyed in the points' dtype), and each
    voxel's point count (M,)."""
    grid = np.floor(points / voxel).astype(np.int64)
    grid -= grid.min(axis=0)
    dims = grid.max(axis=0) + 1
    cells = int(dims[0]) * int(dims[1]) * int(dims[2])  # Python ints: a cloud metres wide overflows int64
    if cells >= 1 << 62:  # no int64 key fits: the rows themselves, in the same x, y, z order
        _, inverse, counts = np.unique(grid, axis=0, return_inverse=True, return_counts=True)
        return inverse.reshape(-1), counts
    keys = (grid[:, 0] * dims[1] + grid[:, 1]) * dims[2] + grid[:, 2]
    if cells <= DENSE_VOXEL_CELLS:  # count into the grid itself: the same voxels, order and counts, no sort
        dense = np.bincount(keys, minlength=cells)
        occupied = np.flatnonzero(dense)
        rank = np.empty(cells, np.intp)
        rank[occupied] = np.arange(len(occupied))
        return rank[keys], dense[occupied]
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


def _padded(points: NDArray[np.floating]) -> NDArray[np.float64]:
    """points as float64 with one extra row of zeros: the row cKDTree's 'no neighbour' index (N) gathers."""
    return np.vstack([np.asarray(points, np.float64), np.zeros((1, 3))])


#: Points whose normals one task of pca_normals computes (tasks run on the process's thread budget).
NORMALS_CHUNK = 4096


def pca_normals(points: NDArray[np.floating], radius: float, max_nn: int, chunk: int = NORMALS_CHUNK
                ) -> NDArray[np.float32]:
    """Unit surface normals (N,3), unoriented: the least-variance axis of each point's neighbourhood, the at most
    max_nn nearest points within radius (m; the point itself included: open3d's hybrid search).  (0, 0, 1)
    where fewer than 3 neighbours or a degenerate neighbourhood.  Vectorised over chunks of points, which run on
    the process's thread budget (graspd.core.parallel; each point's normal depends on its neighbours alone)."""
    pts = np.asarray(points, np.float64)
    out = np.tile(np.array([0.0, 0.0, 1.0], np.float32), (len(pts), 1))
    if len(pts) < 3:
        return out
    tree = cKDTree(pts, balanced_tree=False)  # built 4x faster; the nearest neighbours are the same
    padded = _padded(pts)
    k = min(max_nn, len(pts))

    def normals_of(start: int) -> None:
        dist, idx = tree.query(pts[start:start + chunk], k=k, distance_upper_bound=radius * (1 + 1e-12))
        idx = idx.reshape(len(idx), k)
        count = np.isfinite(dist.reshape(len(idx), k)).sum(axis=1)
        nb = padded[idx]  # missing neighbours gather the zero row: they add nothing to the sums
        n = np.maximum(count, 1)[:, None]
        mean = nb.sum(axis=1) / n
        cov = np.matmul(nb.transpose(0, 2, 1), nb) / n[:, :, None] - mean[:, :, None] * mean[:, None, :]
        evals, evecs = np.linalg.eigh(cov)
        ok = (count >= 3) & (evals[:, 2] > 0.0)
        out[start:start + chunk][ok] = evecs[ok, :, 0].astype(np.float32)

    THREADS.map(normals_of, range(0, len(pts), chunk))
    return out


def statistical_inliers(points: NDArray[np.floating], neighbours: int, std_ratio: float) -> NDArray[np.int64]:
    """Indices of the points whose mean distance to their `neighbours` nearest points (itself included) is
    positive and below the cloud's mean of it plus std_ratio standard deviations (open3d's statistical outlier
    removal).  Needs more points than neighbours."""
    pts = np.asarray(points, np.float64)
    dist, _ = cKDTree(pts).query(pts, k=neighbours)
    mean = dist.reshape(len(pts), -1).mean(axis=1)
    valid = mean > 0.0
    if valid.sum() < 2:
        return np.flatnonzero(valid)
    threshold = mean[valid].mean() + std_ratio * mean[valid].std(ddof=1)
    return np.flatnonzero(valid & (mean < threshold))


def ransac_plane(points: NDArray[np.floating], distance: float, iterations: int = 200, seed: int = 0,
                 batch: int = 25) -> tuple[NDArray[np.float64], int]:
    """The plane (a, b, c, d; unit normal, a x + b y + c z + d = 0) through the most points within distance
    (m) among `iterations` seeded 3-point hypotheses, refit by least squares to those points; and how many
    there were.  Hypotheses are scored in batches (a matrix product each).  Needs at least 3 points."""
    pts = np.asarray(points, np.float64)
    rng = np.random.default_rng(seed)
    tri = np.stack([rng.choice(len(pts), 3, replace=False) for _ in range(iterations)])
    p0, p1, p2 = pts[tri[:, 0]], pts[tri[:, 1]], pts[tri[:, 2]]
    normals = np.cross(p1 - p0, p2 - p0)
    norm = np.linalg.norm(normals, axis=1)
    good = norm > 1e-12
    normals, p0 = normals[good] / norm[good, None], p0[good]
    offsets = -np.einsum("ij,ij->i", normals, p0)
    best, best_count = -1, -1
    for start in range(0, len(normals), batch):
        counts = (np.abs(pts @ normals[start:start + batch].T + offsets[start:start + batch]) <= distance).sum(axis=0)
        i = int(np.argmax(counts)) if len(counts) else -1
        if i >= 0 and counts[i] > best_count:
            best, best_count = start + i, int(counts[i])
    if best < 0:
        return np.array([0.0, 0.0, 1.0, 0.0]), 0
    inliers = pts[np.abs(pts @ normals[best] + offsets[best]) <= distance]
    centre = inliers.mean(axis=0)
    _, vecs = np.linalg.eigh(np.cov((inliers - centre).T))
    normal = vecs[:, 0]
    return np.append(normal, -float(normal @ centre)), best_count


def eps_clusters(points: NDArray[np.floating], eps: float) -> NDArray[np.int64]:
    """A cluster label per point (N,): the connected components of the graph joining points at most eps (m)
    apart (DBSCAN with min_points 1)."""
    if len(points) == 0:
        return np.zeros(0, np.int64)
    pairs = cKDTree(np.asarray(points, np.float64)).query_pairs(eps, output_type="ndarray")
    graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(len(points), len(points)))
    _, labels = connected_components(graph, directed=False)
    return labels.astype(np.int64)
