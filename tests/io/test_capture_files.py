"""Captures as their owners' tools write them: PCD fields beyond x y z (normals, packed colour, scalars, padding,
COUNT > 1, any order, organised), PLY from Open3D and CloudCompare (colours, normals, scalar_*, faces), camera
calibration YAML, and ROS bags (rosbag2 MCAP, sqlite3 and folders, ROS 1) read with rosbags, the /tf_static
chain composed, every chunk decompressed under a bound."""

from __future__ import annotations

import struct
import sys
from pathlib import Path

import lz4.frame
import numpy as np
import open3d as o3d
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))  # tests/io/bags.py
from bags import (  # noqa: E402
    CLOUD_TOPIC,
    IMAGE_TOPIC,
    INFO_TOPIC,
    INTRINSICS,
    OPTICAL,
    STEPS,
    chain_pose,
    depth_cloud,
    depth_image,
    quaternion_matrix,
    write_rosbag1,
    write_rosbag2,
)
from PIL import Image

from graspd.core.cloud import CloudError
from graspd.io import bag_limits
from graspd.io.bag import BagQuery, read_bag
from graspd.io.calibration import parse_calibration
from graspd.io.cloud_files import read_input
from graspd.io.pcd import read_pcd
from graspd.io.ply import read_ply

RNG = np.random.default_rng(11)
N = 40
PTS = RNG.normal(size=(N, 3)).astype(np.float32)
NRM = (lambda v: v / np.linalg.norm(v, axis=1, keepdims=True))(RNG.normal(size=(N, 3))).astype(np.float32)
RGB = RNG.integers(0, 256, (N, 3)).astype(np.uint8)
PACKED = (RGB[:, 0].astype(np.uint32) << 16) | (RGB[:, 1].astype(np.uint32) << 8) | RGB[:, 2] | np.uint32(0xFF000000)
INTENSITY = RNG.uniform(0, 100, N).astype(np.float32)
FPFH = RNG.uniform(0, 1, (N, 33)).astype(np.float32)

# shuffled order, padding, a 33-value descriptor, rgb as a float (PCL's PointXYZRGB) between the normals
FIELDS = [("normal_y", "F", 4, 1, NRM[:, 1:2]), ("_", "U", 1, 4, np.zeros((N, 4), np.uint8)),
          ("z", "F", 4, 1, PTS[:, 2:3]), ("fpfh", "F", 4, 33, FPFH),
          ("rgb", "F", 4, 1, PACKED.view(np.float32)[:, None]), ("x", "F", 4, 1, PTS[:, 0:1]),
          ("normal_x", "F", 4, 1, NRM[:, 0:1]), ("intensity", "F", 4, 1, INTENSITY[:, None]),
          ("y", "F", 4, 1, PTS[:, 1:2]), ("normal_z", "F", 4, 1, NRM[:, 2:3]),
          ("label", "U", 4, 1, np.arange(N, dtype=np.uint32)[:, None])]


def _pcd(kind: str, width: int = N, height: int = 1) -> bytes:
    head = "# .PCD v0.7\nVERSION 0.7\nFIELDS " + " ".join(f[0] for f in FIELDS) + "\nSIZE " + " ".join(
        str(f[2]) for f in FIELDS) + "\nTYPE " + " ".join(f[1] for f in FIELDS) + "\nCOUNT " + " ".join(
        str(f[3]) for f in FIELDS) + f"\nWIDTH {width}\nHEIGHT {height}\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS {N}\n" \
        f"DATA {kind}\n"
    columns = [np.ascontiguousarray(f[4]).astype(f"<{ {'F': 'f', 'U': 'u'}[f[1]]}{f[2]}") for f in FIELDS]
    if kind == "ascii":  # PCL writes a float rgb as the integer of its bytes
        rows = []
        for i in range(N):
            values = []
            for f, c in zip(FIELDS, columns, strict=True):
                values += [str(int(PACKED[i]))] if f[0] == "rgb" else [repr(float(v)) if f[1] == "F" else str(int(v))
                                                                        for v in c[i]]
            rows.append(" ".join(values))
        return head.encode() + "\n".join(rows).encode() + b"\n"
    if kind == "binary":
        records = b"".join(b"".join(c[i].tobytes() for c in columns) for i in range(N))
        return head.encode() + records
    raw = b"".join(np.ascontiguousarray(c).tobytes() for c in columns)  # field blocks, each point's values together
    packed = b"".join(bytes([len(raw[i:i + 32]) - 1]) + raw[i:i + 32] for i in range(0, len(raw), 32))  # LZF literals
    return head.encode() + struct.pack("<II", len(packed), len(raw)) + packed


