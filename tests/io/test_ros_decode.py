"""graspd.io.ros.decode: CDR clouds built by rosbags' serialize_cdr, as zenoh-bridge-ros2dds forwards them from a ROS 2
node, decode to the right ViewpointCloud, header and sample points; malformed ones raise RosDecodeError naming the
field; the fast input builders of graspd.io.ros.encode write what rosbags reads (byte for byte what it writes)."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from graspd.io.ros import (
    Header,
    RosDecodeError,
    decode_cloud_indexed,
    decode_cloud_message,
    decode_cloud_samples,
    decode_cloud_sources,
    decode_pointcloud2,
    encode_cloud_indexed,
    encode_cloud_samples,
    encode_cloud_sources,
    encode_pointcloud2,
)
from graspd.io.ros.decode import MAX_POINTS
from graspd.io.ros.types import CLOUD_INDEXED, CLOUD_SAMPLES, CLOUD_SOURCES, POINTCLOUD2, typestore

TS = typestore()


def deser(payload: bytes, msgtype: str) -> Any:
    """What a ROS 2 node reads: rosbags' deserialize_cdr."""
    return TS.deserialize_cdr(payload, msgtype)
T = TS.types
VIEWS = np.array([[0.6, 0.0, 0.5], [-0.6, 0.1, 0.5], [0.0, 0.7, 0.9]])


def ros_header(frame_id: str = "camera_link", stamp: tuple[int, int] = (1712345678, 123456789)) -> Any:
    return T["std_msgs/msg/Header"](stamp=T["builtin_interfaces/msg/Time"](sec=stamp[0], nanosec=stamp[1]),
                                    frame_id=frame_id)


def ros_cloud(points: np.ndarray, *, extra: dict[str, np.ndarray] | None = None, dtype: str = "<f4",
              height: int = 1, row_pad: int = 0, bigendian: bool = False, frame_id: str = "camera_link",
              stamp: tuple[int, int] = (1712345678, 123456789)) -> Any:
    """A rosbags sensor_msgs/PointCloud2: x y z (and extra named columns) of dtype, with an rgb float between
    y and z to make the layout non-trivial; rows padded by row_pad bytes."""
    n = len(points)
    width = n // height
    order = ">" if bigendian else "<"
    base = np.dtype(order + dtype.lstrip("<>"))
    names = ["x", "y", "rgb", "z", *(extra or {})]
    formats = [base, base, np.dtype(order + "f4"), base] + [base] * len(extra or {})
    rec_dtype = np.dtype({"names": names, "formats": formats})
    rec = np.zeros(n, rec_dtype)
    rec["x"], rec["y"], rec["z"] = points[:, 0], points[:, 1], points[:, 2]
    rec["rgb"] = 7.0
    for k, v in (extra or {}).items():
        rec[k] = v
    step = rec_dtype.itemsize
    rows = rec.view(np.uint8).reshape(height, width * step)
    data = np.concatenate([rows, np.full((height, row_pad), 0xAB, np.uint8)], axis=1).reshape(-1)
    code = {4: 7, 8: 8}[base.itemsize]
    offsets = {nm: rec_dtype.fields[nm][1] for nm in names} if rec_dtype.fields else {}
    fields = [T["sensor_msgs/msg/PointField"](name=nm, offset=offsets[nm],
                                              datatype=7 if nm == "rgb" else code, count=1) for nm in names]
    return T[POINTCLOUD2](header=ros_header(frame_id, stamp), height=height, width=width, fields=fields,
                          is_bigendian=bigendian, point_step=step, row_step=width * step + row_pad, data=data,
                          is_dense=False)


def ros_sources(cloud: Any, camera_source: np.ndarray, views: Any = VIEWS) -> Any:
    return T[CLOUD_SOURCES](
        cloud=cloud,
        camera_source=[T["std_msgs/msg/Int64"](data=int(c)) for c in camera_source],
        view_points=[T["geometry_msgs/msg/Point"](x=float(a), y=float(b), z=float(c)) for a, b, c in views],
    )


def cdr(msg: Any, msgtype: str) -> bytes:
    return bytes(TS.serialize_cdr(msg, msgtype))


@pytest.fixture()
def points() -> np.ndarray:
    rng = np.random.default_rng(7)
    return (rng.random((60, 3)) * [0.4, 0.3, 0.2] + [0.3, -0.15, 0.0]).astype(np.float32)


