"""The voxel grid (graspd.core.points.voxel_groups / voxel_sums / voxel_downsample and graspd.gpd.preprocess
.voxelize, one compiled pass) against a straightforward reference written here: numpy's floor of p / voxel,
np.unique over the grid rows (x, then y, then z), float64 sums in point order (np.add.at), votes per camera.
Inputs: a noisy two-camera tabletop, a cloud kilometres wide, points on voxel boundaries, and the edge cases (no,
one, two points, duplicates, one point repeated, huge coordinates)."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest
from numpy.typing import NDArray

from graspd.core.points import voxel_downsample, voxel_groups, voxel_sums
from graspd.gpd.preprocess import voxelize


def reference(points: NDArray[np.floating], voxel: Any, source: NDArray[np.int32] | None = None,
              normals: NDArray[np.float32] | None = None) -> dict[str, NDArray[Any]]:
    """Each point's voxel, the counts, float64 sums, means (float32) and majority camera (lowest on a tie) per
    voxel, voxels in grid order; grid indices clipped to +-2^61 as the kernel's are."""
    limit = float(1 << 61)
    with np.errstate(over="ignore"):  # float32's largest coordinates over a few mm: inf, clipped
        grid = np.clip(np.floor(points / voxel), -limit, limit).astype(np.int64).reshape(-1, 3)
    _, inverse, counts = np.unique(grid, axis=0, return_inverse=True, return_counts=True)
    inverse = inverse.reshape(-1)
    m = len(counts)
    sums = np.zeros((m, 3))
    np.add.at(sums, inverse, np.asarray(points, np.float64))  # unbuffered, in point order
    out: dict[str, NDArray[Any]] = {"inverse": inverse, "counts": counts, "sums": sums,
                                    "means": (sums / counts[:, None]).astype(np.float32)}
    if source is not None:
        ncam = int(source.max()) + 1
        votes = np.zeros((m, ncam), np.int64)
        np.add.at(votes, (inverse, source), 1)
        out["camera"] = np.argmax(votes, axis=1).astype(np.int32)
    if normals is not None:
        nsum = np.zeros((m, 3))
        np.add.at(nsum, inverse, np.asarray(normals, np.float64))
        out["normals"] = (nsum / np.maximum(np.linalg.norm(nsum, axis=1, keepdims=True), 1e-12)).astype(np.float32)
    return out


