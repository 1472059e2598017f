"""Finger placement and closing regions of the hands around each sample: the compiled inner loop of the hand
search (graspd.gpd.candidates, whose module docstring gives the method).

For each sample, its slab's points in the sample frame (x along the approach, y along the binormal, z along the
curvature axis; m) are rotated into each orientation, binned across the hand, and the deepest collision-free
fingertip depth of each finger placement found; the middle valid placement is taken, moved to the placement
nearest the middle of what lies between the fingers when centring, and the points of its closing region kept.
Arithmetic follows numpy's rules for the float32 arrays and Python floats of the vectorised version it replaced
(float32 depths and bins, float64 closing-region coordinates), so the hands are the same."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from graspd.core.jit import kernel

F32 = np.float32


@kernel
def _slab_coords(points: NDArray[np.float32], samples: NDArray[np.float32], frames: NDArray[np.float32],
                 sid: NDArray[np.int64], idx: NDArray[np.int64], half_h: float, keep: NDArray[np.bool_],
                 local: NDArray[np.float32]) -> None:
    """For each (sample row, point row) pair: the point in its sample's frame (x, y, z columns of frames; float32,
    m) and whether it lies in the slab |z| <= half_h."""
    hh = F32(half_h)
    for t in range(len(sid)):
        s, i = sid[t], idx[t]
        d0, d1, d2 = points[i, 0] - samples[s, 0], points[i, 1] - samples[s, 1], points[i, 2] - samples[s, 2]
        zz = d0 * frames[s, 0, 2] + d1 * frames[s, 1, 2] + d2 * frames[s, 2, 2]
        keep[t] = abs(zz) <= hh
        local[t, 0] = d0 * frames[s, 0, 0] + d1 * frames[s, 1, 0] + d2 * frames[s, 2, 0]
        local[t, 1] = d0 * frames[s, 0, 1] + d1 * frames[s, 1, 1] + d2 * frames[s, 2, 1]
        local[t, 2] = zz


def slab_coordinates(points: NDArray[np.float32], samples: NDArray[np.float32], frames: NDArray[np.float32],
                     sid: NDArray[np.int64], idx: NDArray[np.int64], half_h: float
                     ) -> tuple[NDArray[np.bool_], NDArray[np.float32]]:
    """The pairs (sample row sid, point row idx) whose point lies within half_h (m) of its sample's plane normal
    to the frame's third axis, and every pair's point in the sample frame (T, 3; float32, m).  frames (S, 3, 3)
    hold the axes as columns."""
    keep = np.empty(len(sid), np.bool_)
    local = np.empty((len(sid), 3), np.float32)
    _slab_coords(np.ascontiguousarray(points, np.float32), np.ascontiguousarray(samples, np.float32),
                 np.ascontiguousarray(frames, np.float32), sid, idx, half_h, keep, local)
    return keep, local


@kernel
def _slab_scan(points: NDArray[np.float32], samples: NDArray[np.float32], frames: NDArray[np.float32],
               reach: float, half_h: float, capacity: int
               ) -> tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.float32], int]:
    """Every point of points within reach (m, float64 test) of each sample and within half_h of its slab (float32
    test), in sample then point order: sample rows, point rows, sample-frame coordinates, and their number (the
    arrays grow by doubling from capacity rows)."""
    hh, r2 = F32(half_h), reach * reach
    sid = np.empty(capacity, np.int64)
    idx = np.empty(capacity, np.int64)
    local = np.empty((capacity, 3), np.float32)
    o = 0
    for s in range(len(samples)):
        sx, sy, sz = samples[s, 0], samples[s, 1], samples[s, 2]
        ax, ay, az = frames[s, 0, 2], frames[s, 1, 2], frames[s, 2, 2]
        for i in range(len(points)):
            d0, d1, d2 = points[i, 0] - sx, points[i, 1] - sy, points[i, 2] - sz
            zz = d0 * ax + d1 * ay + d2 * az
            if not abs(zz) <= hh:
                continue
            e0 = np.float64(points[i, 0]) - np.float64(sx)
            e1 = np.float64(points[i, 1]) - np.float64(sy)
            e2 = np.float64(points[i, 2]) - np.float64(sz)
            if not e0 * e0 + e1 * e1 + e2 * e2 <= r2:
                continue
            if o == len(sid):
                grown = max(2 * len(sid), 1024)
                sid2, idx2, local2 = np.empty(grown, np.int64), np.empty(grown, np.int64), np.empty((grown, 3),
                                                                                                     np.float32)
                sid2[:o], idx2[:o], local2[:o] = sid[:o], idx[:o], local[:o]
                sid, idx, local = sid2, idx2, local2
            sid[o], idx[o] = s, i
            local[o, 0] = d0 * frames[s, 0, 0] + d1 * frames[s, 1, 0] + d2 * frames[s, 2, 0]
            local[o, 1] = d0 * frames[s, 0, 1] + d1 * frames[s, 1, 1] + d2 * frames[s, 2, 1]
            local[o, 2] = zz
            o += 1
    return sid, idx, local, o


def slab_neighbours(points: NDArray[np.float32], samples: NDArray[np.float32], frames: NDArray[np.float32],
                    reach: float, half_h: float) -> tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.float32]]:
    """By testing every point against every sample: the (sample row, point row) pairs closer than reach (m) whose
    point lies within half_h (m) of the sample's plane normal to its frame's third axis, in sample then point
    order, and their points in the sample frame (T, 3; float32, m): slab_pairs then slab_coordinates, in one
    pass, for the point sets small enough that testing all pairs is cheaper than a kd-tree."""
    sid, idx, local, n = _slab_scan(np.ascontiguousarray(points, np.float32), np.ascontiguousarray(samples, np.float32),
                                    np.ascontiguousarray(frames, np.float32), reach, half_h, 256 * len(samples))
    return sid[:n], idx[:n], local[:n]


@kernel
def _placements(starts: NDArray[np.int64], lx: NDArray[np.float32], ly: NDArray[np.float32],
                cos: NDArray[np.float32], sin: NDArray[np.float32], s_grid: NDArray[np.float64],
                ranges: NDArray[np.int64], support: NDArray[np.float64], use_support: bool,
                y_max: float, bin_w: float, n_bins: int, hd: float, clear: float, init_bite: float,
                low_bite: NDArray[np.float32], tip: NDArray[np.float32], valid: NDArray[np.bool_]) -> None:
    """tip (S, Phi, Y): the deepest collision-free fingertip depth (m past the sample) of every placement; valid
    where it reaches init_bite, or the sample's low_bite (S,) where the support plane stops the fingertips first.
    ranges (Y, 6): each placement's left finger, right finger and palm bin ranges."""
    n_s, n_phi, n_y = tip.shape
    depth = np.empty(n_bins, np.float32)
    y_off, bw = F32(y_max), F32(bin_w)
    reach, hd32, clear32, bite = F32(hd + clear), F32(hd), F32(clear), F32(init_bite)
    for s in range(n_s):
        for k in range(n_phi):
            depth[:] = np.inf
            c, sn = cos[k], sin[k]
            for t in range(starts[s], starts[s + 1]):
                x = c * lx[t] + sn * ly[t]
                if not x < reach:
                    continue
                y = -sn * lx[t] + c * ly[t]
                b = np.floor((y + y_off) / bw)
                if b >= 0 and b < n_bins:
                    i = int(b)
                    if x < depth[i]:
                        depth[i] = x
            for j in range(n_y):
                left = F32(np.inf)
                for i in range(ranges[j, 0], ranges[j, 1]):
                    left = min(left, depth[i])
                right = F32(np.inf)
                for i in range(ranges[j, 2], ranges[j, 3]):
                    right = min(right, depth[i])
                palm = F32(np.inf)
                for i in range(ranges[j, 4], ranges[j, 5]):
                    palm = min(palm, depth[i])
                v = min(min(left, right) - clear32, palm + hd32)
                v = min(v, hd32)
                need = bite
                if use_support and support[s, k, j] < v:  # the support stops the fingertips, not a point
                    v = F32(support[s, k, j])
                    need = low_bite[s]
                tip[s, k, j] = v
                valid[s, k, j] = v >= need


