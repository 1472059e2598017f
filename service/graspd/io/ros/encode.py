"""graspd outputs -> CDR bytes a ROS 2 node reads: gpd_ros GraspConfigList, geometry_msgs PoseArray,
visualization_msgs MarkerArray (RViz grippers) and moveit_msgs Grasp; plus fast builders of the inputs a robot
sends (PointCloud2, CloudSources, CloudIndexed, CloudSamples) for tests, benchmarks and clients.

Everything is in the frame of the input cloud (header.frame_id, carried through with its stamp), in metres.
Grasps follow graspd.core.grasp: position = hand base centre, rotation columns [approach, binormal, axis].
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray
from rosbags.typesys.base import Nodetype

from graspd.core.grasp import GraspSet, rotation_to_quat_xyzw
from graspd.core.hand import HandGeometry
from graspd.io.ros.types import (
    MARKER,
    MOVEIT_GRASP,
    Header,
    default_message,
    header_message,
    typestore,
)

#: RViz marker namespace; marker ids are 3 * rank + part (part 0 left finger, 1 right finger, 2 palm).
MARKER_NS = "graspd"
MARKER_PARTS = 3
#: visualization_msgs/Marker constants.
MARKER_CUBE, MARKER_ADD, MARKER_DELETEALL = 1, 0, 3

# --------------------------------------------------------------------------------------------------- outputs


def _poses(t: dict[str, Any], positions: NDArray[np.float64], quats: NDArray[np.float64]) -> list[Any]:
    point, quat, pose = t["geometry_msgs/msg/Point"], t["geometry_msgs/msg/Quaternion"], t["geometry_msgs/msg/Pose"]
    return [pose(position=point(x=p[0], y=p[1], z=p[2]), orientation=quat(x=q[0], y=q[1], z=q[2], w=q[3]))
            for p, q in zip(positions.tolist(), quats.tolist(), strict=True)]


#: gpd_ros/GraspConfig as CDR lays it out: position, approach, binormal, axis (3 x float64 each), width and score
#: (float32), sample (3 x float64); 128 bytes, a multiple of 8, so that every element of a sequence starts 8-aligned
#: as the first one does and a whole GraspConfig[] is one array's bytes.
GRASP_CONFIG_CDR = np.dtype({"names": ["position", "approach", "binormal", "axis", "width", "score", "sample"],
                             "formats": [("<f8", 3)] * 4 + ["<f4", "<f4", ("<f8", 3)],
                             "offsets": [0, 24, 48, 72, 96, 100, 104], "itemsize": 128})
#: geometry_msgs/Pose: position (3 x float64), orientation x y z w (4 x float64); 56 bytes.
POSE_CDR = np.dtype({"names": ["position", "orientation"], "formats": [("<f8", 3), ("<f8", 4)],
                     "offsets": [0, 24], "itemsize": 56})


def _with_sequence(header: Header, rec: NDArray[np.void]) -> bytes:
    """CDR of a message {std_msgs/Header header, T[] items} whose T is all float64-aligned (rec: its elements in
    CDR layout, little-endian)."""
    w = _Writer()
    w.header(header)
    w.scalar("u4", len(rec))
    if len(rec):
        w.raw(rec.tobytes(), 8)
    return w.getvalue()


def encode_grasp_config_list(grasps: GraspSet, header: Header) -> bytes:
    """gpd_ros/GraspConfigList: one GraspConfig per grasp in order (position, approach, binormal, axis in
    header.frame_id, m; width m; score NaN when unscored; sample = the cloud point it was found at); written as one
    array (GRASP_CONFIG_CDR), byte for byte what rosbags' serialize_cdr writes."""
    rec = np.zeros(len(grasps), GRASP_CONFIG_CDR)
    rec["position"] = grasps.positions
    rec["approach"] = grasps.approach
    rec["binormal"] = grasps.binormal
    rec["axis"] = grasps.axis
    rec["width"] = grasps.widths
    rec["score"] = grasps.scores
    rec["sample"] = grasps.samples
    return _with_sequence(header, rec)