def tabletop(n: int, seed: int = 0) -> tuple[NDArray[np.float32], NDArray[np.int32], NDArray[np.float32]]:
    """n points (m, table frame) of a 60 x 40 cm table top at z = 0 (on a voxel boundary: points alternate
    between two layers) with a box and a ball on it, 0.5 mm noise; two cameras; random unit normals."""
    rng = np.random.default_rng(seed)
    k = n // 3
    table = np.c_[rng.uniform(-0.3, 0.3, k), rng.uniform(-0.2, 0.2, k), np.zeros(k)]
    box = np.c_[rng.uniform(0.0, 0.1, k), rng.uniform(0.0, 0.08, k), rng.choice([0.05, 0.12], k)]
    d = rng.normal(size=(n - 2 * k, 3))
    ball = np.array([-0.1, -0.05, 0.04]) + 0.04 * d / np.linalg.norm(d, axis=1, keepdims=True)
    pts = np.concatenate([table, box, ball]) + rng.normal(0.0, 5e-4, (n, 3))
    source = (pts[:, 0] > rng.normal(0.0, 0.05, n)).astype(np.int32)  # overlapping views: mixed voxels
    normals = rng.normal(size=(n, 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    return pts.astype(np.float32), source, normals.astype(np.float32)


def assert_grid(points: NDArray[np.floating], voxel: float, **kw: Any) -> None:
    """voxel_groups and voxel_sums equal the reference exactly (the same float64 additions in the same order)."""
    ref = reference(points, voxel)
    inverse, counts = voxel_groups(points, voxel)
    assert np.array_equal(inverse, ref["inverse"]) and np.array_equal(counts, ref["counts"])
    rows, ids = voxel_sums(points, voxel, with_ids=True, **kw)
    assert ids is not None and np.array_equal(ids, ref["inverse"])
    assert np.array_equal(rows[:, 0], ref["counts"]) and np.array_equal(rows[:, 1:4], ref["sums"])


def test_tabletop_voxelize_matches_reference() -> None:
    pts, source, normals = tabletop(60_000)
    ref = reference(pts, 0.003, source, normals)
    out_pts, out_src, out_nrm = voxelize(pts, source, 0.003, normals)
    assert out_pts.dtype == np.float32 and out_src.dtype == np.int32 and out_nrm is not None
    assert np.array_equal(out_pts, ref["means"])
    assert np.array_equal(out_src, ref["camera"])
    assert np.array_equal(out_nrm, ref["normals"])
    no_normals = voxelize(pts, source, 0.003)
    assert np.array_equal(no_normals[0], ref["means"]) and no_normals[2] is None
    one_camera = voxelize(pts, np.zeros(len(pts), np.int32), 0.003)
    assert np.array_equal(one_camera[0], ref["means"]) and not one_camera[1].any()
    assert_grid(pts, 0.003)
    assert_grid(pts, 0.01)


def test_float64_points_keep_their_arithmetic() -> None:
    pts = tabletop(20_000, seed=1)[0].astype(np.float64) + 0.1234567
    assert_grid(pts, 0.004)
    down = voxel_downsample(pts, 0.004)
    assert down.dtype == np.float64 and np.array_equal(down, reference(pts, 0.004)["sums"] /
                                                        reference(pts, 0.004)["counts"][:, None])
    down32 = voxel_downsample(pts.astype(np.float32), 0.004)
    assert down32.dtype == np.float32 and np.array_equal(down32, reference(pts.astype(np.float32), 0.004)["means"])


def test_points_on_voxel_boundaries() -> None:
    """Multiples of the voxel (in float32 and in float64) land where numpy's division puts them."""
    k = np.arange(-2000, 2000)
    for dtype in (np.float32, np.float64):
        on = (k * dtype(0.003)).astype(dtype)
        pts = np.stack([on, on[::-1], np.roll(on, 7)], axis=1)
        assert_grid(pts, 0.003)
        assert_grid(np.nextafter(pts, dtype(np.inf)), 0.003)
        assert_grid(np.nextafter(pts, dtype(-np.inf)), 0.003)


def test_slabs_change_nothing() -> None:
    """Clouds split into slabs of x (threads) give the same voxels, order, ids and float64 sums."""
    pts, source, normals = tabletop(600_000, seed=2)
    base, ids = voxel_sums(pts, 0.003, source, normals, with_ids=True, slabs=1)
    assert ids is not None
    for slabs in (2, 3, 7):
        rows, ids_k = voxel_sums(pts, 0.003, source, normals, with_ids=True, slabs=slabs)
        assert np.array_equal(rows, base) and ids_k is not None and np.array_equal(ids_k, ids)
    assert np.array_equal(ids, reference(pts, 0.003)["inverse"])


def test_kilometres_wide_cloud() -> None:
    """Grids far too large for any dense array or one int64 key (3 km x 3 km x 3 km at 3 mm: 1e18 cells; and 40 km
    tall: more than 2^62) are fine: memory follows the occupied voxels."""
    rng = np.random.default_rng(3)
    pts = np.concatenate([tabletop(5000, seed=4)[0] + np.float32([1500.0, -1500.0, 0.0]),
                          rng.uniform(-1500.0, 1500.0, (3000, 3)).astype(np.float32)])
    assert_grid(pts, 0.003)
    tall = np.concatenate([pts, np.float32([[0.0, 0.0, 40_000.0], [0.0, 0.0, -40_000.0]])])
    assert_grid(tall, 0.003)


def test_no_one_and_two_points() -> None:
    inverse, counts = voxel_groups(np.zeros((0, 3), np.float32), 0.003)
    assert inverse.shape == (0,) and counts.shape == (0,)
    out_pts, out_src, _ = voxelize(np.zeros((0, 3), np.float32), np.zeros(0, np.int32), 0.003)
    assert out_pts.shape == (0, 3) and out_src.shape == (0,)
    assert voxel_downsample(np.zeros((0, 3)), 0.003).shape == (0, 3)
    one = np.float32([[0.1, -0.2, 0.3]])
    assert np.array_equal(voxelize(one, np.zeros(1, np.int32), 0.003)[0], one)
    two = np.float32([[0.1, -0.2, 0.3], [0.1005, -0.2005, 0.3005]])
    assert_grid(two, 0.003)
    assert_grid(two, 0.0001)


def test_duplicates_and_one_repeated_point() -> None:
    pts, source, _ = tabletop(5000, seed=5)
    dup = np.concatenate([pts, pts[::-1], pts[:100]])
    assert_grid(dup, 0.003)
    same = np.full((100_000, 3), -0.25, np.float32)
    inverse, counts = voxel_groups(same, 0.003)
    assert not inverse.any() and counts.tolist() == [100_000]
    out = voxelize(same, np.zeros(len(same), np.int32), 0.003)[0]
    assert np.array_equal(out, same[:1])


def test_camera_votes_ties_go_to_the_lowest_camera() -> None:
    pts = np.float32([[0.0005, 0.0005, 0.0005]] * 4 + [[0.0105, 0.0, 0.0]] * 3)
    source = np.int32([2, 1, 1, 2, 3, 0, 3])
    assert voxelize(pts, source, 0.003)[1].tolist() == [1, 3]


@pytest.mark.parametrize("scale", [1e9, 1e15, 3e38])
def test_huge_coordinates(scale: float) -> None:
    """Finite coordinates far beyond any scene: grid indices past +-2^61 voxels share the edge voxel; nothing
    overflows and the other points' voxels are untouched."""
    pts, _, _ = tabletop(3000, seed=6)
    far = np.float32([[scale, 0, 0], [-scale, scale, 0], [0, 0, scale], [scale, 0, 0]])
    both = np.concatenate([pts, far])
    assert_grid(both, 0.003)
    inverse, _ = voxel_groups(both, 0.003)
    assert np.array_equal(np.unique(inverse[:3000], return_inverse=True)[1], reference(pts, 0.003)["inverse"])


def test_point_beyond_the_sampled_grid() -> None:
    """One far point that the bounds sample skips (a cloud of 200k points is sampled every 48th row) leaves the
    packed keys' room: the grid is made again with three-index keys, the same as the reference."""
    pts, source, _ = tabletop(200_000, seed=7)
    pts[100_001] = [9000.0, -0.1, 0.2]  # 9 km: beyond 3 km of room at 3 mm
    assert_grid(pts, 0.003)
    out = voxelize(pts, source, 0.003)
    ref = reference(pts, 0.003, source)
    assert np.array_equal(out[0], ref["means"]) and np.array_equal(out[1], ref["camera"])
