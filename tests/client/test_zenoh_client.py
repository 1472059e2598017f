"""The Zenoh clients as typed and documented as the HTTP ones: the same exception types for the same failures,
timeouts honoured (no server: said at once; a silent server: said after the timeout), Grasps iterable and
indexable into Grasp, and the async Zenoh client with the same methods.  Real server, real zenoh sessions."""

from __future__ import annotations

import asyncio
import threading
import time
from typing import Any

import numpy as np
import pytest

from graspd.core.cloud import ViewpointCloud
from graspd.server.runner import free_port
from graspd.server.settings import Settings
from graspd_client import (
    AsyncZenohGraspClient,
    Grasp,
    GraspClient,
    Grasps,
    RequestRejected,
    TransportError,
    ZenohGraspClient,
)
from graspd_client.zenoh_client import zenoh_config

Server = tuple[str, str, Settings]


def test_grasps_iterate_and_index_into_grasp(server: Server, krylon: ViewpointCloud) -> None:
    """HTTP and Zenoh give the same Grasps (one implementation): len, iteration and indexing give Grasp."""
    url, endpoint, _ = server
    with GraspClient(url) as hc, ZenohGraspClient(connect=[endpoint], timeout=60) as zc:
        for grasps in (hc.detect(krylon.points, krylon.viewpoints, num_samples=30, max_grasps=5),
                       zc.detect(krylon.points, krylon.viewpoints, num_samples=30, max_grasps=5)):
            assert isinstance(grasps, Grasps) and 0 < len(grasps) <= 5
            listed = list(grasps)
            assert len(listed) == len(grasps) and all(isinstance(g, Grasp) for g in listed)
            for i, g in enumerate(grasps):
                assert g.id == grasps.ids[i] and g.rank == i
                assert np.array_equal(g.pose, grasps.poses[i]) and np.array_equal(g.position, grasps.positions[i])
                assert g.width == grasps.widths[i] and (np.isnan(g.score) and np.isnan(grasps.scores[i]))
                assert np.allclose(g.approach, grasps.approach[i]) and np.allclose(g.axis, grasps.axis[i])
            assert grasps[-1].id == grasps.ids[-1] and [g.id for g in grasps[1:3]] == grasps.ids[1:3]
            with pytest.raises(IndexError):
                grasps[len(grasps)]


@pytest.mark.parametrize(("options", "field"), [({"num_samples": 0}, "num_samples"),
                                                ({"hand": "no-such-hand"}, "hand.preset")])
def test_same_rejection_over_http_and_zenoh(server: Server, krylon: ViewpointCloud, options: dict[str, Any],
                                            field: str) -> None:
    url, endpoint, _ = server
    errors = []
    with GraspClient(url) as hc, ZenohGraspClient(connect=[endpoint], timeout=30) as zc:
        for client in (hc, zc):
            with pytest.raises(RequestRejected) as info:
                client.detect(krylon.points, krylon.viewpoints, **options)
            errors.append((type(info.value), info.value.status, info.value.field))
    assert errors[0] == errors[1] == (RequestRejected, 422, field)


def test_no_server_is_a_transport_error_said_at_once() -> None:
    """Nothing listens: TransportError like HTTP's refused connection, saying none is reachable (not a
    timeout), well before the timeout."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    with pytest.raises(TransportError):
        with GraspClient(f"http://127.0.0.1:{free_port()}", timeout=3) as hc:
            hc.detect([[0.0, 0.0, 1.0]])
    with ZenohGraspClient(connect=[endpoint], timeout=10, retries=0) as zc:  # nothing at the endpoint
        t0 = time.monotonic()
        with pytest.raises(TransportError) as info:
            zc.detect([[0.0, 0.0, 1.0]])
        assert "no server reachable" in str(info.value) and time.monotonic() - t0 < 5
    import zenoh  # noqa: PLC0415

    listen = f"tcp/127.0.0.1:{free_port()}"
    with zenoh.open(zenoh_config(listen=[listen], connect=[])), \
            ZenohGraspClient(connect=[listen], timeout=10, retries=0) as zc:  # a peer, but no graspd
        t0 = time.monotonic()
        with pytest.raises(TransportError) as info:
            zc.detect([[0.0, 0.0, 1.0]])
        elapsed = time.monotonic() - t0
    assert "no server reachable" in str(info.value) and elapsed < 5


def test_silent_server_times_out_after_the_timeout() -> None:
    """A queryable that never answers: TransportError "no reply within 1 s", after 1 s (as HTTP's timeout)."""
    import zenoh  # noqa: PLC0415

    listen = f"tcp/127.0.0.1:{free_port()}"
    held: list[Any] = []
    release = threading.Event()

    def never(query: Any) -> None:
        held.append(query)  # keep it unanswered

    with zenoh.open(zenoh_config(listen=[listen], connect=[])) as silent:
        q = silent.declare_queryable("graspd/detect", never)
        with ZenohGraspClient(connect=[listen], timeout=1.0, retries=0) as zc:
            time.sleep(0.5)  # the declaration reaches the client's session
            t0 = time.monotonic()
            with pytest.raises(TransportError) as info:
                zc.query(b"{}")
            elapsed = time.monotonic() - t0
        release.set()
        held.clear()
        q.undeclare()
    assert "no reply within 1 s" in str(info.value)
    assert 0.9 <= elapsed < 3.0, elapsed


def test_async_zenoh_client_has_the_same_methods(server: Server, krylon: ViewpointCloud) -> None:
    _, endpoint, _ = server
    sync_methods = {m for m in dir(ZenohGraspClient) if not m.startswith("_")} - {"close"}
    async_methods = {m for m in dir(AsyncZenohGraspClient) if not m.startswith("_")} - {"aclose", "sync"}
    assert sync_methods <= async_methods, sync_methods - async_methods

    async def run() -> tuple[Grasps, Any, Any, Any]:
        async with AsyncZenohGraspClient(connect=[endpoint], timeout=60) as zc:
            grasps, library = await asyncio.gather(
                zc.detect(krylon.points, krylon.viewpoints, num_samples=20, max_grasps=4), zc.library())
            options = await zc.set_stream_options(max_grasps=3)
            with pytest.raises(RequestRejected) as info:
                await zc.set_stream_options(max_grasps=-1)
            assert info.value.field == "max_grasps"
            return grasps, library, options, await zc.stream_options()

    grasps, library, options, now = asyncio.run(run())
    assert 0 < len(grasps) <= 4 and isinstance(grasps[0], Grasp)
    assert "num_entries" in library
    assert options["max_grasps"] == 3 and now["max_grasps"] == 3
