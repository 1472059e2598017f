"""PCD, PLY and NPZ readers: points, viewpoints and camera indices arrive intact."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from graspd.cloud import CloudError, ViewpointCloud
from graspd.cloud_io import read_cloud, save_npz


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
    import open3d as o3d

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
