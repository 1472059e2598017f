"""ROS bags as clouds, with no ROS install (rosbags, pure Python): rosbag2 (an MCAP file, a sqlite3 .db3 file, or
a bag directory with its metadata.yaml) and ROS 1 .bag.  A topic's sensor_msgs/PointCloud2, or its depth
sensor_msgs/Image with the CameraInfo of its camera, one message (index) or every Nth (every); the bag's
/tf_static and /tf composed along the whole chain from the cloud's frame_id to the root of its tree (or to a
named frame) at the message's stamp gives the camera's pose (graspd.io.tf_tree: /tf transforms interpolated
between the two that bracket the stamp, else the nearest within 0.1 s).

The raw message bytes are decoded by graspd's own bounded readers (graspd.io.ros.decode, graspd.io.ros.sensors);
a ROS 1 message is made CDR first (rosbags' ros1_to_cdr).  Every chunk is decompressed under a bound
(graspd.io.bag_limits); an upload is read from memory under a total.  A bag that cannot be read, or a topic,
index or frame that is not in it, is a CloudError naming the field (body, topic, info_topic, index, frame).
Points are in metres; with a pose from the transforms, the points are in the camera's frame (frame_id) and the
pose is the camera-to-robot transform, the robot frame being the root (or the named frame)."""

from __future__ import annotations

import io
from collections.abc import Iterator
from contextlib import ExitStack
from dataclasses import dataclass, replace
from pathlib import Path, PurePosixPath
from typing import Any

import numpy as np
import yaml
from numpy.typing import NDArray
from rosbags.interfaces import Connection
from rosbags.rosbag1 import Reader as Rosbag1Reader
from rosbags.rosbag2 import Reader as Rosbag2Reader

from graspd.core.cloud import CloudError
from graspd.io import bag_limits
from graspd.io.depth import DEFAULT_DEPTH_SCALE, depth_pixels, depth_points
from graspd.io.inputs import CloudInput, cloud_input
from graspd.io.ros.decode import RosDecodeError, pointcloud2_rows
from graspd.io.ros.sensors import CameraInfo, decode_camera_info, decode_depth_image, decode_tf_message
from graspd.io.ros.types import typestore
from graspd.io.tf_tree import TfTree

MCAP_MAGIC = b"\x89MCAP0\r\n"
ROSBAG1_MAGIC = b"#ROSBAG V2.0\n"
SQLITE_MAGIC = b"SQLite format 3\x00"
#: File names a bag has (a rosbag2 directory is recognised by its metadata.yaml).
BAG_SUFFIXES = (".mcap", ".db3", ".bag")
#: Bytes the chunks of an uploaded bag may inflate to in one read (the .npz cap's size).
MAX_UPLOAD_INFLATE = 256 << 20
#: Largest rosbag2 metadata.yaml read (bytes).
MAX_METADATA_BYTES = 1 << 20
#: Most /tf_static messages read (each holds up to 10,000 transforms; a bag has one per broadcaster).
MAX_TF_MESSAGES = 1000
#: Most /tf messages read (a broadcaster at 100 Hz for 10 minutes): all of them, before the first cloud, since a
#: message's stamp may lie anywhere in the bag's time.
MAX_TF_DYNAMIC_MESSAGES = 60_000
POINTCLOUD2 = "sensor_msgs/msg/PointCloud2"
IMAGE = "sensor_msgs/msg/Image"
CAMERA_INFO = "sensor_msgs/msg/CameraInfo"
TF_MESSAGE = "tf2_msgs/msg/TFMessage"
TF_STATIC = "/tf_static"
TF = "/tf"