def encode_pose_array(grasps: GraspSet, header: Header) -> bytes:
    """geometry_msgs/PoseArray: per grasp the hand base pose in header.frame_id (m; orientation x = approach,
    y = binormal, z = axis); one array (POSE_CDR), byte for byte what rosbags' serialize_cdr writes."""
    rec = np.zeros(len(grasps), POSE_CDR)
    rec["position"] = grasps.positions
    rec["orientation"] = grasps.quat_xyzw
    return _with_sequence(header, rec)


def score_colors(scores: NDArray[np.float64], score_range: tuple[float, float] | None = None) -> NDArray[np.float64]:
    """RGB (M, 3) in [0, 1] from red (lowest score of score_range, default the set's) to green (highest);
    grey for NaN scores."""
    s = np.asarray(scores, np.float64)
    finite = np.isfinite(s)
    if score_range is None:
        lo, hi = (float(s[finite].min()), float(s[finite].max())) if finite.any() else (0.0, 1.0)
    else:
        lo, hi = score_range
    frac = np.clip((np.where(finite, s, lo) - lo) / (hi - lo), 0.0, 1.0) if hi > lo else np.ones_like(s)
    rgb = np.stack([1.0 - frac, frac, np.zeros_like(frac)], axis=1)
    rgb[~finite] = 0.5
    return rgb


