"""graspd.io.ros.encode: every output decoded with rosbags' deserialize_cdr as a ROS 2 node behind
zenoh-bridge-ros2dds would, its fields checked against the GraspSet (positions, quaternion <-> rotation, widths,
scores, samples) and the input header carried through."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from graspd.core.grasp import GraspSet
from graspd.core.hand import HandGeometry, hand_preset
from graspd.io.ros import (
    Header,
    encode_grasp_config_list,
    encode_marker_array,
    encode_moveit_grasps,
    encode_pose_array,
)
from graspd.io.ros.encode import score_colors
from graspd.io.ros.types import GRASP_CONFIG_LIST, MARKER_ARRAY, MOVEIT_GRASP, POSE_ARRAY, msg_text, typestore

TS = typestore()


def deser(payload: bytes, msgtype: str) -> Any:
    """What a ROS 2 node reads: rosbags' deserialize_cdr."""
    return TS.deserialize_cdr(payload, msgtype)
HEADER = Header("base_link", (1712345678, 987654321))


@pytest.fixture()
def grasps() -> GraspSet:
    """Twelve grasps with random proper rotations, best first, one unscored."""
    rng = np.random.default_rng(5)
    m = 12
    scores = np.sort(rng.random(m))[::-1].copy()
    scores[-1] = np.nan
    return GraspSet(positions=rng.random((m, 3)) * 0.5, rotations=Rotation.random(m, random_state=2).as_matrix(),
                    widths=rng.random(m) * 0.08, scores=scores, samples=rng.random((m, 3)) * 0.5)


def vec(v: Any) -> list[float]:
    return [v.x, v.y, v.z]


def quat_to_matrix(q: Any) -> np.ndarray:
    return np.asarray(Rotation.from_quat([q.x, q.y, q.z, q.w]).as_matrix())


def stamp(h: Any) -> tuple[str, tuple[int, int]]:
    return h.frame_id, (h.stamp.sec, h.stamp.nanosec)


def test_grasp_config_list(grasps: GraspSet) -> None:
    msg = deser(encode_grasp_config_list(grasps, HEADER), GRASP_CONFIG_LIST)
    assert stamp(msg.header) == ("base_link", HEADER.stamp)
    assert len(msg.grasps) == len(grasps)
    for i, g in enumerate(msg.grasps):
        np.testing.assert_array_equal(vec(g.position), grasps.positions[i])
        np.testing.assert_array_equal(vec(g.approach), grasps.approach[i])
        np.testing.assert_array_equal(vec(g.binormal), grasps.binormal[i])
        np.testing.assert_array_equal(vec(g.axis), grasps.axis[i])
        np.testing.assert_array_equal(vec(g.sample), grasps.samples[i])
        np.testing.assert_allclose(g.width.data, grasps.widths[i], rtol=1e-6)  # std_msgs/Float32
        if np.isnan(grasps.scores[i]):
            assert np.isnan(g.score.data)
        else:
            np.testing.assert_allclose(g.score.data, grasps.scores[i], rtol=1e-6)


def test_pose_array_quaternions_give_back_the_rotations(grasps: GraspSet) -> None:
    msg = deser(encode_pose_array(grasps, HEADER), POSE_ARRAY)
    assert stamp(msg.header) == ("base_link", HEADER.stamp)
    assert len(msg.poses) == len(grasps)
    for i, pose in enumerate(msg.poses):
        np.testing.assert_array_equal(vec(pose.position), grasps.positions[i])
        q = pose.orientation
        assert abs(np.linalg.norm([q.x, q.y, q.z, q.w]) - 1.0) < 1e-9
        # columns of the rotation are [approach, binormal, axis]
        np.testing.assert_allclose(quat_to_matrix(q), grasps.rotations[i], atol=1e-9)


def test_empty_grasp_set_gives_empty_messages() -> None:
    empty = GraspSet()
    assert deser(encode_grasp_config_list(empty, HEADER), GRASP_CONFIG_LIST).grasps == []
    assert deser(encode_pose_array(empty, HEADER), POSE_ARRAY).poses == []
    markers = deser(encode_marker_array(empty, HEADER, HandGeometry()), MARKER_ARRAY).markers
    assert [m.action for m in markers] == [3]  # DELETEALL only
    assert encode_moveit_grasps(empty, HEADER) == []


