"""PCA normals (graspd.core.points.pca_normals, a compiled grid search) against a brute-force reference written
here: every pairwise distance, the max_nn nearest within the radius (the point itself included), the centred
covariance and numpy's eigh.  Inputs: a noisy procedural surface, patches kilometres apart, and the edge cases
(no, one, two points, duplicates, one point repeated, huge coordinates)."""

from __future__ import annotations

import numpy as np
import pytest
from numpy.typing import NDArray

from graspd.core.points import pca_normals

#: Normals agree to this angle (rad) up to sign: the output is float32 (about 6e-8 per component).
ANGLE = 1e-6


def reference_normals(points: NDArray[np.floating], radius: float, max_nn: int
                      ) -> tuple[NDArray[np.float64], NDArray[np.bool_], NDArray[np.float64]]:
    """Unit normals (N,3) by brute force; which points' normals are ambiguous: their neighbour set (the max_nn-th
    and the next nearest point within the radius at the same distance but elsewhere: either may be taken) or
    their least axis (the two least eigenvalues equal to 1e-9 of the largest: neighbours on a line); and each
    point's neighbourhood covariance (N,3,3, to check an ambiguous axis is still a least-variance one)."""
    pts = np.asarray(points, np.float64)
    out = np.tile([0.0, 0.0, 1.0], (len(pts), 1))
    ambiguous = np.zeros(len(pts), bool)
    covs = np.zeros((len(pts), 3, 3))
    reach = radius * (1.0 + 1e-12)
    for i, p in enumerate(pts):
        d2 = ((pts - p) ** 2).sum(axis=1)
        order = np.argsort(d2, kind="stable")
        within = order[d2[order] <= reach * reach]
        if len(within) > max_nn:
            ambiguous[i] = d2[within[max_nn - 1]] == d2[within[max_nn]] and not np.array_equal(
                pts[within[max_nn - 1]], pts[within[max_nn]])
        nb = pts[within[:max_nn]]
        if len(nb) < 3:
            continue
        centred = nb - nb.mean(axis=0)
        covs[i] = centred.T @ centred / len(nb)
        w, v = np.linalg.eigh(covs[i])
        if w[2] > 0.0:
            out[i] = v[:, 0]
            ambiguous[i] |= w[1] - w[0] <= 1e-9 * w[2]
    return out, ambiguous, covs


def angles(a: NDArray[np.floating], b: NDArray[np.floating]) -> NDArray[np.float64]:
    """Angle (rad) between unit vectors up to sign, accurate near 0 (from the chord, not the dot product)."""
    a64 = np.asarray(a, np.float64)
    b64 = np.asarray(b, np.float64)
    a64 = a64 / np.linalg.norm(a64, axis=1, keepdims=True)
    b64 = b64 / np.linalg.norm(b64, axis=1, keepdims=True)
    chord = np.minimum(np.linalg.norm(a64 - b64, axis=1), np.linalg.norm(a64 + b64, axis=1))
    return np.asarray(2.0 * np.arcsin(np.minimum(chord / 2.0, 1.0)))


def wavy_surface(n: int, seed: int = 0, noise: float = 3e-4) -> NDArray[np.float32]:
    """n points (m) of a 20 x 20 cm wavy sheet with Gaussian noise."""
    rng = np.random.default_rng(seed)
    xy = rng.uniform(-0.1, 0.1, (n, 2))
    z = 0.02 * np.sin(30 * xy[:, 0]) * np.cos(20 * xy[:, 1]) + rng.normal(0.0, noise, n)
    return np.c_[xy, z].astype(np.float32)


def assert_match(points: NDArray[np.floating], radius: float = 0.01, max_nn: int = 30, max_ambiguous: int = 0
                 ) -> None:
    """pca_normals agrees with the reference within ANGLE wherever the reference's normal is unambiguous; where it
    is not (at most max_ambiguous points), the normal is still one of least variance (a linear neighbourhood's
    axes normal to the line) or the point had neighbours at tied distances."""
    got = pca_normals(points, radius, max_nn)
    ref, ambiguous, covs = reference_normals(points, radius, max_nn)
    assert got.shape == (len(points), 3) and got.dtype == np.float32
    assert int(ambiguous.sum()) <= max_ambiguous
    if len(points):
        assert np.allclose(np.linalg.norm(got, axis=1), 1.0, atol=1e-6)
        err = angles(got, ref)[~ambiguous]
        assert err.max(initial=0.0) <= ANGLE, (err.max(), int((err > ANGLE).sum()))
        g = got[ambiguous].astype(np.float64)
        variance = np.einsum("ni,nij,nj->n", g, covs[ambiguous], g)
        least = np.linalg.eigvalsh(covs[ambiguous])
        assert np.all(variance <= least[:, 1] + 1e-6 * least[:, 2] + 1e-30)