def _hand_parts(hand: HandGeometry) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Centres and sizes (3, 3) of [left finger, right finger, palm] in the hand frame (m); the palm is drawn
    at least a finger width thick."""
    boxes = hand.swept_boxes(0.0).copy()
    boxes[2, 0, 0] = min(boxes[2, 0, 0], -hand.finger_width)
    return boxes.mean(axis=1), boxes[:, 1] - boxes[:, 0]


#: The fields of one gripper part's Marker that differ between parts and grasps, (dotted path of the first value,
#: CDR type, values): id, pose (position then orientation, 7 float64), scale (3 float64), color (4 float32).
_MARKER_COLUMNS = (("id", "<i4", 1), ("pose.position.x", "<f8", 7), ("scale.x", "<f8", 3), ("color.r", "<f4", 4))
_CDR_CODES = {"bool": "u1", "int8": "i1", "uint8": "u1", "byte": "u1", "char": "u1", "int16": "i2", "uint16": "u2",
              "int32": "i4", "uint32": "u4", "int64": "i8", "uint64": "u8", "float32": "f4", "float64": "f8"}


def _write_message(w: _Writer, msgtype: str, values: dict[str, Any], offsets: dict[str, int] | None = None,
                   path: str = "") -> None:
    """msgtype's CDR into w with every field at its ROS default (zeros, "", empty sequences) but those in values
    (dotted paths, e.g. "header.frame_id"); offsets, when given, gets where each leaf field went (w.size)."""
    fields: list[tuple[str, Any]] = typestore().fielddefs[msgtype][1]
    for name, (kind, detail) in fields:
        key = f"{path}{name}"
        if kind == Nodetype.NAME:
            _write_message(w, detail, values, offsets, f"{key}.")
            continue
        if kind == Nodetype.SEQUENCE and key not in values:  # every sequence of a marker graspd draws is empty
            w.scalar("u4", 0)
            continue
        if kind != Nodetype.BASE:
            raise TypeError(f"{msgtype}.{name}: only plain fields and empty sequences are written here")
        value = values.get(key)
        if detail[0] == "string":
            w.string(value or "")
            continue
        code = _CDR_CODES[detail[0]]
        w._align(np.dtype(code).itemsize)
        if offsets is not None:
            offsets[key] = w.size
        w.scalar(code, value or 0)


def _marker_chunk(phase: int, values: dict[str, Any]) -> tuple[bytes, dict[str, int], int]:
    """One Marker's CDR starting phase bytes past an 8-aligned position (0 or 4: a Marker starts 4-aligned and holds
    float64s), padded to 4 bytes for the next one: (bytes, offsets of its leaf fields in those bytes, the padding
    at the end)."""
    w = _Writer()
    w.chunks, w.size = [], phase
    offsets: dict[str, int] = {}
    _write_message(w, MARKER, values, offsets)
    end = w.size
    w._align(4)
    return b"".join(w.chunks), {k: v - phase for k, v in offsets.items()}, w.size - end


def _markers(count: int, start: int, columns: dict[str, NDArray[np.generic]], values: dict[str, Any]) -> bytes:
    """count Markers written from start (a 4-aligned offset in the message), values the fields they share, columns
    (_MARKER_COLUMNS) one row per Marker.  A Marker's padding, hence its layout, depends on whether it starts
    8-aligned: each run of Markers of one layout is one template repeated with the varying fields written as
    strided columns (in practice one run, or the first Marker then one run).  Ends after the last Marker (no
    padding)."""
    chunks: dict[int, tuple[bytes, dict[str, int], int]] = {}
    phases = []
    at = start
    for _ in range(count):
        phase = at % 8
        if phase not in chunks:
            chunks[phase] = _marker_chunk(phase, values)
        phases.append(phase)
        at += len(chunks[phase][0])
    out: list[bytes] = []
    first = 0
    while first < count:
        phase = phases[first]
        last = first
        while last + 1 < count and phases[last + 1] == phase:
            last += 1
        chunk, offsets, _pad = chunks[phase]
        rows = last + 1 - first
        flat = np.tile(np.frombuffer(chunk, np.uint8), rows)
        for name, code, width in _MARKER_COLUMNS:
            view = np.ndarray((rows, width), code, buffer=flat, offset=offsets[name],
                              strides=(len(chunk), np.dtype(code).itemsize))
            view[...] = columns[name][first:last + 1].reshape(rows, width)
        out.append(flat.tobytes())
        first = last + 1
    data = b"".join(out)
    return data[: len(data) - chunks[phases[-1]][2]] if count else data


def encode_marker_array(grasps: GraspSet, header: Header, hand: HandGeometry, *, lifetime_s: float = 2.0,
                        score_range: tuple[float, float] | None = None, alpha: float = 0.8) -> bytes:
    """visualization_msgs/MarkerArray for RViz: a DELETEALL of namespace "graspd", then per grasp (rank i) three
    CUBE markers, ids 3i..3i+2 [left finger, right finger, palm], sized from hand (m), posed in header.frame_id,
    coloured red -> green by score (score_colors), vanishing after lifetime_s seconds.  The grasps' markers are
    written as arrays (one template per layout, the varying fields filled in by columns), byte for byte what
    rosbags' serialize_cdr writes."""
    sec = int(np.floor(lifetime_s))
    m = len(grasps)
    w = _Writer()
    w.scalar("u4", 1 + MARKER_PARTS * m)
    hdr = {"header.stamp.sec": header.stamp[0], "header.stamp.nanosec": header.stamp[1],
           "header.frame_id": header.frame_id, "ns": MARKER_NS}
    _write_message(w, MARKER, {**hdr, "action": MARKER_DELETEALL})
    if m:
        centres, sizes = _hand_parts(hand)
        # part centres in the cloud frame: position + R @ centre, (M, 3 parts, 3)
        world = grasps.positions[:, None, :] + np.einsum("mij,pj->mpi", grasps.rotations, centres)
        quats = np.repeat(grasps.quat_xyzw, MARKER_PARTS, axis=0)
        rgba = np.concatenate([score_colors(grasps.scores, score_range), np.full((m, 1), float(alpha))], axis=1)
        columns = {"id": np.arange(MARKER_PARTS * m),
                   "pose.position.x": np.concatenate([world.reshape(-1, 3), quats], axis=1),
                   "scale.x": np.tile(sizes, (m, 1)),
                   "color.r": np.repeat(rgba, MARKER_PARTS, axis=0)}
        shared = {**hdr, "type": MARKER_CUBE, "action": MARKER_ADD, "lifetime.sec": sec,
                  "lifetime.nanosec": int(round((lifetime_s - sec) * 1e9))}
        w._align(4)
        w.raw(_markers(MARKER_PARTS * m, w.size, columns, shared))
    return w.getvalue()


def encode_moveit_grasps(grasps: GraspSet, header: Header, **options: Any) -> list[bytes]:
    """One CDR moveit_msgs/Grasp per grasp, best first: the messages of moveit_grasp_messages(grasps, header,
    **options), serialised."""
    store = typestore()
    return [bytes(store.serialize_cdr(msg, MOVEIT_GRASP)) for msg in moveit_grasp_messages(grasps, header, **options)]