@pytest.mark.parametrize("hand", [HandGeometry(), hand_preset("panda")])
def test_marker_array_draws_hand_sized_grippers(grasps: GraspSet, hand: HandGeometry) -> None:
    msg = deser(encode_marker_array(grasps, HEADER, hand, lifetime_s=1.5), MARKER_ARRAY)
    first, parts = msg.markers[0], msg.markers[1:]
    assert first.action == 3 and first.ns == "graspd"  # DELETEALL clears the last answer
    assert len(parts) == 3 * len(grasps)
    assert [m.id for m in parts] == list(range(3 * len(grasps)))  # stable: 3 * rank + part
    for m in parts:
        assert (m.ns, m.type, m.action) == ("graspd", 1, 0)  # CUBE, ADD
        assert stamp(m.header) == ("base_link", HEADER.stamp)
        assert (m.lifetime.sec, m.lifetime.nanosec) == (1, 500_000_000)
    od, fw, hd, hh = hand.hand_outer_diameter, hand.finger_width, hand.hand_depth, hand.hand_height
    for i in range(len(grasps)):
        left, right, palm = parts[3 * i: 3 * i + 3]
        r, p = grasps.rotations[i], grasps.positions[i]
        np.testing.assert_allclose(vec(left.scale), [hd, fw, hh], atol=1e-12)
        np.testing.assert_allclose(vec(palm.scale), [max(hand.palm_depth, fw), od, hh], atol=1e-12)
        # fingers: half the depth along approach, at +-(od - fw)/2 along the binormal
        np.testing.assert_allclose(vec(left.pose.position), p + r @ [hd / 2, -(od - fw) / 2, 0.0], atol=1e-12)
        np.testing.assert_allclose(vec(right.pose.position), p + r @ [hd / 2, (od - fw) / 2, 0.0], atol=1e-12)
        assert np.allclose(vec(palm.pose.position), p + r @ [-max(hand.palm_depth, fw) / 2, 0.0, 0.0])
        for m in (left, right, palm):
            np.testing.assert_allclose(quat_to_matrix(m.pose.orientation), r, atol=1e-9)
    # best is green, worst scored red, unscored grey
    best, worst, unscored = parts[0].color, parts[3 * (len(grasps) - 2)].color, parts[-1].color
    assert (best.r, best.g) == (0.0, 1.0) and (worst.r, worst.g) == (1.0, 0.0)
    assert (unscored.r, unscored.g, unscored.b) == (0.5, 0.5, 0.5)


def test_score_colors_with_a_fixed_range() -> None:
    rgb = score_colors(np.array([0.0, 0.25, 1.0, 2.0]), (0.0, 1.0))
    np.testing.assert_allclose(rgb, np.array([[1, 0, 0], [0.75, 0.25, 0], [0, 1, 0], [0, 1, 0]], np.float64))


def test_moveit_grasps(grasps: GraspSet) -> None:
    payloads = encode_moveit_grasps(grasps, HEADER, approach_distance=0.07, retreat_distance=0.12)
    assert len(payloads) == len(grasps)
    for i, payload in enumerate(payloads):
        g = deser(payload, MOVEIT_GRASP)
        assert g.id == f"graspd/{i}"
        assert stamp(g.grasp_pose.header) == ("base_link", HEADER.stamp)
        np.testing.assert_array_equal(vec(g.grasp_pose.pose.position), grasps.positions[i])
        np.testing.assert_allclose(quat_to_matrix(g.grasp_pose.pose.orientation), grasps.rotations[i], atol=1e-9)
        if np.isnan(grasps.scores[i]):
            assert np.isnan(g.grasp_quality)
        else:
            assert g.grasp_quality == grasps.scores[i]
        app = g.pre_grasp_approach
        assert stamp(app.direction.header) == ("base_link", HEADER.stamp)
        np.testing.assert_array_equal(vec(app.direction.vector), grasps.approach[i])
        np.testing.assert_allclose([app.desired_distance, app.min_distance], [0.07, 0.035], rtol=1e-6)
        ret = g.post_grasp_retreat
        assert vec(ret.direction.vector) == [0.0, 0.0, 1.0]
        np.testing.assert_allclose([ret.desired_distance, ret.min_distance], [0.12, 0.06], rtol=1e-6)
        np.testing.assert_array_equal(vec(g.post_place_retreat.direction.vector), -grasps.approach[i])
        assert g.pre_grasp_posture.joint_names == [] and g.allowed_touch_objects == []


