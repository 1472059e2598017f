"""The nearest-camera stand-in for a lost camera_source: the same indices as the argmin of the full N x K
distance table (ties to the first camera), in memory that does not grow with the count of cameras."""

from __future__ import annotations

import tracemalloc

import numpy as np
import pytest

from graspd.core.cloud import CloudError
from graspd.io.camera_source import nearest_camera
from graspd.io.inputs import cloud_input


def table_argmin(points: np.ndarray, viewpoints: np.ndarray) -> np.ndarray:
    """The N x K x 3 way: what nearest_camera must equal."""
    d = np.linalg.norm(points[:, None, :] - viewpoints[None, :, :], axis=2)
    return np.argmin(d, axis=1).astype(np.int32)


@pytest.mark.parametrize(("pts_dtype", "vps_dtype"), [(np.float32, np.float64), (np.float32, np.float32),
                                                      (np.float64, np.float64)])
def test_nearest_camera_equals_the_argmin_of_the_distance_table(pts_dtype: type, vps_dtype: type) -> None:
    rng = np.random.default_rng(3)
    points = rng.normal(size=(150_000, 3)).astype(pts_dtype)  # more than one block of rows
    viewpoints = rng.normal(size=(9, 3)).astype(vps_dtype)
    viewpoints[6] = viewpoints[2]  # an exact tie: the first camera keeps the point
    got = nearest_camera(points, viewpoints)
    assert got.dtype == np.int32 and np.array_equal(got, table_argmin(points, viewpoints))
    assert not (got == 6).any()
    assert np.array_equal(nearest_camera(points[:5], viewpoints[:1]), np.zeros(5, np.int32))


def test_nearest_camera_memory_does_not_grow_with_the_cameras() -> None:
    """200k points and 64 cameras: the table would be 200k x 64 x 3 float64 (307 MB); the search takes a few MB
    (the answer's 0.8 MB and a block's temporaries)."""
    rng = np.random.default_rng(4)
    points = rng.normal(size=(200_000, 3)).astype(np.float32)
    viewpoints = rng.normal(size=(64, 3))
    tracemalloc.start()
    try:
        nearest_camera(points, viewpoints)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 8 << 20


def test_cloud_input_counts_the_cameras_before_any_array_is_built_from_them() -> None:
    points = np.zeros((10, 3), np.float32)
    with pytest.raises(CloudError) as err:
        cloud_input(points, np.ones((1000, 3)))
    assert err.value.field == "cloud.viewpoints" and "64" in err.value.message
    assert len(cloud_input(points, np.ones((64, 3))).cloud.viewpoints) == 64
