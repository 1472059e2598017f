"""Warnings instead of silence, the same on every transport: table_mug.pcd sent with its
camera at 0,0,0 warns of nothing; sent with the camera behind it (0,0,3) it warns viewpoint_flipped, with the
same codes and sentences over HTTP JSON, a PCD upload and Zenoh."""

from __future__ import annotations

import json
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from fastapi.testclient import TestClient

from graspd.cli.main import main as cli_main
from graspd.io.cloud_files import read_cloud
from graspd.server.app import create_app
from graspd.server.runner import free_port
from graspd.server.settings import Settings
from graspd_client import Grasps, build_detect_request
from graspd_client.zenoh_client import ZenohGraspClient

SAMPLES = 100


@pytest.fixture(scope="module")
def mug_path(real_data: Path) -> Path:
    return real_data / "table_mug.pcd"


@pytest.fixture
def server(make_settings: Callable[..., Settings], models_and_default: tuple[Path, str]
           ) -> Iterator[tuple[TestClient, str]]:
    """A scored app (the shipped models) with its Zenoh node listening on a free local port."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    settings = make_settings(zenoh_enabled=True, zenoh_listen=[endpoint], zenoh_instance="warn",
                             models_dir=models_and_default[0])
    with TestClient(create_app(settings)) as c:
        yield c, endpoint


def _three_ways(server: tuple[TestClient, str], mug_path: Path, viewpoint: tuple[float, float, float]
                ) -> list[list[dict[str, Any]]]:
    """The warnings of the same request over HTTP JSON, a PCD upload and a Zenoh query."""
    http, endpoint = server
    cloud = read_cloud(mug_path)
    body = build_detect_request(cloud.points, np.array([viewpoint], np.float32), num_samples=SAMPLES)
    by_json = http.post("/detect", json=body)
    assert by_json.status_code == 200, by_json.text
    query = {"viewpoint": ",".join(f"{c:g}" for c in viewpoint), "num_samples": str(SAMPLES)}
    by_upload = http.post("/detect", content=mug_path.read_bytes(), params=query,
                          headers={"Content-Type": "application/octet-stream"})
    assert by_upload.status_code == 200, by_upload.text
    with ZenohGraspClient(connect=[endpoint], timeout=60) as zc:
        by_zenoh = zc.query(json.dumps(body).encode())
    return [by_json.json()["warnings"], by_upload.json()["warnings"], by_zenoh["warnings"]]


def test_a_correct_request_warns_of_nothing(server: tuple[TestClient, str], mug_path: Path) -> None:
    assert _three_ways(server, mug_path, (0.0, 0.0, 0.0)) == [[], [], []]


def test_a_camera_behind_the_cloud_warns_the_same_everywhere(server: tuple[TestClient, str],
                                                               mug_path: Path) -> None:
    by_json, by_upload, by_zenoh = _three_ways(server, mug_path, (0.0, 0.0, 3.0))
    assert by_json == by_upload == by_zenoh
    assert Grasps.from_response({"grasps": [], "warnings": by_json}).warnings == by_json  # the client keeps them
    codes = [w["code"] for w in by_json]
    assert codes[0] == "viewpoint_flipped" and len(set(codes)) == len(codes)
    assert "(0, 0, 3)" in by_json[0]["message"]


def test_the_cli_warns_as_the_service_does(server: tuple[TestClient, str], mug_path: Path, tmp_path: Path,
                                           models_and_default: tuple[Path, str],
                                           capsys: pytest.CaptureFixture[str]) -> None:
    by_json = _three_ways(server, mug_path, (0.0, 0.0, 3.0))[0]
    out = tmp_path / "g.json"
    assert cli_main(["detect", str(mug_path), "--viewpoint", "0", "0", "3", "--samples", str(SAMPLES),
                     "--models-dir", str(models_and_default[0]), "--out", str(out)]) == 0
    answer = json.loads(out.read_text())
    assert answer["warnings"] == by_json
    assert f"warning viewpoint_flipped: {by_json[0]['message']}" in capsys.readouterr().err


def test_an_empty_workspace_says_so(server: tuple[TestClient, str], mug_path: Path) -> None:
    http, _ = server
    cloud = read_cloud(mug_path)
    body = build_detect_request(cloud.points, cloud.viewpoints, num_samples=SAMPLES, workspace=[5, 6, 5, 6, 5, 6])
    out = http.post("/detect", json=body).json()
    assert out["grasps"] == []
    assert [w["code"] for w in out["warnings"]] == ["few_points", "no_candidates"]
    assert "preprocess stage" in out["warnings"][1]["message"]


def test_a_model_for_another_hand_warns(server: tuple[TestClient, str], mug_path: Path,
                                        models_and_default: tuple[Path, str]) -> None:
    http, _ = server
    cloud = read_cloud(mug_path)
    wide = {"finger_width": 0.01, "hand_outer_diameter": 0.14, "hand_depth": 0.06, "hand_height": 0.02}
    body = build_detect_request(cloud.points, cloud.viewpoints, num_samples=SAMPLES, hand=wide,
                                model=models_and_default[1])
    out = http.post("/detect", json=body).json()
    assert out["model_fits_hand"] is False
    assert "model_hand_mismatch" in [w["code"] for w in out["warnings"]]
