"""Point-set geometry every layer shares (numpy, scipy, and compiled kernels for the per-point loops): the one
voxel grid, PCA normals, statistical outlier removal, a seeded RANSAC plane and distance clusters."""

from __future__ import annotations

from typing import Any, TypeVar

import numpy as np
from numpy.typing import NDArray
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from graspd.core.jit import kernel
from graspd.core.parallel import THREADS

FloatArray = TypeVar("FloatArray", NDArray[np.float32], NDArray[np.float64])


#: Grid indices are clamped to +-this: a coordinate more than 2^61 voxels from the origin (not a real cloud: 6.9e15 m
#: at 3 mm) falls in the edge voxel, and differences of two indices fit int64.
_GRID_LIMIT = float(1 << 61)
#: Points a slab of x holds at least when voxel_sums splits a cloud over the thread budget's threads (each slab's
#: thread reads every point, so a small cloud gains nothing from a split).
VOXEL_SLAB_POINTS = 1 << 20


@kernel
def _grid_index(c: float, voxel: float) -> np.int64:
    """floor(c / voxel) as int64, in the arithmetic of c's and voxel's dtype (float32 points: float32 division, as
    numpy's); clamped to +-2^61, NaN to 0, so that the cast is defined."""
    g = np.floor(c / voxel)
    if g >= -_GRID_LIMIT and g <= _GRID_LIMIT:
        return np.int64(g)
    if g < 0.0:
        return np.int64(-_GRID_LIMIT)
    return np.int64(_GRID_LIMIT) if g > 0.0 else np.int64(0)


@kernel
def _slot(x: int | np.int64, y: int | np.int64, z: int | np.int64, shift: int) -> np.int64:
    """Hash-table slot of voxel (x, y, z) in a table of 2^(64 - shift) slots (multiplicative hashing)."""
    h = (np.uint64(x) * np.uint64(0x9E3779B97F4A7C15) + np.uint64(y) * np.uint64(0xC2B2AE3D27D4EB4F)
         + np.uint64(z) * np.uint64(0x165667B19E3779F9))
    return np.int64(h >> np.uint64(shift))


@kernel
def _add_point(acc: NDArray[np.float64], v: int, i: int, points: NDArray[np.floating], normals: NDArray[np.float32],
               source: NDArray[np.int32], with_normals: bool, with_votes: bool, vote0: int) -> None:
    """Add point i to voxel v's row of acc: its count, coordinate sums, [normal sums,] and its camera's vote."""
    acc[v, 0] += 1.0
    acc[v, 1] += points[i, 0]
    acc[v, 2] += points[i, 1]
    acc[v, 3] += points[i, 2]
    if with_normals:
        acc[v, 4] += normals[i, 0]
        acc[v, 5] += normals[i, 1]
        acc[v, 6] += normals[i, 2]
    if with_votes:
        acc[v, vote0 + source[i]] += 1.0


@kernel
def _voxel_fill(points: NDArray[np.floating], voxel: float, source: NDArray[np.int32],
                normals: NDArray[np.float32], keep: NDArray[np.bool_], x_lo: int, x_hi: int, start: int,
                table: NDArray[np.int64], shift: int, acc: NDArray[np.float64], m: int, ids: NDArray[np.int64],
                id_stride: int, id_offset: int) -> tuple[int, int]:
    """Accumulate points start.. (those keep (N,) flags, where given) whose grid x index lies in [x_lo, x_hi] into
    their voxels: table (4S,) slots of x, y,
    z, voxel (-1: free; open addressing), acc (C,W) rows count, sum x, y, z, [normal sums x, y, z,] camera votes
    (float64; W says which), and where ids (N,) is given, each point's voxel v as v * id_stride + id_offset.
    Voxels are numbered as first met; each one's sums run in point order (numpy's bincount order: the same
    float64 sums).  Stops at the first point that finds the table half full or acc full: returns (that point,
    voxels so far); (N, voxels) when done."""
    n = points.shape[0]
    mask = (table.shape[0] >> 2) - 1
    limit = min(table.shape[0] >> 3, acc.shape[0])
    with_normals = normals.shape[0] == n
    vote0 = 7 if with_normals else 4
    with_votes = acc.shape[1] > vote0
    with_ids = ids.shape[0] == n
    with_keep = keep.shape[0] == n
    for i in range(start, n):
        if with_keep and not keep[i]:
            if with_ids:
                ids[i] = -1
            continue
        x = _grid_index(points[i, 0], voxel)
        if x < x_lo or x > x_hi:
            continue
        y = _grid_index(points[i, 1], voxel)
        z = _grid_index(points[i, 2], voxel)
        h = _slot(x, y, z, shift)
        while True:
            b = h << 2
            v = table[b + 3]
            if v < 0:
                if m == limit:
                    return i, m
                v = m
                table[b], table[b + 1], table[b + 2], table[b + 3] = x, y, z, v
                m += 1
                break
            if (table[b] == x) & (table[b + 1] == y) & (table[b + 2] == z):  # no branch per coordinate
                break
            h = (h + 1) & mask
        _add_point(acc, v, i, points, normals, source, with_normals, with_votes, vote0)
        if with_ids:
            ids[i] = v * id_stride + id_offset
    return n, m


