"""Degenerate geometry a caller may send (all points equal, all at the camera, on a line, in a plane, metres
apart, millions of zeros) gets a 200 with warnings or a 422 naming the field: never a 500.  A property-based
run draws clouds from such pieces and checks the same over HTTP."""

from __future__ import annotations

import io
from typing import Any

import numpy as np
import pytest
from fastapi.testclient import TestClient
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

RNG = np.random.default_rng(0)
CASES: dict[str, np.ndarray] = {
    "every point at the viewpoint": np.zeros((200, 3)),
    "every point equal": np.tile([0.1, 0.2, 0.5], (200, 1)),
    "collinear": np.c_[np.linspace(0, 0.2, 300), np.zeros(300), np.full(300, 0.5)],
    "planar, facing the camera": np.c_[RNG.uniform(-0.2, 0.2, (3000, 2)), np.full(3000, 0.5)],
    "planar, through the camera": np.c_[RNG.uniform(-0.2, 0.2, (3000, 2)), np.zeros(3000)],
    "a micrometre cube": RNG.uniform(0, 1e-6, (500, 3)) + [0, 0, 0.5],
    "spread over 20 km": RNG.uniform(-1e4, 1e4, (500, 3)),
}


def _answered(response: Any) -> dict[str, Any]:
    """The JSON of a 200, or of a 422 that names its field; anything else fails the test."""
    assert response.status_code in (200, 422), (response.status_code, response.text[:300])
    body = response.json()
    if response.status_code == 422:
        assert body["field"], body
    return dict(body)


@pytest.mark.parametrize("name", list(CASES))
def test_degenerate_clouds_get_an_answer_not_a_server_error(client: TestClient, name: str) -> None:
    body = _answered(client.post("/detect", json={"cloud": {"points": CASES[name].tolist()}, "num_samples": 60}))
    if "grasps" in body:
        assert body["grasps"] == [] or name == "collinear", name  # only a wire-like line can hold a hand
        assert body["warnings"], f"{name}: no grasps and no warning saying why"


def test_a_cloud_entirely_at_the_camera_is_warned_about(client: TestClient) -> None:
    body = _answered(client.post("/detect", json={"cloud": {"points": CASES["every point at the viewpoint"].tolist()},
                                                  "num_samples": 60}))
    assert {w["code"] for w in body["warnings"]} >= {"viewpoint_flipped"}


def test_five_million_zeros_in_an_npy_get_an_answer(client: TestClient) -> None:
    buf = io.BytesIO()
    np.save(buf, np.zeros((5_000_000, 3), np.float32))
    body = _answered(client.post("/detect?num_samples=60", content=buf.getvalue(),
                                 headers={"content-type": "application/x-npy"}))
    assert body["grasps"] == [] and body["warnings"]


def _piece(kind: str, n: int, centre: list[float], scale: float, seed: int) -> np.ndarray:
    """n points of one degenerate kind around centre (m) at scale (m)."""
    rng = np.random.default_rng(seed)
    c = np.asarray(centre)
    if kind == "point":
        return np.tile(c, (n, 1))
    if kind == "line":
        return c + np.outer(rng.uniform(-1, 1, n) * scale, rng.normal(size=3))
    if kind == "plane":
        u, v = np.linalg.qr(rng.normal(size=(3, 2)))[0].T
        return c + np.outer(rng.uniform(-1, 1, n) * scale, u) + np.outer(rng.uniform(-1, 1, n) * scale, v)
    return c + rng.normal(size=(n, 3)) * scale  # "blob"


coordinate = st.floats(-3.0, 3.0, allow_nan=False)
pieces = st.lists(st.tuples(st.sampled_from(["point", "line", "plane", "blob"]), st.integers(1, 400),
                            st.lists(coordinate, min_size=3, max_size=3),
                            st.sampled_from([0.0, 1e-7, 1e-3, 0.05, 0.5, 20.0]), st.integers(0, 2**16)),
                  min_size=1, max_size=4)
viewpoints = st.lists(st.lists(coordinate, min_size=3, max_size=3), min_size=1, max_size=3)


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(pieces=pieces, viewpoints=viewpoints, at_camera=st.booleans())
def test_fuzzed_geometry_never_gets_a_server_error(client: TestClient, pieces: list[Any],
                                                   viewpoints: list[list[float]], at_camera: bool) -> None:
    points = np.vstack([_piece(*p) for p in pieces])
    if at_camera:  # some points exactly at the first camera
        points[: max(1, len(points) // 3)] = viewpoints[0]
    _answered(client.post("/detect", json={"cloud": {"points": points.tolist(), "viewpoints": viewpoints},
                                           "num_samples": 40}))