@pytest.mark.parametrize("kind", ["ascii", "binary", "binary_compressed"])
def test_pcd_fields_in_any_order_with_padding_and_descriptors(kind: str, tmp_path: Path) -> None:
    data = _pcd(kind)
    cloud = read_pcd(data)
    assert np.array_equal(cloud.points, PTS)
    assert cloud.normals is not None and np.allclose(cloud.normals, NRM)
    assert cloud.colors is not None and np.array_equal(cloud.colors, RGB)
    assert np.allclose(cloud.scalars["intensity"], INTENSITY) and np.array_equal(cloud.scalars["label"], np.arange(N))
    assert "fpfh" not in cloud.scalars and "_" not in cloud.scalars and cloud.shape is None
    (tmp_path / "c.pcd").write_bytes(data)
    given = read_input(tmp_path / "c.pcd")  # the file's normals are the detector's
    assert given.cloud.normals is not None and np.allclose(given.cloud.normals, NRM)
    if kind == "binary":  # Open3D reads the same points, normals and colours
        o3 = o3d.io.read_point_cloud(str(tmp_path / "c.pcd"))
        assert np.allclose(np.asarray(o3.points), PTS) and np.allclose(np.asarray(o3.normals), NRM)
        assert np.array_equal(np.rint(np.asarray(o3.colors) * 255).astype(np.uint8), RGB)


def test_an_organised_pcd_keeps_its_shape_and_nan_pixels() -> None:
    cloud = read_pcd(_pcd("binary", width=8, height=5))
    assert cloud.shape == (5, 8) and len(cloud.points) == 40


def test_normals_that_are_nan_where_points_are_finite_are_not_used(tmp_path: Path) -> None:
    """PCL leaves NaN normals where a point had too few neighbours: the detector then estimates its own rather
    than dropping those points."""
    global NRM
    saved = NRM.copy()
    try:
        NRM[3] = np.nan
        FIELDS[0] = ("normal_y", "F", 4, 1, NRM[:, 1:2])
        (tmp_path / "c.pcd").write_bytes(_pcd("binary"))
        given = read_input(tmp_path / "c.pcd")
        assert given.cloud.normals is None and len(given.cloud) == N and given.dropped == 0
    finally:
        NRM = saved
        FIELDS[0] = ("normal_y", "F", 4, 1, NRM[:, 1:2])


def test_real_pcl_captures_keep_their_colour_and_shape(real_data: Path) -> None:
    path = real_data / "milk_cartoon_all_small_clorox.pcd"
    cloud = read_pcd(path.read_bytes())
    expected = o3d.t.io.read_point_cloud(str(path))
    assert cloud.shape == (480, 640)
    assert np.array_equal(cloud.points, expected.point.positions.numpy(), equal_nan=True)
    assert cloud.colors is not None
    assert np.array_equal(cloud.colors, expected.point.colors.numpy().astype(np.uint8))


def test_ply_as_open3d_writes_it(tmp_path: Path) -> None:
    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(PTS.astype(np.float64)))
    pc.normals = o3d.utility.Vector3dVector(NRM.astype(np.float64))
    pc.colors = o3d.utility.Vector3dVector(RGB / 255.0)
    for ascii_ in (False, True):
        path = tmp_path / f"o3d-{ascii_}.ply"
        assert o3d.io.write_point_cloud(str(path), pc, write_ascii=ascii_)
        cloud = read_ply(path.read_bytes())
        assert np.allclose(cloud.points, PTS, atol=1e-6) and cloud.normals is not None
        assert np.allclose(cloud.normals, NRM, atol=1e-6)
        assert cloud.colors is not None and np.array_equal(cloud.colors, RGB)
        assert np.allclose(read_input(path).cloud.normals, NRM, atol=1e-6)  # type: ignore[arg-type]