@kernel
def _voxel_slab(points: NDArray[np.floating], voxel: float, source: NDArray[np.int32], width: int,
                normals: NDArray[np.float32], keep: NDArray[np.bool_], x_lo: int, x_hi: int, ids: NDArray[np.int64],
                id_stride: int, id_offset: int) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
    """The voxels (grid indices (M,3), first met first) and their acc rows (M,W) of the points whose grid x index
    lies in [x_lo, x_hi] (_voxel_fill, which also writes ids); memory grows with the voxels (a hash table), not
    with the cloud's extent."""
    cap = 1 << 10
    bits = 11
    table = np.full(4 << bits, -1, np.int64)
    acc = np.zeros((cap, width), np.float64)
    i, m = 0, 0
    while True:
        i, m = _voxel_fill(points, voxel, source, normals, keep, x_lo, x_hi, i, table, 64 - bits, acc, m, ids,
                           id_stride, id_offset)
        if i == points.shape[0]:
            break
        if m == acc.shape[0]:
            cap *= 2
            grown = np.zeros((cap, width), np.float64)
            grown[:m] = acc[:m]
            acc = grown
        if 2 * m >= table.shape[0] >> 2:
            bits += 1
            old = table
            table = np.full(4 << bits, -1, np.int64)
            mask = (1 << bits) - 1
            for r in range(0, old.shape[0], 4):
                if old[r + 3] >= 0:
                    h = _slot(old[r], old[r + 1], old[r + 2], 64 - bits)
                    while table[(h << 2) + 3] >= 0:
                        h = (h + 1) & mask
                    table[h << 2:(h << 2) + 4] = old[r:r + 4]
    keys = np.empty((m, 3), np.int64)
    for r in range(0, table.shape[0], 4):
        v = table[r + 3]
        if v >= 0:
            keys[v, 0], keys[v, 1], keys[v, 2] = table[r], table[r + 1], table[r + 2]
    return keys, acc[:m]


#: Grid spans (voxels per axis) below this pack a voxel's three indices into one int64 key (21 bits each, x in
#: the high bits: the key orders voxels as the grid does): 6 km at 3 mm.
_PACK = 1 << 21


@kernel
def _packed_fill(points: NDArray[np.floating], voxel: float, source: NDArray[np.int32],
                 normals: NDArray[np.float32], keep: NDArray[np.bool_], base: NDArray[np.int64], x_lo: int,
                 x_hi: int, start: int, table_keys: NDArray[np.int64], table_ids: NDArray[np.int32], shift: int,
                 acc: NDArray[np.float64], m: int, ids: NDArray[np.int64], id_stride: int, id_offset: int, step: int
                 ) -> tuple[int, int]:
    """_voxel_fill for grids within _PACK voxels an axis of base (3,): voxels keyed by one packed int64 (grid
    index - base, 21 bits each) in a table of keys and voxel + 1 (0: free), 12 bytes a slot.  Every step-th point
    from start (step > 1: a sample, to size the table).  Returns (the point, -1) at the first point outside that
    grid: the caller falls back to three-index keys."""
    n = points.shape[0]
    mask = table_keys.shape[0] - 1
    limit = min(table_keys.shape[0] >> 1, acc.shape[0])
    with_normals = normals.shape[0] == n
    vote0 = 7 if with_normals else 4
    with_votes = acc.shape[1] > vote0
    with_ids = ids.shape[0] == n
    with_keep = keep.shape[0] == n
    for i in range(start, n, step):
        if with_keep and not keep[i]:
            if with_ids:
                ids[i] = -1
            continue
        x = _grid_index(points[i, 0], voxel) - base[0]
        if x < x_lo or x > x_hi:
            continue
        y = _grid_index(points[i, 1], voxel) - base[1]
        z = _grid_index(points[i, 2], voxel) - base[2]
        if (x < 0) | (x >= _PACK) | (y < 0) | (y >= _PACK) | (z < 0) | (z >= _PACK):
            return i, -1
        key = (x << 42) | (y << 21) | z
        h = np.int64((np.uint64(key) * np.uint64(0x9E3779B97F4A7C15)) >> np.uint64(shift))
        while True:
            t = table_ids[h]
            if t == 0:
                if m == limit:
                    return i, m
                table_keys[h] = key
                table_ids[h] = m + 1
                v = m
                m += 1
                break
            if table_keys[h] == key:
                v = t - 1
                break
            h = (h + 1) & mask
        _add_point(acc, v, i, points, normals, source, with_normals, with_votes, vote0)
        if with_ids:
            ids[i] = v * id_stride + id_offset
    return n, m


@kernel
def _packed_slab(points: NDArray[np.floating], voxel: float, source: NDArray[np.int32], width: int,
                 normals: NDArray[np.float32], keep: NDArray[np.bool_], base: NDArray[np.int64], x_lo: int,
                 x_hi: int, ids: NDArray[np.int64], id_stride: int, id_offset: int, expected: int, step: int = 1
                 ) -> tuple[NDArray[np.int64], NDArray[np.float64], bool]:
    """_voxel_slab with packed keys (_packed_fill, every step-th point): the voxels' keys (M,), first met first,
    acc rows (M,W), and False (nothing else) when a point lies outside the packed grid.  Sized for `expected`
    voxels at first (grown by doubling)."""
    cap = max(1 << 10, expected)
    bits = 1
    while (1 << bits) < 2 * cap:
        bits += 1
    table_keys = np.empty(1 << bits, np.int64)
    table_ids = np.zeros(1 << bits, np.int32)
    acc = np.zeros((cap, width), np.float64)
    i, m = 0, 0
    while True:
        i, m = _packed_fill(points, voxel, source, normals, keep, base, x_lo, x_hi, i, table_keys, table_ids,
                            64 - bits, acc, m, ids, id_stride, id_offset, step)
        if m < 0:
            return np.zeros(0, np.int64), np.zeros((0, width)), False
        if i >= points.shape[0]:
            break
        if m == acc.shape[0]:
            cap *= 2
            grown = np.zeros((cap, width), np.float64)
            grown[:m] = acc[:m]
            acc = grown
        if 2 * m >= table_keys.shape[0]:
            bits += 1
            old_keys, old_ids = table_keys, table_ids
            table_keys = np.empty(1 << bits, np.int64)
            table_ids = np.zeros(1 << bits, np.int32)
            mask = (1 << bits) - 1
            for r in range(old_ids.shape[0]):
                if old_ids[r] != 0:
                    h = np.int64((np.uint64(old_keys[r]) * np.uint64(0x9E3779B97F4A7C15)) >> np.uint64(64 - bits))
                    while table_ids[h] != 0:
                        h = (h + 1) & mask
                    table_keys[h] = old_keys[r]
                    table_ids[h] = old_ids[r]
    keys = np.empty(m, np.int64)
    for r in range(table_ids.shape[0]):
        if table_ids[r] != 0:
            keys[table_ids[r] - 1] = table_keys[r]
    return keys, acc[:m], True