def test_pointcloud2_float32_with_padding_rgb_and_header(points: np.ndarray) -> None:
    """Organised 6 x 10 cloud, rows padded, rgb between y and z, NaN points dropped, header carried."""
    pts = points.copy()
    pts[[3, 17, 42]] = np.nan
    msg = decode_pointcloud2(cdr(ros_cloud(pts, height=6, row_pad=5, frame_id="head_camera", stamp=(17, 99)),
                                 POINTCLOUD2), viewpoints=[[0.1, 0.2, 0.3]])
    keep = np.isfinite(pts).all(axis=1)
    np.testing.assert_array_equal(msg.cloud.points, pts[keep])
    np.testing.assert_allclose(msg.cloud.viewpoints, [[0.1, 0.2, 0.3]], atol=1e-7)
    assert msg.cloud.camera_source.tolist() == [0] * int(keep.sum())
    assert msg.cloud.normals is None
    assert msg.header == Header("head_camera", (17, 99))
    assert msg.sample_indices is None and msg.samples is None
    assert (msg.received, msg.dropped) == (60, 3)  # the organised cloud's holes, counted (warning non_finite_dropped)


@pytest.mark.parametrize("bigendian", [False, True])
def test_pointcloud2_float64_and_big_endian(points: np.ndarray, bigendian: bool) -> None:
    msg = decode_pointcloud2(cdr(ros_cloud(points.astype(np.float64), dtype="f8", bigendian=bigendian),
                                 POINTCLOUD2))
    np.testing.assert_allclose(msg.cloud.points, points, atol=1e-7)


def test_big_endian_cdr_encapsulation(points: np.ndarray) -> None:
    """A big-endian CDR payload (encapsulation 00 00), as a big-endian DDS host would send it."""
    sources = ros_sources(ros_cloud(points), np.arange(len(points)) % 3)
    payload = bytes(TS.serialize_cdr(sources, CLOUD_SOURCES, little_endian=False))
    assert payload[:2] == b"\x00\x00"
    msg = decode_cloud_sources(payload)
    np.testing.assert_array_equal(msg.cloud.points, points)
    assert msg.cloud.camera_source.tolist() == (np.arange(len(points)) % 3).tolist()


def test_cloud_sources_gives_per_point_cameras_and_normals(points: np.ndarray) -> None:
    rng = np.random.default_rng(3)
    normals = rng.normal(size=points.shape).astype(np.float32)
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    pts = points.copy()
    pts[5] = np.inf
    src = rng.integers(0, 3, len(pts))
    cloud = ros_cloud(pts, extra={"normal_x": normals[:, 0], "normal_y": normals[:, 1], "normal_z": normals[:, 2]},
                      frame_id="base_link", stamp=(5, 6))
    msg = decode_cloud_sources(cdr(ros_sources(cloud, src), CLOUD_SOURCES))
    keep = np.arange(len(pts)) != 5
    np.testing.assert_array_equal(msg.cloud.points, pts[keep])
    assert msg.cloud.camera_source.dtype == np.int32
    np.testing.assert_array_equal(msg.cloud.camera_source, src[keep])
    np.testing.assert_allclose(msg.cloud.viewpoints, VIEWS, atol=1e-7)
    assert msg.cloud.normals is not None
    np.testing.assert_array_equal(msg.cloud.normals, normals[keep])
    assert msg.header == Header("base_link", (5, 6))
    assert msg.msg_type == CLOUD_SOURCES


def test_cloud_sources_without_camera_source_means_camera_zero(points: np.ndarray) -> None:
    msg = decode_cloud_sources(cdr(ros_sources(ros_cloud(points), np.zeros(0, int), VIEWS[:1]), CLOUD_SOURCES))
    assert msg.cloud.camera_source.tolist() == [0] * len(points)


def test_cloud_indexed_renumbers_indices_after_dropping_nan(points: np.ndarray) -> None:
    pts = points.copy()
    pts[[0, 10]] = np.nan
    indices = [1, 0, 11, 59, 10, 30]
    sources = ros_sources(ros_cloud(pts), np.arange(len(pts)) % 2)
    msg = T[CLOUD_INDEXED](cloud_sources=sources, indices=[T["std_msgs/msg/Int64"](data=i) for i in indices])
    out = decode_cloud_indexed(cdr(msg, CLOUD_INDEXED))
    assert out.sample_indices is not None
    # the rows of the decoded cloud at sample_indices are the message's points at its finite indices, in order
    np.testing.assert_array_equal(out.cloud.points[out.sample_indices], pts[[1, 11, 59, 30]])
    assert len(out.cloud) == len(pts) - 2
    assert out.samples is None and out.msg_type == CLOUD_INDEXED


