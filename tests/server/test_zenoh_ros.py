"""Zenoh as a ROS 2 node behind zenoh-bridge-ros2dds sees it: CDR CloudSources / CloudIndexed / CloudSamples /
PointCloud2 in on their keys, GraspConfigList, PoseArray, moveit_msgs Grasp and MarkerArray out, each decoded here
with rosbags (gpd_ros registered from the upstream .msg text in shared/ros), the header carried through; the stream
options set on graspd/config (validated like a DetectRequest, guarded by the token, errors on graspd/errors).
A real server, a real zenoh session, peer mode on loopback."""

from __future__ import annotations

import json
import re
import threading
import time
from collections.abc import Callable, Iterator
from functools import lru_cache
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from fastapi.testclient import TestClient
from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from rosbags.typesys.store import Typestore
from scipy.spatial.transform import Rotation

from fixtures import krylon_camera_frame
from graspd.core.cloud import ViewpointCloud
from graspd.io.ros import (
    Header,
    encode_cloud_indexed,
    encode_cloud_samples,
    encode_cloud_sources,
    encode_pointcloud2,
)
from graspd.io.ros.types import msg_text
from graspd.server.app import create_app
from graspd.server.services.ros_stream import DEFAULT_INPUT_KEYS, DEFAULT_OUTPUT_KEYS, parse_options
from graspd.server.settings import Settings
from graspd_client import RequestRejected
from graspd_client.wire import zenoh_token_attachment
from graspd_client.zenoh_client import ZenohGraspClient, zenoh_config

from .conftest import free_port

UPSTREAM_MSGS = Path(__file__).resolve().parents[3] / "shared" / "ros" / "gpd_ros" / "msg"
HEADER = Header("base_link", (1712345678, 123456789))
TOKEN = "ros-stream-token-0123456789"
OUT_KEYS = {"json": "graspd/grasps", "gcl": "graspd/grasp_config_list", "poses": "graspd/grasp_poses",
            "moveit": "graspd/moveit_grasps", "markers": "graspd/grasp_markers", "errors": "graspd/errors"}


@lru_cache(maxsize=1)
def ros_node_types() -> Typestore:
    """A ROS 2 node's view: Humble types plus gpd_ros from the upstream .msg files, moveit_msgs Grasp."""
    store = get_typestore(Stores.ROS2_HUMBLE)
    types: dict[str, Any] = {}
    for name in ("CloudSources", "CloudIndexed", "CloudSamples", "GraspConfig", "GraspConfigList"):
        source = UPSTREAM_MSGS / f"{name}.msg"
        text = source.read_text() if source.exists() else msg_text("gpd_ros", name)
        types.update(get_types_from_msg(text, f"gpd_ros/msg/{name}"))
    for name in ("GripperTranslation", "Grasp"):
        types.update(get_types_from_msg(msg_text("moveit_msgs", name), f"moveit_msgs/msg/{name}"))
    store.register(types)
    return store


class Listener:
    """Subscribes every output key and collects what arrives, per key."""

    def __init__(self, session: Any) -> None:
        self.got: dict[str, list[bytes]] = {k: [] for k in OUT_KEYS}
        self.cond = threading.Condition()
        self.subs = [session.declare_subscriber(key, lambda s, k=k: self._on(k, s)) for k, key in OUT_KEYS.items()]

    def _on(self, name: str, sample: Any) -> None:
        with self.cond:
            self.got[name].append(bytes(sample.payload.to_bytes()))
            self.cond.notify_all()

    def wait(self, pred: Callable[[], bool], timeout: float = 60.0) -> bool:
        with self.cond:
            return self.cond.wait_for(pred, timeout)

    def clear(self) -> None:
        with self.cond:
            for v in self.got.values():
                v.clear()

    def quiet(self, for_s: float = 1.0, timeout: float = 60.0) -> None:
        """Wait until nothing has arrived for for_s seconds (no frame in flight)."""
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            with self.cond:
                before = sum(len(v) for v in self.got.values())
                self.cond.wait(for_s)
                if sum(len(v) for v in self.got.values()) == before:
                    return

    def close(self) -> None:
        for s in self.subs:
            s.undeclare()


@pytest.fixture
def ros_server(make_settings: Callable[..., Settings]) -> Iterator[tuple[TestClient, str]]:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    settings = make_settings(zenoh_enabled=True, zenoh_listen=[endpoint], zenoh_instance="ros",
                             stream_num_samples=60, stream_options={"max_grasps": 8}, token=TOKEN,
                             zenoh_stream_token=False)
    with TestClient(create_app(settings)) as c:
        yield c, endpoint


