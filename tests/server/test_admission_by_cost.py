"""Admission by what a detection costs: the occupied voxels it keeps, not the points sent.  A volume of as many
points as a surface scan keeps ~10-20x its voxels; under small settings (memory budget, deadline, one worker) a
modest volume takes the paths a 5M-point one takes at the defaults: 413 at once when it never fits, queued work
that cannot start in time answered 503 with Retry-After at once and never run, and what starts answered even
past the deadline, on every entrance alike."""

from __future__ import annotations

import asyncio
import io
import json
import threading
import time
from collections.abc import Callable
from typing import Any

import numpy as np
import pytest
from fastapi.testclient import TestClient

from graspd.core.cloud import ViewpointCloud
from graspd.core.points import voxel_groups
from graspd.gpd.preprocess import region_mask
from graspd.server.app import create_app
from graspd.server.problems import Problem
from graspd.server.requests import parse_request
from graspd.server.services.budget import VOXEL_SAMPLE, occupied_voxels
from graspd.server.services.mapping import response_json
from graspd.server.services.outcome import Outcome, Parsed
from graspd.server.settings import Settings
from graspd_client import ZenohGraspClient
from graspd_client.errors import RequestRejected

from .conftest import free_port

POINTS = 200_000


def surface(n: int = POINTS, seed: int = 0) -> np.ndarray:
    """n points (N,3 float32, m) of a 30 x 30 cm table 60 cm below the camera, 0.5 mm depth noise: ~20k voxels
    of 3 mm (the noise straddles a layer of cells, as a real scan's does)."""
    rng = np.random.default_rng(seed)
    xy = rng.uniform(-0.15, 0.15, (n, 2))
    return np.c_[xy, 0.6 + rng.normal(0.0, 0.0005, n)].astype(np.float32)


def volume(n: int = POINTS, seed: int = 0) -> np.ndarray:
    """n points (N,3 float32, m) filling a 30 cm cube 60 cm from the camera: ~0.19M voxels of 3 mm at 200k."""
    rng = np.random.default_rng(seed)
    return (rng.uniform(-0.15, 0.15, (n, 3)) + [0.0, 0.0, 0.6]).astype(np.float32)


def npy(points: np.ndarray) -> bytes:
    buf = io.BytesIO()
    np.save(buf, points)
    return buf.getvalue()


def post(client: TestClient, points: np.ndarray, num_samples: int = 50) -> Any:
    return client.post(f"/detect?num_samples={num_samples}&viewpoint=0,0,0", content=npy(points),
                       headers={"content-type": "application/x-npy"})


def exact_voxels(points: np.ndarray, keep: np.ndarray | None = None) -> int:
    kept = points if keep is None else points[keep]
    return len(voxel_groups(kept, 0.003)[1]) if len(kept) else 0


def test_the_voxel_count_is_that_of_the_detections_grid_and_region() -> None:
    """occupied_voxels against the detector's own voxel grid (core.points.voxel_groups) over the detector's
    region (preprocess.region_mask): exact below VOXEL_SAMPLE points, within 2% above; a surface of as many
    points keeps a ninth of a volume's voxels."""
    cam = np.zeros((1, 3), np.float32)
    flat, solid = surface(), volume()
    n_flat = occupied_voxels(ViewpointCloud(points=flat, viewpoints=cam), 0.003)
    n_solid = occupied_voxels(ViewpointCloud(points=solid, viewpoints=cam), 0.003)
    assert (n_flat, n_solid) == (exact_voxels(flat), exact_voxels(solid))
    assert n_solid > 8 * n_flat

    box = (-0.05, 0.1, -0.1, 0.05, 0.55, 0.7)
    cloud = ViewpointCloud(points=solid, viewpoints=cam)
    assert occupied_voxels(cloud, 0.003, box) == exact_voxels(solid, region_mask(cloud, box, 0.0))

    room = np.random.default_rng(1).uniform(-2, 2, (50_000, 3)).astype(np.float32) + np.float32([0, 0, 3.5])
    scene = ViewpointCloud(points=np.r_[flat, room, np.full((10, 3), np.nan, np.float32)], viewpoints=cam)
    keep = region_mask(scene, None, 1.0)  # the range window leaves the room 3 m behind the table out
    assert keep.sum() < len(flat) + 1000
    assert occupied_voxels(scene, 0.003, None, 1.0) == exact_voxels(scene.points, keep)
    assert occupied_voxels(scene, 0.0, None, 1.0) == int(keep.sum())  # no grid: every kept point stays

    big = volume(3 * VOXEL_SAMPLE, seed=2)  # the hash-sampled count
    estimate = occupied_voxels(ViewpointCloud(points=big, viewpoints=cam), 0.003)
    assert estimate == pytest.approx(exact_voxels(big), rel=0.02)