@dataclass(frozen=True)
class BagQuery:
    """What to read of a bag: topic (None: the bag's only PointCloud2 topic, else its only depth Image topic);
    info_topic of a depth image (None: the sibling camera_info of its topic); index: the message (0-based, among
    the topic's messages in time order); every: each every-th message from index on instead of one; frame: the
    frame the camera pose is given in (None: the root of the cloud's /tf_static and /tf tree); depth_scale:
    metres per unit of a 16UC1 depth image."""

    topic: str | None = None
    info_topic: str | None = None
    index: int = 0
    every: int | None = None
    frame: str | None = None
    depth_scale: float = DEFAULT_DEPTH_SCALE


@dataclass(frozen=True)
class BagCloud:
    """One message's cloud: points (N,3) float32 and normals, in frame_id (m): a PointCloud2's every row
    (non-finite ones included, in pixel order; shape (height, width) when organised), a depth image's pixels that
    have depth (shape the image's, pixel each point's row-major pixel index); camera_pose (4,4) of frame_id in
    pose_frame from the bag's transforms at the message's stamp (None: the bag has no chain for frame_id)."""

    topic: str
    index: int
    stamp: tuple[int, int]
    frame_id: str
    points: NDArray[np.float32]
    normals: NDArray[np.float32] | None = None
    shape: tuple[int, int] | None = None
    camera_pose: NDArray[np.float64] | None = None
    pose_frame: str | None = None
    pixel: NDArray[np.int64] | None = None

    def cloud_input(self) -> CloudInput:
        """The detector's cloud (graspd.io.inputs.cloud_input: non-finite rows dropped and counted): in
        pose_frame with the camera pose, else in frame_id with the camera at its origin; organised ones with their
        grid."""
        poses = None if self.camera_pose is None else [self.camera_pose.tolist()]
        return cloud_input(self.points, normals=self.normals, camera_poses=poses,
                           points_frame="camera" if poses else None, shape=self.shape, pixel=self.pixel)

    def describe(self) -> dict[str, Any]:
        """The message an answer came from: topic, index, stamp, frame_id, and the frame of the grasps."""
        return {"topic": self.topic, "index": self.index, "stamp": {"sec": self.stamp[0], "nanosec": self.stamp[1]},
                "frame_id": self.frame_id, "grasps_frame": self.pose_frame or self.frame_id}


class _MemoryPath:
    """A bag file held in memory, as rosbags' readers open a path (an upload: nothing is written to disk)."""

    def __init__(self, data: bytes, suffix: str) -> None:
        self.data, self.suffix, self.name, self.stem = data, suffix, f"upload{suffix}", "upload"

    def exists(self) -> bool:
        return True

    def is_dir(self) -> bool:
        return False

    def open(self, *_args: object, **_kwargs: object) -> io.BytesIO:
        return io.BytesIO(self.data)

    def read_text(self, encoding: str | None = None) -> str:
        return self.data.decode(encoding or "utf-8")

    def stat(self, *, follow_symlinks: bool = True) -> Any:
        return type("Stat", (), {"st_size": len(self.data)})()

    def __truediv__(self, key: object) -> _MemoryPath:
        raise CloudError("body", "an uploaded bag is one file (MCAP or ROS 1 .bag), not a directory")

    def __str__(self) -> str:
        return self.name


def bag_kind(data: bytes) -> str | None:
    """'mcap', 'rosbag1' or 'sqlite3' from a file's first bytes; None when it is none of them."""
    for kind, magic in (("mcap", MCAP_MAGIC), ("rosbag1", ROSBAG1_MAGIC), ("sqlite3", SQLITE_MAGIC)):
        if data.startswith(magic):
            return kind
    return None


def is_bag_path(path: str | Path) -> bool:
    """Whether a path names a bag: a .mcap, .db3 or .bag file, or a directory with a rosbag2 metadata.yaml."""
    p = Path(path)
    return p.suffix.lower() in BAG_SUFFIXES or (p.is_dir() and (p / "metadata.yaml").is_file())


