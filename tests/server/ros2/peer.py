"""A ROS 2 peer without ROS: a cyclonedds participant that names its topics and types as a ROS 2 node on
rmw_cyclonedds does, frames service requests as rmw_cyclonedds does (CDR encapsulation, {client guid u64,
sequence number i64}, then the request), and decodes what it gets with rosbags, gpd_ros registered from the
upstream .msg files in ../shared/ros.  Used by the ROS 2 tests (in-process) and bench/hostile_ros2.py (across
the loopback, joining a domain made with the node's localhost discovery)."""

from __future__ import annotations

import itertools
import struct
import threading
import time
from functools import lru_cache
from pathlib import Path
from typing import Any

import numpy as np
from cyclonedds.domain import DomainParticipant
from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from rosbags.typesys.store import Typestore

from graspd.io.ros import Header
from graspd.io.ros.encode import encode_grasp_planning
from graspd.server.ros2.dds import RawReader, RawWriter, reliable_qos, sensor_qos
from graspd.server.ros2.interfaces import ros_types

SHARED_ROS = Path(__file__).resolve().parents[4] / "shared" / "ros" / "gpd_ros"


@lru_cache(maxsize=1)
def peer_types() -> Typestore:
    """A ROS 2 node's view: Jazzy types plus gpd_ros from the upstream .msg files (shared/ros) and the moveit and
    vision_msgs messages the node ships."""
    store = get_typestore(Stores.ROS2_JAZZY)
    node = ros_types("jazzy")
    types: dict[str, Any] = {}
    for name in ("CloudSources", "CloudIndexed", "CloudSamples", "GraspConfig", "GraspConfigList"):
        types.update(get_types_from_msg((SHARED_ROS / "msg" / f"{name}.msg").read_text(), f"gpd_ros/msg/{name}"))
    store.register(types)
    extra = {k: v for k, v in node.fielddefs.items()
             if k.split("/")[0] in ("moveit_msgs", "object_recognition_msgs", "vision_msgs")}
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


#: The frame the audit's GraspPlanning requests are in (the camera's optical frame of the clouds sent with them).
PLAN_FRAME = "camera_depth_optical_frame"


def hostile_primitives(count: int = 60_000) -> bytes:
    """The audit's 5.8 MB GraspPlanning request: count 5 cm boxes spread over a metre cube."""
    centres = np.random.default_rng(0).random((count, 3))
    return encode_grasp_planning(Header(PLAN_FRAME, (5, 6)), box_centres=centres, box_sizes=np.full((count, 3), 0.05))


def hostile_meshes(vertices: int = 1_700_000) -> bytes:
    """The audit's 61 MB GraspPlanning request: one mesh of as many vertices and triangles."""
    rng = np.random.default_rng(1)
    return encode_grasp_planning(Header(PLAN_FRAME, (5, 6)), meshes=((rng.random((vertices, 3)),
                                                                      rng.integers(0, vertices, (vertices, 3))),))