def test_moveit_grasp_pose_of_the_end_effector_link(grasps: GraspSet) -> None:
    """hand_to_link: the MoveIt link sits 0.1 m behind the hand base, its z along the approach."""
    link = np.eye(4)
    link[:3, :3] = np.array([[0, 0, -1], [0, 1, 0], [1, 0, 0]]).T  # columns: link x, y, z in the hand frame
    link[:3, 3] = [-0.1, 0.0, 0.0]
    g = deser(encode_moveit_grasps(grasps, HEADER, hand_to_link=link)[0], MOVEIT_GRASP)
    r, p = grasps.rotations[0], grasps.positions[0]
    np.testing.assert_allclose(vec(g.grasp_pose.pose.position), p - 0.1 * r[:, 0], atol=1e-12)
    rot = quat_to_matrix(g.grasp_pose.pose.orientation)
    np.testing.assert_allclose(rot[:, 2], r[:, 0], atol=1e-9)


def test_moveit_grasp_fields_are_moveits() -> None:
    """The registered moveit_msgs/Grasp has the field names, types and order of MoveIt's definition."""
    names = [(n, d[1] if d[0] != 1 else d[1][0]) for n, d in TS.fielddefs[MOVEIT_GRASP][1]]
    assert names == [
        ("id", "string"), ("pre_grasp_posture", "trajectory_msgs/msg/JointTrajectory"),
        ("grasp_posture", "trajectory_msgs/msg/JointTrajectory"), ("grasp_pose", "geometry_msgs/msg/PoseStamped"),
        ("grasp_quality", "float64"), ("pre_grasp_approach", "moveit_msgs/msg/GripperTranslation"),
        ("post_grasp_retreat", "moveit_msgs/msg/GripperTranslation"),
        ("post_place_retreat", "moveit_msgs/msg/GripperTranslation"), ("max_contact_force", "float32"),
        ("allowed_touch_objects", ((1, ("string", 0)), 0)),
    ]
    assert [n for n, _ in TS.fielddefs["moveit_msgs/msg/GripperTranslation"][1]] == \
        ["direction", "desired_distance", "min_distance"]


def test_gpd_ros_msg_text_ships_in_the_package() -> None:
    for name in ("CloudSources", "CloudIndexed", "CloudSamples", "GraspConfig", "GraspConfigList"):
        assert msg_text("gpd_ros", name).strip()
    assert "float32 width" not in msg_text("gpd_ros", "GraspConfig")  # std_msgs/Float32, as gpd_ros has it
    assert [n for n, _ in TS.fielddefs["gpd_ros/msg/GraspConfig"][1]] == \
        ["position", "approach", "binormal", "axis", "width", "score", "sample"]


# ------------------------------------------------------------------- the array encoders against rosbags' serializer


def _ros_points(kind: str, xyz: np.ndarray) -> list[Any]:
    return [TS.types[kind](x=float(a), y=float(b), z=float(c)) for a, b, c in xyz.tolist()]


def _ros_header(header: Header) -> Any:
    t = TS.types
    return t["std_msgs/msg/Header"](stamp=t["builtin_interfaces/msg/Time"](sec=header.stamp[0],
                                                                          nanosec=header.stamp[1]),
                                    frame_id=header.frame_id)


def _ros_pose(p: list[float], q: list[float]) -> Any:
    t = TS.types
    return t["geometry_msgs/msg/Pose"](position=t["geometry_msgs/msg/Point"](x=p[0], y=p[1], z=p[2]),
                                       orientation=t["geometry_msgs/msg/Quaternion"](x=q[0], y=q[1], z=q[2], w=q[3]))


def rosbags_grasp_config_list(grasps: GraspSet, header: Header) -> bytes:
    """The reference: one rosbags message object per field, serialised by rosbags."""
    t = TS.types
    f32, cfg = t["std_msgs/msg/Float32"], t["gpd_ros/msg/GraspConfig"]
    pos, smp = (_ros_points("geometry_msgs/msg/Point", a) for a in (grasps.positions, grasps.samples))
    app, bi, ax = (_ros_points("geometry_msgs/msg/Vector3", a) for a in (grasps.approach, grasps.binormal,
                                                                          grasps.axis))
    pairs = zip(grasps.widths.tolist(), grasps.scores.tolist(), strict=True)
    items = [cfg(position=pos[i], approach=app[i], binormal=bi[i], axis=ax[i], width=f32(data=w), score=f32(data=s),
                 sample=smp[i]) for i, (w, s) in enumerate(pairs)]
    return bytes(TS.serialize_cdr(t[GRASP_CONFIG_LIST](header=_ros_header(header), grasps=items), GRASP_CONFIG_LIST))


def rosbags_pose_array(grasps: GraspSet, header: Header) -> bytes:
    poses = [_ros_pose(p, q) for p, q in zip(grasps.positions.tolist(), grasps.quat_xyzw.tolist(), strict=True)]
    return bytes(TS.serialize_cdr(TS.types[POSE_ARRAY](header=_ros_header(header), poses=poses), POSE_ARRAY))