@pytest.fixture
def session(ros_server: tuple[TestClient, str]) -> Iterator[Any]:
    import zenoh  # noqa: PLC0415

    with zenoh.open(zenoh_config(connect=[ros_server[1]])) as s:
        yield s


def publish_until(session: Any, key: str, payload: bytes, listener: Listener, pred: Callable[[], bool],
                  attachment: bytes | None = None, whole_frame: bool = False) -> None:
    """Put payload on key until pred holds (declarations take a moment to propagate), then wait for it.
    whole_frame: then let the frames in flight pass, clear, and put once more: every output of that one frame
    (the stream keeps only the newest cloud, so earlier puts may have been answered in part)."""
    pub = session.declare_publisher(key)
    try:
        for _ in range(50):
            pub.put(payload, attachment=attachment)
            if listener.wait(pred, 0.3):
                break
        assert listener.wait(pred, 60), f"nothing arrived for {key}"
        if whole_frame:
            listener.quiet()
            listener.clear()
            pub.put(payload, attachment=attachment)
            assert listener.wait(pred, 60), f"no whole frame for {key}"
    finally:
        pub.undeclare()


def frames(listener: Listener) -> bool:
    """A frame arrived on every output: the JSON answer, one moveit Grasp per grasp, the MarkerArray (each key's
    subscriber runs its callbacks on its own, so the last one published need not be the last one received)."""
    if not all(listener.got[k] for k in ("json", "gcl", "poses", "markers")):
        return False
    answer = json.loads(listener.got["json"][0])
    return len(listener.got["moveit"]) >= len(answer.get("grasps", [])) > 0


def sources_of(cloud: ViewpointCloud) -> tuple[np.ndarray, np.ndarray]:
    return cloud.points, cloud.viewpoints


def check_outputs(listener: Listener, header: Header) -> dict[str, Any]:
    """Decode every output as a ROS 2 node would and check them against the JSON answer of the same frame."""
    ts = ros_node_types()
    answer = json.loads(listener.got["json"][0])
    assert "grasps" in answer, answer
    assert answer["header"] == {"frame_id": header.frame_id,
                                "stamp": {"sec": header.stamp[0], "nanosec": header.stamp[1]}}
    grasps = answer["grasps"]
    m = len(grasps)
    assert 0 < m <= 8  # stream_options max_grasps
    gcl = ts.deserialize_cdr(listener.got["gcl"][0], "gpd_ros/msg/GraspConfigList")
    assert (gcl.header.frame_id, gcl.header.stamp.sec, gcl.header.stamp.nanosec) == \
        (header.frame_id, *header.stamp)
    assert len(gcl.grasps) == m
    for g, cfg in zip(grasps, gcl.grasps, strict=True):
        assert np.allclose([cfg.position.x, cfg.position.y, cfg.position.z], g["position"], atol=1e-9)
        assert np.allclose([cfg.approach.x, cfg.approach.y, cfg.approach.z], g["approach"], atol=1e-9)
        assert cfg.width.data == pytest.approx(g["width"], abs=1e-6)
    poses = ts.deserialize_cdr(listener.got["poses"][0], "geometry_msgs/msg/PoseArray")
    assert poses.header.frame_id == header.frame_id and len(poses.poses) == m
    for g, p in zip(grasps, poses.poses, strict=True):
        rot = Rotation.from_quat([p.orientation.x, p.orientation.y, p.orientation.z, p.orientation.w]).as_matrix()
        assert np.allclose(rot, np.asarray(g["pose"])[:3, :3], atol=1e-6)
    moveit = [ts.deserialize_cdr(b, "moveit_msgs/msg/Grasp") for b in listener.got["moveit"][:m]]
    assert [g.id for g in moveit] == [f"graspd/{i}" for i in range(m)]  # one per grasp, best first
    for g, mg in zip(grasps, moveit, strict=True):
        assert mg.grasp_pose.header.frame_id == header.frame_id
        pos = mg.grasp_pose.pose.position
        assert np.allclose([pos.x, pos.y, pos.z], g["position"], atol=1e-9)
        d = mg.pre_grasp_approach.direction.vector
        assert np.allclose([d.x, d.y, d.z], g["approach"], atol=1e-9)
        assert mg.pre_grasp_approach.desired_distance == pytest.approx(0.05)
    markers = ts.deserialize_cdr(listener.got["markers"][0], "visualization_msgs/msg/MarkerArray")
    assert markers.markers[0].action == 3  # DELETEALL, then three cubes per grasp
    assert len(markers.markers) == 1 + 3 * m
    assert {mk.header.frame_id for mk in markers.markers} == {header.frame_id}
    return answer


