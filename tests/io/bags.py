"""Bags written in the tests with rosbags' writers: a PointCloud2, a depth Image with its CameraInfo, and a
/tf_static chain of two steps (world -> camera_link -> camera_depth_optical_frame)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from numpy.typing import NDArray
from rosbags.rosbag1 import Writer as Rosbag1Writer
from rosbags.rosbag2 import StoragePlugin
from rosbags.rosbag2 import Writer as Rosbag2Writer
from rosbags.rosbag2.enums import CompressionFormat, CompressionMode
from rosbags.typesys import Stores, get_typestore

from graspd.core.camera import Intrinsics
from graspd.io.depth import depth_points
from graspd.io.ros.encode import encode_pointcloud2
from graspd.io.ros.types import Header

OPTICAL = "camera_depth_optical_frame"
#: world <- camera_link: 1 m up, turned 90 degrees about z; camera_link <- optical: the optical frame convention.
STEPS = [("world", "camera_link", (0.2, -0.1, 1.0), (0.0, 0.0, np.sqrt(0.5), np.sqrt(0.5))),
         ("camera_link", OPTICAL, (0.0, 0.015, 0.0), (-0.5, 0.5, -0.5, 0.5))]
INTRINSICS = Intrinsics(120.0, 120.0, 79.5, 59.5)
CLOUD_TOPIC = "/camera/depth/points"
IMAGE_TOPIC = "/camera/depth/image_rect_raw"
INFO_TOPIC = "/camera/depth/camera_info"


def quaternion_matrix(t: tuple[float, float, float], q: tuple[float, float, float, float]) -> NDArray[np.float64]:
    """4x4 of a translation and a quaternion x, y, z, w (as TF gives them)."""
    x, y, z, w = q
    m = np.eye(4)
    m[:3, :3] = [[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                 [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                 [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]]
    m[:3, 3] = t
    return m


def chain_pose() -> NDArray[np.float64]:
    """The optical frame's pose in world: both steps composed."""
    return quaternion_matrix(*STEPS[0][2:]) @ quaternion_matrix(*STEPS[1][2:])  # type: ignore[arg-type]


def depth_image() -> NDArray[np.uint16]:
    """A 160x120 depth image (mm): a table 0.9 m away with a box (5 x 7 cm) 0.75 m away in the middle, some
    pixels without depth."""
    depth = np.full((120, 160), 900, np.uint16)
    depth[54:66, 76:84] = 750
    depth[:3, :5] = 0
    return depth


def depth_cloud() -> NDArray[np.float32]:
    """The points of depth_image(), as graspd back-projects a depth PNG (optical frame, m)."""
    return depth_points(depth_image().astype(np.float32) * np.float32(0.001), INTRINSICS)


def _messages(ros1: bool) -> dict[str, tuple[str, list[bytes]]]:
    """topic -> (type, serialised messages): the clouds of three frames, the image pair and /tf_static (ROS 2
    CDR, or ROS 1 bytes through rosbags' cdr_to_ros1)."""
    store = get_typestore(Stores.ROS2_HUMBLE)
    t = store.types

    def header(frame: str) -> object:
        return t["std_msgs/msg/Header"](stamp=t["builtin_interfaces/msg/Time"](sec=10, nanosec=0), frame_id=frame)

    def serialise(msg: object, msgtype: str) -> bytes:
        return bytes(store.serialize_cdr(msg, msgtype))

    clouds = [encode_pointcloud2(depth_cloud() + np.float32(0.01 * k), Header(OPTICAL, (10 + k, 0)))
              for k in range(3)]
    image = t["sensor_msgs/msg/Image"](header=header(OPTICAL), height=120, width=160, encoding="16UC1",
                                       is_bigendian=0, step=320, data=depth_image().view(np.uint8).reshape(-1))
    p = np.array([[INTRINSICS.fx, 0, INTRINSICS.cx, 0], [0, INTRINSICS.fy, INTRINSICS.cy, 0], [0, 0, 1, 0]])
    info = t["sensor_msgs/msg/CameraInfo"](
        header=header(OPTICAL), height=120, width=160, distortion_model="plumb_bob", d=np.zeros(5),
        k=p[:, :3].reshape(-1), r=np.eye(3).reshape(-1), p=p.reshape(-1), binning_x=0, binning_y=0,
        roi=t["sensor_msgs/msg/RegionOfInterest"](x_offset=0, y_offset=0, height=0, width=0, do_rectify=False))
    transforms = [t["geometry_msgs/msg/TransformStamped"](
        header=header(parent), child_frame_id=child, transform=t["geometry_msgs/msg/Transform"](
            translation=t["geometry_msgs/msg/Vector3"](x=tr[0], y=tr[1], z=tr[2]),
            rotation=t["geometry_msgs/msg/Quaternion"](x=q[0], y=q[1], z=q[2], w=q[3])))
        for parent, child, tr, q in STEPS]
    out = {
        "/tf_static": ("tf2_msgs/msg/TFMessage",
                       [serialise(t["tf2_msgs/msg/TFMessage"](transforms=transforms), "tf2_msgs/msg/TFMessage")]),
        CLOUD_TOPIC: ("sensor_msgs/msg/PointCloud2", clouds),
        IMAGE_TOPIC: ("sensor_msgs/msg/Image", [serialise(image, "sensor_msgs/msg/Image")]),
        INFO_TOPIC: ("sensor_msgs/msg/CameraInfo", [serialise(info, "sensor_msgs/msg/CameraInfo")]),
    }
    if ros1:
        out = {topic: (msgtype, [bytes(store.cdr_to_ros1(raw, msgtype)) for raw in raws])
               for topic, (msgtype, raws) in out.items()}
    return out


