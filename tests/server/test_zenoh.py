"""Zenoh: the detect queryable (JSON and CDR PointCloud2), error replies, streaming, and load spread over
several servers through their per-instance keys.  Peer mode on loopback, no router."""

from __future__ import annotations

import json
import socket
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import ExitStack
from typing import Any

import pytest
from fastapi.testclient import TestClient

from fixtures import krylon_camera_frame
from graspd.core.cloud import ViewpointCloud
from graspd.io.ros import Header, encode_pointcloud2
from graspd.server.app import create_app
from graspd.server.settings import Settings
from graspd_client import RequestRejected
from graspd_client.zenoh_client import ZenohGraspClient, zenoh_config


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@pytest.fixture
def zenoh_server(make_settings: Callable[..., Settings]) -> Iterator[tuple[TestClient, str]]:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    settings = make_settings(zenoh_enabled=True, zenoh_listen=[endpoint], zenoh_instance="solo",
                             stream_num_samples=60)
    with TestClient(create_app(settings)) as c:
        yield c, endpoint


def test_query_matches_http(zenoh_server: tuple[TestClient, str], body: dict[str, Any]) -> None:
    http, endpoint = zenoh_server
    assert http.get("/readyz").json()["zenoh"] is True
    with ZenohGraspClient(connect=[endpoint], timeout=30) as zc:
        reply = zc.query(json.dumps(body).encode())
    expected = http.post("/detect", json=body).json()
    assert [g["pose"] for g in reply["grasps"]] == [g["pose"] for g in expected["grasps"]]
    assert reply["scored"] is False and reply["model"] is None


@pytest.mark.parametrize(
    ("payload", "field"),
    [
        (b"\xff\xfe garbage", "payload"),
        (b"{not json", "body"),
        (json.dumps({"cloud": {"points": [[0, 0]]}}).encode(), "cloud.points"),
        (json.dumps({"cloud": {"points": [[0, 0, 1]]}, "num_samples": 10**9}).encode(), "num_samples"),
        (b"\x00\x01\x00\x00" + bytes(10), "header.frame_id"),  # CDR header, truncated PointCloud2: the ROS field
        (b"", "payload"),
    ],
)
def test_garbage_gets_an_error_reply(zenoh_server: tuple[TestClient, str], payload: bytes, field: str,
                                     krylon: ViewpointCloud) -> None:
    _, endpoint = zenoh_server
    with ZenohGraspClient(connect=[endpoint], timeout=30, retries=0) as zc:
        with pytest.raises(RequestRejected) as info:
            zc.query(payload)
        assert info.value.field == field and 400 <= info.value.status < 500
        assert len(zc.detect(krylon.points, krylon.viewpoints, num_samples=20)) > 0  # still serving


def test_cdr_pointcloud2_query(zenoh_server: tuple[TestClient, str], krylon: ViewpointCloud) -> None:
    _, endpoint = zenoh_server
    payload = encode_pointcloud2(krylon_camera_frame(krylon.points), Header("camera_depth_optical_frame", (12, 34)))
    with ZenohGraspClient(connect=[endpoint], timeout=30) as zc:
        reply = zc.query(payload)
    assert reply["header"] == {"frame_id": "camera_depth_optical_frame", "stamp": {"sec": 12, "nanosec": 34}}
    assert len(reply["grasps"]) > 0


def test_streaming_cloud_to_grasps(zenoh_server: tuple[TestClient, str], krylon: ViewpointCloud) -> None:
    import zenoh  # noqa: PLC0415

    _, endpoint = zenoh_server
    got: list[dict[str, Any]] = []
    done = threading.Event()

    def on_grasps(sample: Any) -> None:
        got.append(json.loads(sample.payload.to_bytes()))
        done.set()

    with zenoh.open(zenoh_config(connect=[endpoint])) as session:
        sub = session.declare_subscriber("graspd/grasps", on_grasps)
        pub = session.declare_publisher("graspd/cloud")
        for _ in range(50):  # until the subscription has propagated
            pub.put(encode_pointcloud2(krylon_camera_frame(krylon.points), Header("cam", (1, 2))))
            if done.wait(0.2):
                break
        assert done.wait(30)
        pub.put(b"not a cloud")
        # clouds put while the subscription propagated may still be answered first: wait for the error itself
        deadline = time.monotonic() + 30
        while not any(m.get("field") == "payload" for m in got) and time.monotonic() < deadline:
            time.sleep(0.05)
        sub.undeclare()
    ok = [m for m in got if "grasps" in m]
    assert ok and ok[0]["header"]["frame_id"] == "cam" and len(ok[0]["grasps"]) > 0
    assert any(m.get("field") == "payload" for m in got)


def test_two_servers_share_the_load(make_settings: Callable[..., Settings], krylon: ViewpointCloud) -> None:
    """Documented way to run several servers: each declares <prefix>/instances/<id>/detect, and the client
    (balance=True) discovers them and rotates over their keys."""
    endpoints = [f"tcp/127.0.0.1:{free_port()}" for _ in range(2)]
    with ExitStack() as stack:
        apps = []
        for i, ep in enumerate(endpoints):
            s = make_settings(zenoh_enabled=True, zenoh_listen=[ep], zenoh_connect=endpoints[:i],
                              zenoh_instance=f"worker{i}", zenoh_stream=False)
            apps.append(stack.enter_context(TestClient(create_app(s))))
        zc = stack.enter_context(ZenohGraspClient(connect=endpoints, timeout=30, balance=True))
        for _ in range(50):  # until both peers' declarations have reached the client
            found = [i["instance"] for i in zc.instances()]
            if len(found) == 2:
                break
            time.sleep(0.1)
        assert found == ["worker0", "worker1"]
        for _ in range(4):
            assert len(zc.detect(krylon.points, krylon.viewpoints, num_samples=20)) > 0
        for app in apps:
            assert 'graspd_requests_total{outcome="ok",transport="zenoh"} 2.0' in app.get("/metrics").text