def test_cloud_samples_gives_sample_positions(points: np.ndarray) -> None:
    samples = np.array([[0.4, 0.0, 0.1], [0.5, 0.05, 0.12]])
    sources = ros_sources(ros_cloud(points, frame_id="world"), np.arange(len(points)) % 3)
    msg = T[CLOUD_SAMPLES](cloud_sources=sources, samples=[T["geometry_msgs/msg/Point"](x=a, y=b, z=c)
                                                           for a, b, c in samples.tolist()])
    out = decode_cloud_samples(cdr(msg, CLOUD_SAMPLES))
    assert out.samples is not None
    np.testing.assert_array_equal(out.samples, samples)
    np.testing.assert_array_equal(out.cloud.points, points)
    assert out.header.frame_id == "world" and out.sample_indices is None


def test_decode_cloud_message_dispatches_on_type(points: np.ndarray) -> None:
    payload = cdr(ros_sources(ros_cloud(points), np.zeros(len(points), int)), CLOUD_SOURCES)
    assert decode_cloud_message(payload, "gpd_ros/CloudSources").msg_type == CLOUD_SOURCES
    assert decode_cloud_message(payload, CLOUD_SOURCES).msg_type == CLOUD_SOURCES
    with pytest.raises(RosDecodeError) as err:
        decode_cloud_message(payload, "sensor_msgs/msg/Image")
    assert err.value.field == "type"


# ---------------------------------------------------------------------------------------- the fast builders


@pytest.mark.parametrize("frame_id", ["", "a", "cam", "base_link", "camera_color_optical_frame"])
def test_builders_write_what_rosbags_writes(points: np.ndarray, frame_id: str) -> None:
    """encode_* builds, rosbags deserialize_cdr reads, and rosbags' own serialization of that is byte-identical
    (alignment after strings of every length mod 4 included)."""
    header = Header(frame_id, (42, 7))
    src = np.arange(len(points)) % 3
    cases = [
        (encode_pointcloud2(points, header), POINTCLOUD2),
        (encode_cloud_sources(points, VIEWS, src, header), CLOUD_SOURCES),
        (encode_cloud_sources(points, VIEWS[:1], np.zeros(0, int), header), CLOUD_SOURCES),
        (encode_cloud_indexed(points, VIEWS, [3, 1, 4], src, header), CLOUD_INDEXED),
        (encode_cloud_indexed(points, VIEWS, [], src, header), CLOUD_INDEXED),
        (encode_cloud_samples(points, VIEWS, [[0.1, 0.2, 0.3]], src, header, normals=points), CLOUD_SAMPLES),
    ]
    for payload, msgtype in cases:
        msg = deser(payload, msgtype)
        assert bytes(TS.serialize_cdr(msg, msgtype)) == payload, msgtype
        cloud = msg if msgtype == POINTCLOUD2 else (msg.cloud if msgtype == CLOUD_SOURCES else msg.cloud_sources.cloud)
        assert cloud.header.frame_id == frame_id and (cloud.header.stamp.sec, cloud.header.stamp.nanosec) == (42, 7)
        xyz = np.frombuffer(cloud.data.tobytes(), np.float32).reshape(len(points), -1)[:, :3]
        np.testing.assert_array_equal(xyz, points)


def test_builder_round_trip_through_decoder(points: np.ndarray) -> None:
    src = np.arange(len(points)) % 3
    out = decode_cloud_indexed(encode_cloud_indexed(points, VIEWS, [2, 5], src, Header("cam", (1, 2))))
    np.testing.assert_array_equal(out.cloud.points, points)
    np.testing.assert_array_equal(out.cloud.camera_source, src)
    assert out.sample_indices is not None and out.sample_indices.tolist() == [2, 5]
    assert out.header == Header("cam", (1, 2))



def test_packed_float32_cloud_is_one_copy_of_the_message(points: np.ndarray) -> None:
    """x y z float32 at point_step 12 (what encode_pointcloud2 and a packed driver send): the same values, in an
    array of its own (writeable, sharing no memory with the message's bytes)."""
    payload = encode_pointcloud2(points, Header("cam", (1, 2)))
    msg = decode_pointcloud2(payload)
    np.testing.assert_array_equal(msg.cloud.points, points)
    assert msg.cloud.points.flags.writeable and msg.cloud.points.flags.c_contiguous
    assert not np.shares_memory(msg.cloud.points, np.frombuffer(payload, np.uint8))
    assert (msg.received, msg.dropped) == (len(points), 0)