def _check_directory(path: Path) -> None:
    """A rosbag2 directory's metadata.yaml, read before rosbags opens it: compression_mode 'file' or 'message'
    (rosbag2's older zstd compression, which rosbags inflates with no bound) is refused."""
    meta = path / "metadata.yaml"
    if meta.stat().st_size > MAX_METADATA_BYTES:
        raise CloudError("body", f"{meta.name} exceeds {MAX_METADATA_BYTES} bytes")
    try:
        doc = yaml.safe_load(meta.read_bytes())
    except yaml.YAMLError:
        raise CloudError("body", f"{meta.name} is not YAML") from None
    info = doc.get("rosbag2_bagfile_information") if isinstance(doc, dict) else None
    mode = str(info.get("compression_mode", "") if isinstance(info, dict) else "").lower()
    if mode in ("file", "message"):
        raise CloudError("body", f"the bag is compressed with rosbag2's compression_mode {mode!r}, which is not "
                         "read (no bound on what it inflates to); record with MCAP chunk compression "
                         "(ros2 bag record -s mcap --storage-preset-profile zstd_fast) or decompress it first")


def _open(source: Path | bytes) -> tuple[Any, bool]:
    """An unopened rosbags reader for a path or uploaded bytes, and whether it is a ROS 1 bag."""
    if isinstance(source, bytes):
        kind = bag_kind(source)
        if kind == "sqlite3":
            raise CloudError("body", "a rosbag2 sqlite3 (.db3) bag is read from a file (graspd detect BAG --topic "
                             "...), not as an upload; upload MCAP or a ROS 1 .bag")
        if kind is None:
            raise CloudError("body", "not a bag (MCAP or ROS 1 .bag magic bytes)")
        memory = _MemoryPath(source, ".mcap" if kind == "mcap" else ".bag")
        return (Rosbag1Reader(memory) if kind == "rosbag1" else Rosbag2Reader(memory)), kind == "rosbag1"  # type: ignore[arg-type]
    if source.is_dir():
        _check_directory(source)
        return Rosbag2Reader(source), False
    with source.open("rb") as f:
        kind = bag_kind(f.read(16))
    if kind is None:
        raise CloudError("body", f"{source.name} is not a bag (MCAP, sqlite3 or ROS 1 .bag magic bytes)")
    return (Rosbag1Reader(source) if kind == "rosbag1" else Rosbag2Reader(source)), kind == "rosbag1"


def _cdr(raw: bytes, msgtype: str, ros1: bool, field: str) -> bytes | memoryview:
    """The CDR bytes of a message: a ROS 1 message converted to its ROS 2 type's CDR (rosbags' ros1_to_cdr with
    the ROS 2 types: the Header's seq is dropped; the other layouts are the same)."""
    if not ros1:
        return raw
    try:
        return typestore().ros1_to_cdr(raw, msgtype)
    except Exception as exc:  # rosbags' generated converters raise struct, index and key errors on bad bytes
        raise CloudError(field, f"a {msgtype} message of the bag is unreadable ({type(exc).__name__})") from None


def _topics(connections: list[Connection]) -> dict[str, str]:
    """topic -> message type."""
    return {c.topic: c.msgtype for c in connections}


def _choose_topic(query: BagQuery, topics: dict[str, str]) -> str:
    """The topic to read: the query's, else the only PointCloud2 topic, else the only depth Image topic."""
    listed = ", ".join(f"{t} ({m.rsplit('/', 1)[-1]})" for t, m in sorted(topics.items())[:30])
    if query.topic is not None:
        if query.topic not in topics:
            raise CloudError("topic", f"no topic {query.topic!r} in the bag; it has {listed or 'no topics'}")
        if topics[query.topic] not in (POINTCLOUD2, IMAGE):
            raise CloudError("topic", f"{query.topic} carries {topics[query.topic]}; a PointCloud2 or a depth Image "
                             "topic is read")
        return query.topic
    for msgtype in (POINTCLOUD2, IMAGE):
        found = [t for t, m in topics.items() if m == msgtype]
        if len(found) == 1:
            return found[0]
        if len(found) > 1:
            raise CloudError("topic", f"the bag has {len(found)} {msgtype} topics; name one: {sorted(found)}")
    raise CloudError("topic", f"the bag has no PointCloud2 or Image topic; it has {listed or 'no topics'}")


