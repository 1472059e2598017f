"""A capture file over Zenoh: the detect queryable takes the file bodies POST /detect takes (here the two PCL
captures as PCD, a flat NPY) with the same options as selector parameters, reads them with the same parser and
limits, and answers what the HTTP upload answers: the same points kept and dropped, the same grasps."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from fastapi.testclient import TestClient

from graspd.server.app import create_app
from graspd.server.settings import Settings
from graspd_client import RequestRejected
from graspd_client.zenoh_client import ZenohGraspClient
from server.transport_cases import agree, npy_bytes

from .conftest import free_port

CAPTURES = ["milk_cartoon_all_small_clorox.pcd", "table_scene_mug_stereo_textured.pcd"]
OPTIONS = {"num_samples": 30, "max_grasps": 5, "seed": 1}


@pytest.fixture(scope="module")
def served(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[TestClient, ZenohGraspClient]]:
    tmp = tmp_path_factory.mktemp("zenoh-files")
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    settings = Settings(zenoh_enabled=True, zenoh_listen=[endpoint], zenoh_stream=False, models_dir=tmp / "none",
                        data_dir=tmp / "data", detect_workers=2, deadline_s=300.0, allow_unscored=True, warmup=False)
    with TestClient(create_app(settings)) as http, ZenohGraspClient(connect=[endpoint], timeout=120,
                                                                     retries=0) as zc:
        yield http, zc


def selector(options: dict[str, Any]) -> str:
    """graspd/detect with options as selector parameters (a repeated one's values joined by '|')."""
    return "graspd/detect?" + ";".join(f"{k}={'|'.join(map(str, v)) if isinstance(v, list) else v}"
                                       for k, v in options.items())


def _http_upload(http: TestClient, data: bytes, content_type: str, params: dict[str, Any]) -> dict[str, Any]:
    r = http.post("/detect", params=params, content=data, headers={"content-type": content_type})
    assert r.status_code == 200, r.text
    answer: dict[str, Any] = r.json()
    return answer


@pytest.mark.parametrize("name", CAPTURES)
def test_a_pcl_capture_over_zenoh_is_the_http_uploads_answer(served: tuple[TestClient, ZenohGraspClient],
                                                             real_data: Path, name: str) -> None:
    http, zc = served
    data = (real_data / name).read_bytes()
    over_http = _http_upload(http, data, "application/x-pcd", OPTIONS)
    assert len(over_http["grasps"]) > 0
    assert over_http["num_points_dropped"] > 0  # an organised capture's pixels without depth: counted, not warned of
    assert all(w["code"] != "non_finite_dropped" for w in over_http["warnings"])
    agree(zc.query(data, selector(OPTIONS)), over_http, f"{name} over zenoh (type told by its first bytes)")
    agree(zc.query(data, selector({**OPTIONS, "content_type": "application/x-pcd"})), over_http,
          f"{name} over zenoh (content_type)")


def test_an_npy_with_viewpoints_over_zenoh_is_the_http_uploads_answer(
        served: tuple[TestClient, ZenohGraspClient], real_data: Path) -> None:
    http, zc = served
    points = np.random.default_rng(0).normal([0.0, 0.0, 0.6], 0.03, (3000, 3)).astype(np.float32)
    options = {**OPTIONS, "viewpoint": ["0,0,0", "0.2,0,0"]}
    over_http = http.post("/detect", params=[*((k, str(v)) for k, v in OPTIONS.items()),
                                             ("viewpoint", "0,0,0"), ("viewpoint", "0.2,0,0")],
                          content=npy_bytes(points), headers={"content-type": "application/x-npy"})
    assert over_http.status_code == 200, over_http.text
    agree(zc.query(npy_bytes(points), selector(options)), over_http.json(), "npy over zenoh, two viewpoints")


@pytest.mark.parametrize(("options", "payload", "field"), [
    ({"num_samples": 0}, None, "num_samples"),  # an option checked as over HTTP
    ({"no_such_option": 1}, None, "no_such_option"),  # an option HTTP does not know either
    ({}, b"FIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH 2\nHEIGHT 1\nPOINTS 2\nDATA ascii\n1 2\n",
     "cloud.points"),  # a file lying about its points
])
def test_a_bad_file_or_option_over_zenoh_is_refused_as_over_http(
        served: tuple[TestClient, ZenohGraspClient], real_data: Path, options: dict[str, Any],
        payload: bytes | None, field: str) -> None:
    http, zc = served
    data = payload if payload is not None else (real_data / CAPTURES[0]).read_bytes()
    r = http.post("/detect", params=options, content=data, headers={"content-type": "application/x-pcd"})
    assert 400 <= r.status_code < 500 and r.json()["field"] == field, r.text
    with pytest.raises(RequestRejected) as err:
        zc.query(data, selector(options))
    assert (err.value.status, err.value.field) == (r.status_code, field)


def test_the_zenoh_clients_detect_file_is_the_http_clients(served: tuple[TestClient, ZenohGraspClient],
                                                           real_data: Path) -> None:
    """ZenohGraspClient.detect_file sends a capture file (by its path) and its options as selector parameters, as
    GraspClient.detect_file sends them over HTTP: the same grasps."""
    http, zc = served
    path = real_data / "table_scene_mug_stereo_textured.pcd"
    over_http = _http_upload(http, path.read_bytes(), "application/x-pcd", OPTIONS)
    got = zc.detect_file(path, **OPTIONS)
    assert len(got) == len(over_http["grasps"]) > 0
    assert np.allclose(got.positions, [g["position"] for g in over_http["grasps"]], atol=1e-6)
