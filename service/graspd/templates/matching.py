"""Template distance and matching function (Herzog et al. 2012, Sec. II-D/E).

sigma(c, l) = o_{c,l} * mean_i W[c^_i, l^_i] |c_i - l_i|   (eq. 1), heights in metres;
o_{c,l} = max(surf_c, surf_l) / surf_{c,l}  (surface tiles of each, and of both at once; inf without overlap);
m(c, l) = alpha / ([1 - exp(-3 beta^2)] [1 - exp(-10 gamma^2)])  (eq. 2), alpha = sigma(c, l),
beta = min_f sigma(c, f), gamma = min_f sigma(l, f) over the failure set F_l (beta = gamma = inf if empty).

Eq. 1 in the paper is a sum over the n^2 tiles and leaves the height unit open; the constants 3 and 10 of
eq. 2 only act when sigma is of order one.  We average over the tiles with heights in metres (i.e. sum
with heights in units of n^2 m), which puts sigma of templates a few millimetres apart at ~0.1-0.5:
identical failures drive m to infinity, unrelated ones leave it unchanged.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from graspd.core.types import F32, F64
from graspd.templates.geometry import SURFACE

U8 = NDArray[np.uint8]

#: The paper's weights by (type of c, type of l), in the order surface, void, occlusion, background.
W = np.array([[50, 50, 50, 50], [50, 12, 12, 12], [50, 12, 12, 12], [50, 12, 12, 12]], np.float32)
W_LOW, W_HIGH = float(W[1, 1]), float(W[0, 0])


def distances(c_heights: F32, c_types: U8, l_heights: F32, l_types: U8, chunk: int = 64) -> F64:
    """sigma (K, L) between every candidate (K, T) and every library template (L, T).

    W has two values: W_HIGH where either tile is surface, W_LOW elsewhere; so
    sum_i W |d_i| = W_LOW sum_i |d_i| + (W_HIGH - W_LOW) sum_i [c^_i or l^_i surface] |d_i|.
    """
    k, t = c_heights.shape
    n_l = l_heights.shape[0]
    out = np.full((k, n_l), np.inf)
    if k == 0 or n_l == 0:
        return out
    cs = c_types == SURFACE
    ls = l_types == SURFACE
    both = np.einsum("kt,lt->kl", cs.astype(np.float32), ls.astype(np.float32))  # (K, L) surface overlaps
    surf_c = cs.sum(axis=1).astype(np.float64)
    surf_l = ls.sum(axis=1).astype(np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        o = np.maximum(surf_c[:, None], surf_l[None, :]) / both
    extra = np.float32(W_HIGH - W_LOW)
    low = np.float32(W_LOW)
    ch = np.ascontiguousarray(c_heights, np.float32)
    csf = cs.astype(np.float32)
    lsf = ls.astype(np.float32)
    ones = np.ones(t, np.float32)
    for j in range(n_l):
        live = np.flatnonzero(both[:, j] > 0)
        if len(live) == 0:
            continue
        lh = l_heights[j].astype(np.float32)
        for s in range(0, len(live), chunk * 16):
            rows = live[s : s + chunk * 16]
            d = ch[rows] - lh
            np.abs(d, out=d)
            # sum_i W|d_i| = low sum_i |d_i| + extra (sum_{l^ surface} |d_i| + sum_{l^ not surface} [c^ surface] |d_i|)
            # einsum's own loops, not BLAS: OpenBLAS threads spin badly on a busy machine
            total = (low * np.einsum("kt,t->k", d, ones) + extra * (np.einsum("kt,t->k", d, lsf[j])
                     + np.einsum("kt,kt,t->k", d, csf[rows], 1.0 - lsf[j])))
            out[rows, j] = total / t
    return np.where(both > 0, o * out, np.inf)


def matching(alpha: F64, beta: F64, gamma: F64) -> F64:
    """Eq. 2, broadcast over arrays of alpha, beta, gamma (beta, gamma inf for an empty failure set)."""
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        den = (1.0 - np.exp(-3.0 * np.square(beta))) * (1.0 - np.exp(-10.0 * np.square(gamma)))
        m = np.where(den > 0.0, alpha / np.where(den > 0.0, den, 1.0), np.inf)
    return np.where(np.isnan(m), np.inf, m)


def failure_minima(heights: F32, types: U8, f_heights: F32, f_types: U8, f_owner: NDArray[np.int64],
                   num_entries: int) -> F64:
    """min_f sigma(x, f) over the failures of each entry: (X, num_entries), inf where an entry has none.
    f_owner (F,) is the entry row (0..num_entries-1) each failure template belongs to."""
    out = np.full((len(heights), num_entries), np.inf)
    if len(f_heights) == 0 or len(heights) == 0:
        return out
    d = distances(heights, types, f_heights, f_types)  # (X, F)
    for e in np.unique(f_owner):
        out[:, e] = d[:, f_owner == e].min(axis=1)
    return out


def match(c_heights: F32, c_types: U8, l_heights: F32, l_types: U8, f_heights: F32, f_types: U8,
          f_owner: NDArray[np.int64], gamma: F64 | None = None) -> tuple[F64, F64]:
    """m(c, l) for every candidate and library entry: (K, L) mismatch and (K, L) alpha = sigma(c, l).
    gamma (L,) may be passed if already known (it depends on the library only)."""
    n_l = len(l_heights)
    alpha = distances(c_heights, c_types, l_heights, l_types)
    beta = failure_minima(c_heights, c_types, f_heights, f_types, f_owner, n_l)
    if gamma is None:
        gamma = entry_gammas(l_heights, l_types, f_heights, f_types, f_owner)
    return matching(alpha, beta, gamma[None, :]), alpha


def entry_gammas(l_heights: F32, l_types: U8, f_heights: F32, f_types: U8, f_owner: NDArray[np.int64]) -> F64:
    """gamma (L,) = min_f sigma(l, f) over each entry's own failures (inf if none)."""
    n_l = len(l_heights)
    gamma = np.full(n_l, np.inf)
    for e in np.unique(f_owner):
        own = f_owner == e
        gamma[e] = distances(l_heights[e : e + 1], l_types[e : e + 1], f_heights[own], f_types[own]).min()
    return gamma