def rosbags_marker_array(grasps: GraspSet, header: Header, hand: HandGeometry, lifetime_s: float,
                         score_range: tuple[float, float] | None, alpha: float) -> bytes:
    """The reference MarkerArray: rosbags Marker objects (ROS defaults for what graspd does not set)."""
    from graspd.io.ros.encode import _hand_parts  # noqa: PLC0415 - the part boxes, not under test here
    from graspd.io.ros.types import default_message  # noqa: PLC0415

    t = TS.types
    sec = int(np.floor(lifetime_s))
    lifetime = t["builtin_interfaces/msg/Duration"](sec=sec, nanosec=int(round((lifetime_s - sec) * 1e9)))
    base = {"header": _ros_header(header), "ns": "graspd"}
    markers = [default_message("visualization_msgs/msg/Marker", **base, action=3)]
    centres, sizes = _hand_parts(hand)
    world = grasps.positions[:, None, :] + np.einsum("mij,pj->mpi", grasps.rotations, centres)
    colors = score_colors(grasps.scores, score_range).tolist()
    for i, (parts, q, c) in enumerate(zip(world.tolist(), grasps.quat_xyzw.tolist(), colors, strict=True)):
        for k, p in enumerate(parts):
            s = sizes[k].tolist()
            markers.append(default_message(
                "visualization_msgs/msg/Marker", **base, id=3 * i + k, type=1, action=0, pose=_ros_pose(p, q),
                scale=t["geometry_msgs/msg/Vector3"](x=s[0], y=s[1], z=s[2]),
                color=t["std_msgs/msg/ColorRGBA"](r=c[0], g=c[1], b=c[2], a=float(alpha)), lifetime=lifetime))
    return bytes(TS.serialize_cdr(t[MARKER_ARRAY](markers=markers), MARKER_ARRAY))


@pytest.mark.parametrize("frame_id", ["", "a", "ab", "abc", "base_link", "camera_depth_optical_frame", "/x/yz"])
@pytest.mark.parametrize("m", [0, 1, 2, 3, 12])
def test_array_encoders_write_what_rosbags_writes(grasps: GraspSet, frame_id: str, m: int) -> None:
    """GraspConfigList, PoseArray and MarkerArray byte for byte as rosbags serialises the message objects, for
    every alignment the frame_id's length gives (a Marker's padding depends on where it starts)."""
    g, header = grasps[:m], Header(frame_id, (-3, 999))
    assert encode_grasp_config_list(g, header) == rosbags_grasp_config_list(g, header)
    assert encode_pose_array(g, header) == rosbags_pose_array(g, header)
    hand = hand_preset("panda") if m == 3 else HandGeometry()
    assert encode_marker_array(g, header, hand) == rosbags_marker_array(g, header, hand, 2.0, None, 0.8)
    assert encode_marker_array(g, header, hand, lifetime_s=0.25, score_range=(0.2, 0.9), alpha=0.5) == \
        rosbags_marker_array(g, header, hand, 0.25, (0.2, 0.9), 0.5)


@pytest.mark.parametrize("start", [0, 4, 12])
def test_marker_runs_match_markers_written_one_by_one(start: int) -> None:
    """The columns filled into repeated templates give the bytes of each Marker written field by field, whichever
    alignment the first one starts at (a MarkerArray's first gripper marker follows the DELETEALL: 4 past 8)."""
    from graspd.io.ros.encode import _markers, _write_message, _Writer  # noqa: PLC0415 - the internals compared

    rng = np.random.default_rng(start)
    count = 7
    columns = {"id": np.arange(count), "pose.position.x": rng.normal(size=(count, 7)),
               "scale.x": rng.random((count, 3)), "color.r": rng.random((count, 4))}
    shared = {"header.frame_id": "abcde", "header.stamp.sec": 3, "ns": "graspd", "type": 1, "lifetime.sec": 2}
    w = _Writer()
    w.chunks, w.size = [], start
    for j in range(count):
        w._align(4)
        values = dict(shared, id=int(columns["id"][j]))
        for name, prefix in (("pose.position.x", "pose."), ("scale.x", "scale."), ("color.r", "color.")):
            keys = [f"{prefix}{k}" for k in ("position.x", "position.y", "position.z", "orientation.x",
                                             "orientation.y", "orientation.z", "orientation.w")] \
                if name.startswith("pose") else [f"{prefix}{k}" for k in ("xyz" if name == "scale.x" else "rgba")]
            values.update(zip(keys, columns[name][j].tolist(), strict=True))
        _write_message(w, "visualization_msgs/msg/Marker", values)
    assert _markers(count, start, columns, shared) == b"".join(w.chunks)