def test_a_volume_over_the_memory_budget_is_413_naming_the_cloud_before_any_detection(
        make_settings: Callable[..., Settings]) -> None:
    """Budget 420 MiB: a 200k-point surface (~380 MiB estimated) is detected; a 200k-point volume (its ~0.18M
    voxels: ~460 MiB) is 413 naming the cloud and what to send instead, at once and without a detection (one
    would teach the engine its seconds per unit)."""
    with TestClient(create_app(make_settings(detect_memory_mb=420))) as client:
        engine = client.app.state.service.engine  # type: ignore[attr-defined]
        learnt = engine.budget.unit_seconds
        t0 = time.monotonic()
        refused = post(client, volume())
        took = time.monotonic() - t0
        assert refused.status_code == 413, refused.text[:300]
        error = refused.json()
        assert error["field"] == "cloud" and "occupied 3 mm voxels" in error["error"], error
        assert "workspace" in error["error"] and took < 5.0
        assert engine.budget.unit_seconds == learnt  # no detection ran
        answered = post(client, surface())
        assert answered.status_code == 200, answered.text[:300]
        assert engine.budget.unit_seconds != learnt


def test_a_volume_that_would_outlast_twice_the_deadline_is_413_not_run(
        make_settings: Callable[..., Settings]) -> None:
    """Deadline 2 s (a started request is awaited up to 4 s), 0.4 s a work unit: the volume's ~14 units (~5.8 s)
    can never end in time, so it is 413 naming the cloud and how few voxels would do, at once (not a 504 after
    the deadline); the surface's ~3.6 units (~1.4 s) run to a 200."""
    with TestClient(create_app(make_settings(deadline_s=2.0))) as client:
        engine = client.app.state.service.engine  # type: ignore[attr-defined]
        engine.budget.unit_seconds = 0.4
        refused = post(client, volume())
        assert refused.status_code == 413, refused.text[:300]
        error = refused.json()["error"]
        assert refused.json()["field"] == "cloud" and "GRASPD_DEADLINE_S = 2 s" in error, error
        assert "occupied 3 mm voxels" in error
        assert engine.budget.unit_seconds == 0.4
        assert post(client, surface()).status_code == 200


def test_a_volume_over_the_deadline_runs_only_on_an_idle_server_and_teaches_its_cost(
        make_settings: Callable[..., Settings], small_body: Callable[..., dict[str, Any]],
        krylon: ViewpointCloud) -> None:
    """Deadline 3 s, 0.25 s a work unit (a stale estimate): the volume's ~3.6 s would outlast the deadline but
    not twice it.  While another request holds a worker it is 503 with Retry-After; on an idle server it runs as
    best effort, is answered, and what it took is learnt."""
    with TestClient(create_app(make_settings(deadline_s=3.0))) as client:
        engine = client.app.state.service.engine  # type: ignore[attr-defined]
        engine.budget.unit_seconds = 0.25
        release = threading.Event()
        held = _held_worker(engine, release, small_body(krylon, num_samples=20))
        try:
            busy = post(client, volume())
            assert busy.status_code == 503 and int(busy.headers["retry-after"]) >= 1, busy.text[:300]
            assert "runs only when nothing else runs or waits" in busy.json()["error"]
        finally:
            release.set()
        held.exception(timeout=30)
        time.sleep(0.2)
        answered = post(client, volume())
        assert answered.status_code == 200, answered.text[:300]
        assert engine.budget.unit_seconds != 0.25


def _held_worker(engine: Any, release: threading.Event, body: dict[str, Any]) -> Any:
    """Occupy one detect worker: a request whose parsing waits for `release` (a slow upload's decoding)."""
    taken = threading.Event()

    def parse() -> Any:
        taken.set()
        release.wait(30)
        return Parsed(parse_request(body))

    engine.admit()
    fut, _ = engine.enqueue(parse, {})
    assert taken.wait(10)  # the worker took it
    return fut


