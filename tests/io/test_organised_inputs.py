"""Every organised source keeps its image grid on the way to the detector (ViewpointCloud.grid: height, width and
each kept point's pixel index, rows without depth dropped): organised PCD files (the real PCL captures), (H,W,3)
.npy, .npz with a shape, depth images, organised PointCloud2 and bag messages.  Unorganised ones have none."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).parent))
from bags import IMAGE_TOPIC, INTRINSICS, depth_image, write_rosbag2  # noqa: E402

from graspd.core.cloud import CloudError  # noqa: E402
from graspd.io.bag import BagQuery, read_bag  # noqa: E402
from graspd.io.cloud_files import read_input  # noqa: E402
from graspd.io.inputs import cloud_input  # noqa: E402
from graspd.io.pcd import read_pcd  # noqa: E402
from graspd.io.ros.decode import decode_cloud_sources, decode_pointcloud2  # noqa: E402
from graspd.io.ros.encode import encode_cloud_sources, encode_pointcloud2  # noqa: E402


@pytest.mark.parametrize("name", ["milk_cartoon_all_small_clorox.pcd", "table_scene_mug_stereo_textured.pcd"])
def test_the_real_organised_captures_keep_their_grid(real_data: Path, name: str) -> None:
    """640x480 with NaN holes: each kept point is the file's row at its pixel."""
    path = real_data / name
    got = read_input(path)
    grid = got.cloud.grid
    assert grid is not None and (grid.height, grid.width) == (480, 640)
    rows = read_pcd(path.read_bytes()).points
    assert got.received == 480 * 640 and got.dropped == 480 * 640 - len(got.cloud) > 0
    assert np.array_equal(got.cloud.points, rows[grid.pixel])
    assert np.isfinite(rows[grid.pixel]).all() and np.all(np.diff(grid.pixel) > 0)


@pytest.mark.parametrize("name", ["krylon.pcd", "table_mug.pcd"])
def test_unorganised_captures_have_no_grid(real_data: Path, name: str) -> None:
    assert read_input(real_data / name).cloud.grid is None


def test_a_depth_image_keeps_the_pixels_that_have_depth(tmp_path: Path) -> None:
    depth = depth_image().astype(np.float32) * np.float32(0.001)
    depth[5, 7] = np.nan  # no reading: a non-finite row, dropped and counted
    path = tmp_path / "depth.npy"
    np.save(path, depth)
    got = read_input(path, intrinsics=tuple(INTRINSICS))
    grid = got.cloud.grid
    assert grid is not None and (grid.height, grid.width) == depth.shape
    has_depth = (depth != 0) & np.isfinite(depth)
    assert np.array_equal(grid.pixel, np.flatnonzero(has_depth))
    assert got.dropped == 1
    # each point lies on its pixel's ray: x / z = (u - cx) / fx
    u = grid.pixel % depth.shape[1]
    pts = got.cloud.points
    assert np.allclose(pts[:, 0] / pts[:, 2], (u - INTRINSICS.cx) / INTRINSICS.fx, atol=1e-6)


def test_an_organised_npy_and_npz_keep_their_grid(tmp_path: Path) -> None:
    image = np.random.default_rng(0).uniform(0.5, 1.0, (6, 8, 3)).astype(np.float32)
    image[0, :2] = np.nan
    np.save(tmp_path / "cloud.npy", image)
    got = read_input(tmp_path / "cloud.npy").cloud
    assert got.grid is not None and (got.grid.height, got.grid.width) == (6, 8)
    assert np.array_equal(got.grid.pixel, np.arange(2, 48))
    np.savez(tmp_path / "cloud.npz", points=image.reshape(-1, 3), shape=np.array([6, 8]))
    npz = read_input(tmp_path / "cloud.npz").cloud
    assert npz.grid is not None and np.array_equal(npz.grid.pixel, got.grid.pixel)
    np.savez(tmp_path / "bad.npz", points=image.reshape(-1, 3), shape=np.array([7, 8]))
    with pytest.raises(CloudError) as err:
        read_input(tmp_path / "bad.npz")
    assert err.value.field == "cloud.shape"


def test_an_organised_pointcloud2_keeps_its_grid() -> None:
    pts = np.random.default_rng(1).uniform(0.5, 1.0, (12, 3)).astype(np.float32)
    pts[[3, 7]] = np.nan
    organised = decode_pointcloud2(encode_pointcloud2(pts, shape=(3, 4)))
    assert organised.cloud.grid is not None and (organised.cloud.grid.height, organised.cloud.grid.width) == (3, 4)
    assert np.array_equal(organised.cloud.grid.pixel, [0, 1, 2, 4, 5, 6, 8, 9, 10, 11])
    assert decode_pointcloud2(encode_pointcloud2(pts)).cloud.grid is None  # height 1: unorganised
    # one camera's organised CloudSources keeps it; several cameras' points in one message are no one image
    one = decode_cloud_sources(encode_cloud_sources(pts, [[0, 0, 0]], shape=(3, 4)))
    assert one.cloud.grid is not None and np.array_equal(one.cloud.grid.pixel, organised.cloud.grid.pixel)
    two = decode_cloud_sources(encode_cloud_sources(pts, [[0, 0, 0], [1, 0, 0]], [0, 1] * 6, shape=(3, 4)))
    assert two.cloud.grid is None


def test_a_bag_depth_image_keeps_its_grid(tmp_path: Path) -> None:
    bag = write_rosbag2(tmp_path / "bag")
    message = next(read_bag(bag, BagQuery(topic=IMAGE_TOPIC)))
    cloud = message.cloud_input().cloud
    assert cloud.grid is not None and (cloud.grid.height, cloud.grid.width) == depth_image().shape
    assert np.array_equal(cloud.grid.pixel, np.flatnonzero(depth_image() != 0))


def test_shape_counts_the_rows_as_sent_and_poses_keep_the_grid() -> None:
    """cloud_input with shape: height * width rows as sent (NaN ones included, then dropped), each kept point's
    pixel its row as sent; a camera pose moves the points, not their pixels; a wrong shape names cloud.shape."""
    pts = np.random.default_rng(2).uniform(0.5, 1.0, (12 * 16, 3)).astype(np.float32)
    pts[:16] = np.nan
    pose = np.eye(4)
    pose[:3, 3] = [0.125, 0.25, 0.5]
    got = cloud_input(pts, shape=(12, 16), camera_poses=[pose.tolist()], points_frame="camera")
    assert got.dropped == 16 and got.cloud.grid is not None
    assert np.array_equal(got.cloud.grid.pixel, np.arange(16, 12 * 16))
    assert np.array_equal(got.cloud.points, (pts[16:].astype(np.float64) + pose[:3, 3]).astype(np.float32))
    assert cloud_input(pts).cloud.grid is None
    with pytest.raises(CloudError) as err:
        cloud_input(pts, shape=(11, 16))  # the finite rows only: not what was sent
    assert err.value.field == "cloud.shape"
