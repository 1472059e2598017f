"""The ROS 2 tests' server and peer (peer.py: a ROS 2 node without ROS).  The server under test runs in this
process (TestClient, so its lifespan runs) on a DDS domain of its own, picked at random per test session,
loopback only.

The peer joins the domain the node made (one process, one domain instance per id): Cyclone delivers within the
process, with the same type matching, QoS matching and CDR checks as across the loopback."""

from __future__ import annotations

import itertools
import random
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from fastapi.testclient import TestClient

from graspd.io.cloud_files import read_input
from graspd.server.app import create_app
from graspd.server.settings import Settings

from .peer import Collector, RosPeer, ServiceClient, peer_types

__all__ = ["Collector", "RosPeer", "ServiceClient", "next_domain", "peer_types", "serve_ros2"]

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
