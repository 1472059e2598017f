"""PCD, PLY and NPZ readers: points, viewpoints and camera indices arrive intact."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import open3d as o3d
import pytest

from graspd.core.cloud import CloudError, ViewpointCloud
from graspd.io.cloud_files import parse_pcd, parse_ply, read_cloud, save_npz


def _pcd_header(n: int, kind: str, viewpoint: str = "0 0 0 1 0 0 0") -> bytes:
    return (f"# .PCD v0.7\nVERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH {n}\nHEIGHT 1\n"
            f"VIEWPOINT {viewpoint}\nPOINTS {n}\nDATA {kind}\n").encode()


def test_binary_and_ascii_pcd_agree_and_keep_the_viewpoint(tmp_path: Path) -> None:
    pts = np.random.default_rng(1).normal(size=(50, 3)).astype(np.float32)
    (tmp_path / "b.pcd").write_bytes(_pcd_header(50, "binary", "0.1 0.2 0.3 1 0 0 0") + pts.astype("<f4").tobytes())
    text = "\n".join(" ".join(f"{v:.9g}" for v in p) for p in pts)
    (tmp_path / "a.pcd").write_bytes(_pcd_header(50, "ascii", "0.1 0.2 0.3 1 0 0 0") + text.encode() + b"\n")
    a, b = read_cloud(tmp_path / "a.pcd"), read_cloud(tmp_path / "b.pcd")
    assert np.allclose(a.points, pts) and np.allclose(b.points, pts)
    assert np.allclose(b.viewpoints, [[0.1, 0.2, 0.3]])
    override = read_cloud(tmp_path / "b.pcd", viewpoints=np.array([[1.0, 2.0, 3.0]]))
    assert np.allclose(override.viewpoints, [[1, 2, 3]])


def test_real_kinect_pcd_reads(real_data: Path) -> None:
    cloud = read_cloud(real_data / "table_mug.pcd")
    assert len(cloud) == 104444 and np.allclose(cloud.viewpoints, 0.0)


def test_ply_reads(tmp_path: Path) -> None:
    pts = np.random.default_rng(2).normal(size=(30, 3))
    o3d.io.write_point_cloud(str(tmp_path / "c.ply"), o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts)))
    assert np.allclose(read_cloud(tmp_path / "c.ply").points, pts, atol=1e-6)


def test_npz_round_trip_keeps_cameras(tmp_path: Path) -> None:
    cloud = ViewpointCloud(points=np.ones((4, 3)), viewpoints=np.array([[0, 0, 1.0], [1.0, 0, 0]]),
                           camera_source=np.array([0, 1, 1, 0]))
    save_npz(tmp_path / "c.npz", cloud)
    back = read_cloud(tmp_path / "c.npz")
    assert np.array_equal(back.camera_source, [0, 1, 1, 0]) and back.num_cameras == 2


def test_unknown_suffix_and_broken_header_are_named(tmp_path: Path) -> None:
    (tmp_path / "c.xyz").write_text("1 2 3\n")
    with pytest.raises(CloudError, match="unsupported cloud file type"):
        read_cloud(tmp_path / "c.xyz")
    (tmp_path / "bad.pcd").write_bytes(b"VERSION 0.7\nFIELDS a b\nDATA ascii\n1 2\n")
    with pytest.raises(CloudError, match="pcd"):
        read_cloud(tmp_path / "bad.pcd")


# ---- headers that lie, caps, binary_compressed ------------------------------------------------------------------
def _binary_pcd(points: np.ndarray, **header: object) -> bytes:
    fields = {"WIDTH": len(points), "HEIGHT": 1, "POINTS": len(points), **header}
    text = "# .PCD v0.7\nVERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\n"
    text += "".join(f"{k} {v}\n" for k, v in fields.items()) + "DATA binary\n"
    return text.encode() + points.astype("<f4").tobytes()


PTS = np.random.default_rng(3).normal(size=(500, 3)).astype(np.float32)
ASCII_ROWS = "\n".join(" ".join(f"{v:.6g}" for v in p) for p in PTS[:10]).encode() + b"\n"

LYING_PCD = [
    ("POINTS beyond 64 bits", _binary_pcd(PTS, POINTS=10**20), "POINTS"),
    ("POINTS negative", _binary_pcd(PTS, POINTS=-1), "POINTS"),
    ("POINTS 5 with 500 records", _binary_pcd(PTS, POINTS=5, WIDTH=5), "6000 bytes"),
    ("POINTS 5000 with 500 records", _binary_pcd(PTS, POINTS=5000, WIDTH=5000), "6000 bytes"),
    ("WIDTH not POINTS", _binary_pcd(PTS, WIDTH=7), "WIDTH x HEIGHT"),
    ("POINTS above the cap", _binary_pcd(PTS, POINTS=6_000_000, WIDTH=6_000_000), "limit"),
    ("POINTS not a number", _binary_pcd(PTS, POINTS="1e3"), "POINTS"),
    ("ascii 1000 declared, 10 rows", _pcd_header(1000, "ascii") + ASCII_ROWS, "10 rows"),
    ("ascii short row", _pcd_header(2, "ascii") + b"1 2\n3 4 5\n", "unreadable"),
    ("ascii words", _pcd_header(1, "ascii") + b"a b c\n", "unreadable"),
    ("VIEWPOINT short", _binary_pcd(PTS, VIEWPOINT="1 2"), "VIEWPOINT"),
]


@pytest.mark.parametrize(("name", "data", "why"), LYING_PCD, ids=[c[0] for c in LYING_PCD])
def test_pcd_headers_that_lie_are_refused(name: str, data: bytes, why: str) -> None:
    with pytest.raises(CloudError, match=why):
        parse_pcd(data)


def test_binary_compressed_pcd_round_trips_with_its_viewpoint(tmp_path: Path) -> None:
    """PCL's most common format, written by open3d (LZF); the VIEWPOINT line is honoured in every format."""

    path = tmp_path / "c.pcd"
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(PTS.astype(np.float64)))
    assert o3d.io.write_point_cloud(str(path), cloud, write_ascii=False, compressed=True)
    data = path.read_bytes()
    assert b"DATA binary_compressed\n" in data
    points, viewpoint = parse_pcd(data.replace(b"VIEWPOINT 0 0 0 1 0 0 0", b"VIEWPOINT 0.5 0 0.25 1 0 0 0"))
    assert np.array_equal(points, PTS) and np.allclose(viewpoint, [0.5, 0, 0.25])
    head, _, body = data.partition(b"DATA binary_compressed\n")
    fewer = head.replace(b"POINTS 500", b"POINTS 400").replace(b"WIDTH 500", b"WIDTH 400")
    with pytest.raises(CloudError, match="uncompressed"):  # the size words say 500 points
        parse_pcd(fewer + b"DATA binary_compressed\n" + body)
    with pytest.raises(CloudError, match="compressed bytes"):  # truncated
        parse_pcd(data[:-100])
    trailing, _ = parse_pcd(data + bytes(3901))  # bytes after the block, as older PCL writers leave: ignored
    assert np.array_equal(trailing, PTS)