@pytest.mark.parametrize("code", ["i2", "u1", "i4"])
def test_integer_fields_are_read_at_their_offsets(code: str) -> None:
    """Integer x y z (a depth camera's raw units) at unaligned offsets with row padding: the strided copy converts
    each column as the structured read did."""
    rng = np.random.default_rng(5)
    height, width, pad = 3, 7, 3
    dt = np.dtype({"names": ["i", "x", "y", "z"], "formats": ["u1", code, code, code], "offsets": [0, 1, 5, 9],
                   "itemsize": 14})
    rec = np.zeros(height * width, dt)
    values = rng.integers(0, 100, (height * width, 3))
    for k, name in enumerate("xyz"):
        rec[name] = values[:, k]
    rows = rec.view(np.uint8).reshape(height, width * dt.itemsize)
    data = np.concatenate([rows, np.zeros((height, pad), np.uint8)], axis=1).reshape(-1)
    datatype = {"u1": 2, "i2": 3, "i4": 5}[code]
    fields = [T["sensor_msgs/msg/PointField"](name=name, offset=off, datatype=datatype, count=1)
              for name, off in zip("xyz", (1, 5, 9), strict=True)]
    cloud = T[POINTCLOUD2](header=ros_header(), height=height, width=width, fields=fields, is_bigendian=False,
                           point_step=dt.itemsize, row_step=width * dt.itemsize + pad, data=data, is_dense=True)
    msg = decode_pointcloud2(cdr(cloud, POINTCLOUD2))
    np.testing.assert_array_equal(msg.cloud.points, values.astype(np.float32))


@pytest.mark.parametrize("seed", range(6))
def test_dropped_rows_follow_the_one_finite_rule(points: np.ndarray, seed: int) -> None:
    """NaN, +inf and -inf in points and normals drop exactly the rows graspd.io.inputs.finite_rows drops (the rule
    of every entrance); float32-sized extremes (3e38) are finite and kept."""
    from graspd.io.inputs import finite_rows  # noqa: PLC0415 - the reference rule

    rng = np.random.default_rng(seed)
    pts = points.copy()
    normals = rng.normal(size=pts.shape).astype(np.float32)
    for arr in (pts, normals):
        cells = rng.integers(0, arr.size, int(rng.integers(0, 6)))
        arr.reshape(-1)[cells] = rng.choice([np.nan, np.inf, -np.inf], len(cells))
    pts[0, 1] = 3e38
    normals[1, 2] = -3e38
    src = np.arange(len(pts)) % 3
    msg = decode_cloud_sources(encode_cloud_sources(pts, VIEWS, src, normals=normals))
    keep = finite_rows(pts, normals)
    np.testing.assert_array_equal(msg.cloud.points, pts[keep])
    assert msg.cloud.normals is not None
    np.testing.assert_array_equal(msg.cloud.normals, normals[keep])
    np.testing.assert_array_equal(msg.cloud.camera_source, src[keep])
    assert (msg.received, msg.dropped) == (len(pts), int((~keep).sum()))
    indexed = decode_cloud_indexed(encode_cloud_indexed(pts, VIEWS, np.arange(len(pts)), src, normals=normals))
    assert indexed.sample_indices is not None
    assert indexed.sample_indices.tolist() == list(range(int(keep.sum())))


# ------------------------------------------------------------------------------------------------ malformed


def _field_of(payload: bytes, decoder: Any = decode_cloud_sources) -> str:
    with pytest.raises(RosDecodeError) as err:
        decoder(payload)
    assert isinstance(err.value, ValueError)
    return str(err.value.field)


def test_not_cdr() -> None:
    assert _field_of(b"") == "encapsulation"
    assert _field_of(b'{"cloud": 1}') == "encapsulation"


def test_wrong_camera_source_length_and_range(points: np.ndarray) -> None:
    cloud = ros_cloud(points)
    assert _field_of(cdr(ros_sources(cloud, np.zeros(len(points) - 1, int)), CLOUD_SOURCES)) == "camera_source"
    bad = np.zeros(len(points), int)
    bad[4] = 3  # three view points: indices 0..2
    assert _field_of(cdr(ros_sources(cloud, bad), CLOUD_SOURCES)) == "camera_source"
    bad[4] = -1
    assert _field_of(cdr(ros_sources(cloud, bad), CLOUD_SOURCES)) == "camera_source"