def _info_topic(query: BagQuery, topic: str, topics: dict[str, str]) -> str:
    """The CameraInfo topic of a depth image topic: the query's, else the conventional sibling camera_info."""
    info = query.info_topic or str(PurePosixPath(topic).parent / "camera_info")
    if topics.get(info) != CAMERA_INFO:
        raise CloudError("info_topic", f"no CameraInfo topic {info!r} in the bag for the depth images of {topic}; "
                         "name it (info_topic)")
    return info


def _messages(reader: Any, topic: str, topics_conns: list[Connection]) -> Iterator[bytes]:
    """The raw bytes of a topic's messages in time order."""
    conns = [c for c in topics_conns if c.topic == topic]
    for _, _, raw in reader.messages(connections=conns):
        yield raw


def _tf_tree(reader: Any, conns: list[Connection], ros1: bool) -> TfTree:
    """The bag's /tf_static transforms and its /tf ones with their stamps (empty when it has neither)."""
    tree = TfTree()
    topics = _topics(conns)
    for topic, cap in ((TF_STATIC, MAX_TF_MESSAGES), (TF, MAX_TF_DYNAMIC_MESSAGES)):
        if topics.get(topic) != TF_MESSAGE:
            continue
        for k, raw in enumerate(_messages(reader, topic, conns)):
            if k >= cap:
                raise CloudError("frame", f"the bag has more than {cap} {topic} messages")
            try:
                for t in decode_tf_message(_cdr(raw, TF_MESSAGE, ros1, "frame")):
                    if topic == TF_STATIC:
                        tree.add(t.parent, t.child, t.matrix, "frame")
                    else:
                        tree.add_dynamic(t.parent, t.child, _nanoseconds(t.stamp), t.matrix, "frame")
            except RosDecodeError as exc:
                raise CloudError("frame", f"a {topic} message is unreadable ({exc})") from None
    return tree


def _nanoseconds(stamp: tuple[int, int]) -> int:
    """A ROS stamp (sec, nanosec) in ns."""
    return int(stamp[0]) * 1_000_000_000 + int(stamp[1])


def _camera_info(reader: Any, topic: str, conns: list[Connection], ros1: bool) -> CameraInfo:
    """The first CameraInfo of the topic (a camera's calibration does not change while it records)."""
    for raw in _messages(reader, topic, conns):
        try:
            return decode_camera_info(_cdr(raw, CAMERA_INFO, ros1, "info_topic"))
        except RosDecodeError as exc:
            raise CloudError("info_topic", f"the CameraInfo on {topic} is unreadable ({exc})") from None
    raise CloudError("info_topic", f"{topic} has no message")


def _decode(raw: bytes, msgtype: str, ros1: bool, query: BagQuery, info: CameraInfo | None, topic: str,
            index: int) -> BagCloud:
    """One message's BagCloud (without its pose)."""
    payload = _cdr(raw, msgtype, ros1, "topic")
    try:
        if msgtype == POINTCLOUD2:
            rows = pointcloud2_rows(payload)
            return BagCloud(topic, index, rows.header.stamp, rows.header.frame_id.lstrip("/"), rows.points,
                            rows.normals, rows.shape if rows.shape[0] > 1 else None)
        image = decode_depth_image(payload, query.depth_scale)
    except RosDecodeError as exc:
        raise CloudError("topic", f"message {index} of {topic} is unreadable ({exc})") from None
    assert info is not None
    height, width = image.depth.shape
    if (info.width, info.height) not in ((width, height), (0, 0)):
        raise CloudError("info_topic", f"the CameraInfo is for {info.width}x{info.height} images; message {index} "
                         f"of {topic} is {width}x{height}")
    points = depth_points(image.depth, info.intrinsics())  # pixels without depth (0) left out, as in a depth PNG
    return BagCloud(topic, index, image.header.stamp, image.header.frame_id.lstrip("/"), points,
                    shape=(height, width), pixel=depth_pixels(image.depth))


