"""Admission by estimated cost: a request that can never fit the detection memory budget gets 413
naming the field that costs most, one that cannot fit now 503 with Retry-After; over HTTP before the body is read
when its size alone says so, and the same budget on Zenoh."""

from __future__ import annotations

import json
import socket
import threading
import time
from collections.abc import Callable
from typing import Any
from urllib.parse import urlparse

import pytest
from fastapi.testclient import TestClient

from graspd.core.cloud import ViewpointCloud
from graspd.server.app import create_app
from graspd.server.problems import Problem
from graspd.server.requests import parse_request
from graspd.server.runner import serve_in_thread
from graspd.server.services.budget import (
    BASE_MB,
    SAMPLE_MB,
    MemoryBudget,
    occupied_voxels,
    request_cost,
    work_units,
)
from graspd.server.services.mapping import detection_inputs
from graspd.server.settings import Settings
from graspd_client import ZenohGraspClient
from graspd_client.errors import RequestRejected

from .conftest import free_port


def test_the_budget_refuses_what_never_fits_and_defers_what_does_not_fit_now() -> None:
    budget = MemoryBudget(1000)
    with pytest.raises(Problem) as never:
        budget.take(request_cost(10_000, 5000), retry_after=2)
    assert never.value.status == 413 and never.value.field == "num_samples"
    assert f"num_samples at most {int((1000 - BASE_MB - 10_000 * 40 / 2**20) / SAMPLE_MB)}" in never.value.message
    with pytest.raises(Problem) as points:
        budget.take(request_cost(50_000_000, 10), retry_after=2)
    assert points.value.status == 413 and points.value.field == "cloud"
    first = budget.take(request_cost(10_000, 1000), retry_after=2)  # ~600 MiB
    t0 = time.monotonic()
    with pytest.raises(Problem) as later:
        budget.take(request_cost(10_000, 1000), retry_after=2, wait_s=0.2)
    assert later.value.status == 503 and later.value.retry_after == 2 and time.monotonic() - t0 >= 0.2
    threading.Timer(0.2, budget.give, (first,)).start()  # a running detection finishes: the waiter gets in
    assert budget.take(request_cost(10_000, 1000), retry_after=2, wait_s=5) == pytest.approx(first)
    assert budget.used_mb == pytest.approx(first) and budget.waiters == 0


def test_http_413_names_the_field_and_503_comes_before_the_body(
        make_settings: Callable[..., Settings], krylon: ViewpointCloud,
        small_body: Callable[..., dict[str, Any]]) -> None:
    settings = make_settings(detect_memory_mb=600, detect_memory_wait_s=0.2)
    with TestClient(create_app(settings)) as client:
        big = client.post("/detect", json=small_body(krylon, num_samples=2000))  # 350 + 500 MiB > 600
        assert big.status_code == 413 and big.json()["field"] == "num_samples", big.text
        assert "GRASPD_DETECT_MEMORY_MB" in big.json()["error"]
        assert client.post("/detect", json=small_body(krylon)).status_code == 200
        budget = client.app.state.service.engine.budget  # type: ignore[attr-defined]
        held = budget.take({"base": 500.0}, retry_after=1)  # a detection running now holds most of it
        busy = client.post("/detect", json=small_body(krylon))
        assert busy.status_code == 503 and int(busy.headers["retry-after"]) >= 1, busy.text
        budget.give(held)
        assert client.post("/detect", json=small_body(krylon)).status_code == 200


def test_a_body_too_big_for_the_budget_is_refused_before_it_is_read(make_settings: Callable[..., Settings]) -> None:
    settings = make_settings(port=0, detect_memory_mb=400)  # 20 MB could hold 1.7M points: ~414 MiB
    with serve_in_thread(settings) as url:
        u = urlparse(url)
        with socket.create_connection((u.hostname, u.port), timeout=10) as s:
            t0 = time.monotonic()
            s.sendall(b"POST /detect HTTP/1.1\r\nHost: x\r\nContent-Type: application/octet-stream\r\n"
                      b"Content-Length: 20000000\r\n\r\n")  # the body never comes
            data = b""
            while b"}" not in data:
                chunk = s.recv(65536)
                assert chunk, data
                data += chunk
        head, _, body = data.partition(b"\r\n\r\n")
        assert head.split()[1] == b"413" and time.monotonic() - t0 < 2.0
        assert b"x-request-id" in head.lower() and json.loads(body)["field"] == "body"


def test_the_same_budget_on_zenoh(make_settings: Callable[..., Settings], krylon: ViewpointCloud) -> None:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    settings = make_settings(zenoh_enabled=True, zenoh_listen=[endpoint], zenoh_stream=False, detect_memory_mb=600)
    with TestClient(create_app(settings)), ZenohGraspClient(connect=[endpoint], timeout=30, retries=0) as zc:
        with pytest.raises(RequestRejected) as info:
            zc.detect(krylon.points, krylon.viewpoints, num_samples=2000)
        assert info.value.status == 413 and info.value.field == "num_samples"


def test_a_request_that_would_end_past_its_deadline_is_503_not_started(
        make_settings: Callable[..., Settings], krylon: ViewpointCloud,
        small_body: Callable[..., dict[str, Any]]) -> None:
    """Expected seconds = work units x learned seconds per unit: a request expected to need the whole deadline
    after it waited and was parsed is refused with 503 + Retry-After instead of running into a 504."""
    body = small_body(krylon, num_samples=300)
    req = parse_request(body)
    inputs = detection_inputs(req)
    params = inputs.params
    units = work_units(req, occupied_voxels(inputs.given.cloud, params.voxel_size, params.workspace,
                                            params.range_window))  # what the engine counts on its worker
    with TestClient(create_app(make_settings(deadline_s=10))) as client:
        budget = client.app.state.service.engine.budget  # type: ignore[attr-defined]
        budget.unit_seconds = 9.99999 / units  # expected ~10 s: it fits the deadline only if it started at once
        late = client.post("/detect", json=body)  # alone: shared by 1
        assert late.status_code == 503 and int(late.headers["retry-after"]) >= 1, late.text[:300]
        assert "would not end within the deadline" in late.json()["error"]
        assert budget.unit_seconds == pytest.approx(9.99999 / units)  # a refusal teaches nothing
        budget.unit_seconds = 0.6
        assert client.post("/detect", json=small_body(krylon, num_samples=300)).status_code == 200
        assert budget.unit_seconds != 0.6  # learned from the detection that ran