def test_noisy_surface_matches_brute_force() -> None:
    pts = wavy_surface(3000)
    assert_match(pts)
    assert_match(pts, radius=0.02, max_nn=12)  # the max_nn nearest, not all within the radius
    assert_match(pts, radius=0.004, max_nn=30)  # sparse: some points with fewer than 3 neighbours


def test_same_normals_whatever_the_chunking() -> None:
    pts = wavy_surface(2000, seed=1)
    base = pca_normals(pts, 0.01, 30)
    for chunk in (1, 7, 500, 100_000):
        assert np.array_equal(pca_normals(pts, 0.01, 30, chunk=chunk), base)


def test_kilometres_wide_cloud() -> None:
    """Patches 3 km apart and far from the origin (the covariance is centred: no cancellation), among isolated
    points spread over the whole extent (no dense grid over it)."""
    rng = np.random.default_rng(2)
    patches = [wavy_surface(600, seed=s) + np.float32(off) for s, off in
               enumerate([(0.0, 0.0, 0.0), (1500.0, -1500.0, 20.0), (-1500.0, 1400.0, -5.0)])]
    scattered = rng.uniform(-1500.0, 1500.0, (400, 3)).astype(np.float32)
    pts = np.concatenate([*patches, scattered])
    assert_match(pts)
    got = pca_normals(pts, 0.01, 30)
    assert np.array_equal(got[-400:], np.tile(np.float32([0, 0, 1]), (400, 1)))  # isolated points
    far = wavy_surface(800, seed=3).astype(np.float64) + 2.0e5  # float64 input 200 km away
    assert_match(far)


def test_no_one_and_two_points() -> None:
    assert pca_normals(np.zeros((0, 3), np.float32), 0.01, 30).shape == (0, 3)
    for n in (1, 2):
        got = pca_normals(np.random.default_rng(n).uniform(0, 0.001, (n, 3)), 0.01, 30)
        assert np.array_equal(got, np.tile(np.float32([0, 0, 1]), (n, 1)))


def test_three_points_and_max_nn_below_three() -> None:
    tri = np.array([[0.0, 0.0, 0.0], [0.004, 0.0, 0.0], [0.0, 0.004, 0.001]], np.float32)
    assert_match(tri)
    assert np.array_equal(pca_normals(wavy_surface(200), 0.01, 2), np.tile(np.float32([0, 0, 1]), (200, 1)))


def test_duplicates_and_one_repeated_point() -> None:
    pts = wavy_surface(800, seed=4)
    # ties between copies are no ambiguity (the same coordinates either way); the few points whose neighbourhood
    # is two places (copies of two points: a line) have no unique normal (27 and 39 of them here)
    assert_match(np.concatenate([pts, pts, pts[:100]]), max_ambiguous=30)
    assert_match(np.repeat(pts, 3, axis=0), max_ambiguous=45)  # copies next to each other
    same = np.full((5000, 3), 0.25, np.float32)
    assert np.array_equal(pca_normals(same, 0.01, 30), np.tile(np.float32([0, 0, 1]), (5000, 1)))


@pytest.mark.parametrize("scale", [1e6, 1e15, 3e38])
def test_huge_coordinates(scale: float) -> None:
    """Finite coordinates far beyond any scene (up to float32's largest) leave the other points' normals alone and
    get (0, 0, 1) when isolated."""
    pts = np.concatenate([wavy_surface(500, seed=5), np.float32([[scale, 0, 0], [-scale, scale, 0], [0, 0, scale]])])
    got = pca_normals(pts, 0.01, 30)
    ref, ambiguous, _ = reference_normals(pts[:500], 0.01, 30)
    assert not ambiguous.any()
    assert angles(got[:500], ref).max() <= ANGLE
    assert np.array_equal(got[500:], np.tile(np.float32([0, 0, 1]), (3, 1)))


def test_neighbour_exactly_at_the_radius_counts() -> None:
    """Points on a 0.25 m lattice with a 0.5 m radius: neighbours at exactly the radius are in (open3d's hybrid
    search includes them), so the lattice's ties at the max_nn-th distance are the only ambiguity."""
    g = np.arange(0.0, 2.0, 0.25)
    x, y = np.meshgrid(g, g)
    pts = np.c_[x.ravel(), y.ravel(), 0.01 * x.ravel() ** 2]
    got = pca_normals(pts, 0.5, 200)  # every neighbour within the radius: no ties
    ref, ambiguous, _ = reference_normals(pts, 0.5, 200)
    assert not ambiguous.any() and angles(got, ref).max() <= ANGLE