@kernel
def _choose(tip: NDArray[np.float32], valid: NDArray[np.bool_], starts: NDArray[np.int64],
            lx: NDArray[np.float32], ly: NDArray[np.float32], z: NDArray[np.float32],
            cos: NDArray[np.float32], sin: NDArray[np.float32], s_grid: NDArray[np.float64],
            hd: float, half_w: float, half_h: float, centre: bool,
            chosen: NDArray[np.int64], counts: NDArray[np.int64], ymin: NDArray[np.float64],
            ymax: NDArray[np.float64]) -> None:
    """Per (sample, orientation) with a valid placement: the chosen placement (-1 where none), and the number of
    closing-region points and their y bounds (m, inf/-inf where none) at that placement."""
    n_s, n_phi, n_y = tip.shape
    roomy = np.empty(n_y, np.bool_)
    no_local, no_element = np.empty((0, 3), np.float32), np.empty(0, np.int64)  # counting only: nothing written
    for s in range(n_s):
        for k in range(n_phi):
            n_valid = 0
            total = 0.0
            for j in range(n_y):
                if valid[s, k, j]:
                    n_valid += 1
                    total += j
            if n_valid == 0:
                chosen[s, k] = -1
                continue
            mean_j = total / n_valid
            bj, best = -1, np.inf
            for j in range(n_y):
                if valid[s, k, j] and abs(j - mean_j) < best:
                    bj, best = j, abs(j - mean_j)
            cnt, lo, hi = _closing_region(s, k, bj, tip, starts, lx, ly, z, cos, sin, s_grid, hd, half_w, half_h,
                                          no_local, no_element, -1)
            if centre:
                middle = s_grid[bj] + ((lo + hi) / 2.0 if cnt > 0 else 0.0)
                floor32 = F32(F32(tip[s, k, bj]) - F32(1e-3))
                for j in range(n_y):
                    inner = 0 < j < n_y - 1 and valid[s, k, j - 1] and valid[s, k, j + 1]
                    roomy[j] = valid[s, k, j] and inner and tip[s, k, j] >= floor32
                roomy[bj] = True
                cj, cbest = bj, np.inf
                for j in range(n_y):
                    if roomy[j]:
                        g = round(abs(s_grid[j] - middle) / 1e-4) * n_y + abs(j - bj)
                        if g < cbest:
                            cj, cbest = j, g
                if cj != bj:
                    bj = cj
                    cnt, lo, hi = _closing_region(s, k, bj, tip, starts, lx, ly, z, cos, sin, s_grid, hd, half_w,
                                                  half_h, no_local, no_element, -1)
            chosen[s, k] = bj
            counts[s, k] = cnt
            ymin[s, k] = lo
            ymax[s, k] = hi


