"""The compiled loops that draw grasp images (graspd.gpd.images gives the method and the channels).

Each follows the arithmetic of the vectorised numpy it replaced: pixel means summed in float64 in point order and
stored as float32, uint8 values as round(255 x) in float32, grid lookups in float32."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from graspd.core.jit import kernel

F32 = np.float32


@kernel
def _u8(x: np.float32) -> np.uint8:
    """A value in [0, 1] as round(255 x) (half to even, float32), clipped to 0..255."""
    y = np.rint(x * F32(255.0))
    return np.uint8(min(max(y, F32(0.0)), F32(255.0)))


@kernel
def project_points(gid: NDArray[np.int64], unit: NDArray[np.float32], values: NDArray[np.float32], row_axis: int,
                   col_axis: int, first_channel: int, out: NDArray[np.uint8]) -> None:
    """Into channels first_channel.. of out (M, C, size, size): for each grasp's points (gid sorted, unit
    coordinates in [0, 1]^3), the mean of each column of values (T, V) over the points falling in each pixel
    (rows from unit[:, row_axis], columns from unit[:, col_axis]) as uint8; pixels without points untouched."""
    m, _, size, _ = out.shape
    n_v = values.shape[1]
    sums = np.zeros((size, size, n_v), np.float64)
    counts = np.zeros((size, size), np.int64)
    touched = np.empty(size * size, np.int64)
    t = 0
    while t < len(gid):
        g = gid[t]
        n_touched = 0
        while t < len(gid) and gid[t] == g:
            r = min(int(unit[t, row_axis] * F32(size)), size - 1)
            c = min(int(unit[t, col_axis] * F32(size)), size - 1)
            if counts[r, c] == 0:
                touched[n_touched] = r * size + c
                n_touched += 1
            counts[r, c] += 1
            for v in range(n_v):
                sums[r, c, v] += values[t, v]
            t += 1
        for q in range(n_touched):
            r, c = touched[q] // size, touched[q] % size
            for v in range(n_v):
                out[g, first_channel + v, r, c] = _u8(F32(sums[r, c, v] / counts[r, c]))
                sums[r, c, v] = 0.0
            counts[r, c] = 0


@kernel
def unobserved_cells(cells: NDArray[np.bool_], origin: NDArray[np.float32], inv_voxel: float,
                     positions: NDArray[np.float32], rotations: NDArray[np.float32], local: NDArray[np.float32],
                     out: NDArray[np.bool_]) -> None:
    """out (M, P): whether each point of local (P, 3; hand frame, m) of each hand (positions (M, 3), rotations
    (M, 3, 3), cloud frame) lies in a true cell of cells (grid from origin, voxel 1 / inv_voxel m; positions
    outside clipped onto its border)."""
    s0, s1, s2 = cells.shape
    hi0, hi1, hi2 = F32(s0 - 1), F32(s1 - 1), F32(s2 - 1)
    inv, zero = F32(inv_voxel), F32(0.0)
    for h in range(len(positions)):
        for q in range(len(local)):
            l0, l1, l2 = local[q, 0], local[q, 1], local[q, 2]
            w0 = positions[h, 0] + (l0 * rotations[h, 0, 0] + l1 * rotations[h, 0, 1] + l2 * rotations[h, 0, 2])
            w1 = positions[h, 1] + (l0 * rotations[h, 1, 0] + l1 * rotations[h, 1, 1] + l2 * rotations[h, 1, 2])
            w2 = positions[h, 2] + (l0 * rotations[h, 2, 0] + l1 * rotations[h, 2, 1] + l2 * rotations[h, 2, 2])
            i0 = int(min(max(np.floor((w0 - origin[0]) * inv), zero), hi0))
            i1 = int(min(max(np.floor((w1 - origin[1]) * inv), zero), hi1))
            i2 = int(min(max(np.floor((w2 - origin[2]) * inv), zero), hi2))
            out[h, q] = cells[i0, i1, i2]


@kernel
def depth_maps(grid: NDArray[np.bool_], depth_axis: int, channel: int, out: NDArray[np.uint8]) -> None:
    """Into channel of out (M, C, size, size): the mean unit depth ((i + 0.5) / k over the true cells along
    depth_axis of grid (M, n0, n1, n2)) of each column of the other two axes, as uint8 (0 where none), upsampled
    to size x size by nearest cell."""
    m, _, size, _ = out.shape
    n = grid.shape[1:]
    k = n[depth_axis]
    a_axis = 1 if depth_axis == 0 else 0
    b_axis = 1 if depth_axis == 2 else 2
    na, nb = n[a_axis], n[b_axis]
    weight = np.empty(k, np.float32)
    for i in range(k):
        weight[i] = F32((i + 0.5) / k)
    mean = np.empty((na, nb), np.uint8)
    r_idx = np.empty(size, np.int64)
    c_idx = np.empty(size, np.int64)
    for i in range(size):
        r_idx[i] = int((i + 0.5) / size * na)
        c_idx[i] = int((i + 0.5) / size * nb)
    idx = np.zeros(3, np.int64)
    for g in range(m):
        for a in range(na):
            for b in range(nb):
                count, total = F32(0.0), F32(0.0)
                idx[a_axis], idx[b_axis] = a, b
                for i in range(k):
                    idx[depth_axis] = i
                    if grid[g, idx[0], idx[1], idx[2]]:
                        count += F32(1.0)
                        total += weight[i]
                mean[a, b] = _u8(total / max(count, F32(1.0))) if count > 0 else np.uint8(0)
        for r in range(size):
            for c in range(size):
                out[g, channel, r, c] = mean[r_idx[r], c_idx[c]]
