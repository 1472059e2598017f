"""POST /detect over HTTP: JSON body and raw PCD/PLY uploads give grasps in the wire convention."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import open3d as o3d
from fastapi.testclient import TestClient
from scipy.spatial import cKDTree

from graspd.core.cloud import ViewpointCloud
from graspd_client import Grasps


def test_json_detect_unscored(client: TestClient, body: dict[str, Any], check_convention: Callable) -> None:
    r = client.post("/detect", json=body)
    assert r.status_code == 200, r.text
    out = r.json()
    assert out["model"] is None and out["scored"] is False
    assert 0 < len(out["grasps"]) <= 100
    assert all(g["score"] is None for g in out["grasps"])
    ids = [g["id"] for g in out["grasps"]]
    assert len(set(ids)) == len(ids) and all(i.startswith(out["request_id"]) for i in ids)
    assert {"decode", "queue", "preprocess", "scene", "sample", "select", "total"} <= set(out["timings"])
    assert out["num_candidates"] >= len(out["grasps"]) and out["num_points"] > 1000
    check_convention(out["grasps"])
    g = Grasps.from_response(out)
    assert g.poses.shape == (len(ids), 4, 4) and np.isnan(g.scores).all()
    assert np.allclose(g.rotations[:, :, 0], g.approach)


def test_ids_unique_across_requests(client: TestClient, body: dict[str, Any]) -> None:
    a = client.post("/detect", json=body).json()
    b = client.post("/detect", json=body).json()
    assert not {g["id"] for g in a["grasps"]} & {g["id"] for g in b["grasps"]}
    assert [g["position"] for g in a["grasps"]] == [g["position"] for g in b["grasps"]]  # same seed


def test_pcd_upload_matches_json(client: TestClient, krylon_path: Path, krylon: ViewpointCloud,
                                 small_body: Callable) -> None:
    data = krylon_path.read_bytes()
    raw = client.post("/detect?num_samples=60&viewpoint=0.5,0,0.3", content=data,
                      headers={"Content-Type": "application/octet-stream"})
    assert raw.status_code == 200, raw.text
    js = client.post("/detect", json=small_body(krylon)).json()
    assert [g["position"] for g in raw.json()["grasps"]] == [g["position"] for g in js["grasps"]]
    # curl --data-binary sends application/x-www-form-urlencoded unless told otherwise: sniffed as PCD
    curl = client.post("/detect?num_samples=60&viewpoint=0.5,0,0.3", content=data,
                       headers={"Content-Type": "application/x-www-form-urlencoded"})
    assert curl.status_code == 200 and len(curl.json()["grasps"]) == len(js["grasps"])


def test_ply_upload(client: TestClient, krylon: ViewpointCloud, tmp_path: Path) -> None:
    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(krylon.points.astype(np.float64)))
    path = tmp_path / "krylon.ply"
    o3d.io.write_point_cloud(str(path), pcd)
    r = client.post("/detect?num_samples=60&viewpoint=0.5,0,0.3", content=path.read_bytes(),
                    headers={"Content-Type": "application/ply"})
    assert r.status_code == 200, r.text
    body = r.json()
    as_json = client.post("/detect", json={"cloud": {"points": krylon.points.tolist(), "viewpoints": [[0.5, 0, 0.3]]},
                                           "num_samples": 60}).json()
    assert body["num_points"] == as_json["num_points"]  # the PLY's points are the cloud's, none lost or invented
    samples = np.array([g["sample"] for g in body["grasps"]])
    assert len(samples) > 0 and cKDTree(krylon.points).query(samples)[0].max() < 0.005  # sampled on the can


def test_options_are_honoured(client: TestClient, krylon: ViewpointCloud, small_body: Callable) -> None:
    r = client.post("/detect", json=small_body(krylon, hand="panda", max_grasps=3)).json()
    assert len(r["grasps"]) <= 3 and r["hand"]["hand_depth"] == 0.045
    r = client.post("/detect", json=small_body(krylon, hand={"preset": "panda", "hand_depth": 0.05})).json()
    assert r["hand"]["hand_depth"] == 0.05 and r["hand"]["hand_outer_diameter"] == 0.10
    lo, hi = krylon.points.min(0), krylon.points.max(0)
    mid = (lo + hi) / 2
    ws = [float(lo[0]), float(mid[0]), float(lo[1]), float(hi[1]), float(lo[2]), float(hi[2])]
    r = client.post("/detect", json=small_body(krylon, workspace=ws)).json()
    pos = np.array([g["position"] for g in r["grasps"]]).reshape(-1, 3)
    assert len(pos) and (pos[:, 0] <= mid[0] + 1e-6).all()
    direction = np.array([0.0, 0.0, 1.0])
    r = client.post("/detect", json=small_body(krylon, approach_direction=direction,
                                               approach_max_angle_deg=60)).json()
    app = np.array([g["approach"] for g in r["grasps"]]).reshape(-1, 3)
    assert (app @ direction >= np.cos(np.radians(60)) - 1e-9).all()
    r = client.post("/detect", json=small_body(krylon, selection=False, max_grasps=1000)).json()
    assert len(r["grasps"]) == r["num_candidates"]


def test_health_models_metrics(client: TestClient, body: dict[str, Any]) -> None:
    assert client.get("/healthz").json() == {"status": "ok"}
    ready = client.get("/readyz")
    assert ready.status_code == 200 and ready.json()["scoring"] is False and ready.json()["provider"] is None
    assert client.get("/models").json() == {"default": None, "cascade": None, "models": [], "jobs": []}
    client.post("/detect", json=body)
    client.post("/detect", json={"cloud": {"points": [[0, 0]]}})
    text = client.get("/metrics").text
    assert 'graspd_requests_total{outcome="ok",transport="http"} 1.0' in text
    assert 'graspd_requests_total{outcome="invalid",transport="http"} 1.0' in text
    assert 'graspd_stage_seconds_count{stage="sample"} 1.0' in text
    assert "graspd_candidates_count 1.0" in text and "graspd_queue_depth" in text
