"""The template distance (eq. 1, W and the surface-overlap normalisation) and the matching function (eq. 2)."""

from __future__ import annotations

import numpy as np

from graspd.templates.geometry import BACKGROUND, OCCLUSION, SURFACE, VOID
from graspd.templates.matching import W, distances, entry_gammas, match, matching

T = 900


def _template(surface: slice, height: float = 0.01, rest: int = VOID) -> tuple[np.ndarray, np.ndarray]:
    h = np.full(T, 0.09, np.float32)
    t = np.full(T, rest, np.uint8)
    t[surface] = SURFACE
    h[surface] = height
    return h, t


def _sigma(a: tuple[np.ndarray, np.ndarray], b: tuple[np.ndarray, np.ndarray]) -> float:
    return float(distances(a[0][None], a[1][None], b[0][None], b[1][None])[0, 0])


def test_weight_matrix_is_the_papers() -> None:
    assert W[SURFACE].tolist() == [50, 50, 50, 50] and W[:, SURFACE].tolist() == [50, 50, 50, 50]
    for a in (VOID, OCCLUSION, BACKGROUND):
        for b in (VOID, OCCLUSION, BACKGROUND):
            assert W[a, b] == 12


def test_distance_against_a_direct_sum() -> None:
    rng = np.random.default_rng(0)
    c_h = rng.uniform(0, 0.09, (7, T)).astype(np.float32)
    l_h = rng.uniform(0, 0.09, (5, T)).astype(np.float32)
    c_t = rng.integers(0, 4, (7, T)).astype(np.uint8)
    l_t = rng.integers(0, 4, (5, T)).astype(np.uint8)
    got = distances(c_h, c_t, l_h, l_t)
    for k in range(7):
        for j in range(5):
            sc, sl = c_t[k] == SURFACE, l_t[j] == SURFACE
            o = max(sc.sum(), sl.sum()) / (sc & sl).sum()
            want = o * np.sum(W[c_t[k], l_t[j]] * np.abs(c_h[k].astype(np.float64) - l_h[j])) / T
            assert np.isclose(got[k, j], want, rtol=1e-5)


def test_identical_templates_are_at_zero_and_height_differences_cost_by_type() -> None:
    a = _template(slice(0, 300))
    assert _sigma(a, a) == 0.0
    b = _template(slice(0, 300), height=0.02)  # every surface tile 1 cm lower
    assert np.isclose(_sigma(a, b), 50 * 0.01 * 300 / T, rtol=1e-5)
    c = (a[0].copy(), a[1].copy())
    c[0][600:] = 0.08  # non-surface tiles 1 cm higher: the low weight
    assert np.isclose(_sigma(a, c), 12 * 0.01 * 300 / T, rtol=1e-5)


def test_surface_overlap_normalisation() -> None:
    a = _template(slice(0, 300))
    half = _template(slice(150, 450))  # half of a's surface overlaps
    none = _template(slice(450, 750))
    o_half = max(300, 300) / 150
    raw = np.sum(W[a[1], half[1]] * np.abs(a[0] - half[0])) / T
    assert np.isclose(_sigma(a, half), o_half * raw, rtol=1e-5)
    assert _sigma(a, none) == np.inf  # no common surface: no match at all
    empty = _template(slice(0, 0))
    assert _sigma(empty, empty) == np.inf  # nothing to grasp in either


def test_matching_function_equation_2() -> None:
    alpha = np.array([0.3])
    assert matching(alpha, np.array([np.inf]), np.array([np.inf]))[0] == 0.3  # empty failure set
    beta, gamma = np.array([0.4]), np.array([0.7])
    want = 0.3 / ((1 - np.exp(-3 * 0.16)) * (1 - np.exp(-10 * 0.49)))
    assert np.isclose(matching(alpha, beta, gamma)[0], want)
    assert matching(alpha, np.array([0.0]), gamma)[0] == np.inf  # the candidate is a known failure
    betas = np.linspace(0.05, 2.0, 20)
    assert np.all(np.diff(matching(np.full(20, 0.3), betas, np.full(20, np.inf))) < 0)


def test_failures_raise_the_mismatch_of_similar_candidates_most() -> None:
    lib = _template(slice(0, 300))
    near = _template(slice(0, 300), height=0.02)
    far = _template(slice(0, 300), height=0.0)
    fail = _template(slice(0, 300), height=0.021)  # a failed candidate close to `near`
    c_h, c_t = np.stack([near[0], far[0]]), np.stack([near[1], far[1]])
    no_fail, _ = match(c_h, c_t, lib[0][None], lib[1][None], np.zeros((0, T), np.float32),
                       np.zeros((0, T), np.uint8), np.zeros(0, np.int64))
    with_fail, _ = match(c_h, c_t, lib[0][None], lib[1][None], fail[0][None], fail[1][None], np.zeros(1, np.int64))
    assert np.isclose(no_fail[0, 0], no_fail[1, 0])  # equally far from the library template ...
    assert with_fail[0, 0] > 5 * with_fail[1, 0]  # ... but near is much like a known failure now
    assert with_fail[1, 0] > no_fail[1, 0]  # gamma: the entry's grasp is less trusted everywhere
    gamma = entry_gammas(lib[0][None], lib[1][None], fail[0][None], fail[1][None], np.zeros(1, np.int64))
    assert np.isclose(gamma[0], _sigma(lib, fail))