def test_ply_as_cloudcompare_and_the_realsense_viewer_write_it() -> None:
    """Big-endian float colours named diffuse_*, CloudCompare's scalar_ fields, and a face element after the
    vertices (ignored for a cloud)."""
    head = ("ply\nformat binary_big_endian 1.0\ncomment CloudCompare\nelement vertex 40\nproperty float x\n"
            "property float y\nproperty float z\nproperty float diffuse_red\nproperty float diffuse_green\n"
            "property float diffuse_blue\nproperty float scalar_Intensity\nproperty double scalar_Dip\n"
            "element face 2\nproperty list uchar int vertex_indices\nend_header\n")
    rows = np.zeros(N, [("p", ">f4", 3), ("c", ">f4", 3), ("i", ">f4"), ("d", ">f8")])
    rows["p"], rows["c"], rows["i"], rows["d"] = PTS, RGB / 255.0, INTENSITY, INTENSITY * 2
    faces = b"".join(struct.pack(">Biii", 3, i, i + 1, i + 2) for i in range(2))
    cloud = read_ply(head.encode() + rows.tobytes() + faces)
    assert np.array_equal(cloud.points, PTS) and cloud.normals is None
    assert cloud.colors is not None and np.array_equal(cloud.colors, RGB)
    assert np.allclose(cloud.scalars["scalar_Intensity"], INTENSITY)
    assert np.allclose(cloud.scalars["scalar_Dip"], 2 * INTENSITY)


CALIBRATION = f"""image_width: 160
image_height: 120
camera_name: depth_camera
camera_matrix:
  rows: 3
  cols: 3
  data: [{INTRINSICS.fx + 5}, 0, {INTRINSICS.cx + 1}, 0, {INTRINSICS.fy + 5}, {INTRINSICS.cy + 1}, 0, 0, 1]
distortion_model: plumb_bob
distortion_coefficients:
  rows: 1
  cols: 5
  data: [0.01, -0.02, 0, 0, 0]
rectification_matrix:
  rows: 3
  cols: 3
  data: [1, 0, 0, 0, 1, 0, 0, 0, 1]
projection_matrix:
  rows: 3
  cols: 4
  data: [{INTRINSICS.fx}, 0, {INTRINSICS.cx}, 0, 0, {INTRINSICS.fy}, {INTRINSICS.cy}, 0, 0, 0, 1, 0]
"""


def test_a_calibration_yaml_gives_the_projection_intrinsics(tmp_path: Path) -> None:
    """P's fx, fy, cx, cy, as depth_image_proc uses for a rectified depth image: the same cloud as the four
    numbers."""
    calibration = parse_calibration(CALIBRATION)
    assert calibration.intrinsics() == INTRINSICS and calibration.distortion.shape == (5,)
    png = tmp_path / "d.png"
    Image.fromarray(depth_image()).save(png)
    by_yaml = read_input(png, intrinsics=calibration).cloud.points
    assert np.array_equal(by_yaml, read_input(png, intrinsics=list(INTRINSICS)).cloud.points)
    assert np.allclose(by_yaml, depth_cloud())
    small = parse_calibration(CALIBRATION.replace("image_width: 160", "image_width: 640"))
    with pytest.raises(CloudError, match="calibration is for 640x120 images; the depth image is 160x120"):
        read_input(png, intrinsics=small)


@pytest.mark.parametrize(("text", "words"), [
    ("[1, 2", "not YAML"),
    ("- 1\n- 2\n", "mapping"),
    ("image_width: 160\nimage_height: 120\n", "camera_matrix"),
    (CALIBRATION.replace("rows: 3\n  cols: 4", "rows: 3\n  cols: 3"), "projection_matrix must be 3x4"),
    (CALIBRATION.replace("camera_name: depth_camera", "camera_name: &a [*a]"), "must be text"),
    ("a: &a [1]\nb: &b [*a, *a, *a, *a, *a, *a, *a, *a]\nc: &c [*b, *b, *b, *b, *b, *b, *b, *b]\n"
     "camera_name: [*c, *c, *c, *c, *c, *c, *c, *c]\nimage_width: 1\nimage_height: 1\n", "must be text"),
    ("x" * 70_000, "exceeds the limit"),
])
def test_a_bad_calibration_is_named(text: str, words: str) -> None:
    with pytest.raises(CloudError, match=words) as info:
        parse_calibration(text)
    assert info.value.field == "intrinsics"


# ---- bags -------------------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def bag_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    folder = tmp_path_factory.mktemp("bags")
    write_rosbag2(folder / "mcap")
    write_rosbag2(folder / "sqlite", "sqlite3")
    write_rosbag1(folder / "ros1.bag")
    return folder


