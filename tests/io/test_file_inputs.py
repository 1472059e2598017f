"""The .npy/.npz/depth-image readers refuse what they cannot safely read, naming the field, before allocating
it: pickled objects, records, headers that lie, zip members declaring more than the cap, colour PNGs; and a depth
image back-projects through the one camera model onto the points the camera saw."""

from __future__ import annotations

import io
import zipfile

import numpy as np
import pytest
from PIL import Image

from graspd.core.camera import Camera, Intrinsics, backproject, camera_intrinsics, camera_pose, depth_image
from graspd.core.cloud import CloudError
from graspd.io.cloud_files import MAX_NPY_VALUES, array_cloud, parse_npy, parse_npz
from graspd.io.depth import depth_metres, depth_points, read_depth_png


def npy(array: np.ndarray) -> bytes:
    buf = io.BytesIO()
    np.save(buf, array, allow_pickle=True)
    return buf.getvalue()


def test_npy_reads_numbers_and_refuses_the_rest() -> None:
    pts = np.arange(12, dtype=np.float32).reshape(4, 3)
    assert np.array_equal(parse_npy(npy(pts)), pts)
    for bad, words in ((np.array([{"a": 1}], dtype=object), "numbers expected"),
                       (np.zeros(3, dtype=[("x", "f4"), ("y", "f4")]), "numbers expected"),
                       (np.array(["a", "b"]), "numbers expected")):
        with pytest.raises(CloudError, match=words):
            parse_npy(npy(bad))
    with pytest.raises(CloudError, match="the file holds"):
        parse_npy(npy(pts)[:-4])  # truncated
    header = npy(np.zeros((1, 3), np.float32))
    lying = header.replace(b"(1, 3)", b"(" + str(MAX_NPY_VALUES).encode() + b", 3)")
    with pytest.raises(CloudError, match="exceeds the limit"):  # refused from the header, nothing allocated
        parse_npy(lying)
    broken = header.replace(b"), }", b"   ").replace(b"(1, 3", b"(1, 3 ")  # numpy's parser: a TokenError
    with pytest.raises(CloudError, match="unreadable header"):  # found by fuzzing: once a 500
        parse_npy(broken)


def test_npz_reads_the_cloud_arrays_and_refuses_a_bomb() -> None:
    buf = io.BytesIO()
    np.savez(buf, points=np.ones((5, 3)), viewpoints=np.zeros((1, 3)), colours=np.zeros((5, 3)))
    arrays = parse_npz(buf.getvalue())
    assert set(arrays) == {"points", "viewpoints"}
    buf = io.BytesIO()
    np.savez(buf, cloud=np.ones((5, 3)))
    with pytest.raises(CloudError) as err:
        parse_npz(buf.getvalue())
    assert err.value.field == "cloud.points" and "'points'" in err.value.message
    bomb = io.BytesIO()
    with zipfile.ZipFile(bomb, "w", zipfile.ZIP_DEFLATED) as z:
        with z.open("points.npy", "w", force_zip64=True) as f:
            f.write(npy(np.zeros((1, 3), np.float32))[:128])
            chunk = bytes(1 << 20)
            for _ in range(130):  # 130 MB of zeros: a few hundred kB compressed
                f.write(chunk)
    with pytest.raises(CloudError) as err:
        parse_npz(bomb.getvalue())
    assert err.value.field == "cloud.points" and "beyond the limit" in err.value.message
    with pytest.raises(CloudError, match="not a zip"):
        parse_npz(b"PK\x03\x04 nothing")


def test_array_shapes() -> None:
    assert array_cloud(np.zeros((4, 5, 3))).shape == (20, 3)
    with pytest.raises(CloudError) as err:
        array_cloud(np.zeros((4, 5)))
    assert err.value.field == "intrinsics"
    with pytest.raises(CloudError):
        array_cloud(np.zeros((4, 5, 2)))


def png(image: np.ndarray) -> bytes:
    buf = io.BytesIO()
    Image.fromarray(image).save(buf, format="PNG")
    return buf.getvalue()


def test_depth_png_in_millimetres_back_projects_onto_the_seen_points() -> None:
    """backproject with camera_intrinsics inverts Camera.project: a depth image made of back-projected points is
    the same image, and its PNG in millimetres comes back to the same world points within the rounding."""
    cam = Camera(position=(0.3, -0.2, 0.6), target=(0.0, 0.0, 0.0), width=64, height=48)
    depth = np.random.default_rng(1).uniform(0.5, 0.7, (48, 64)).astype(np.float32)
    depth[5:9, 10:20] = 0.0  # no depth there
    intr = camera_intrinsics(cam)
    pose = camera_pose(cam)
    seen = backproject(depth, *intr)[depth > 0]
    world = seen @ pose[:3, :3].T + pose[:3, 3]
    assert np.allclose(depth_image(cam, world), depth, atol=1e-5)
    metres = read_depth_png(png(np.round(depth * 1000).astype(np.uint16)))
    assert np.allclose(metres, depth, atol=5e-4)
    pts = depth_points(metres, Intrinsics(*intr))
    assert len(pts) == len(world)
    assert np.abs(pts @ pose[:3, :3].T + pose[:3, 3] - world).max() < 1e-3
    assert np.allclose(depth_metres(np.round(depth * 1000).astype(np.uint16)), metres)
    grid = backproject(np.full((2, 2), 2.0), 1.0, 1.0, 0.5, 0.5)
    assert np.allclose(grid[0, 0], [-1.0, -1.0, 2.0]) and np.allclose(grid[1, 1], [1.0, 1.0, 2.0])


def test_depth_inputs_that_hold_no_depth_are_refused() -> None:
    with pytest.raises(CloudError, match="16-bit"):
        read_depth_png(png(np.zeros((4, 4, 3), np.uint8)))
    with pytest.raises(CloudError, match="16-bit"):
        read_depth_png(png(np.zeros((4, 4), np.uint8)))
    with pytest.raises(CloudError, match="not a PNG"):
        read_depth_png(b"GIF89a")
    with pytest.raises(CloudError, match="no pixel with depth"):
        depth_points(np.zeros((4, 4), np.float32), Intrinsics(100, 100, 2, 2))
    with pytest.raises(CloudError) as err:
        Intrinsics.parse([100, -1, 2, 2])
    assert err.value.field == "intrinsics"
    nan = np.full((3, 3), 0.5, np.float32)
    nan[1, 1] = np.nan
    assert np.isnan(depth_points(nan, Intrinsics(100, 100, 1, 1))).any()  # kept: graspd.io.inputs counts it