def test_cloud_sources_stream_to_every_ros_output(session: Any, krylon: ViewpointCloud) -> None:
    listener = Listener(session)
    try:
        pts, vps = sources_of(krylon)
        publish_until(session, "graspd/cloud_sources", encode_cloud_sources(pts, vps, header=HEADER), listener,
                      lambda: frames(listener), whole_frame=True)
        check_outputs(listener, HEADER)
    finally:
        listener.close()


def test_pointcloud2_stream_to_ros_outputs(session: Any, krylon: ViewpointCloud) -> None:
    listener = Listener(session)
    header = Header("camera_depth_optical_frame", (5, 6))
    try:
        publish_until(session, "graspd/cloud", encode_pointcloud2(krylon_camera_frame(krylon.points), header), listener,
                      lambda: frames(listener), whole_frame=True)
        check_outputs(listener, header)
    finally:
        listener.close()


@pytest.mark.parametrize("kind", ["indexed", "samples"])
def test_indexed_and_samples_restrict_where_hands_are_sampled(session: Any, krylon: ViewpointCloud,
                                                              kind: str) -> None:
    """Every grasp's sample lies at (within a voxel of) one of the points the message names: a CloudIndexed's
    indices are a target (a patch of the can), a CloudSamples' samples sample points."""
    pts, vps = sources_of(krylon)
    rng = np.random.default_rng(3)
    if kind == "indexed":
        idx = np.flatnonzero(np.linalg.norm(pts - np.median(pts, axis=0), axis=1) < 0.05)
    else:
        idx = rng.choice(len(pts), 12, replace=False)
    chosen = pts[idx].astype(np.float64)
    payload = (encode_cloud_indexed(pts, vps, idx, header=HEADER) if kind == "indexed"
               else encode_cloud_samples(pts, vps, chosen, header=HEADER))
    listener = Listener(session)
    try:
        publish_until(session, f"graspd/cloud_{kind}", payload, listener, lambda: frames(listener), whole_frame=True)
        answer = check_outputs(listener, HEADER)
    finally:
        listener.close()
    samples = np.array([g["sample"] for g in answer["grasps"]])
    nearest = np.linalg.norm(samples[:, None, :] - chosen[None], axis=-1).min(axis=1)
    assert nearest.max() < 0.01, nearest


def test_cdr_query_with_type(ros_server: tuple[TestClient, str], krylon: ViewpointCloud) -> None:
    """A CDR CloudSources as a query (selector parameter type=cloud_sources): the JSON answer with its header;
    a wrong type names the parameter, a malformed message names the ROS field."""
    _, endpoint = ros_server
    pts, vps = sources_of(krylon)
    payload = encode_cloud_sources(pts, vps, header=HEADER)
    with ZenohGraspClient(connect=[endpoint], timeout=60, token=TOKEN, retries=0) as zc:
        reply = zc.query(payload, "graspd/detect?type=cloud_sources")
        assert reply["header"]["frame_id"] == "base_link" and 0 < len(reply["grasps"]) <= 8
        reply = zc.query(payload, "graspd/detect?type=gpd_ros/msg/CloudSources")
        assert reply["header"]["stamp"] == {"sec": HEADER.stamp[0], "nanosec": HEADER.stamp[1]}
        with pytest.raises(RequestRejected) as info:
            zc.query(payload, "graspd/detect?type=sensor_msgs/Image")
        assert info.value.field == "type"
        bad = encode_cloud_sources(pts, vps, camera_source=np.full(len(pts), 5), header=HEADER)
        with pytest.raises(RequestRejected) as info:
            zc.query(bad, "graspd/detect?type=cloud_sources")
        assert info.value.field == "camera_source" and info.value.status == 422


