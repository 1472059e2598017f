"""A ROS 2 peer without ROS: a cyclonedds participant that names its topics and types as a ROS 2 node on
rmw_cyclonedds does, frames service requests as rmw_cyclonedds does (CDR encapsulation, {client guid u64,
sequence number i64}, then the request), and decodes what it gets with rosbags, gpd_ros registered from the
upstream .msg files in ../shared/ros.  The server under test runs in this process (TestClient, so its lifespan
runs) on a DDS domain of its own, picked at random per test session, loopback only.

The peer joins the domain the node made (one process, one domain instance per id): Cyclone delivers within the
process, with the same type matching, QoS matching and CDR checks as across the loopback."""

from __future__ import annotations

import itertools
import random
import struct
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from functools import lru_cache
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from cyclonedds.domain import DomainParticipant
from fastapi.testclient import TestClient
from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from rosbags.typesys.store import Typestore

from graspd.io.cloud_files import read_input
from graspd.server.app import create_app
from graspd.server.ros2.dds import RawReader, RawWriter, reliable_qos, sensor_qos
from graspd.server.ros2.interfaces import ros_types
from graspd.server.settings import Settings

SHARED_ROS = Path(__file__).resolve().parents[4] / "shared" / "ros" / "gpd_ros"
#: Domain ids of this test session: a random block, one id per node started (a domain id is made once per process).
_DOMAINS = itertools.count(random.randrange(0, 230))
_USED: set[int] = set()


def next_domain() -> int:
    """A DDS domain id no other node of this session used (0..232)."""
    while True:
        d = next(_DOMAINS) % 230 + 1
        if d not in _USED:
            _USED.add(d)
            return d


@lru_cache(maxsize=1)
def peer_types() -> Typestore:
    """A ROS 2 node's view: Jazzy types plus gpd_ros from the upstream .msg files (shared/ros) and the moveit
    messages the node ships."""
    store = get_typestore(Stores.ROS2_JAZZY)
    node = ros_types("jazzy")
    types: dict[str, Any] = {}
    for name in ("CloudSources", "CloudIndexed", "CloudSamples", "GraspConfig", "GraspConfigList"):
        types.update(get_types_from_msg((SHARED_ROS / "msg" / f"{name}.msg").read_text(), f"gpd_ros/msg/{name}"))
    store.register(types)
    extra = {k: v for k, v in node.fielddefs.items() if k.split("/")[0] in ("moveit_msgs", "object_recognition_msgs")}
    store.register(extra)
    return store


class Collector:
    """Samples arriving on one topic (CDR bytes), with a condition to wait on."""

    def __init__(self) -> None:
        self.got: list[bytes] = []
        self.cond = threading.Condition()

    def __call__(self, data: bytes) -> None:
        with self.cond:
            self.got.append(data)
            self.cond.notify_all()

    def wait(self, count: int = 1, timeout: float = 60.0) -> bool:
        with self.cond:
            return self.cond.wait_for(lambda: len(self.got) >= count, timeout)

    def clear(self) -> None:
        with self.cond:
            self.got.clear()


class RosPeer:
    """The test's ROS 2 node: publishes, subscribes and calls services on DDS with ROS 2 names."""

    def __init__(self, domain_id: int) -> None:
        self.dp = DomainParticipant(domain_id)
        self._topics: dict[str, Any] = {}
        self.readers: list[RawReader] = []
        self.writers: list[RawWriter] = []
        self._seq = itertools.count(1)

    def topic(self, name: str, ros_type: str, distro: str) -> Any:  # the interface RawReader/RawWriter use
        from cyclonedds.topic import Topic  # noqa: PLC0415

        from graspd.server.ros2.interfaces import idl_type  # noqa: PLC0415

        if name not in self._topics:
            self._topics[name] = Topic(self.dp, name, idl_type(ros_type, distro))
        return self._topics[name]

    def subscribe(self, ros_topic: str, ros_type: str, qos: Any = None) -> Collector:
        sink = Collector()
        self.readers.append(RawReader(self, f"rt{ros_topic}", ros_type, "jazzy", qos or reliable_qos(300), sink))
        return sink

    def publisher(self, ros_topic: str, ros_type: str, qos: Any = None) -> RawWriter:
        w = RawWriter(self, f"rt{ros_topic}", ros_type, "jazzy", qos or sensor_qos())
        self.writers.append(w)
        return w

    def publish_until(self, writer: RawWriter, payload: bytes, sinks: list[Collector], timeout: float = 60.0) -> None:
        """Publish until one of sinks got something (matching takes a moment), then wait for it."""
        end = time.monotonic() + timeout
        while writer.matched() == 0 and time.monotonic() < end:
            time.sleep(0.05)
        time.sleep(0.2)  # the node's reader matches our writer too
        writer.write(payload)
        while time.monotonic() < end:
            if any(s.wait(1, 0.5) for s in sinks):
                return
        raise AssertionError(f"no answer to {writer.name}")

    def client(self, service: str, srv_type: str) -> ServiceClient:
        c = ServiceClient(self, service, srv_type)
        self.readers.append(c.reader)
        self.writers.append(c.writer)
        return c

    def reader(self, name: str, ros_type: str, qos: Any, sink: Collector) -> RawReader:
        """A reader of a DDS topic by its DDS name (ros_discovery_info has no rt/ prefix)."""
        r = RawReader(self, name, ros_type, "jazzy", qos, sink)
        self.readers.append(r)
        return r

    def close(self) -> None:
        """Delete readers (listeners first), writers, topics and the participant."""
        for endpoint in [*self.readers, *self.writers]:
            endpoint.close()
        for entity in [*self._topics.values(), self.dp]:
            entity.__del__()
        self._topics.clear()