@pytest.mark.parametrize("name", ["milk_cartoon_all_small_clorox.pcd", "table_scene_mug_stereo_textured.pcd"])
def test_pcl_captures_load_as_pcl_wrote_them(real_data: Path, name: str) -> None:
    """Organised 640 x 480 binary_compressed Kinect and stereo captures whose block is followed by ~3.9 kB:
    PCL's reader and open3d read them; so does graspd, with the same points (NaN pixels kept in order)."""
    points, _ = parse_pcd((real_data / name).read_bytes())
    expected = np.asarray(o3d.t.io.read_point_cloud(str(real_data / name)).point.positions.numpy(), np.float32)
    assert points.shape == (640 * 480, 3)
    assert np.array_equal(points, expected, equal_nan=True)


def test_pcd_with_other_fields_and_types_reads_xyz() -> None:
    """x y z in float64 beside a 3-value descriptor, and int16 coordinates: open3d reads xyz of any layout."""

    dt = np.dtype([("x", "<f8"), ("y", "<f8"), ("z", "<f8"), ("f", "<f4", (3,))])
    rec = np.zeros(2, dt)
    rec["x"], rec["z"] = [1, 2], [3, 4]
    head = b"FIELDS x y z fpfh\nSIZE 8 8 8 4\nTYPE F F F F\nCOUNT 1 1 1 3\nWIDTH 2\nHEIGHT 1\nPOINTS 2\nDATA binary\n"
    points, viewpoint = parse_pcd(b"# .PCD v0.7\n" + head + rec.tobytes())
    assert np.array_equal(points, [[1, 0, 3], [2, 0, 4]]) and viewpoint is None


PLY_HEAD = "ply\nformat binary_little_endian 1.0\nelement vertex {n}\nproperty float x\nproperty float y\n" \
           "property float z\n{extra}end_header\n"
LYING_PLY = [
    ("list bomb 2e7", PLY_HEAD.format(n=20_000_000, extra="property list uchar int idx\n").encode() + bytes(40),
     "limit"),
    ("list bomb under the cap", PLY_HEAD.format(n=4_000_000, extra="property list uchar int idx\n").encode()
     + bytes(40), "bytes"),
    ("short binary", PLY_HEAD.format(n=100, extra="").encode() + bytes(12 * 99), "bytes"),
    ("negative count", PLY_HEAD.format(n=-5, extra="").encode(), "count"),
    ("unknown type", PLY_HEAD.format(n=1, extra="property quad w\n").encode() + bytes(16), "not understood"),
    ("face bomb", PLY_HEAD.format(n=1, extra="element face 900000000\nproperty list uchar int vertex_indices\n")
     .encode() + bytes(12), "bytes"),
]


@pytest.mark.parametrize(("name", "data", "why"), LYING_PLY, ids=[c[0] for c in LYING_PLY])
def test_ply_counts_are_checked_before_reading(name: str, data: bytes, why: str) -> None:
    assert len(data) < 2000  # a few hundred bytes that declare up to hundreds of megabytes
    with pytest.raises(CloudError, match=why):
        parse_ply(data)


def test_ply_with_a_list_property_still_reads(tmp_path: Path) -> None:
    rec = np.zeros(3, np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("n", "u1"), ("i", "<i4", (2,))]))
    rec["x"], rec["n"] = [1, 2, 3], 2
    data = PLY_HEAD.format(n=3, extra="property list uchar int idx\n").encode() + rec.tobytes()
    assert np.array_equal(parse_ply(data)[:, 0], [1, 2, 3])