def test_config_changes_the_stream_options(ros_server: tuple[TestClient, str], session: Any,
                                           krylon: ViewpointCloud) -> None:
    """A put on graspd/config (with the token) changes the next frames' options; an invalid one is refused on
    graspd/errors naming the field and changes nothing; one without the token is dropped; the query answers the
    options in force."""
    _, endpoint = ros_server
    listener = Listener(session)
    config = session.declare_publisher("graspd/config")
    token = zenoh_token_attachment(TOKEN)
    try:
        for _ in range(50):  # until the config subscription has propagated: the invalid put's error comes back
            config.put(json.dumps({"num_samples": -1}).encode(), attachment=token)
            if listener.wait(lambda: bool(listener.got["errors"]), 0.3):
                break
        err = json.loads(listener.got["errors"][0])
        assert err["status"] == 422 and err["field"] == "num_samples"
        config.put(json.dumps({"max_grasps": 2, "crops": None}).encode(), attachment=token)
        assert listener.wait(lambda: len(listener.got["errors"]) >= 2)
        assert json.loads(listener.got["errors"][-1])["field"] == "crops"
        config.put(b"{not json", attachment=token)
        assert listener.wait(lambda: len(listener.got["errors"]) >= 3)
        assert json.loads(listener.got["errors"][-1])["field"] == "body"
        config.put(json.dumps({"max_grasps": 1}).encode())  # no token: dropped, nothing said on the keys
        with ZenohGraspClient(connect=[endpoint], timeout=30, token=TOKEN, retries=0) as zc:
            assert zc.query(b"", "graspd/config")["max_grasps"] == 8
            assert zc.query(json.dumps({"max_grasps": 3, "gravity": [0, 0, -1]}).encode(),
                            "graspd/config")["max_grasps"] == 3
            with pytest.raises(RequestRejected) as info:
                zc.query(json.dumps({"approach": {"direction": [0, 0, 0]}}).encode(), "graspd/config")
            assert info.value.field == "approach.direction"
        with ZenohGraspClient(connect=[endpoint], timeout=30, retries=0) as anon:
            with pytest.raises(RequestRejected) as info:
                anon.query(json.dumps({"max_grasps": 1}).encode(), "graspd/config")
            assert info.value.status == 401
        listener.clear()
        pts, vps = sources_of(krylon)
        publish_until(session, "graspd/cloud_sources", encode_cloud_sources(pts, vps, header=HEADER), listener,
                      lambda: frames(listener), whole_frame=True)
        answer = json.loads(listener.got["json"][0])
        assert 0 < len(answer["grasps"]) <= 3
        assert len(listener.got["errors"]) == 0
    finally:
        config.undeclare()
        listener.close()


def test_malformed_stream_message_names_the_field(session: Any, krylon: ViewpointCloud) -> None:
    listener = Listener(session)
    try:
        good = encode_cloud_sources(krylon.points, krylon.viewpoints, header=HEADER)
        publish_until(session, "graspd/cloud_sources", good[: len(good) // 2], listener,
                      lambda: bool(listener.got["errors"]))
        err = json.loads(listener.got["errors"][0])
        assert err["status"] == 422 and err["field"].startswith("cloud.")
        deadline = time.monotonic() + 5
        while not listener.got["json"] and time.monotonic() < deadline:
            time.sleep(0.05)
        assert any(json.loads(b).get("field") == err["field"] for b in listener.got["json"])
    finally:
        listener.close()


def test_ros2_examples_match_the_server() -> None:
    """examples/ros2: the run-time options and the env's stream options validate; the bridge allows exactly the
    server's default input and ROS output keys."""
    examples = Path(__file__).resolve().parents[2] / "examples" / "ros2"
    parse_options((examples / "stream_options.json").read_bytes(), {}, ((0.0, 0.0, 0.0),))
    env = (examples / "graspd.env").read_text()
    options = re.search(r"^GRASPD_STREAM_OPTIONS='(.*)'$", env, re.M)
    assert options is not None
    parse_options(options.group(1), {}, ((0.0, 0.0, 0.0),))
    bridge = (examples / "zenoh-bridge-ros2dds.json5").read_text()
    publishers = re.search(r"publishers: \[(.*?)\]", bridge, re.S)
    subscribers = re.search(r"subscribers: \[(.*?)\]", bridge, re.S)
    assert publishers is not None and subscribers is not None
    assert set(re.findall(r'"/graspd/(\w+)"', publishers.group(1))) == set(DEFAULT_INPUT_KEYS.values())
    ros_outputs = {v for k, v in DEFAULT_OUTPUT_KEYS.items() if k not in ("json", "errors")}
    assert set(re.findall(r'"/graspd/(\w+)"', subscribers.group(1))) == ros_outputs
