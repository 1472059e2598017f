"""GraspClient, AsyncGraspClient and ZenohGraspClient against a real server: numpy in, Grasps out,
503 retried after Retry-After, errors that name what went wrong."""

from __future__ import annotations

import asyncio
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial import cKDTree

from fixtures import KRYLON_VIEWPOINT
from graspd.core.cloud import ViewpointCloud
from graspd.server.runner import free_port
from graspd.server.settings import Settings
from graspd_client import AsyncGraspClient, GraspClient, RequestRejected, ServerBusy, TransportError
from graspd_client.zenoh_client import ZenohGraspClient

Server = tuple[str, str, Settings]


def test_sync_client_detect(server: Server, krylon: ViewpointCloud) -> None:
    url, _, _ = server
    with GraspClient(url, timeout=60) as client:
        assert client.ready()
        g = client.detect(krylon.points, krylon.viewpoints, num_samples=60, hand="panda", max_grasps=5)
        assert 0 < len(g) <= 5 and g.poses.shape == (len(g), 4, 4)
        assert np.allclose(g.poses[:, :3, 0], g.approach) and np.allclose(g.poses[:, :3, 3], g.positions)
        assert np.allclose(np.linalg.norm(g.quat_xyzw, axis=1), 1.0)
        assert np.isnan(g.scores).all() and g.scored is False and g.model is None
        assert len(set(g.ids)) == len(g) and g.timings["total"] > 0
        assert client.models() == {"default": None, "cascade": None, "models": [], "jobs": []}


def test_sync_client_file_upload(server: Server, real_data: Path, krylon: ViewpointCloud) -> None:
    """The file's points are the cloud detection ran on: every grasp was sampled on the can, best first."""
    url, _, _ = server
    with GraspClient(url, timeout=60) as client:
        g = client.detect_file((real_data / "krylon.pcd").read_bytes(), num_samples=60, viewpoint=KRYLON_VIEWPOINT)
    assert len(g) > 0 and g.frame == "cloud"
    gap, _ = cKDTree(krylon.points).query(g.samples)
    assert gap.max() < 0.005  # a voxel-mean of the file's points, not a point of some other cloud
    order = g.raw["grasps"]
    assert [x["id"] for x in order] == g.ids


def test_errors_name_the_field(server: Server, krylon: ViewpointCloud) -> None:
    url, _, _ = server
    with GraspClient(url, timeout=60) as client:
        with pytest.raises(RequestRejected) as info:
            client.detect(krylon.points, krylon.viewpoints, model="no-such-model")
        assert info.value.status == 422 and info.value.field == "model" and "no-such-model" in str(info.value)
        with pytest.raises(RequestRejected) as info:
            client.detect(krylon.points, krylon.viewpoints, camera_source=np.full(len(krylon), 3))
        assert info.value.field == "cloud.camera_source"


def test_unreachable_server_is_a_transport_error() -> None:
    with GraspClient(f"http://127.0.0.1:{free_port()}", timeout=2, retries=0) as client:
        with pytest.raises(TransportError, match="POST /detect"):
            client.detect(np.zeros((3, 3)), num_samples=5)


def test_503_is_retried_after_retry_after(server: Server, krylon: ViewpointCloud) -> None:
    url, _, _ = server
    with GraspClient(url, timeout=60) as busy_maker, GraspClient(url, timeout=60, retries=0) as impatient, \
            GraspClient(url, timeout=60, retries=50, max_retry_delay=0.2) as patient:
        worker = threading.Thread(target=busy_maker.detect, args=(krylon.points,), kwargs={"num_samples": 4000})
        worker.start()

        time.sleep(0.15)  # the slow request holds the only worker; no queue
        with pytest.raises(ServerBusy):
            impatient.detect(krylon.points, num_samples=20)
        assert len(patient.detect(krylon.points, krylon.viewpoints, num_samples=20)) > 0
        worker.join()


def test_async_client(server: Server, krylon: ViewpointCloud) -> None:
    url, _, _ = server

    async def run() -> list[int]:
        async with AsyncGraspClient(url, timeout=60, retries=50, max_retry_delay=0.2) as client:
            results = await asyncio.gather(*[client.detect(krylon.points, krylon.viewpoints, num_samples=30)
                                             for _ in range(3)])
            with pytest.raises(RequestRejected):
                await client.detect(krylon.points, num_samples=10**9)
            return [len(r) for r in results]

    counts = asyncio.run(run())
    assert len(set(counts)) == 1 and counts[0] > 0


def test_zenoh_client(server: Server, krylon: ViewpointCloud) -> None:
    url, endpoint, _ = server
    with ZenohGraspClient(connect=[endpoint], timeout=60) as zc, GraspClient(url, timeout=60) as hc:
        gz = zc.detect(krylon.points, krylon.viewpoints, num_samples=40)
        gh = hc.detect(krylon.points, krylon.viewpoints, num_samples=40)
        assert np.allclose(gz.poses, gh.poses) and len(gz) > 0
        with pytest.raises(RequestRejected) as info:
            zc.detect(krylon.points, krylon.viewpoints, hand="no-such-hand")
        assert info.value.field == "hand.preset"


def test_detection_options_reach_the_server(server: Server, krylon: ViewpointCloud) -> None:
    """gravity, apertures, exclude_support_plane, use_classifier and clustering as keyword arguments of all three
    clients give the same, honoured result; a bad value is rejected naming the field."""
    url, endpoint, _ = server
    options = {"num_samples": 60, "gravity": [0.0, -1.0, 0.0], "min_aperture": 0.02, "max_aperture": 0.06,
               "exclude_support_plane": True, "use_classifier": False, "clustering": False}
    with GraspClient(url, timeout=60) as hc, ZenohGraspClient(connect=[endpoint], timeout=60) as zc:
        g = hc.detect(krylon.points, krylon.viewpoints, **options)
        plain = hc.detect(krylon.points, krylon.viewpoints, num_samples=60)
        assert len(g) > 0 and ((g.widths >= 0.02) & (g.widths <= 0.06)).all() and not g.scored
        assert not np.array_equal(g.positions[: len(plain)], plain.positions[: len(g)])
        assert np.allclose(zc.detect(krylon.points, krylon.viewpoints, **options).poses, g.poses)
        with pytest.raises(RequestRejected) as info:
            hc.detect(krylon.points, krylon.viewpoints, gravity=[0, 0, 0])
        assert info.value.status == 422 and info.value.field == "gravity"

    async def run() -> np.ndarray:
        async with AsyncGraspClient(url, timeout=60, retries=50, max_retry_delay=0.2) as client:
            return (await client.detect(krylon.points, krylon.viewpoints, **options)).poses

    assert np.allclose(asyncio.run(run()), g.poses)