def test_view_points_needed_and_finite(points: np.ndarray) -> None:
    cloud = ros_cloud(points)
    assert _field_of(cdr(ros_sources(cloud, np.zeros(0, int), np.zeros((0, 3))), CLOUD_SOURCES)) == "view_points"
    assert _field_of(cdr(ros_sources(cloud, np.zeros(0, int), [[np.nan, 0, 0]]), CLOUD_SOURCES)) == "view_points"


def test_layout_errors_name_the_cloud_field(points: np.ndarray) -> None:
    def field_after(**change: Any) -> str:
        msg = ros_cloud(points)
        for k, v in change.items():
            setattr(msg, k, v)
        return _field_of(cdr(msg, POINTCLOUD2), decode_pointcloud2)

    assert field_after(point_step=8) == "fields.z.offset"  # z at offset 12 passes an 8-byte point
    assert field_after(point_step=0) == "point_step"
    assert field_after(row_step=10) == "row_step"
    assert field_after(width=61) == "row_step"
    assert field_after(height=2, row_step=60 * 16) == "data"  # two rows declared, one row of bytes
    assert field_after(height=100_000, width=100_000) == "width"  # 10^10 points: refused before any allocation
    msg = ros_cloud(points)
    msg.fields = [f for f in msg.fields if f.name != "z"]
    assert _field_of(cdr(msg, POINTCLOUD2), decode_pointcloud2) == "fields"
    msg = ros_cloud(points)
    msg.fields[0].datatype = 42
    assert _field_of(cdr(msg, POINTCLOUD2), decode_pointcloud2) == "fields.x.datatype"
    # inside a CloudSources the field path says so
    bad = ros_cloud(points)
    bad.point_step = 0
    assert _field_of(cdr(ros_sources(bad, np.zeros(0, int)), CLOUD_SOURCES)) == "cloud.point_step"


def test_index_and_sample_errors(points: np.ndarray) -> None:
    sources = ros_sources(ros_cloud(points), np.zeros(0, int))
    for bad in ([0, len(points)], [-1]):
        msg = T[CLOUD_INDEXED](cloud_sources=sources, indices=[T["std_msgs/msg/Int64"](data=i) for i in bad])
        assert _field_of(cdr(msg, CLOUD_INDEXED), decode_cloud_indexed) == "indices"
    msg = T[CLOUD_SAMPLES](cloud_sources=sources, samples=[T["geometry_msgs/msg/Point"](x=np.nan, y=0.0, z=0.0)])
    assert _field_of(cdr(msg, CLOUD_SAMPLES), decode_cloud_samples) == "samples"


def test_huge_declared_counts_are_refused_before_allocation(points: np.ndarray) -> None:
    """A sequence length that the remaining bytes cannot hold is refused from the count alone."""
    payload = bytearray(encode_cloud_sources(points, VIEWS, np.zeros(len(points), int)))
    # the camera_source count sits right after the cloud: find it (= len(points)) and inflate it
    cloud_len = len(encode_pointcloud2(points))
    at = cloud_len + (-(cloud_len - 4) % 4)
    assert int.from_bytes(payload[at:at + 4], "little") == len(points)
    payload[at:at + 4] = (MAX_POINTS - 1).to_bytes(4, "little")
    assert _field_of(bytes(payload)) == "camera_source"
    payload[at:at + 4] = (2**32 - 1).to_bytes(4, "little")
    assert _field_of(bytes(payload)) == "camera_source"


def test_every_truncation_raises_the_named_error(points: np.ndarray) -> None:
    payload = encode_cloud_samples(points[:4], VIEWS, [[0.1, 0.2, 0.3]], [0, 1, 2, 0], Header("cam", (1, 2)))
    decode_cloud_samples(payload)
    for cut in range(len(payload)):
        with pytest.raises(RosDecodeError) as err:
            decode_cloud_samples(payload[:cut])
        assert err.value.field


@pytest.mark.filterwarnings("error")
def test_random_corruption_never_escapes_unnamed(points: np.ndarray) -> None:
    """Flipped bytes decode to something or raise RosDecodeError; nothing else escapes."""
    payload = encode_cloud_indexed(points[:8], VIEWS, [1, 2], np.arange(8) % 3, Header("cam", (1, 2)))
    rng = np.random.default_rng(11)
    for _ in range(400):
        bad = bytearray(payload)
        for at in rng.integers(4, len(bad), 3):
            bad[at] = int(rng.integers(0, 256))
        try:
            decode_cloud_indexed(bytes(bad))
        except RosDecodeError as exc:
            assert exc.field