def read_bag(source: str | Path | bytes, query: BagQuery, max_inflate: int | None = None) -> Iterator[BagCloud]:
    """The clouds a query selects from a bag (a path, or an upload's bytes), one per selected message, with the
    camera pose of /tf_static; CloudError naming the field at fault.  Chunks inflate under
    graspd.io.bag_limits' bound, all of them together under max_inflate bytes (default: MAX_UPLOAD_INFLATE for
    bytes, none for a path the caller chose)."""
    if query.index < 0 or (query.every is not None and query.every < 1):
        raise CloudError("index" if query.index < 0 else "every", "index must be >= 0 and every >= 1")
    bag_limits.install()
    data = source if isinstance(source, bytes) else None
    total = max_inflate if max_inflate is not None else (MAX_UPLOAD_INFLATE if data is not None else None)
    with ExitStack() as stack:
        stack.enter_context(bag_limits.decompression_budget(total))
        try:
            reader, ros1 = _open(data if data is not None else Path(source))  # type: ignore[arg-type]
            stack.enter_context(reader)
            conns = list(reader.connections)
            yield from _read_open(reader, conns, ros1, query)
        except CloudError:
            raise
        except (OSError, EOFError, MemoryError, ValueError, KeyError, IndexError, AssertionError, TypeError) as exc:
            raise CloudError("body", f"the bag is unreadable ({type(exc).__name__}: {_short(exc)})") from None
        except Exception as exc:  # rosbags' ReaderError and its storage errors (apsw, struct) have no common base
            raise CloudError("body", f"the bag is unreadable ({type(exc).__name__}: {_short(exc)})") from None


def _short(exc: BaseException) -> str:
    """An error's first line, shortened (rosbags' messages may name the file's path: only its name is kept)."""
    text = str(exc).splitlines()[0] if str(exc) else ""
    return text[:200]


def _read_open(reader: Any, conns: list[Connection], ros1: bool, query: BagQuery) -> Iterator[BagCloud]:
    topics = _topics(conns)
    topic = _choose_topic(query, topics)
    msgtype = topics[topic]
    info = None
    if msgtype == IMAGE:
        info = _camera_info(reader, _info_topic(query, topic, topics), conns, ros1)
    tree = _tf_tree(reader, conns, ros1)
    if query.frame is not None and query.frame.lstrip("/") not in tree:
        raise CloudError("frame", f"frame {query.frame!r} is not in the bag's {TF_STATIC} or {TF} "
                         f"({sorted(tree.frames())[:20] or 'none'})")
    found = 0
    for index, raw in enumerate(_messages(reader, topic, conns)):
        if index < query.index or (query.every is not None and (index - query.index) % query.every):
            continue
        cloud = _decode(raw, msgtype, ros1, query, info, topic, index)
        yield _posed(cloud, tree, query.frame)
        found += 1
        if query.every is None:
            return
    if not found:
        raise CloudError("index", f"{topic} has fewer than {query.index + 1} messages")


def _posed(cloud: BagCloud, tree: TfTree, frame: str | None) -> BagCloud:
    """The cloud with its camera pose from the /tf_static and /tf tree at the message's stamp (unchanged when its
    frame is not in the tree and no frame was asked for)."""
    if cloud.frame_id not in tree:
        if frame is not None:
            raise CloudError("frame", f"the cloud's frame {cloud.frame_id!r} is not in the bag's {TF_STATIC} "
                             f"or {TF}")
        return cloud
    pose, target = tree.pose(cloud.frame_id, None if frame is None else frame.lstrip("/"), "frame",
                             _nanoseconds(cloud.stamp))
    if target == cloud.frame_id:
        return cloud
    return replace(cloud, camera_pose=pose, pose_frame=target)