def test_queued_work_that_cannot_start_in_time_is_503_at_once_and_never_runs(
        make_settings: Callable[..., Settings], small_body: Callable[..., dict[str, Any]],
        krylon: ViewpointCloud) -> None:
    """One worker, deadline 2.5 s, the worker held, nothing timed yet (a request is expected to take the smallest
    detection's time, one unit: 1 s here).  A request queued behind the held one gets 503 with Retry-After as
    soon as it can no longer start and end within its deadline (~1.5 s) and is never parsed; one more arriving
    while that one waits is 503 at the door, at once (~2 s ahead of it, ~1 s its own)."""
    body = small_body(krylon, num_samples=20)
    with TestClient(create_app(make_settings(detect_workers=1, deadline_s=2.5))) as client:
        engine = client.app.state.service.engine  # type: ignore[attr-defined]
        engine.budget.unit_seconds = 1.0
        release = threading.Event()
        held = _held_worker(engine, release, body)
        parsed: list[bool] = []
        try:
            engine.admit()
            t0 = time.monotonic()
            queued, _ = engine.enqueue(lambda: (parsed.append(True), Parsed(parse_request(body)))[1], {})
            door = client.post("/detect", json=body)
            assert door.status_code == 503 and time.monotonic() - t0 < 1.0, door.text[:300]
            assert int(door.headers["retry-after"]) >= 1
            with pytest.raises(Problem) as late:
                queued.result(timeout=10)
            waited = time.monotonic() - t0
            assert late.value.status == 503 and late.value.retry_after is not None and late.value.retry_after >= 1
            assert 1.0 < waited < 2.5, waited  # before its deadline, not after it
        finally:
            release.set()
        held_answer = held.exception(timeout=30)  # parsed 2 s late: 503 (would not end in time) or an answer
        assert held_answer is None or getattr(held_answer, "status", None) == 503, held_answer
        time.sleep(0.2)
        assert not parsed and engine.pending == 0
        assert client.post("/detect", json=body).status_code == 200


def test_a_started_detection_is_answered_even_past_its_deadline(
        make_settings: Callable[..., Settings], small_body: Callable[..., dict[str, Any]],
        krylon: ViewpointCloud) -> None:
    """Deadline 2 s: a detection admitted in time, whose parsing (a slow upload's decoding) took it to 80 ms (at
    most a third of its own time) before its deadline while its estimate said it would still end in time (the
    learnt seconds per unit set tiny), ends past its deadline and is still answered with its grasps, on the
    blocking path (the streams) and the awaited one (HTTP), not 504 with the work thrown away."""
    body = small_body(krylon, num_samples=400)
    with TestClient(create_app(make_settings(detect_workers=1, deadline_s=2.0))) as client:
        state = client.app.state.service  # type: ignore[attr-defined]
        engine, life = state.engine, state.lifecycle
        life.detect_sync(lambda: Parsed(parse_request(body)), {})  # its kernels loaded
        t0 = time.monotonic()
        life.detect_sync(lambda: Parsed(parse_request(body)), {})  # its time known
        took = time.monotonic() - t0
        assert took < 1.0, took

        def late(t0: float) -> Callable[[], Parsed]:
            def parse() -> Parsed:
                time.sleep(max(0.0, t0 + 2.0 - min(0.08, took / 3) - time.monotonic()))
                engine.budget.unit_seconds = 1e-6  # expected to end in time
                return Parsed(parse_request(body))
            return parse

        t0 = time.monotonic()
        outcome = life.detect_sync(late(t0), {})
        assert time.monotonic() - t0 > 2.0 and len(outcome.result.grasps) > 0

        async def awaited() -> Outcome:
            life.admit()
            return await life.detect(late(time.monotonic()), {})

        t0 = time.monotonic()
        outcome = asyncio.run(awaited())
        assert time.monotonic() - t0 > 2.0 and "grasps" in json.loads(response_json(outcome))


def test_zenoh_refuses_the_volume_as_http_does(make_settings: Callable[..., Settings]) -> None:
    """The same engine behind Zenoh: the volume over the 420 MiB budget is 413 naming the cloud."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    settings = make_settings(zenoh_enabled=True, zenoh_listen=[endpoint], zenoh_stream=False, detect_memory_mb=420)
    with TestClient(create_app(settings)), ZenohGraspClient(connect=[endpoint], timeout=30, retries=0) as zc:
        with pytest.raises(RequestRejected) as info:
            zc.detect(volume(), np.zeros((1, 3)), num_samples=50)
        assert info.value.status == 413 and info.value.field == "cloud"
