"""What the environment stage found travels in every /detect answer (surfaces with kinds, planes and confidence),
and the unseen-space and flat-objects options are request options like the others: checked, honoured, and the
unseen-space one the same over uploads."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
from fastapi.testclient import TestClient

from box_scene import pose_from, render_boxes, table_box
from graspd.core.camera import tabletop_cameras
from graspd.io.cloud_files import read_cloud
from graspd_client import build_detect_request

MUG = "table_mug.pcd"


def _mug_body(real_data: Path, **options: Any) -> dict[str, Any]:
    cloud = read_cloud(real_data / MUG, viewpoints=np.zeros((1, 3), np.float32))
    return build_detect_request(cloud.points, cloud.viewpoints, num_samples=150, use_classifier=False, **options)


def test_the_answer_reports_each_surface_found(client: TestClient, real_data: Path) -> None:
    out = client.post("/detect", json=_mug_body(real_data)).json()
    env = out["environment"]
    kinds = [s["kind"] for s in env["surfaces"]]
    assert kinds[0] == "support" and env["support"] == env["surfaces"][0]["plane"]
    table = env["surfaces"][0]
    assert table["box"] is None and min(table["extent"]) > 0.15 and table["num_points"] > 1000
    assert 0.0 <= env["confidence"] <= 1.0 and table["confidence"] > 0.5
    assert not [w for w in out["warnings"] if w["code"] in ("no_support", "environment_unsure")]


def test_unknown_space_is_checked_and_honoured(client: TestClient, real_data: Path,
                                               small_body: Callable[..., dict[str, Any]]) -> None:
    bad = client.post("/detect", json=_mug_body(real_data, unknown_space="ignore"))
    assert bad.status_code == 422 and "unknown_space" in bad.json()["field"]
    safe = client.post("/detect", json=_mug_body(real_data)).json()
    loose = client.post("/detect", json=_mug_body(real_data, unknown_space="allow")).json()
    assert safe["num_candidates"] < loose["num_candidates"]
    assert all(g["ranking"]["unknown"] == 1.0 for g in safe["grasps"])  # nothing of a safe hand is unseen
    assert any(w["code"] == "unknown_space" for w in loose["warnings"])
    assert not any(w["code"] == "unknown_space" for w in safe["warnings"])
    # hands keep out of unseen space here, so "fallback" (hands entering it least when none keeps out) answers alike
    fallback = client.post("/detect", json=_mug_body(real_data, unknown_space="fallback")).json()
    def poses(answer: dict[str, Any]) -> list[Any]:
        return [g["pose"] for g in answer["grasps"]]

    assert poses(fallback) == poses(safe) and fallback["warnings"] == safe["warnings"]
    upload = client.post("/detect?num_samples=150&use_classifier=false&viewpoint=0,0,0&unknown_space=allow",
                         content=(real_data / MUG).read_bytes(), headers={"Content-Type": "application/octet-stream"})
    assert upload.status_code == 200, upload.text
    assert upload.json()["num_candidates"] == loose["num_candidates"]


def test_flat_objects_is_a_request_option_like_the_others(client: TestClient) -> None:
    """A packet 1 cm thick lying flat has no hand by default; with flat_objects it is grasped by its edges, over a
    JSON body, and a wrong type is a 422 naming the field."""
    packet = ((0.045, 0.07, 0.01), pose_from(np.eye(3), (0.0, 0.0, 0.005)))  # 4.5 x 7 cm, 1 cm thick
    eyes = np.array([c.position for c in tabletop_cameras(2, distance=0.7, elevation_deg=50.0, azimuth_deg=-90.0)])
    cloud = render_boxes([table_box(0.3), packet], eyes, (0.0, 0.0, 0.0), width=320, height=240, noise=0.001)
    options = {"num_samples": 300, "use_classifier": False}
    body = build_detect_request(cloud.points, cloud.viewpoints, camera_source=cloud.camera_source, **options)
    plain = client.post("/detect", json=body)
    flat = client.post("/detect", json={**body, "flat_objects": True})
    assert plain.status_code == flat.status_code == 200, plain.text
    assert plain.json()["grasps"] == [] and len(flat.json()["grasps"]) >= 5
    assert {w["code"] for w in flat.json()["warnings"]}.isdisjoint({"no_candidates", "no_grasps"})
    bad = client.post("/detect", json={**body, "flat_objects": "sometimes"})
    assert bad.status_code == 422 and "flat_objects" in bad.json()["field"]