class ServiceClient:
    """A ROS 2 service client as rmw_cyclonedds makes one: request writer on rq/<name>Request and reply reader
    on rr/<name>Reply (reliable, volatile, keep last 10, user data "clientid=...;"); requests framed with the
    writer's instance handle and a sequence number; replies taken when their header carries our guid."""

    def __init__(self, peer: RosPeer, service: str, srv_type: str) -> None:
        from cyclonedds.pub import DataWriter  # noqa: PLC0415

        self.replies = Collector()
        user = b"clientid=graspd.test;"
        self.writer = RawWriter(peer, f"rq{service}Request", f"{srv_type}_Request", "jazzy", reliable_qos(10, user))
        self.reader = RawReader(peer, f"rr{service}Reply", f"{srv_type}_Response", "jazzy", reliable_qos(10, user),
                                self.replies)
        writer: DataWriter[Any] = self.writer.writer
        self.guid = int(writer.get_instance_handle()) & 0xFFFF_FFFF_FFFF_FFFF  # the u64 rmw sends
        self.peer = peer

    def wait_for_service(self, timeout: float = 30.0) -> None:
        """rmw_service_server_is_available: a matched request reader and reply writer."""
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            if self.writer.matched() and self.reader.matched():
                return
            time.sleep(0.05)
        raise AssertionError("service not available")

    def call(self, request_cdr: bytes, timeout: float = 120.0) -> tuple[int, int, bytes]:
        """Send one request (a plain little-endian CDR message of the request's fields); the reply's (guid,
        sequence number, fields as a plain CDR message)."""
        seq = next(self.peer._seq)
        sample = request_cdr[:4] + struct.pack("<Qq", self.guid, seq) + request_cdr[4:]
        self.writer.write(sample)
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            with self.replies.cond:
                for data in self.replies.got:
                    guid, got_seq = struct.unpack_from("<Qq" if data[1] == 1 else ">Qq", data, 4)
                    if guid == self.guid and got_seq == seq:
                        return guid, got_seq, data[:4] + data[20:]
                self.replies.cond.wait(0.5)
        raise AssertionError(f"no reply to request {seq}")


@pytest.fixture(scope="session")
def mug_points(real_data: Path) -> np.ndarray:
    """table_mug.pcd (camera frame, the camera at the origin), every 4th point (26k): fast, still a mug."""
    return read_input(real_data / "table_mug.pcd").cloud.points[::4].copy()


#: A small detection: the default tests stay fast on two shared cores.
NODE_OPTIONS = {"max_grasps": 6}
NUM_SAMPLES = 30
MAX_BODY = 3 << 20


@contextmanager
def serve_ros2(tmp: Path, **overrides: Any) -> Iterator[tuple[TestClient, int]]:
    """A real server with its ROS 2 node on a fresh domain (unscored, 30 samples, 6 grasps, 3 MiB body cap, one
    worker), settings overridden by overrides; yields (client, domain id)."""
    domain = next_domain()
    base: dict[str, Any] = {"zenoh_enabled": False, "ros2_enabled": True, "ros2_domain_id": domain,
                            "models_dir": tmp / "no-models", "data_dir": tmp / "data", "allow_unscored": True,
                            "warmup": False, "detect_workers": 1, "deadline_s": 300, "queue_size": 4,
                            "stream_num_samples": NUM_SAMPLES, "stream_options": NODE_OPTIONS,
                            "max_body_bytes": MAX_BODY}
    with TestClient(create_app(Settings(**{**base, **overrides}))) as client:
        yield client, domain


@pytest.fixture(scope="module")
def ros2_server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[TestClient, int]]:
    with serve_ros2(tmp_path_factory.mktemp("ros2")) as served:
        yield served


@pytest.fixture(scope="module")
def peer(ros2_server: tuple[TestClient, int]) -> Iterator[RosPeer]:
    p = RosPeer(ros2_server[1])
    yield p
    p.close()  # before the node deletes the domain


Decode = Callable[[bytes, str], Any]


@pytest.fixture(scope="session")
def decode() -> Decode:
    """decode(cdr, ros type) with the peer's typestore."""
    return lambda data, msgtype: peer_types().deserialize_cdr(data, msgtype)