def moveit_grasp_messages(grasps: GraspSet, header: Header, *, approach_distance: float = 0.05,
                          min_approach_distance: float | None = None,
                          retreat_direction: ArrayLike = (0.0, 0.0, 1.0), retreat_distance: float = 0.1,
                          hand_to_link: ArrayLike | None = None, id_prefix: str = "graspd",
                          postures: Callable[[int], tuple[Any, Any]] | None = None) -> list[Any]:
    """One moveit_msgs/Grasp (rosbags message) per grasp, best first: id "{id_prefix}/{rank}"; grasp_pose = hand base
    pose (x = approach) in header.frame_id, times hand_to_link (4x4 pose of the MoveIt end-effector parent link in
    the hand frame, default identity); pre_grasp_approach along approach for approach_distance (m, min default
    half); post_grasp_retreat along retreat_direction (header frame, default +z "up") for retreat_distance (m);
    post_place_retreat back along -approach; grasp_quality = score; hand postures postures(rank) ->
    (pre_grasp_posture, grasp_posture), trajectory_msgs/JointTrajectory messages, else left empty."""
    store = typestore()
    t = store.types
    hdr = header_message(header)
    poses = grasps.poses
    if hand_to_link is not None:
        link = np.asarray(hand_to_link, np.float64).reshape(4, 4)
        poses = poses @ link
    quats = rotation_to_quat_xyzw(poses[:, :3, :3])
    pose_msgs = _poses(t, poses[:, :3, 3], quats)
    min_app = 0.5 * approach_distance if min_approach_distance is None else min_approach_distance
    vec, v3s, gt = t["geometry_msgs/msg/Vector3"], t["geometry_msgs/msg/Vector3Stamped"], \
        t["moveit_msgs/msg/GripperTranslation"]
    up = np.asarray(retreat_direction, np.float64).reshape(3).tolist()
    retreat = gt(direction=v3s(header=hdr, vector=vec(x=up[0], y=up[1], z=up[2])),
                 desired_distance=float(retreat_distance), min_distance=0.5 * float(retreat_distance))
    grasp, posture = t[MOVEIT_GRASP], default_message("trajectory_msgs/msg/JointTrajectory")
    out = []
    for i, (a, score) in enumerate(zip(grasps.approach.tolist(), grasps.scores.tolist(), strict=True)):
        approach = gt(direction=v3s(header=hdr, vector=vec(x=a[0], y=a[1], z=a[2])),
                      desired_distance=float(approach_distance), min_distance=float(min_app))
        back = gt(direction=v3s(header=hdr, vector=vec(x=-a[0], y=-a[1], z=-a[2])),
                  desired_distance=float(approach_distance), min_distance=float(min_app))
        opened, closed = (posture, posture) if postures is None else postures(i)
        msg = grasp(id=f"{id_prefix}/{i}", pre_grasp_posture=opened, grasp_posture=closed,
                    grasp_pose=t["geometry_msgs/msg/PoseStamped"](header=hdr, pose=pose_msgs[i]),
                    grasp_quality=float(score), pre_grasp_approach=approach, post_grasp_retreat=retreat,
                    post_place_retreat=back, max_contact_force=0.0, allowed_touch_objects=[])
        out.append(msg)
    return out


# ---------------------------------------------------------------------------------------------------- inputs


class _Writer:
    """Little-endian CDR (XCDR1) writer; alignment is relative to the end of the encapsulation header."""

    def __init__(self) -> None:
        self.chunks: list[bytes] = [b"\x00\x01\x00\x00"]
        self.size = 0

    def _align(self, n: int) -> None:
        pad = -self.size % n
        if pad:
            self.chunks.append(b"\x00" * pad)
            self.size += pad

    def raw(self, data: bytes, align: int = 1) -> None:
        self._align(align)
        self.chunks.append(data)
        self.size += len(data)

    def scalar(self, code: str, value: float | int) -> None:
        dt = np.dtype("<" + code)
        self.raw(np.array(value, dt).tobytes(), dt.itemsize)

    def string(self, text: str) -> None:
        data = text.encode("utf-8") + b"\x00"
        self.scalar("u4", len(data))
        self.raw(data)

    def sequence(self, values: NDArray[np.generic]) -> None:
        """A sequence of fixed-size items (rows of a C-contiguous little-endian array)."""
        self.scalar("u4", len(values))
        if len(values):
            self.raw(values.tobytes(), values.dtype.itemsize)

    def header(self, header: Header) -> None:
        self.scalar("i4", header.stamp[0])
        self.scalar("u4", header.stamp[1])
        self.string(header.frame_id)

    def getvalue(self) -> bytes:
        return b"".join(self.chunks)