@kernel
def _closing_region(s: int, k: int, j: int, tip: NDArray[np.float32], starts: NDArray[np.int64],
                    lx: NDArray[np.float32], ly: NDArray[np.float32], z: NDArray[np.float32],
                    cos: NDArray[np.float32], sin: NDArray[np.float32], s_grid: NDArray[np.float64],
                    hd: float, half_w: float, half_h: float, local: NDArray[np.float32], element: NDArray[np.int64],
                    at: int) -> tuple[int, float, float]:
    """How many slab points of sample s lie in the closing region of its hand at orientation k, placement j, and
    their least and greatest y (m, hand frame); with at >= 0 their hand-frame x, y, z (m) and slab rows are also
    written to local and element from row at, in slab order."""
    shift = np.float64(tip[s, k, j]) - hd
    across = s_grid[j]
    c, sn = cos[k], sin[k]
    hh = F32(half_h)
    cnt, lo, hi = 0, np.inf, -np.inf
    for t in range(starts[s], starts[s + 1]):
        if not abs(z[t]) <= hh:
            continue
        hx = np.float64(c * lx[t] + sn * ly[t]) - shift
        hy = np.float64(-sn * lx[t] + c * ly[t]) - across
        if hx >= 0.0 and hx <= hd and abs(hy) <= half_w:
            if at >= 0:
                local[at + cnt, 0] = F32(hx)
                local[at + cnt, 1] = F32(hy)
                local[at + cnt, 2] = z[t]
                element[at + cnt] = t
            cnt += 1
            lo = min(lo, hy)
            hi = max(hi, hy)
    return cnt, lo, hi