@pytest.mark.parametrize("where", ["mcap/mcap.mcap", "mcap", "sqlite/sqlite.db3", "sqlite", "ros1.bag"])
def test_every_bag_kind_gives_the_clouds_and_the_composed_pose(bag_dir: Path, where: str) -> None:
    clouds = list(read_bag(bag_dir / where, BagQuery(topic=CLOUD_TOPIC, every=2)))
    assert [c.index for c in clouds] == [0, 2]
    for c in clouds:
        assert np.allclose(c.points, depth_cloud() + np.float32(0.01 * c.index)) and c.frame_id == OPTICAL
        assert c.pose_frame == "world" and c.camera_pose is not None
        assert np.allclose(c.camera_pose, chain_pose())  # both steps, not camera_link's alone
        assert not np.allclose(c.camera_pose, quaternion_matrix(*STEPS[1][2:]))  # type: ignore[arg-type]
    image = next(read_bag(bag_dir / where, BagQuery(topic=IMAGE_TOPIC, info_topic=INFO_TOPIC)))
    assert np.allclose(image.points, depth_cloud())
    moved = image.cloud_input()  # in world: each point moved by the chain's pose
    assert moved.frame == "robot"
    expected = depth_cloud().astype(np.float64) @ chain_pose()[:3, :3].T + chain_pose()[:3, 3]
    assert np.allclose(moved.cloud.points, expected, atol=1e-5)
    assert np.allclose(moved.cloud.viewpoints, chain_pose()[:3, 3])


def test_a_named_frame_is_reached_through_the_tree(bag_dir: Path) -> None:
    cloud = next(read_bag(bag_dir / "mcap", BagQuery(topic=CLOUD_TOPIC, frame="camera_link")))
    assert cloud.pose_frame == "camera_link" and cloud.camera_pose is not None
    assert np.allclose(cloud.camera_pose, quaternion_matrix(*STEPS[1][2:]))  # type: ignore[arg-type]


def test_rosbag2_file_and_message_compression_is_refused(tmp_path: Path, bag_dir: Path) -> None:
    folder = tmp_path / "bag"
    folder.mkdir()
    meta = (bag_dir / "mcap" / "metadata.yaml").read_text()
    (folder / "metadata.yaml").write_text(meta.replace("compression_mode: ''", "compression_mode: FILE")
                                          .replace("compression_mode: \"\"", "compression_mode: FILE"))
    if "FILE" not in (folder / "metadata.yaml").read_text():
        pytest.skip("the writer's metadata.yaml spells compression_mode otherwise")
    with pytest.raises(CloudError, match="compression_mode 'file'"):
        next(read_bag(folder, BagQuery()))


def test_a_ros1_chunk_that_inflates_past_the_limit_is_stopped(monkeypatch: pytest.MonkeyPatch) -> None:
    """ROS 1 chunks declare no size to the decompressor: each inflates at most MAX_CHUNK_BYTES (here 1 MB), and
    stops there, whatever the data holds."""
    monkeypatch.setattr(bag_limits, "MAX_CHUNK_BYTES", 1 << 20)
    bomb = lz4.frame.compress(bytes(8 << 20))
    bag_limits.install()
    import rosbags.rosbag1.reader as reader  # noqa: PLC0415

    with pytest.raises(CloudError, match="inflates past 1048576 bytes"):
        reader.decompressors["lz4"](bomb)
    assert reader.decompressors["lz4"](lz4.frame.compress(b"abc" * 1000)) == b"abc" * 1000
    with bag_limits.decompression_budget(2500), pytest.raises(CloudError, match="inflates past 2500"):
        reader.decompressors["lz4"](lz4.frame.compress(b"abc" * 1000))


def test_two_zstd_frames_in_one_chunk_count_together() -> None:
    import rosbags.rosbag2.storage_mcap as mcap  # noqa: PLC0415
    from backports import zstd  # noqa: PLC0415

    bag_limits.install()
    two = zstd.compress(bytes(1000)) + zstd.compress(bytes(1000))
    assert mcap.DECOMPRESSORS["zstd"](two, 2000) == bytes(2000)
    with pytest.raises(CloudError, match="declared 1500"):
        mcap.DECOMPRESSORS["zstd"](two, 1500)
    with pytest.raises(CloudError, match="truncated"):
        mcap.DECOMPRESSORS["zstd"](two[:-5], 2000)