def _write_pointcloud2(w: _Writer, points: ArrayLike, header: Header, normals: ArrayLike | None,
                       shape: tuple[int, int] | None = None) -> int:
    pts = np.asarray(points, np.float32).reshape(-1, 3)
    height, width = (1, len(pts)) if shape is None else (int(shape[0]), int(shape[1]))
    if height * width != len(pts):
        raise ValueError(f"shape {height}x{width} does not hold the {len(pts)} points")
    names = list("xyz")
    cols = [pts]
    if normals is not None:
        names += ["normal_x", "normal_y", "normal_z"]
        cols.append(np.asarray(normals, np.float32).reshape(pts.shape))
    packed = np.ascontiguousarray(np.concatenate(cols, axis=1), "<f4")
    step = 4 * len(names)
    w.header(header)
    w.scalar("u4", height)
    w.scalar("u4", width)
    w.scalar("u4", len(names))
    for k, name in enumerate(names):
        w.string(name)
        w.scalar("u4", 4 * k)
        w.scalar("u1", 7)  # FLOAT32
        w.scalar("u4", 1)
    w.scalar("u1", 0)  # is_bigendian
    w.scalar("u4", step)
    w.scalar("u4", step * width)
    w.scalar("u4", packed.nbytes)
    w.raw(packed.tobytes())
    w.scalar("u1", int(bool(np.isfinite(packed).all())))  # is_dense
    return len(pts)


def _write_cloud_sources(w: _Writer, points: ArrayLike, viewpoints: ArrayLike, camera_source: ArrayLike | None,
                         header: Header, normals: ArrayLike | None, shape: tuple[int, int] | None = None) -> None:
    n = _write_pointcloud2(w, points, header, normals, shape)
    src = np.zeros(n, "<i8") if camera_source is None else np.asarray(camera_source, "<i8").reshape(-1)
    w.sequence(np.ascontiguousarray(src))
    w.sequence(np.ascontiguousarray(np.asarray(viewpoints, "<f8").reshape(-1, 3)))


def encode_pointcloud2(points: ArrayLike, header: Header | None = None, normals: ArrayLike | None = None,
                       shape: tuple[int, int] | None = None) -> bytes:
    """CDR sensor_msgs/PointCloud2, float32 x y z (+ normal_x/y/z) of points (N, 3) in header.frame_id (m): what
    a ROS 2 camera driver publishes; unorganised (height 1), or organised with shape (height, width), the points
    then its pixels row-major (NaN where there is no depth)."""
    w = _Writer()
    _write_pointcloud2(w, points, header or Header(), normals, shape)
    return w.getvalue()


def encode_cloud_sources(points: ArrayLike, viewpoints: ArrayLike, camera_source: ArrayLike | None = None,
                         header: Header | None = None, normals: ArrayLike | None = None,
                         shape: tuple[int, int] | None = None) -> bytes:
    """CDR gpd_ros/CloudSources: points (N, 3), per point the index into viewpoints (K, 3, camera positions) of
    the camera that saw it (default all 0), all in header.frame_id (m); the cloud organised with shape (height,
    width) as encode_pointcloud2's."""
    w = _Writer()
    _write_cloud_sources(w, points, viewpoints, camera_source, header or Header(), normals, shape)
    return w.getvalue()


def encode_cloud_indexed(points: ArrayLike, viewpoints: ArrayLike, indices: ArrayLike,
                         camera_source: ArrayLike | None = None, header: Header | None = None,
                         normals: ArrayLike | None = None) -> bytes:
    """CDR gpd_ros/CloudIndexed: a CloudSources (see encode_cloud_sources) plus indices of the points to sample."""
    w = _Writer()
    _write_cloud_sources(w, points, viewpoints, camera_source, header or Header(), normals)
    w.sequence(np.ascontiguousarray(np.asarray(indices, "<i8").reshape(-1)))
    return w.getvalue()


