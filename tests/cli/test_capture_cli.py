"""graspd detect on captures as their owners' tools write them: a PCL capture (organised, binary_compressed,
bytes after the block) with every point Open3D reads; a ROS bag's PointCloud2 messages (one or every Nth, posed by
its /tf_static chain) and depth Image + CameraInfo; a depth PNG with its calibration YAML."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import open3d as o3d
import pytest
from PIL import Image

from graspd.cli.main import main

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "io"))
from bags import CLOUD_TOPIC, IMAGE_TOPIC, INTRINSICS, chain_pose, depth_image, write_rosbag1, write_rosbag2  # noqa: E402

FAST = ["--no-classifier", "--samples", "30", "--max-grasps", "5"]


def test_a_pcl_capture_arrives_whole(real_data: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = real_data / "table_scene_mug_stereo_textured.pcd"
    points = o3d.t.io.read_point_cloud(str(path)).point.positions.numpy()
    nan = int((~np.isfinite(points).all(axis=1)).sum())
    assert main(["detect", str(path), *FAST, "--out", str(tmp_path / "g.json")]) == 0
    answer = json.loads((tmp_path / "g.json").read_text())
    assert (answer["num_points_dropped"], answer["num_points_received"]) == (nan, len(points))
    assert "non_finite_dropped" not in [w["code"] for w in answer["warnings"]]  # pixels without depth: counted only
    assert answer["num_points_out_of_range"] > 0  # no workspace: the wall 2.5 m behind the table, left out and counted


@pytest.fixture(scope="module")
def bags(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    folder = tmp_path_factory.mktemp("bags")
    return {"mcap": write_rosbag2(folder / "r2"), "ros1": write_rosbag1(folder / "r1.bag"), "folder": folder / "r2"}


@pytest.mark.parametrize("kind", ["mcap", "ros1", "folder"])
def test_every_second_message_of_a_bag(bags: dict[str, Path], kind: str, tmp_path: Path) -> None:
    out = tmp_path / "g.json"
    assert main(["detect", str(bags[kind]), "--topic", CLOUD_TOPIC, "--every", "2", *FAST, "--out", str(out)]) == 0
    answers = json.loads(out.read_text())
    assert [a["message"]["index"] for a in answers] == [0, 2]
    for a in answers:
        assert a["frame"] == "robot" and a["message"]["grasps_frame"] == "world" and a["grasps"]


def test_one_message_and_the_same_cloud_given_directly(bags: dict[str, Path], tmp_path: Path) -> None:
    """Message 1 of the bag gives the grasps of its points saved as .npy with the composed pose."""
    assert main(["detect", str(bags["mcap"]), "--topic", CLOUD_TOPIC, "--index", "1", *FAST,
                 "--out", str(tmp_path / "bag.json")]) == 0
    from bags import depth_cloud  # noqa: PLC0415

    np.save(tmp_path / "c.npy", depth_cloud() + np.float32(0.01))
    assert main(["detect", str(tmp_path / "c.npy"), *FAST, "--points-frame", "camera", "--camera-pose",
                 *(f"{v:.12f}" for v in chain_pose().reshape(-1)), "--out", str(tmp_path / "npy.json")]) == 0
    bag, npy = (json.loads((tmp_path / n).read_text()) for n in ("bag.json", "npy.json"))
    assert bag["message"]["index"] == 1 and bag["grasps"]
    assert np.allclose([g["pose"] for g in bag["grasps"]], [g["pose"] for g in npy["grasps"]], atol=1e-5)


def test_a_depth_image_from_the_bag_and_from_a_png_with_its_calibration(bags: dict[str, Path],
                                                                        tmp_path: Path) -> None:
    assert main(["detect", str(bags["mcap"]), "--topic", IMAGE_TOPIC, "--frame", "world", *FAST,
                 "--out", str(tmp_path / "bag.json")]) == 0
    Image.fromarray(depth_image()).save(tmp_path / "d.png")
    (tmp_path / "camera.yaml").write_text(
        f"image_width: 160\nimage_height: 120\ncamera_name: depth\ncamera_matrix:\n  rows: 3\n  cols: 3\n  data: "
        f"[{INTRINSICS.fx}, 0, {INTRINSICS.cx}, 0, {INTRINSICS.fy}, {INTRINSICS.cy}, 0, 0, 1]\n"
        "distortion_model: plumb_bob\ndistortion_coefficients:\n  rows: 1\n  cols: 5\n  data: [0, 0, 0, 0, 0]\n")
    assert main(["detect", str(tmp_path / "d.png"), "--intrinsics", str(tmp_path / "camera.yaml"), *FAST,
                 "--camera-pose", *(f"{v:.12f}" for v in chain_pose().reshape(-1)),
                 "--out", str(tmp_path / "png.json")]) == 0
    bag, png = (json.loads((tmp_path / n).read_text()) for n in ("bag.json", "png.json"))
    assert bag["grasps"] and np.allclose([g["pose"] for g in bag["grasps"]], [g["pose"] for g in png["grasps"]],
                                         atol=1e-5)


def test_what_is_not_in_the_bag_is_named(bags: dict[str, Path], capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["detect", str(bags["mcap"]), "--topic", "/nothing", *FAST]) == 2
    assert "topic: no topic '/nothing'" in capsys.readouterr().err
    assert main(["detect", str(bags["mcap"]), "--topic", CLOUD_TOPIC, "--index", "9", *FAST]) == 2
    assert "index: /camera/depth/points has fewer than 10 messages" in capsys.readouterr().err
