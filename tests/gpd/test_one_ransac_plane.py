"""One RANSAC plane fit (graspd.core.points.best_plane) serves the environment stage and the core's ransac_plane:
it finds a known plane among outliers, both callers return its plane for their seeded hypotheses, and the
environment package keeps the public names its importers use."""

from __future__ import annotations

import numpy as np

import graspd.gpd.environment as environment
from graspd.core.points import best_plane, ransac_plane
from graspd.gpd.environment import EnvironmentParams, fit_plane


def tilted_table(seed: int = 0) -> np.ndarray:
    """3000 points on the plane z = 0.1 x + 0.3 (1 mm noise) and 1000 points scattered above it (m)."""
    rng = np.random.default_rng(seed)
    xy = rng.uniform(-0.3, 0.3, (3000, 2))
    table = np.column_stack([xy, 0.1 * xy[:, 0] + 0.3 + rng.normal(0.0, 0.001, 3000)])
    clutter = rng.uniform([-0.3, -0.3, 0.35], [0.3, 0.3, 0.6], (1000, 3))
    return np.concatenate([table, clutter])


def test_best_plane_finds_the_table_among_clutter() -> None:
    pts = tilted_table()
    fit = best_plane(pts, np.random.default_rng(1).integers(0, len(pts), (200, 3)), 0.005)
    assert fit is not None
    abcd, count = fit
    expected = np.array([-0.1, 0.0, 1.0]) / np.linalg.norm([-0.1, 0.0, 1.0])
    assert abs(abs(float(abcd[:3] @ expected)) - 1.0) < 1e-4
    assert 2700 <= count <= 3100
    # with the table excluded as not upright to z, only near-vertical planes count (the clutter holds none)
    upright = best_plane(pts, np.random.default_rng(1).integers(0, len(pts), (200, 3)), 0.005,
                         vertical_to=np.array([0.0, 0.0, 1.0]), max_tilt_deg=20.0)
    assert upright is None or upright[1] < 300


def test_environment_and_core_callers_return_the_fit_of_their_own_hypotheses() -> None:
    pts = tilted_table()
    params = EnvironmentParams(ransac_points=2000, ransac_iterations=100)
    plane = fit_plane(pts, params, np.random.default_rng(5))
    rng = np.random.default_rng(5)  # the same draws fit_plane makes: a subsample, then the triplets
    sub = pts[rng.choice(len(pts), 2000, replace=False)]
    expected = best_plane(sub, rng.integers(0, 2000, (100, 3)), params.plane_distance)
    assert plane is not None and expected is not None
    assert np.array_equal(plane.normal, expected[0][:3]) and plane.offset == expected[0][3]
    model, count = ransac_plane(pts, 0.005, iterations=50, seed=3)
    rng = np.random.default_rng(3)
    fit = best_plane(pts, np.stack([rng.choice(len(pts), 3, replace=False) for _ in range(50)]), 0.005)
    assert fit is not None and np.array_equal(model, fit[0]) and count == fit[1]


def test_environment_package_exports_the_names_its_importers_use() -> None:
    names = {"Box", "Environment", "EnvironmentParams", "Label", "Plane", "Surface", "hand_hits_environment",
             "model_environment", "ENVIRONMENT_MODES"}
    assert names <= set(environment.__all__)
    assert all(getattr(environment, n).__module__.startswith("graspd.gpd.environment.")
               for n in names if n != "ENVIRONMENT_MODES")
