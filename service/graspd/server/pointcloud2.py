"""sensor_msgs/PointCloud2 as zenoh-bridge-ros2dds publishes it (CDR with its encapsulation header):
CDR is deserialised by rosbags; the point layout (fields, offsets, point_step) is read with numpy."""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from typing import Any

import numpy as np
from numpy.typing import NDArray

MSG_TYPE = "sensor_msgs/msg/PointCloud2"
#: Most points a cloud may declare (the /detect cap, graspd.server.schemas.MAX_POINTS).
MAX_POINTS = 5_000_000
#: sensor_msgs/PointField datatype codes -> numpy type characters.
_POINTFIELD_TYPES = {1: "i1", 2: "u1", 3: "i2", 4: "u2", 5: "i4", 6: "u4", 7: "f4", 8: "f8"}


class PointCloud2Error(ValueError):
    """The payload is not a usable PointCloud2; the message says which part."""


@dataclass(frozen=True)
class DecodedCloud:
    points: NDArray[np.float32]  # (N,3) finite points, sensor frame (metres)
    frame_id: str
    stamp: tuple[int, int]  # (sec, nanosec)


@lru_cache(maxsize=1)
def _typestore() -> Any:
    from rosbags.typesys import Stores, get_typestore

    return get_typestore(Stores.ROS2_HUMBLE)


def looks_like_cdr(payload: bytes) -> bool:
    """CDR encapsulation header: 0x00 0x00 (big-endian CDR) or 0x00 0x01 (little-endian), then options."""
    return len(payload) >= 4 and payload[0] == 0 and payload[1] in (0, 1)


def decode_pointcloud2(payload: bytes) -> DecodedCloud:
    """x, y, z of every finite point of a CDR PointCloud2 (NaN points of organised clouds dropped)."""
    try:
        msg = _typestore().deserialize_cdr(payload, MSG_TYPE)
    except Exception as exc:  # rosbags raises several types on garbage
        raise PointCloud2Error(f"not a CDR {MSG_TYPE} ({type(exc).__name__}: {exc})") from None
    fields = {f.name: f for f in msg.fields}
    missing = [a for a in "xyz" if a not in fields]
    if missing:
        raise PointCloud2Error(f"fields lack {missing} (have {sorted(fields)})")
    n = int(msg.width) * int(msg.height)
    step = int(msg.point_step)
    if n > MAX_POINTS:  # checked before any array is shaped from the declared layout
        raise PointCloud2Error(f"width x height = {n} points exceeds the limit of {MAX_POINTS}")
    if n * step > len(msg.data) or int(msg.height) * int(msg.row_step) > len(msg.data):
        raise PointCloud2Error(f"width x height x point_step = {n * step} bytes, row_step x height = "
                               f"{int(msg.height) * int(msg.row_step)}; data has {len(msg.data)} bytes")
    order = ">" if msg.is_bigendian else "<"
    names, formats, offsets = [], [], []
    for a in "xyz":
        f = fields[a]
        if f.datatype not in _POINTFIELD_TYPES:
            raise PointCloud2Error(f"field {a} has unknown datatype {f.datatype}")
        names.append(a)
        formats.append(order + _POINTFIELD_TYPES[f.datatype])
        offsets.append(int(f.offset))
    data = np.asarray(msg.data, np.uint8)
    too_far = any(o + np.dtype(f).itemsize > step for o, f in zip(offsets, formats, strict=True))
    if step <= 0 or too_far or int(msg.row_step) < int(msg.width) * step:
        raise PointCloud2Error(f"inconsistent layout (point_step {step}, row_step {msg.row_step})")
    if data.size < int(msg.height) * int(msg.row_step):
        raise PointCloud2Error(f"data has {data.size} bytes, {int(msg.height) * int(msg.row_step)} expected")
    dtype = np.dtype({"names": names, "formats": formats, "offsets": offsets, "itemsize": step})
    rows = data[: int(msg.height) * int(msg.row_step)].reshape(int(msg.height), int(msg.row_step))
    packed = np.ascontiguousarray(rows[:, : int(msg.width) * step]).reshape(-1)
    rec = packed.view(dtype)[:n]
    xyz = np.stack([rec[a].astype(np.float32) for a in "xyz"], axis=1)
    xyz = xyz[np.isfinite(xyz).all(axis=1)]
    stamp = (int(msg.header.stamp.sec), int(msg.header.stamp.nanosec))
    return DecodedCloud(xyz, str(msg.header.frame_id), stamp)


def encode_pointcloud2(points: NDArray[np.floating], frame_id: str = "camera",
                       stamp: tuple[int, int] = (0, 0)) -> bytes:
    """A CDR PointCloud2 (x, y, z float32, unorganised) of points (N,3): what a ROS 2 camera driver sends."""
    ts = _typestore()
    t = ts.types
    pts = np.ascontiguousarray(np.asarray(points, np.float32))
    header = t["std_msgs/msg/Header"](stamp=t["builtin_interfaces/msg/Time"](sec=stamp[0], nanosec=stamp[1]),
                                      frame_id=frame_id)
    fields = [t["sensor_msgs/msg/PointField"](name=a, offset=4 * i, datatype=7, count=1) for i, a in enumerate("xyz")]
    msg = t[MSG_TYPE](header=header, height=1, width=len(pts), fields=fields, is_bigendian=False, point_step=12,
                      row_step=12 * len(pts), data=pts.view(np.uint8).reshape(-1), is_dense=True)
    return bytes(ts.serialize_cdr(msg, MSG_TYPE))