def encode_cloud_samples(points: ArrayLike, viewpoints: ArrayLike, samples: ArrayLike,
                         camera_source: ArrayLike | None = None, header: Header | None = None,
                         normals: ArrayLike | None = None) -> bytes:
    """CDR gpd_ros/CloudSamples: a CloudSources (see encode_cloud_sources) plus samples (K, 3), positions to
    sample at in header.frame_id (m)."""
    w = _Writer()
    _write_cloud_sources(w, points, viewpoints, camera_source, header or Header(), normals)
    w.sequence(np.ascontiguousarray(np.asarray(samples, "<f8").reshape(-1, 3)))
    return w.getvalue()


#: A shape_msgs/SolidPrimitive with 3 dimensions and no polygon, once the writer stands 4 bytes past a multiple of
#: 8 (where every such primitive ends): type, dimension count, dimensions, polygon point count (40 bytes).
_BOX_CDR = np.dtype({"names": ["type", "count", "dimensions", "polygon"], "formats": ["u1", "<u4", ("<f8", 3), "<u4"],
                     "offsets": [0, 4, 12, 36], "itemsize": 40})
_IDENTITY_POSE = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0)


def encode_grasp_planning(header: Header, pose: ArrayLike = _IDENTITY_POSE, *, box_centres: ArrayLike = (),
                          box_sizes: ArrayLike = (), meshes: tuple[tuple[ArrayLike, ArrayLike], ...] = (),
                          target_id: str = "target", group_name: str = "arm") -> bytes:
    """CDR moveit_msgs/srv/GraspPlanning request (the fields; a service sample puts the rmw request header after
    the encapsulation): a target in header.frame_id posed at pose (x y z, quaternion x y z w) made of BOX
    primitives (centres (N, 3) and sizes (N, 3), m, axis-aligned in the target's frame) and meshes ((vertices
    (V, 3) m, triangles (T, 3) vertex indices) each, at the target's origin).  Vectorised: 60k boxes or a
    million vertices encode in milliseconds (what a hostile client sends, and what the tests and bench send)."""
    centres = np.asarray(box_centres, "<f8").reshape(-1, 3)
    sizes = np.asarray(box_sizes, "<f8").reshape(-1, 3)
    if len(centres) != len(sizes):
        raise ValueError(f"{len(centres)} box centres but {len(sizes)} sizes")
    w = _Writer()
    w.string(group_name)
    w.header(header)
    w.raw(np.asarray(pose, "<f8").reshape(7).tobytes(), 8)
    w.string(target_id)
    w.string("")  # type.key
    w.string("")  # type.db
    w.scalar("u4", len(centres))
    if len(centres):
        w.scalar("u1", 1)  # BOX; the first primitive's padding depends on where it starts
        w.scalar("u4", 3)
        w.raw(sizes[0].tobytes(), 8)
        w.scalar("u4", 0)
        rest = np.zeros(len(centres) - 1, _BOX_CDR)
        rest["type"], rest["count"], rest["dimensions"] = 1, 3, sizes[1:]
        w.raw(rest.tobytes())
    poses = np.zeros((len(centres), 7), "<f8")
    poses[:, :3], poses[:, 6] = centres, 1.0
    w.sequence(poses)
    w.scalar("u4", len(meshes))
    for vertices, triangles in meshes:
        w.sequence(np.ascontiguousarray(np.asarray(triangles, "<u4").reshape(-1, 3)))
        w.sequence(np.ascontiguousarray(np.asarray(vertices, "<f8").reshape(-1, 3)))
    w.sequence(np.tile(np.asarray(_IDENTITY_POSE, "<f8"), (len(meshes), 1)))
    for _ in range(4):  # planes, plane_poses, subframe_names, subframe_poses
        w.scalar("u4", 0)
    w.scalar("u1", 0)  # operation ADD
    for _ in range(3):  # support_surfaces, candidate_grasps, movable_obstacles
        w.scalar("u4", 0)
    return w.getvalue()
