"""The same requests give the same answers on every transport, and the answers saved before the transports were
reshaped (tests/server/data/transport_cases/): JSON /detect with a few option mixes (crops included) and the
templates method, a file upload over HTTP and over Zenoh, Zenoh queries; the ROS 2 service's case is in
ros2/test_ros2_transport_cases.py.  Floats agree to 1e-6 relative; request ids, grasp ids and timings are left
out."""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from fastapi.testclient import TestClient

from graspd.server.app import create_app
from graspd.server.settings import Settings
from graspd_client import build_demonstration_request, build_detect_request
from graspd_client.zenoh_client import ZenohGraspClient
from server.transport_cases import (
    SMALL,
    agree,
    check,
    json_body,
    mug_points,
    mug_top_grasp,
    npy_bytes,
    options_case,
)

from .conftest import free_port


@pytest.fixture(scope="module")
def served(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[TestClient, ZenohGraspClient]]:
    """One server with Zenoh on loopback (unscored, 2 workers) and a Zenoh client of it."""
    tmp = tmp_path_factory.mktemp("cases")
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    settings = Settings(zenoh_enabled=True, zenoh_listen=[endpoint], zenoh_instance="cases",
                        models_dir=tmp / "no-models", data_dir=tmp / "data", detect_workers=2, deadline_s=300.0,
                        queue_size=8, allow_unscored=True, warmup=False)
    with TestClient(create_app(settings)) as http, ZenohGraspClient(connect=[endpoint], timeout=60) as zc:
        yield http, zc


@pytest.fixture(scope="module")
def mug(real_data: Path) -> np.ndarray:
    return mug_points(real_data)


def _http(http: TestClient, body: dict[str, Any]) -> dict[str, Any]:
    r = http.post("/detect", json=body)
    assert r.status_code == 200, r.text
    answer: dict[str, Any] = r.json()
    return answer


def test_json_detect_small_is_the_saved_answer_on_http_zenoh_and_uploads(
        served: tuple[TestClient, ZenohGraspClient], mug: np.ndarray) -> None:
    http, zc = served
    body = json_body(mug, **SMALL)
    reference = _http(http, body)
    assert len(reference["grasps"]) > 0
    check("json_small", reference)
    agree(zc.query(json.dumps(body).encode()), reference, "zenoh query")
    upload = http.post("/detect", params={**SMALL, "viewpoint": "0,0,0"}, content=npy_bytes(mug),
                       headers={"content-type": "application/x-npy"})
    assert upload.status_code == 200, upload.text
    agree(upload.json(), reference, "http npy upload")
    selector = "graspd/detect?" + ";".join(f"{k}={v}" for k, v in {**SMALL, "viewpoint": "0,0,0"}.items())
    agree(zc.query(npy_bytes(mug), selector), reference, "zenoh npy upload")


def test_json_detect_with_options_and_crops_is_the_saved_answer_on_http_and_zenoh(
        served: tuple[TestClient, ZenohGraspClient], mug: np.ndarray) -> None:
    http, zc = served
    body = json_body(mug, **options_case(mug))
    reference = _http(http, body)
    assert len(reference["grasps"]) > 0 and all("crop" in g for g in reference["grasps"])
    check("json_options_crops", reference)
    agree(zc.query(json.dumps(body).encode()), reference, "zenoh query")


def test_templates_detect_is_the_saved_answer_on_http_and_zenoh(
        served: tuple[TestClient, ZenohGraspClient], mug: np.ndarray) -> None:
    http, zc = served
    taught = http.post("/demonstrations", json=build_demonstration_request(mug, mug_top_grasp(mug), [[0.0, 0.0, 0.0]],
                                                                            label="mug top"))
    assert taught.status_code == 200, taught.text
    body = build_detect_request(mug, [[0.0, 0.0, 0.0]], method="templates", max_grasps=5)
    reference = _http(http, body)
    assert reference["method"] == "templates" and len(reference["grasps"]) > 0
    check("templates", reference)
    agree(zc.query(json.dumps(body).encode()), reference, "zenoh query")
