"""CDR bytes of sensor_msgs/PointCloud2 and gpd_ros CloudSources / CloudIndexed / CloudSamples -> graspd inputs.

The reader is a bounded, vectorised CDR (XCDR1, the ROS 2 default) parser: every declared size is checked
against the bytes that are left before anything is allocated, and a malformed message raises RosDecodeError
with .field naming the offending field (for example "cloud.point_step", "camera_source", "indices").
It reads exactly what rosbags' deserialize_cdr reads (the tests check both ways), at numpy speed:
rosbags builds one Python object per std_msgs/Int64 of camera_source, about 2 us a point.
Points, viewpoints and samples are in the cloud's header.frame_id, in metres.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from graspd.core.cloud import CloudError, CloudGrid, ViewpointCloud
from graspd.core.limits import MAX_NUM_SAMPLES, MAX_POINTS, MAX_TARGET_INDICES
from graspd.io.inputs import finite_rows
from graspd.io.ros.types import CLOUD_INDEXED, CLOUD_SAMPLES, CLOUD_SOURCES, POINTCLOUD2, Header

#: Most camera positions (view_points) a CloudSources may carry.
MAX_VIEWPOINTS = 1024
#: Most sample points of a CloudSamples; most indices of a CloudIndexed (the rows of a target, as over HTTP).
MAX_SAMPLES = MAX_NUM_SAMPLES
MAX_INDICES = MAX_TARGET_INDICES
#: Most PointField entries, and longest frame_id / field name (bytes).
MAX_FIELDS = 64
MAX_STRING = 4096
#: Largest |coordinate| (m) of a view point or sample: beyond it float32 would overflow, and nothing is that far.
MAX_COORD = 1e6
#: sensor_msgs/PointField datatype codes -> numpy type characters.
POINTFIELD_TYPES = {1: "i1", 2: "u1", 3: "i2", 4: "u2", 5: "i4", 6: "u4", 7: "f4", 8: "f8"}


class RosDecodeError(ValueError):
    """A ROS message is malformed or out of bounds; .field names the offending field (dotted path)."""

    def __init__(self, field: str, message: str) -> None:
        super().__init__(f"{field}: {message}")
        self.field = field


@dataclass(frozen=True)
class CloudMessage:
    """A decoded input: the cloud (points, per-point camera index, viewpoints, normals when the message has
    normal_x/y/z) in header.frame_id (m), its header, and what to grasp (both None: any object; the server makes
    them a request's target, graspd.server.services.ros_stream.message_target)."""

    cloud: ViewpointCloud
    header: Header
    sample_indices: NDArray[np.int64] | None = None  # (K,) rows of cloud.points: the target's (CloudIndexed)
    samples: NDArray[np.float64] | None = None  # (K, 3) positions in header.frame_id, m (CloudSamples)
    msg_type: str = POINTCLOUD2
    #: Rows the message declared (width x height, an organised cloud's NaN pixels included) and how many of them
    #: were dropped for a NaN or infinite coordinate or normal (graspd.io.inputs: the warning non_finite_dropped).
    received: int = 0
    dropped: int = 0


class CdrReader:
    """Sequential CDR reader over one payload; alignment is relative to the end of the 4-byte encapsulation."""

    def __init__(self, payload: bytes | bytearray | memoryview) -> None:
        buf = memoryview(payload).cast("B")
        if len(buf) < 4 or buf[0] != 0 or buf[1] not in (0, 1):
            raise RosDecodeError("encapsulation", "not CDR (expected a 4-byte header 00 00 or 00 01)")
        self.buf = buf
        self.pos = 4
        self.order = "<" if buf[1] == 1 else ">"

    def _take(self, size: int, align: int, field: str) -> int:
        self.pos = 4 + -(-(self.pos - 4) // align) * align if align > 1 else self.pos
        start = self.pos
        if size < 0 or start + size > len(self.buf):
            raise RosDecodeError(field, f"truncated: needs {size} bytes at offset {start}, "
                                        f"the message has {len(self.buf)}")
        self.pos = start + size
        return start

    def scalar(self, code: str, field: str) -> int:
        dt = np.dtype(self.order + code)
        start = self._take(dt.itemsize, dt.itemsize, field)
        return int(np.frombuffer(self.buf, dt, 1, start)[0])

    def boolean(self, field: str) -> bool:
        return self.buf[self._take(1, 1, field)] != 0

    def string(self, field: str) -> str:
        n = self.scalar("u4", field)
        if n > MAX_STRING:
            raise RosDecodeError(field, f"string of {n} bytes exceeds {MAX_STRING}")
        start = self._take(n, 1, field)
        raw = bytes(self.buf[start:start + n])
        return raw.rstrip(b"\x00").decode("utf-8", errors="replace")

    def count(self, field: str, limit: int, item_size: int) -> int:
        """A sequence length, checked against limit and against the bytes left (before any allocation)."""
        n = self.scalar("u4", field)
        if n > limit:
            raise RosDecodeError(field, f"{n} entries exceed the limit of {limit}")
        if n * item_size > len(self.buf) - self.pos:
            raise RosDecodeError(field, f"declares {n} entries ({n * item_size} bytes); "
                                        f"{len(self.buf) - self.pos} bytes are left")
        return n

    def array(self, code: str, n: int, field: str, width: int = 1) -> NDArray[np.generic]:
        """n rows of width values of type code (aligned to the item size when n > 0), a read-only view."""
        dt = np.dtype(self.order + code)
        if n == 0:
            return np.zeros((0, width) if width > 1 else 0, dt)
        start = self._take(n * width * dt.itemsize, dt.itemsize, field)
        out = np.frombuffer(self.buf, dt, n * width, start)
        return out.reshape(n, width) if width > 1 else out

    def header(self, field: str) -> Header:
        sec = self.scalar("i4", f"{field}.stamp.sec")
        nanosec = self.scalar("u4", f"{field}.stamp.nanosec")
        return Header(self.string(f"{field}.frame_id"), (sec, nanosec))


_Reader = CdrReader  # the name graspd.io.ros.planning imports


@dataclass(frozen=True)
class _RawCloud:
    header: Header
    points: NDArray[np.float32]  # (N, 3), every declared point, NaN rows included
    normals: NDArray[np.float32] | None  # (N, 3) when the cloud has normal_x/y/z
    shape: tuple[int, int] = (0, 0)  # (height, width): height > 1 for an organised cloud


def _read_pointcloud2(r: CdrReader, prefix: str) -> _RawCloud:
    header = r.header(f"{prefix}header")
    height = r.scalar("u4", f"{prefix}height")
    width = r.scalar("u4", f"{prefix}width")
    nfields = r.count(f"{prefix}fields", MAX_FIELDS, 13)
    fields: dict[str, tuple[int, int, int]] = {}
    for i in range(nfields):
        name = r.string(f"{prefix}fields[{i}].name")
        offset = r.scalar("u4", f"{prefix}fields[{i}].offset")
        datatype = r.scalar("u1", f"{prefix}fields[{i}].datatype")
        count = r.scalar("u4", f"{prefix}fields[{i}].count")
        fields.setdefault(name, (offset, datatype, count))
    bigendian = r.boolean(f"{prefix}is_bigendian")
    point_step = r.scalar("u4", f"{prefix}point_step")
    row_step = r.scalar("u4", f"{prefix}row_step")
    ndata = r.count(f"{prefix}data", 2**32, 1)
    data = r.array("u1", ndata, f"{prefix}data")
    r.boolean(f"{prefix}is_dense")

    missing = [a for a in "xyz" if a not in fields]
    if missing:
        raise RosDecodeError(f"{prefix}fields", f"lack {missing} (have {sorted(fields)})")
    n = height * width
    if n > MAX_POINTS:
        raise RosDecodeError(f"{prefix}width", f"width x height = {n} points exceeds the limit of {MAX_POINTS}")
    if n and point_step == 0:
        raise RosDecodeError(f"{prefix}point_step", "is 0")
    if row_step < width * point_step:
        raise RosDecodeError(f"{prefix}row_step", f"{row_step} < width x point_step = {width * point_step}")
    if height * row_step > ndata:
        raise RosDecodeError(f"{prefix}data", f"has {ndata} bytes; height x row_step = {height * row_step}")
    order = ">" if bigendian else "<"
    has_normals = all(f"normal_{a}" in fields for a in "xyz")
    names = list("xyz") + ([f"normal_{a}" for a in "xyz"] if has_normals else [])
    formats, offsets = [], []
    for name in names:
        offset, datatype, _count = fields[name]
        if datatype not in POINTFIELD_TYPES:
            raise RosDecodeError(f"{prefix}fields.{name}.datatype", f"unknown datatype {datatype}")
        fmt = np.dtype(order + POINTFIELD_TYPES[datatype])
        if offset + fmt.itemsize > point_step:
            raise RosDecodeError(f"{prefix}fields.{name}.offset",
                                 f"{offset} + {fmt.itemsize} bytes passes point_step {point_step}")
        formats.append(fmt)
        offsets.append(offset)
    if n == 0:
        empty = np.zeros((0, 3), np.float32)
        return _RawCloud(header, empty, empty.copy() if has_normals else None, (height, width))
    points = _gather(data, offsets[:3], formats[:3], height, width, point_step, row_step)
    normals = _gather(data, offsets[3:], formats[3:], height, width, point_step, row_step) if has_normals else None
    return _RawCloud(header, points, normals, (height, width))


def _gather(data: NDArray[np.generic], offsets: list[int], formats: list[np.dtype[np.generic]], height: int,
            width: int, point_step: int, row_step: int) -> NDArray[np.float32]:
    """Three fields of every point of data (the PointCloud2's bytes, rows row_step bytes apart, points point_step
    apart) as (height x width, 3) float32: one copy out of the message, no intermediate.  Packed native float32
    x, y, z (point_step 12, unpadded rows) is one memcpy; anything else three strided column copies, converting
    the field's type and byte order (float64 beyond float32 -> inf, dropped as non-finite later).  The caller has
    checked that every field lies within point_step and height x row_step within data."""
    n = height * width
    f32 = np.dtype(np.float32)
    if (point_step == 3 * f32.itemsize and offsets == [0, 4, 8] and all(f == f32 for f in formats)
            and (height == 1 or row_step == width * point_step)):
        return data[: n * point_step].view(f32).reshape(n, 3).copy()
    out = np.empty((n, 3), np.float32)
    grid = out.reshape(height, width, 3)
    with np.errstate(over="ignore", invalid="ignore"):
        for k, (offset, fmt) in enumerate(zip(offsets, formats, strict=True)):
            grid[:, :, k] = np.ndarray((height, width), fmt, buffer=data, offset=offset,
                                       strides=(row_step, point_step))
    return out


@dataclass(frozen=True)
class PointCloudRows:
    """Every row of a PointCloud2 (non-finite ones included, in pixel order), for a reader that counts and drops
    them itself (graspd.io.inputs): points (N,3) float32 and normals (N,3) when the cloud has normal_x/y/z, in
    header.frame_id (m); shape (height, width)."""

    header: Header
    points: NDArray[np.float32]
    normals: NDArray[np.float32] | None
    shape: tuple[int, int]


def pointcloud2_rows(payload: bytes | bytearray | memoryview) -> PointCloudRows:
    """A CDR sensor_msgs/PointCloud2 -> all its rows, bounded as decode_pointcloud2 is."""
    raw = _read_pointcloud2(CdrReader(payload), "")
    return PointCloudRows(raw.header, raw.points, raw.normals, raw.shape)


def _read_cloud_sources(r: CdrReader, prefix: str) -> tuple[_RawCloud, NDArray[np.int64], NDArray[np.float64]]:
    raw = _read_pointcloud2(r, f"{prefix}cloud.")
    nsrc = r.count(f"{prefix}camera_source", MAX_POINTS, 8)
    camera_source = r.array("i8", nsrc, f"{prefix}camera_source").astype(np.int64)
    nview = r.count(f"{prefix}view_points", MAX_VIEWPOINTS, 24)
    view_points = r.array("f8", nview, f"{prefix}view_points", 3).astype(np.float64)
    return raw, camera_source, view_points


def _finite_rows(raw: _RawCloud) -> NDArray[np.bool_] | None:
    """Rows to keep: finite point and normal (graspd.io.inputs.finite_rows' rule, the one of every entrance);
    None when every row is (the usual case, found by a min and a max over all values: NaN and inf carry through
    both; no mask, and no copy of the cloud later), else the mask."""
    arrays = [raw.points] if raw.normals is None else [raw.points, raw.normals]
    with np.errstate(invalid="ignore"):
        if all(len(a) == 0 or (np.isfinite(a.min()) and np.isfinite(a.max())) for a in arrays):
            return None
    return finite_rows(raw.points, raw.normals)


def _dropped(keep: NDArray[np.bool_] | None) -> int:
    """The dropped field of a CloudMessage: rows not kept."""
    return 0 if keep is None else int(len(keep) - np.count_nonzero(keep))


def _viewpoint_cloud(raw: _RawCloud, camera_source: NDArray[np.int64] | None, view_points: NDArray[np.float64],
                     keep: NDArray[np.bool_] | None, prefix: str) -> ViewpointCloud:
    """The ViewpointCloud of the rows kept (keep None: all of them, no copy)."""
    n = len(raw.points)
    k = len(view_points)
    if k == 0:
        raise RosDecodeError(f"{prefix}view_points", "needs at least one camera position")
    if not (np.abs(view_points) <= MAX_COORD).all():
        raise RosDecodeError(f"{prefix}view_points", f"must be finite, within {MAX_COORD:g} m")
    if camera_source is None or len(camera_source) == 0:
        src = np.zeros(n, np.int32)
    else:
        if len(camera_source) != n:
            raise RosDecodeError(f"{prefix}camera_source",
                                 f"has {len(camera_source)} entries; the cloud has {n} points (one each, or none)")
        lo, hi = int(camera_source.min()), int(camera_source.max())
        if lo < 0 or hi >= k:
            raise RosDecodeError(f"{prefix}camera_source", f"indices must lie in [0, {k - 1}] (one per view point), "
                                                           f"got [{lo}, {hi}]")
        src = camera_source.astype(np.int32)
    height, width = raw.shape
    # an organised cloud (height > 1) of one camera keeps its grid: image-neighbour filters and normals use it
    grid = CloudGrid.of_rows(height, width, keep) if height > 1 and k == 1 else None
    try:
        return ViewpointCloud(
            points=raw.points if keep is None else raw.points[keep],
            viewpoints=view_points.astype(np.float32),
            camera_source=src if keep is None else src[keep],
            normals=raw.normals if raw.normals is None or keep is None else raw.normals[keep],
            grid=grid,
        )
    except CloudError as exc:  # unreachable after the checks above; kept so nothing escapes unnamed
        raise RosDecodeError(f"{prefix}cloud", str(exc)) from None


def decode_pointcloud2(payload: bytes | bytearray | memoryview,
                       viewpoints: ArrayLike = ((0.0, 0.0, 0.0),)) -> CloudMessage:
    """A CDR sensor_msgs/PointCloud2 -> its finite points (header.frame_id, m), seen from viewpoints (K, 3), all
    points attributed to camera 0 (the sensor origin of the cloud frame by default)."""
    r = CdrReader(payload)
    raw = _read_pointcloud2(r, "")
    vps = np.asarray(viewpoints, np.float64).reshape(-1, 3)
    keep = _finite_rows(raw)
    cloud = _viewpoint_cloud(raw, None, vps, keep, "")
    return CloudMessage(cloud, raw.header, msg_type=POINTCLOUD2, received=len(raw.points), dropped=_dropped(keep))


def decode_cloud_sources(payload: bytes | bytearray | memoryview) -> CloudMessage:
    """A CDR gpd_ros/CloudSources -> the cloud's finite points with their camera_source index into view_points
    (camera positions, header.frame_id, m); normals kept when the cloud has normal_x/y/z."""
    r = CdrReader(payload)
    raw, src, vps = _read_cloud_sources(r, "")
    keep = _finite_rows(raw)
    cloud = _viewpoint_cloud(raw, src, vps, keep, "")
    return CloudMessage(cloud, raw.header, msg_type=CLOUD_SOURCES, received=len(raw.points), dropped=_dropped(keep))


def decode_cloud_indexed(payload: bytes | bytearray | memoryview) -> CloudMessage:
    """A CDR gpd_ros/CloudIndexed -> the cloud of cloud_sources plus sample_indices: the rows of cloud.points the
    indices name (the target's points; indices into the message's cloud, renumbered after non-finite points are
    dropped; indices of dropped points are left out).  Up to MAX_INDICES, counted before they are read."""
    r = CdrReader(payload)
    raw, src, vps = _read_cloud_sources(r, "cloud_sources.")
    nidx = r.count("indices", MAX_INDICES, 8)
    indices = r.array("i8", nidx, "indices").astype(np.int64)
    n = len(raw.points)
    if nidx and (int(indices.min()) < 0 or int(indices.max()) >= n):
        raise RosDecodeError("indices", f"must lie in [0, {n - 1}] (rows of the cloud), "
                                        f"got [{int(indices.min())}, {int(indices.max())}]")
    keep = _finite_rows(raw)
    cloud = _viewpoint_cloud(raw, src, vps, keep, "cloud_sources.")
    if keep is None:  # every row kept: the indices stand
        sample_indices = indices
    else:
        new_row = np.cumsum(keep, dtype=np.int64) - 1
        sample_indices = new_row[indices[keep[indices]] if nidx else indices]
    return CloudMessage(cloud, raw.header, sample_indices=sample_indices, msg_type=CLOUD_INDEXED,
                        received=len(raw.points), dropped=_dropped(keep))


def decode_cloud_samples(payload: bytes | bytearray | memoryview) -> CloudMessage:
    """A CDR gpd_ros/CloudSamples -> the cloud of cloud_sources plus samples (K, 3): positions to sample at
    (header.frame_id, m)."""
    r = CdrReader(payload)
    raw, src, vps = _read_cloud_sources(r, "cloud_sources.")
    nsamples = r.count("samples", MAX_SAMPLES, 24)
    samples = r.array("f8", nsamples, "samples", 3).astype(np.float64).reshape(-1, 3)
    if not (np.abs(samples) <= MAX_COORD).all():
        raise RosDecodeError("samples", f"must be finite, within {MAX_COORD:g} m")
    keep = _finite_rows(raw)
    cloud = _viewpoint_cloud(raw, src, vps, keep, "cloud_sources.")
    return CloudMessage(cloud, raw.header, samples=samples, msg_type=CLOUD_SAMPLES, received=len(raw.points),
                        dropped=_dropped(keep))


DECODERS: dict[str, Callable[[bytes | bytearray | memoryview], CloudMessage]] = {
    POINTCLOUD2: decode_pointcloud2,
    CLOUD_SOURCES: decode_cloud_sources,
    CLOUD_INDEXED: decode_cloud_indexed,
    CLOUD_SAMPLES: decode_cloud_samples,
}


def decode_cloud_message(payload: bytes | bytearray | memoryview, msg_type: str) -> CloudMessage:
    """Decode payload as msg_type, one of DECODERS ("sensor_msgs/msg/PointCloud2", "gpd_ros/msg/CloudSources",
    ... ; the "pkg/Name" spelling without /msg/ is accepted)."""
    key = msg_type if "/msg/" in msg_type else msg_type.replace("/", "/msg/", 1)
    if key not in DECODERS:
        raise RosDecodeError("type", f"unsupported message type {msg_type!r}; known: {sorted(DECODERS)}")
    return DECODERS[key](payload)