@kernel
def _relabel(ids: NDArray[np.int64], slabs: int, first: NDArray[np.int64], rank: NDArray[np.int64],
             out: NDArray[np.int64]) -> None:
    """out[i] = rank[first[s] + v] for ids[i] = v * slabs + s (voxel v of slab s): each point's voxel in the grid's
    order (-1 stays -1: a point left out)."""
    for i in range(ids.shape[0]):
        if ids[i] < 0:
            out[i] = -1
            continue
        s = ids[i] % slabs
        out[i] = rank[first[s] + ids[i] // slabs]


def _lexicographic(cells: NDArray[np.int64]) -> NDArray[np.int64]:
    """The order (N,) that sorts integer cell coordinates (N,3) by x, then y, then z (stable): by one int64 key
    where the grid's cell count fits one, else by the three columns."""
    if len(cells) == 0:
        return np.zeros(0, np.int64)
    lo = cells.min(axis=0)
    dims = cells.max(axis=0) - lo + 1
    if int(dims[0]) * int(dims[1]) * int(dims[2]) < 1 << 62:  # Python ints: no overflow in the test itself
        keys = ((cells[:, 0] - lo[0]) * dims[1] + cells[:, 1] - lo[1]) * dims[2] + cells[:, 2] - lo[2]
        return np.argsort(keys, kind="stable").astype(np.int64, copy=False)
    return np.lexsort((cells[:, 2], cells[:, 1], cells[:, 0])).astype(np.int64, copy=False)


#: voxel_sums sizes its tables from every _SAMPLE_STEP-th point's voxels.
_SAMPLE_STEP = 32


def _expected_voxels(points: NDArray[np.floating], voxel: Any, keep: NDArray[np.bool_], base: NDArray[np.int64],
                     count: int) -> int:
    """About how many voxels count points make (a packed grid, _packed_slab's arguments): from the voxels m of
    every _SAMPLE_STEP-th point (k), solving m / count = (1 - exp(-lam / k)) / lam for the points a voxel lam
    (Poisson occupancy; bisection), plus a margin.  Sizing the tables once saves growing them (copies and fresh
    pages on every doubling)."""
    k = _SAMPLE_STEP
    if count < 64 * k:
        return count
    empty = np.zeros(0, np.int64)
    keys, _, inside = _packed_slab(points, voxel, np.zeros(0, np.int32), 4, np.zeros((0, 3), np.float32), keep,
                                   base, -(1 << 62), (1 << 62) - 1, empty, 1, 0, count // k // 4, k)
    if not inside:
        return count // 8
    r = len(keys) / count
    if r >= (1.0 - np.exp(-1.0 / k)) - 1e-12:  # nearly every sampled point alone in its voxel
        return count
    a, b = 1.0, float(count)
    for _ in range(60):  # f(lam) = (1 - exp(-lam / k)) / lam decreases in lam
        lam = np.sqrt(a * b)
        if (1.0 - np.exp(-lam / k)) / lam > r:
            a = lam
        else:
            b = lam
    return min(count, int(1.2 * count / np.sqrt(a * b)) + 1024)


def voxel_sums(points: NDArray[np.floating], voxel: float, camera_source: NDArray[np.int32] | None = None,
               normals: NDArray[np.float32] | None = None, with_ids: bool = False, slabs: int | None = None,
               keep: NDArray[np.bool_] | None = None) -> tuple[NDArray[np.float64], NDArray[np.int64] | None]:
    """The one voxel grid, compiled: each occupied voxel's row (M,W) in grid order (x, then y, then z) of count,
    float64 sums of x, y, z, of the normals' x, y, z when given, and the points per camera when camera_source
    (N,) names more than one; and with_ids, each point's voxel (N,; else None).  With keep (N,) only the points
    it flags count (the others' ids are -1): the voxels of a selection without copying it.

    One pass over the points hashes each one's grid index (floor(p / voxel) in numpy's arithmetic: float32 for
    float32 points and a Python float) into a table of the occupied voxels, then only those are sorted: no array
    over the grid's extent, and nothing the size of the cloud but the ids.  Voxels are keyed by one packed int64
    within _PACK voxels an axis of a sample's bounds (centred on them: 3 km of room each way at 3 mm); a cloud
    with a point beyond (or non-finite ones) is done again with three-index keys.  Clouds of twice
    VOXEL_SLAB_POINTS or more are split into slabs of x (boundaries at quantiles of the sample; `slabs` of them,
    else one per thread the budget shares out, each of VOXEL_SLAB_POINTS at least) run on the thread budget; a
    voxel lies in one slab, so its sums are the same float64 additions in point order however the cloud is
    split."""
    pts = np.ascontiguousarray(points if points.dtype in (np.float32, np.float64) else points.astype(np.float64))
    v = np.result_type(pts.dtype, voxel).type(voxel)  # numpy's points / voxel: float32 for a Python float
    n = len(pts)
    ncam = int(camera_source.max()) + 1 if camera_source is not None and camera_source.size else 1
    src = np.zeros(0, np.int32) if ncam == 1 or camera_source is None else \
        np.ascontiguousarray(camera_source, np.int32)
    nrm = np.zeros((0, 3), np.float32) if normals is None else np.ascontiguousarray(normals, np.float32)
    flags = np.zeros(0, np.bool_) if keep is None else np.ascontiguousarray(keep, np.bool_)
    width = (4 if normals is None else 7) + (ncam if ncam > 1 else 0)
    count = n if keep is None else int(np.count_nonzero(flags))
    if count == 0:
        return np.zeros((0, width)), (np.full(n, -1, np.int64) if with_ids else None)
    step = max(1, n // 4096)  # the packed grid around a sample's bounds, with room for what it missed
    sample = pts[::step] if keep is None else pts[::step][flags[::step]]
    with np.errstate(over="ignore", invalid="ignore"):  # float32's largest coordinates over a voxel: inf
        grid = np.floor(sample / v)
    grid = grid[np.isfinite(grid).all(axis=1)]
    base = np.zeros(3, np.int64)
    packed = len(grid) > 0
    if packed:
        low = grid.min(axis=0)
        span = grid.max(axis=0) - low
        packed = bool(np.all(span < _PACK // 2) and np.all(np.abs(low) < _GRID_LIMIT / 2))
        if packed:
            base = (low - (_PACK - 1 - span) // 2).astype(np.int64)
    bounds = [-(1 << 62), 1 << 62]  # slab k: grid x indices bounds[k] .. bounds[k + 1] - 1 (less base[0])
    if slabs is None:
        slabs = max(1, min(THREADS.share(), count // VOXEL_SLAB_POINTS))
    if slabs > 1 and len(grid):
        cuts = np.unique(np.quantile(grid[:, 0], np.arange(1, slabs) / slabs, method="lower").astype(np.int64))
        bounds = [-(1 << 62), *(int(c) - int(base[0]) for c in cuts), 1 << 62]
    slabs = len(bounds) - 1
    ids = np.empty(n if with_ids else 0, np.int64)
    expected = _expected_voxels(pts, v, flags, base, count) // slabs if packed else count // 8 // slabs

    def packed_slab(k: int) -> tuple[NDArray[np.int64], NDArray[np.float64], bool]:
        keys, acc, inside = _packed_slab(pts, v, src, width, nrm, flags, base, bounds[k], bounds[k + 1] - 1, ids,
                                         slabs, k, expected)
        order = np.argsort(keys)  # packed keys sort as the grid does
        return order, acc[order], inside

    def slab(k: int) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
        cells, acc = _voxel_slab(pts, v, src, width, nrm, flags, bounds[k] + int(base[0]),
                                 bounds[k + 1] - 1 + int(base[0]), ids, slabs, k)
        order = _lexicographic(cells)
        return order, acc[order]

    if packed:
        results = THREADS.map(packed_slab, range(slabs))
        packed = all(inside for _, _, inside in results)  # else a point the sample missed lies outside
        parts = [(order, acc) for order, acc, _ in results]
    if not packed:
        parts = THREADS.map(slab, range(slabs))
    rows = parts[0][1] if slabs == 1 else np.concatenate([acc for _, acc in parts])
    if not with_ids:
        return rows, None
    rank = np.empty(len(rows), np.int64)  # slab s's voxel v (as first met) -> its place in the grid order
    first = np.zeros(slabs, np.int64)
    for s, (order, _) in enumerate(parts):
        rank[first[s] + order] = first[s] + np.arange(len(order))
        if s + 1 < slabs:
            first[s + 1] = first[s] + len(order)
    out = np.empty(n, np.int64)
    _relabel(ids, slabs, first, rank, out)
    return rows, out


def voxel_groups(points: NDArray[np.floating], voxel: float) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
    """The one voxel grid: for points (N,3, m, any frame) the index of the occupied voxel of edge voxel (m) each
    falls in, voxels ordered by grid index (x, then y, then z; keyed in the points' dtype), and each voxel's point
    count (M,).  Compiled (voxel_sums); grid indices beyond +-2^61 voxels are clamped there, and non-finite
    points (which callers drop first) fall in the voxel of index 0 or the edge."""
    rows, ids = voxel_sums(points, voxel, with_ids=True)
    assert ids is not None
    return ids, rows[:, 0].astype(np.int64)


def voxel_downsample(points: FloatArray, voxel: float) -> FloatArray:
    """One point (the mean) per occupied voxel of voxel_groups, in the input's dtype.  graspd.gpd.preprocess
    .voxelize is the same with cameras and normals; points (N,3) in any frame."""
    if len(points) == 0:
        return points
    rows, _ = voxel_sums(points, voxel)
    return np.asarray(rows[:, 1:4] / rows[:, :1]).astype(points.dtype, copy=False)


#: Cell edge of the normals' grid as a multiple of the radius: a little over 1, so two points within the radius
#: lie in the same or adjacent cells despite the rounding of their cell coordinates.
_CELL_MARGIN = 1.0 + 1e-6
#: Cell coordinates are clamped to +-this: a coordinate farther than 2^61 cells from the origin (not a real cloud:
#: 2.3e16 m at 1 cm) shares the edge cell; distances are still exact, so neighbours are too, and differences of
#: two clamped coordinates fit int64.
_CELL_LIMIT = float(1 << 61)


@kernel
def _cells(points: NDArray[np.float64], edge: float, out: NDArray[np.int64]) -> None:
    """Integer cell coordinates (N,3) of points (N,3, float64) in the grid of cubic cells of edge `edge` anchored
    at the origin, shifted to start at 0: floor(p / edge) - its minimum.  Computed from each point alone (not
    from p - min, which rounds away a far cloud's detail), clamped to +-2^61 (NaN to 0) so the cast is defined."""
    n = points.shape[0]
    for k in range(3):
        low = np.int64(0)
        for i in range(n):
            c = np.floor(points[i, k] / edge)
            if not c >= -_CELL_LIMIT:
                c = -_CELL_LIMIT if c < 0.0 else 0.0
            elif c > _CELL_LIMIT:
                c = _CELL_LIMIT
            out[i, k] = np.int64(c)
            if i == 0 or out[i, k] < low:
                low = out[i, k]
        for i in range(n):
            out[i, k] -= low


@kernel
def _cell_runs(cells: NDArray[np.int64], order: NDArray[np.int64]) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """The distinct cells (M,3) of cell coordinates (N,3) visited in `order` (lexicographic: x, then y, then z),
    and where each one's points start in that order (M+1,; the last entry N)."""
    n = order.shape[0]
    uniq = np.empty((n, 3), np.int64)
    start = np.empty(n + 1, np.int64)
    m = 0
    for j in range(n):
        i = order[j]
        if m == 0 or cells[i, 0] != uniq[m - 1, 0] or cells[i, 1] != uniq[m - 1, 1] or cells[i, 2] != uniq[m - 1, 2]:
            uniq[m, 0], uniq[m, 1], uniq[m, 2] = cells[i, 0], cells[i, 1], cells[i, 2]
            start[m] = j
            m += 1
    start[m] = n
    return uniq[:m].copy(), start[:m + 1].copy()


@kernel
def _first_cell_at_least(uniq: NDArray[np.int64], x: int, y: int, z: int) -> int:
    """Index of the first of the lexicographically sorted cells uniq (M,3) that is >= (x, y, z) (M if none)."""
    a, b = 0, uniq.shape[0]
    while a < b:
        h = (a + b) >> 1
        ux, uy, uz = uniq[h, 0], uniq[h, 1], uniq[h, 2]
        if ux < x or (ux == x and (uy < y or (uy == y and uz < z))):
            a = h + 1
        else:
            b = h
    return a


@kernel
def _rotation(app: float, aqq: float, apq: float) -> tuple[float, float]:
    """cos and sin of the Jacobi rotation that diagonalises the symmetric 2x2 [[app, apq], [apq, aqq]] (apq != 0;
    Numerical Recipes' form, small-angle root): the axes (c, -s) and (s, c) then have the eigenvalues
    app - t apq and aqq + t apq, t = s / c."""
    theta = (aqq - app) / (2.0 * apq)
    if abs(theta) > 1e150:  # theta^2 would overflow
        t = 0.5 / theta
    else:
        t = 1.0 / (abs(theta) + np.sqrt(theta * theta + 1.0))
        if theta < 0.0:
            t = -t
    c = 1.0 / np.sqrt(t * t + 1.0)
    return c, t * c


@kernel
def _cross_axis(a00: float, a01: float, a02: float, a11: float, a12: float, a22: float, lam: float
                ) -> tuple[float, float, float]:
    """Unit eigenvector of the symmetric 3x3 a (its upper triangle) for its eigenvalue lam, which must be simple:
    every row of a - lam I is normal to it, so the longest cross product of two rows is along it.  (0, 0, 0) when
    all three vanish."""
    r00, r11, r22 = a00 - lam, a11 - lam, a22 - lam
    x0, y0, z0 = a01 * a12 - a02 * r11, a02 * a01 - r00 * a12, r00 * r11 - a01 * a01  # row 0 x row 1
    x1, y1, z1 = a01 * r22 - a02 * a12, a02 * a02 - r00 * r22, r00 * a12 - a01 * a02  # row 0 x row 2
    x2, y2, z2 = r11 * r22 - a12 * a12, a12 * a02 - a01 * r22, a01 * a12 - r11 * a02  # row 1 x row 2
    n0 = x0 * x0 + y0 * y0 + z0 * z0
    n1 = x1 * x1 + y1 * y1 + z1 * z1
    n2 = x2 * x2 + y2 * y2 + z2 * z2
    if n0 >= n1 and n0 >= n2:
        x, y, z, n = x0, y0, z0, n0
    elif n1 >= n2:
        x, y, z, n = x1, y1, z1, n1
    else:
        x, y, z, n = x2, y2, z2, n2
    if not n > 0.0:
        return 0.0, 0.0, 0.0
    s = 1.0 / np.sqrt(n)
    return x * s, y * s, z * s


@kernel
def _least_axis(c00: float, c01: float, c02: float, c11: float, c12: float, c22: float
                ) -> tuple[float, float, float, float]:
    """The unit eigenvector (x, y, z) of the least eigenvalue of the symmetric 3x3 c (its upper triangle, float64)
    and c's largest eigenvalue (0 for the zero matrix).

    The robust closed form (Eberly, "A Robust Eigensolver for 3x3 Symmetric Matrices"): c is scaled to entries in
    [-1, 1]; the eigenvalues come from the trigonometric solution of the characteristic cubic; then the axis of
    the better separated extreme eigenvalue is taken first (cross products of rows of c - lam I), and, when that
    is the largest one, the least axis from one Jacobi rotation of the 2x2 block normal to it.  The angle error
    is about the float64 rounding over the relative gap to the nearest eigenvalue (eigh's own accuracy): planar
    neighbourhoods (one small eigenvalue) and linear ones (two) alike, at any scale.  A multiple of the identity
    has every axis: (1, 0, 0)."""
    m = max(abs(c00), abs(c01), abs(c02), abs(c11), abs(c12), abs(c22))
    if not m > 0.0:
        return 0.0, 0.0, 1.0, 0.0
    a00, a01, a02, a11, a12, a22 = c00 / m, c01 / m, c02 / m, c11 / m, c12 / m, c22 / m
    q = (a00 + a11 + a22) / 3.0
    b00, b11, b22 = a00 - q, a11 - q, a22 - q
    p2 = (b00 * b00 + b11 * b11 + b22 * b22 + 2.0 * (a01 * a01 + a02 * a02 + a12 * a12)) / 6.0
    if not p2 > 0.0:
        return 1.0, 0.0, 0.0, m * q
    p = np.sqrt(p2)
    det = b00 * (b11 * b22 - a12 * a12) - a01 * (a01 * b22 - a12 * a02) + a02 * (a01 * a12 - b11 * a02)
    phi = np.arccos(min(1.0, max(-1.0, det / (2.0 * p2 * p)))) / 3.0
    lmax = q + 2.0 * p * np.cos(phi)
    lmin = q + 2.0 * p * np.cos(phi + 2.0 * np.pi / 3.0)
    lmid = 3.0 * q - lmax - lmin
    if lmid - lmin >= lmax - lmid:  # the least eigenvalue is the better separated one: its axis directly
        x, y, z = _cross_axis(a00, a01, a02, a11, a12, a22, lmin)
        if x != 0.0 or y != 0.0 or z != 0.0:
            return x, y, z, m * lmax
    ux, uy, uz = _cross_axis(a00, a01, a02, a11, a12, a22, lmax)  # the largest one's axis, then the plane normal
    if ux == 0.0 and uy == 0.0 and uz == 0.0:
        return 1.0, 0.0, 0.0, m * lmax
    if abs(ux) > abs(uy):  # (v, w): an orthonormal pair normal to u
        s = 1.0 / np.sqrt(ux * ux + uz * uz)
        vx, vy, vz = -uz * s, 0.0, ux * s
    else:
        s = 1.0 / np.sqrt(uy * uy + uz * uz)
        vx, vy, vz = 0.0, uz * s, -uy * s
    wx, wy, wz = uy * vz - uz * vy, uz * vx - ux * vz, ux * vy - uy * vx
    avx, avy, avz = a00 * vx + a01 * vy + a02 * vz, a01 * vx + a11 * vy + a12 * vz, a02 * vx + a12 * vy + a22 * vz
    awx, awy, awz = a00 * wx + a01 * wy + a02 * wz, a01 * wx + a11 * wy + a12 * wz, a02 * wx + a12 * wy + a22 * wz
    mvv = vx * avx + vy * avy + vz * avz
    mvw = vx * awx + vy * awy + vz * awz
    mww = wx * awx + wy * awy + wz * awz
    if mvw == 0.0:
        cs, sn = (1.0, 0.0) if mvv <= mww else (0.0, 1.0)
    else:
        c, s = _rotation(mvv, mww, mvw)
        t = s / c
        cs, sn = (c, -s) if mvv - t * mvw <= mww + t * mvw else (s, c)
    x, y, z = cs * vx + sn * wx, cs * vy + sn * wy, cs * vz + sn * wz
    n = np.sqrt(x * x + y * y + z * z)
    return x / n, y / n, z / n, m * lmax


@kernel
def _select_pairs(d: NDArray[np.float64], s: NDArray[np.int64], count: int, k: int) -> None:
    """Reorder d[:count] and s[:count] together so that their first k entries hold the k smallest d
    (quickselect, in place; 0 < k < count)."""
    a, b = 0, count - 1
    while a < b:
        m = (a + b) >> 1  # median of three as the pivot
        x, y, z = d[a], d[m], d[b]
        pivot = max(min(x, y), min(max(x, y), z))
        i, j = a, b
        while i <= j:
            while d[i] < pivot:
                i += 1
            while d[j] > pivot:
                j -= 1
            if i <= j:
                d[i], d[j] = d[j], d[i]
                s[i], s[j] = s[j], s[i]
                i += 1
                j -= 1
        if k - 1 <= j:
            b = j
        elif k - 1 >= i:
            a = i
        else:
            return


#: Distance buckets of the nearest-neighbour selection: a surface's neighbours spread evenly over squared
#: distance, so about one neighbour falls in each.
_BUCKETS = 64


@kernel
def _nearest(kd: NDArray[np.float64], kept: NDArray[np.int64], count: int, k: int, radius2: float,
             hist: NDArray[np.int64], bucket: NDArray[np.int64], tie: NDArray[np.int64], tie_d: NDArray[np.float64]
             ) -> None:
    """Reorder kept[:count] (candidates with squared distances kd[:count], all within radius2) so that its first k
    entries are the k nearest (k < count): a histogram over squared distance finds the bucket holding the k-th;
    the nearer buckets are taken whole and that bucket's points are selected exactly (the first ones first on
    equal distances; quickselect when there are many).  hist (_BUCKETS,), bucket, tie, tie_d (count,) are
    scratch."""
    nb = hist.shape[0]
    hist[:] = 0
    scale = nb / radius2
    for t in range(count):
        b = min(np.int64(kd[t] * scale), nb - 1)
        bucket[t] = b
        hist[b] += 1
    below = 0
    edge = 0
    while below + hist[edge] < k:
        below += hist[edge]
        edge += 1
    m = 0
    ties = 0
    for t in range(count):  # branch-free partition (m <= t: kept is compacted in place)
        j = kept[t]
        kept[m] = j
        tie[ties] = j
        tie_d[ties] = kd[t]
        m += bucket[t] < edge
        ties += bucket[t] == edge
    need = k - below
    if ties > 4 * need + 16:  # many at one distance (duplicates): quickselect
        _select_pairs(tie_d, tie, ties, need)
        for u in range(need):
            kept[m + u] = tie[u]
        return
    for _ in range(need):  # the nearest of the edge bucket, one by one
        best = 0
        for u in range(1, ties):
            if tie_d[u] < tie_d[best]:
                best = u
        kept[m] = tie[best]
        m += 1
        ties -= 1
        for u in range(best, ties):
            tie[u], tie_d[u] = tie[u + 1], tie_d[u + 1]


@kernel
def _normals_of_cells(sorted_pts: NDArray[np.float64], order: NDArray[np.int64], uniq: NDArray[np.int64],
                      start: NDArray[np.int64], first: int, last: int, radius2: float, max_nn: int,
                      out: NDArray[np.float32]) -> None:
    """Normals of the points in cells first..last-1 (of uniq, start: _cell_runs) into out (N,3) at their input
    rows (order): for each point the max_nn nearest points within sqrt(radius2) among the 27 cells around its
    own (points sorted by cell, sorted_pts (N,3)), their centred covariance and its least-variance axis.  The
    candidates of a cell are gathered once (coordinates by axis, so the distance loop vectorises)."""
    cap = 256
    bx = np.empty(cap, np.float64)
    by = np.empty(cap, np.float64)
    bz = np.empty(cap, np.float64)
    dist = np.empty(cap, np.float64)
    kd = np.empty(cap, np.float64)
    kept = np.empty(cap, np.int64)
    bucket = np.empty(cap, np.int64)
    tie = np.empty(cap, np.int64)
    tie_d = np.empty(cap, np.float64)
    hist = np.empty(_BUCKETS, np.int64)
    lo = np.empty(9, np.int64)
    hi = np.empty(9, np.int64)
    for cell in range(first, last):
        cx, cy, cz = uniq[cell, 0], uniq[cell, 1], uniq[cell, 2]
        runs = 0
        size = 0
        for dx in range(-1, 2):
            for dy in range(-1, 2):  # cells (x+dx, y+dy, z-1..z+1) are consecutive in the sorted order
                a = _first_cell_at_least(uniq, cx + dx, cy + dy, cz - 1)
                b = a
                while (b < uniq.shape[0] and uniq[b, 0] == cx + dx and uniq[b, 1] == cy + dy
                       and uniq[b, 2] <= cz + 1):
                    b += 1
                if b > a:
                    lo[runs], hi[runs] = start[a], start[b]
                    size += start[b] - start[a]
                    runs += 1
        if size > cap:
            cap = 2 * size
            bx = np.empty(cap, np.float64)
            by = np.empty(cap, np.float64)
            bz = np.empty(cap, np.float64)
            dist = np.empty(cap, np.float64)
            kd = np.empty(cap, np.float64)
            kept = np.empty(cap, np.int64)
            bucket = np.empty(cap, np.int64)
            tie = np.empty(cap, np.int64)
            tie_d = np.empty(cap, np.float64)
        n = 0
        for run in range(runs):
            for j in range(lo[run], hi[run]):
                bx[n], by[n], bz[n] = sorted_pts[j, 0], sorted_pts[j, 1], sorted_pts[j, 2]
                n += 1
        for i in range(start[cell], start[cell + 1]):
            px, py, pz = sorted_pts[i, 0], sorted_pts[i, 1], sorted_pts[i, 2]
            if (i > start[cell] and px == sorted_pts[i - 1, 0] and py == sorted_pts[i - 1, 1]
                    and pz == sorted_pts[i - 1, 2]):  # a copy of the previous point: the same neighbours
                row, prev = order[i], order[i - 1]
                out[row, 0], out[row, 1], out[row, 2] = out[prev, 0], out[prev, 1], out[prev, 2]
                continue
            for t in range(n):
                ex, ey, ez = bx[t] - px, by[t] - py, bz[t] - pz
                dist[t] = ex * ex + ey * ey + ez * ez
            count = 0
            for t in range(n):  # branch-free: keep t when within the radius (a NaN distance is not)
                kept[count] = t
                kd[count] = dist[t]
                count += dist[t] <= radius2
            if count > max_nn:
                _nearest(kd, kept, count, max_nn, radius2, hist, bucket, tie, tie_d)
                count = max_nn
            if count < 3:
                continue
            mx = my = mz = 0.0
            for t in range(count):
                mx += bx[kept[t]]
                my += by[kept[t]]
                mz += bz[kept[t]]
            mx /= count
            my /= count
            mz /= count
            sxx = sxy = sxz = syy = syz = szz = 0.0
            for t in range(count):
                ex, ey, ez = bx[kept[t]] - mx, by[kept[t]] - my, bz[kept[t]] - mz
                sxx += ex * ex
                sxy += ex * ey
                sxz += ex * ez
                syy += ey * ey
                syz += ey * ez
                szz += ez * ez
            x, y, z, largest = _least_axis(sxx / count, sxy / count, sxz / count, syy / count, syz / count,
                                           szz / count)
            if not largest > 0.0:
                continue  # every neighbour at the same place
            row = order[i]
            out[row, 0] = x
            out[row, 1] = y
            out[row, 2] = z


#: Points (about) whose normals one task of pca_normals computes (tasks run on the process's thread budget).
NORMALS_CHUNK = 4096


def pca_normals(points: NDArray[np.floating], radius: float, max_nn: int, chunk: int = NORMALS_CHUNK
                ) -> NDArray[np.float32]:
    """Unit surface normals (N,3), unoriented: the least-variance axis of each point's neighbourhood, the at most
    max_nn nearest points within radius (m; the point itself included: open3d's hybrid search).  (0, 0, 1)
    where fewer than 3 neighbours or a degenerate neighbourhood (all neighbours at one place).

    Compiled (graspd.core.jit): the points are sorted into cubic cells of edge radius (found by sorting their
    integer cell coordinates, so the memory follows the points, not the cloud's extent: a cloud kilometres wide
    costs what a tabletop does), each point's candidates are the points of the 27 cells around its own, and the
    covariance (centred, float64) is diagonalised by Jacobi rotations.  Chunks of about `chunk` points, whole
    cells each, run on the process's thread budget (graspd.core.parallel; the kernel releases the GIL)."""
    pts = np.ascontiguousarray(points, np.float64)
    out = np.tile(np.array([0.0, 0.0, 1.0], np.float32), (len(pts), 1))
    if len(pts) < 3 or max_nn < 3:
        return out
    edge = float(radius) * _CELL_MARGIN
    cells = np.empty((len(pts), 3), np.int64)
    _cells(pts, edge, cells)
    order = _lexicographic(cells)
    uniq, start = _cell_runs(cells, order)
    sorted_pts = pts[order]
    # chunks of whole cells, about `chunk` points each
    bounds = np.unique(np.searchsorted(start, np.arange(0, len(pts), max(1, chunk)), side="right") - 1)
    bounds = np.append(bounds[bounds < len(uniq)], len(uniq))
    reach = float(radius) * (1.0 + 1e-12)  # a neighbour exactly at the radius counts, despite rounding
    radius2 = reach * reach

    def normals_of(k: int) -> None:
        _normals_of_cells(sorted_pts, order, uniq, start, int(bounds[k]), int(bounds[k + 1]), radius2, int(max_nn),
                          out)

    THREADS.map(normals_of, range(len(bounds) - 1))
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


#: RANSAC hypotheses scored together by one task of plane_inlier_counts.
HYPOTHESES_PER_TASK = 50


def plane_inlier_counts(points: NDArray[np.float64], normals: NDArray[np.float64], offsets: NDArray[np.float64],
                        distance: float) -> NDArray[np.int64]:
    """How many of the points (N,3) lie within distance (m) of each plane (K unit normals, K offsets), in chunks of
    HYPOTHESES_PER_TASK planes on the process's thread budget (each plane's count depends on that plane alone)."""

    def part(a: int) -> NDArray[np.int64]:
        b = a + HYPOTHESES_PER_TASK
        return np.asarray((np.abs(points @ normals[a:b].T + offsets[a:b]) <= distance).sum(axis=0), np.int64)

    return np.concatenate(THREADS.map(part, range(0, len(normals), HYPOTHESES_PER_TASK)))


def best_plane(points: NDArray[np.float64], triplets: NDArray[np.int64], distance: float,
               vertical_to: NDArray[np.float64] | None = None, max_tilt_deg: float = 90.0
               ) -> tuple[NDArray[np.float64], int] | None:
    """The RANSAC plane fit: of the planes through the point triplets (K,3 indices into points (N,3)), the first
    with most points within distance (m), refit by least squares (SVD) to those points.  Returns (a, b, c, d; unit
    normal, a x + b y + c z + d = 0) and the hypothesis' inlier count, or None when no triplet spans a plane (or,
    with vertical_to given, none stands within max_tilt_deg of upright to it: walls) or the fit has under 3 points.
    Callers draw the triplets from their own seeded generator, so the same cloud and seed give the same plane."""
    tri = points[triplets]  # (K, 3 points, xyz)
    normals = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    length = np.linalg.norm(normals, axis=1)
    ok = length > 1e-9
    if not ok.any():
        return None
    normals = normals[ok] / length[ok, None]
    offsets = -np.einsum("kj,kj->k", normals, tri[ok, 0])
    if vertical_to is not None:  # only planes standing up (walls): a slice across a wall would eat its points
        upright = np.abs(normals @ vertical_to) <= np.sin(np.radians(max_tilt_deg))
        if not upright.any():
            return None
        normals, offsets = normals[upright], offsets[upright]
    counts = plane_inlier_counts(points, normals, offsets, distance)
    best = int(np.argmax(counts))
    inliers = points[np.abs(points @ normals[best] + offsets[best]) <= distance]
    if len(inliers) < 3:
        return None
    centre = inliers.mean(axis=0)
    _, _, vt = np.linalg.svd(inliers - centre, full_matrices=False)
    normal = vt[-1] / np.linalg.norm(vt[-1])
    return np.append(normal, -float(normal @ centre)), int(counts[best])


def ransac_plane(points: NDArray[np.floating], distance: float, iterations: int = 200, seed: int = 0
                 ) -> tuple[NDArray[np.float64], int]:
    """The plane (a, b, c, d; unit normal, a x + b y + c z + d = 0) through the most points within distance
    (m) among `iterations` seeded hypotheses, each through 3 distinct points (best_plane); and how many there
    were ((0, 0, 1, 0) and 0 when none spans a plane).  Needs at least 3 points."""
    pts = np.asarray(points, np.float64)
    rng = np.random.default_rng(seed)
    tri = np.stack([rng.choice(len(pts), 3, replace=False) for _ in range(iterations)])
    fit = best_plane(pts, tri, distance)
    if fit is None:
        return np.array([0.0, 0.0, 1.0, 0.0]), 0
    return fit


def eps_clusters(points: NDArray[np.floating], eps: float) -> NDArray[np.int64]:
    """A cluster label per point (N,): the connected components of the graph joining points at most eps (m)
    apart (DBSCAN with min_points 1)."""
    if len(points) == 0:
        return np.zeros(0, np.int64)
    pairs = cKDTree(np.asarray(points, np.float64)).query_pairs(eps, output_type="ndarray")
    graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(len(points), len(points)))
    _, labels = connected_components(graph, directed=False)
    return labels.astype(np.int64)
