"""Bags with /tf (dynamic transforms) as well as /tf_static: the camera pose is the chain at the cloud message's
stamp (a moving base, interpolated between the /tf transforms that bracket the stamp, the nearest within 0.1 s
at the ends), and detecting on the bag's message gives the grasps of the same cloud sent with that pose.

The bags are written here with rosbags' writer: world -> base_link on /tf (a base driving along x and turning),
base_link -> camera_link -> optical frame on /tf_static, and an organised PointCloud2 of a box on a table in the
optical frame."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from rosbags.rosbag2 import StoragePlugin
from rosbags.rosbag2 import Writer as Rosbag2Writer
from rosbags.typesys import Stores, get_typestore
from scipy.spatial.transform import Rotation

from graspd.core.cloud import CloudError
from graspd.gpd.detector import DetectionParams, GraspDetector
from graspd.io.bag import BagQuery, read_bag
from graspd.io.inputs import cloud_input
from graspd.io.ros.encode import encode_pointcloud2
from graspd.io.ros.types import Header
from graspd.io.tf_tree import interpolate

OPTICAL = "camera_optical"
CLOUD_TOPIC = "/camera/points"
H, W = 60, 80


def pose(t: tuple[float, float, float], yaw_deg: float = 0.0, quat: tuple[float, ...] | None = None) -> np.ndarray:
    """4x4 of a translation and a yaw about z (or a quaternion x, y, z, w)."""
    m = np.eye(4)
    rot = Rotation.from_quat(quat) if quat is not None else Rotation.from_euler("z", yaw_deg, degrees=True)
    m[:3, :3] = rot.as_matrix()
    m[:3, 3] = t
    return m


#: base_link -> camera_link: 0.4 m up on a mast, tilted 30 degrees down; camera_link -> optical: the convention.
STATIC = [("base_link", "camera_link", pose((0.1, 0.0, 0.4), quat=tuple(
              Rotation.from_euler("y", 30, degrees=True).as_quat()))),
          ("camera_link", OPTICAL, pose((0.0, 0.0, 0.0), quat=(-0.5, 0.5, -0.5, 0.5)))]
#: world -> base_link at 9.0, 9.5, 10.0 and 10.5 s: driving along x at 0.2 m/s, turning 10 degrees a second.
MOTION = [(9.0 + 0.5 * k, pose((0.2 * 0.5 * k, 0.0, 0.0), 5.0 * k)) for k in range(4)]


def organised_box() -> np.ndarray:
    """An organised cloud (H*W, 3; optical frame, m) of a plane 0.6 m away with a 6 cm box 5 cm in front of it,
    the first row without depth (NaN)."""
    v, u = np.mgrid[0:H, 0:W]
    z = np.full((H, W), 0.6)
    z[20:40, 30:50] = 0.55
    pts = np.stack([(u - W / 2) / 100.0 * z, (v - H / 2) / 100.0 * z, z], axis=-1).reshape(-1, 3)
    pts[:W] = np.nan
    return pts.astype(np.float32)


def write_bag(path: Path, stamps: list[float], motion: list[tuple[float, np.ndarray]] = MOTION,
              frame: str = OPTICAL) -> Path:
    """An MCAP rosbag2 with /tf_static, /tf (motion; none when empty) and one organised PointCloud2 in frame per
    stamp (s)."""
    store = get_typestore(Stores.ROS2_HUMBLE)
    t = store.types

    def transform(parent: str, child: str, m: np.ndarray, stamp: float) -> object:
        q = Rotation.from_matrix(m[:3, :3]).as_quat()
        sec, nsec = int(stamp), int(round((stamp - int(stamp)) * 1e9))
        return t["geometry_msgs/msg/TransformStamped"](
            header=t["std_msgs/msg/Header"](stamp=t["builtin_interfaces/msg/Time"](sec=sec, nanosec=nsec),
                                            frame_id=parent),
            child_frame_id=child, transform=t["geometry_msgs/msg/Transform"](
                translation=t["geometry_msgs/msg/Vector3"](x=m[0, 3], y=m[1, 3], z=m[2, 3]),
                rotation=t["geometry_msgs/msg/Quaternion"](x=q[0], y=q[1], z=q[2], w=q[3])))

    def tf_message(transforms: list[object]) -> bytes:
        return bytes(store.serialize_cdr(t["tf2_msgs/msg/TFMessage"](transforms=transforms),  # type: ignore[arg-type]
                                         "tf2_msgs/msg/TFMessage"))

    writer = Rosbag2Writer(path, version=9, storage_plugin=StoragePlugin.MCAP)
    with writer:
        static = writer.add_connection("/tf_static", "tf2_msgs/msg/TFMessage", typestore=store)
        dynamic = writer.add_connection("/tf", "tf2_msgs/msg/TFMessage", typestore=store) if motion else None
        clouds = writer.add_connection(CLOUD_TOPIC, "sensor_msgs/msg/PointCloud2", typestore=store)
        writer.write(static, 1, tf_message([transform(p, c, m, 0.0) for p, c, m in STATIC]))
        events = [(s, dynamic, tf_message([transform("world", "base_link", m, s)])) for s, m in motion]
        events += [(s, clouds, encode_pointcloud2(organised_box(), Header(frame, (int(s), int(round(
            (s - int(s)) * 1e9)))), shape=(H, W))) for s in stamps]
        for s, conn, raw in sorted(events, key=lambda e: e[0]):
            writer.write(conn, int(s * 1e9), raw)  # type: ignore[arg-type]
    return next(path.glob("*.mcap"))


def expected_pose(stamp: float) -> np.ndarray:
    """The optical frame's pose in world at stamp: the base's motion interpolated, then the static steps."""
    stamps = [s for s, _ in MOTION]
    k = int(np.searchsorted(stamps, stamp, side="right")) - 1
    base = MOTION[k][1] if stamps[k] == stamp else interpolate(
        MOTION[k][1], MOTION[k + 1][1], (stamp - stamps[k]) / (stamps[k + 1] - stamps[k]))
    return base @ STATIC[0][2] @ STATIC[1][2]


def test_the_pose_is_the_chain_at_the_message_stamp(tmp_path: Path) -> None:
    """Between /tf transforms: interpolated; on one: that one; the static steps composed after the dynamic."""
    bag = write_bag(tmp_path / "bag", [9.25, 10.0])
    got = list(read_bag(bag, BagQuery(every=1)))
    assert [m.pose_frame for m in got] == ["world", "world"]
    for message, stamp in zip(got, (9.25, 10.0), strict=True):
        assert message.camera_pose is not None
        assert np.allclose(message.camera_pose, expected_pose(stamp), atol=1e-9)
    # half way from 9.0 to 9.5 s: along x (0.1 m) and in yaw (5 degrees)
    base = got[0].camera_pose @ np.linalg.inv(STATIC[0][2] @ STATIC[1][2])  # type: ignore[operator]
    assert np.isclose(base[0, 3], 0.05) and np.isclose(np.degrees(np.arctan2(base[1, 0], base[0, 0])), 2.5)


def test_near_the_ends_the_nearest_transform_within_the_tolerance(tmp_path: Path) -> None:
    bag = write_bag(tmp_path / "bag", [10.55])  # 50 ms after the last /tf transform
    message = next(read_bag(bag, BagQuery()))
    assert message.camera_pose is not None
    assert np.allclose(message.camera_pose, expected_pose(10.5), atol=1e-9)


def test_a_stamp_far_from_any_transform_is_refused_naming_frame(tmp_path: Path) -> None:
    bag = write_bag(tmp_path / "bag", [12.0])  # 1.5 s after the last /tf transform
    with pytest.raises(CloudError) as err:
        next(read_bag(bag, BagQuery()))
    assert err.value.field == "frame" and "base_link" in err.value.message and "12.000 s" in err.value.message


def test_without_tf_the_static_tree_gives_the_pose_as_before(tmp_path: Path) -> None:
    """No /tf: base_link is the root of the static tree and the pose is in it, as bags were read before."""
    plain = next(read_bag(write_bag(tmp_path / "bag", [10.0], []), BagQuery()))
    assert plain.pose_frame == "base_link"
    assert plain.camera_pose is not None and np.allclose(plain.camera_pose, STATIC[0][2] @ STATIC[1][2])


def test_a_frame_with_no_chain_keeps_the_camera_frame(tmp_path: Path) -> None:
    """A cloud whose frame no transform names: no pose (the cloud in its own frame), as before."""
    bag = write_bag(tmp_path / "bag", [10.0], frame="lidar")
    message = next(read_bag(bag, BagQuery()))
    assert message.camera_pose is None and message.pose_frame is None
    assert message.cloud_input().frame == "cloud"


def test_the_bag_gives_the_grasps_of_the_cloud_sent_with_that_pose(tmp_path: Path) -> None:
    bag = write_bag(tmp_path / "bag", [9.75])
    message = next(read_bag(bag, BagQuery()))
    from_bag = message.cloud_input()
    sent = cloud_input(organised_box(), camera_poses=[expected_pose(9.75).tolist()], points_frame="camera",
                       shape=(H, W))
    assert from_bag.cloud.grid is not None and sent.cloud.grid is not None
    assert np.array_equal(from_bag.cloud.grid.pixel, sent.cloud.grid.pixel)
    assert np.allclose(from_bag.cloud.points, sent.cloud.points, atol=1e-6)
    params = DetectionParams(num_samples=60)
    a = GraspDetector().detect(from_bag.cloud, params).grasps
    b = GraspDetector().detect(sent.cloud, params).grasps
    assert len(a) > 0 and len(a) == len(b)
    assert np.allclose(a.positions, b.positions, atol=1e-5) and np.allclose(a.rotations, b.rotations, atol=1e-4)