@kernel
def _fill_regions(tip: NDArray[np.float32], chosen: NDArray[np.int64], offsets: NDArray[np.int64],
                  starts: NDArray[np.int64], lx: NDArray[np.float32], ly: NDArray[np.float32],
                  z: NDArray[np.float32], cos: NDArray[np.float32], sin: NDArray[np.float32],
                  s_grid: NDArray[np.float64], hd: float, half_w: float, half_h: float,
                  local: NDArray[np.float32], element: NDArray[np.int64]) -> None:
    """The closing-region points of every chosen hand, at offsets (S, Phi) into local (hand frame x, y, z; m) and
    element (the slab row), each hand's points in slab order."""
    n_s, n_phi, _ = tip.shape
    for s in range(n_s):
        for k in range(n_phi):
            if chosen[s, k] >= 0:
                _closing_region(s, k, chosen[s, k], tip, starts, lx, ly, z, cos, sin, s_grid, hd, half_w, half_h,
                                local, element, offsets[s, k])


def place_hands(starts: NDArray[np.int64], lx: NDArray[np.float32], ly: NDArray[np.float32],
                z: NDArray[np.float32], phis: NDArray[np.float64], s_grid: NDArray[np.float64],
                ranges: NDArray[np.int64], support: NDArray[np.float64] | None, *, y_max: float, bin_w: float,
                n_bins: int, hd: float, clear: float, init_bite: float, low_bite: NDArray[np.float64] | None,
                half_w: float, half_h: float, centre: bool
                ) -> tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.int64], NDArray[np.float32],
                           NDArray[np.float64], NDArray[np.float64], NDArray[np.float32], NDArray[np.int64],
                           NDArray[np.int64]]:
    """The hands of S samples whose slab points (sample frame, float32, m; sample s's rows starts[s]:starts[s+1])
    are given: for every (sample, orientation) with a collision-free placement whose closing region holds points,
    its sample row, orientation row and placement row, its fingertip depth past the sample (m) and its points' y
    bounds (hand frame, m); and their closing-region points: hand row, hand-frame x, y, z (m) and slab row.
    A placement is kept when its fingertips reach init_bite past the sample, or the sample's low_bite (S,; m; None:
    init_bite) where the support plane stops them first."""
    n_s, n_phi, n_y = len(starts) - 1, len(phis), len(s_grid)
    cos, sin = np.cos(phis).astype(np.float32), np.sin(phis).astype(np.float32)
    tip = np.empty((n_s, n_phi, n_y), np.float32)
    valid = np.empty((n_s, n_phi, n_y), np.bool_)
    sup = np.zeros((0, 0, 0)) if support is None else np.ascontiguousarray(support, np.float64)
    _placements(starts, lx, ly, cos, sin, s_grid, ranges, sup, support is not None, y_max, bin_w, n_bins, hd,
                clear, init_bite, np.full(n_s, init_bite, np.float32) if low_bite is None
                else np.ascontiguousarray(low_bite, np.float32), tip, valid)
    chosen = np.full((n_s, n_phi), -1, np.int64)
    counts = np.zeros((n_s, n_phi), np.int64)
    ymin, ymax = np.full((n_s, n_phi), np.inf), np.full((n_s, n_phi), -np.inf)
    _choose(tip, valid, starts, lx, ly, z, cos, sin, s_grid, hd, half_w, half_h, centre, chosen, counts, ymin, ymax)
    chosen[counts == 0] = -1  # no points between the fingers: no hand
    offsets = np.zeros(n_s * n_phi + 1, np.int64)
    np.cumsum(counts.reshape(-1), out=offsets[1:])
    local = np.empty((int(offsets[-1]), 3), np.float32)
    element = np.empty(int(offsets[-1]), np.int64)
    _fill_regions(tip, chosen, offsets[:-1].reshape(n_s, n_phi), starts, lx, ly, z, cos, sin, s_grid, hd, half_w,
                  half_h, local, element)
    si, pi = np.nonzero(chosen >= 0)
    bj = chosen[si, pi]
    hand_of = np.repeat(np.arange(len(si)), counts[si, pi])
    return si, pi, bj, tip[si, pi, bj], ymin[si, pi], ymax[si, pi], local, element, hand_of