def write_rosbag2(path: Path, storage: str = "mcap", compressed: bool = True) -> Path:
    """A rosbag2 bag directory at path (storage 'mcap' with zstd chunks, or 'sqlite3'); returns the storage
    file."""
    plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
    store = get_typestore(Stores.ROS2_HUMBLE)
    writer = Rosbag2Writer(path, version=9, storage_plugin=plugin)
    if compressed and storage == "mcap":
        writer.set_compression(CompressionMode.STORAGE, CompressionFormat.ZSTD)
    with writer:
        _write_all(writer, store, ros1=False)
    return next(path.glob("*.mcap" if storage == "mcap" else "*.db3"))


def write_rosbag1(path: Path, compressed: bool = True) -> Path:
    """A ROS 1 .bag (lz4 chunks when compressed)."""
    writer = Rosbag1Writer(path)
    if compressed:
        writer.set_compression(Rosbag1Writer.CompressionFormat.LZ4)
    with writer:
        _write_all(writer, get_typestore(Stores.ROS2_HUMBLE), ros1=True)
    return path


def _write_all(writer: Rosbag1Writer | Rosbag2Writer, store: object, ros1: bool) -> None:
    messages = _messages(ros1)
    conns = {topic: writer.add_connection(topic, msgtype, typestore=store)  # type: ignore[arg-type]
             for topic, (msgtype, _) in messages.items()}
    events = [(0 if topic == "/tf_static" else 1 + k, topic, raw)
              for topic, (_, raws) in messages.items() for k, raw in enumerate(raws)]
    for k, topic, raw in sorted(events, key=lambda e: (e[0], e[1])):
        writer.write(conns[topic], 10**9 * (10 + k), raw)


def mcap_with_chunk_size(data: bytes, uncompressed: int) -> bytes:
    """The MCAP file with every chunk's declared uncompressed size (in its Chunk record and its Chunk Index
    record) set to uncompressed: what a hostile file declares."""
    out = bytearray(data)
    pos = 8
    while pos < len(out) - 8:
        op, length = out[pos], int.from_bytes(out[pos + 1:pos + 9], "little")
        body = pos + 9
        if op == 0x06:  # Chunk: start, end, uncompressed_size, crc, ...
            out[body + 16:body + 24] = uncompressed.to_bytes(8, "little")
            out[body + 24:body + 28] = bytes(4)  # no crc: the size is what is checked
        elif op == 0x08:  # Chunk Index: start, end, offset, length, index offsets map, index length, compression...
            at = body + 32
            at += 4 + int.from_bytes(out[at:at + 4], "little") + 8
            at += 4 + int.from_bytes(out[at:at + 4], "little") + 8  # compression string, compressed size
            out[at:at + 8] = uncompressed.to_bytes(8, "little")
        elif op == 0x02:  # Footer
            break
        pos = body + length
    return bytes(out)
