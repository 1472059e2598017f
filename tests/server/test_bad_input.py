"""Bad input gets a 4xx naming the field, and the server keeps serving afterwards."""

from __future__ import annotations

import base64
import json
from collections.abc import Callable
from typing import Any

import numpy as np
import pytest
from fastapi.testclient import TestClient
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from graspd.server.app import create_app
from graspd.server.requests import parse_request
from graspd.server.settings import Settings
from graspd_client import encode_array

EYE = np.eye(4).tolist()
INTR = {"fx": 500.0, "fy": 500.0, "cx": 320.0, "cy": 240.0}
P = [[0.0, 0.0, 0.5], [0.01, 0.0, 0.5], [0.0, 0.01, 0.5]]


def pts(a: Any) -> dict[str, Any]:
    return {"cloud": {"points": a}}


BAD: list[tuple[str, Any, int, str]] = [
    ("nan point", pts([[np.nan, 0, 0]]) , 422, "cloud.points"),
    ("inf point", pts(encode_array(np.array([[np.inf, 0, 0]], np.float32))), 422, "cloud.points"),
    ("empty cloud list", pts([]), 422, "cloud.points"),
    ("empty cloud array", pts(encode_array(np.zeros((0, 3), np.float32))), 422, "cloud.points"),
    ("wrong shape", pts(encode_array(np.zeros((10, 2), np.float32))), 422, "cloud.points"),
    ("wrong dtype", pts({"dtype": "complex64", "shape": [1, 3], "data": ""}), 422, "cloud.points.dtype"),
    ("strings", pts([["a", "b", "c"]]), 422, "cloud.points"),
    ("truncated base64", pts({"dtype": "float32", "shape": [2, 3],
                              "data": base64.b64encode(bytes(24)).decode()[:-6]}), 422, "cloud.points.data"),
    ("short data", pts({"dtype": "float32", "shape": [2, 3], "data": base64.b64encode(bytes(20)).decode()}),
     422, "cloud.points.data"),
    ("camera_source out of range", {"cloud": {"points": P, "camera_source": [0, 1, 0]}}, 422,
     "cloud.camera_source"),
    ("camera_source negative", {"cloud": {"points": P, "camera_source": [0, -1, 0]}}, 422, "cloud.camera_source"),
    ("camera_source wrong length", {"cloud": {"points": P, "camera_source": [0, 0]}}, 422, "cloud.camera_source"),
    ("camera_source fractional", {"cloud": {"points": P, "camera_source": [0, 0.5, 0]}}, 422,
     "cloud.camera_source"),
    ("viewpoint nan", {"cloud": {"points": P, "viewpoints": [[0, np.nan, 0]]}}, 422, "cloud.viewpoints"),
    ("no viewpoints", {"cloud": {"points": P, "viewpoints": []}}, 422, "cloud.viewpoints"),
    ("huge coordinates", pts([[1e9, 0, 0]]), 422, "cloud.points"),
    ("unknown model", {"cloud": {"points": P}, "model": "nope"}, 422, "model"),
    ("unknown preset", {"cloud": {"points": P}, "hand": "nope"}, 422, "hand.preset"),
    ("impossible hand", {"cloud": {"points": P}, "hand": {"finger_width": 0.07}}, 422, "hand"),
    ("negative hand", {"cloud": {"points": P}, "hand": {"hand_depth": -1}}, 422, "hand.hand_depth"),
    ("num_samples 1e9", {"cloud": {"points": P}, "num_samples": 10**9}, 422, "num_samples"),
    ("num_samples 0", {"cloud": {"points": P}, "num_samples": 0}, 422, "num_samples"),
    ("num_samples beyond 64 bits", {"cloud": {"points": P}, "num_samples": 10**30}, 422, "num_samples"),
    ("excess base64 padding", pts({"dtype": "float32", "shape": [1, 3],
                                   "data": base64.b64encode(bytes(12)).decode() + "=="}), 422, "cloud.points.data"),
    ("max_grasps negative", {"cloud": {"points": P}, "max_grasps": -1}, 422, "max_grasps"),
    ("robust_copies 17", {"cloud": {"points": P}, "robust_copies": 17}, 422, "robust_copies"),
    ("robust_copies negative", {"cloud": {"points": P}, "robust_copies": -1}, 422, "robust_copies"),
    ("workspace length", {"cloud": {"points": P}, "workspace": [0, 1, 0, 1]}, 422, "workspace"),
    ("workspace inverted", {"cloud": {"points": P}, "workspace": [1, 0, 0, 1, 0, 1]}, 422, "workspace"),
    ("approach zero", {"cloud": {"points": P}, "approach": {"direction": [0, 0, 0]}}, 422, "approach.direction"),
    ("approach angle", {"cloud": {"points": P}, "approach": {"direction": [0, 0, 1], "max_angle_deg": 400}},
     422, "approach.max_angle_deg"),
    ("unknown field", {"cloud": {"points": P}, "num_sample": 5}, 422, "num_sample"),
    ("missing cloud", {"points": P}, 422, "cloud"),
    ("crops without image", {"cloud": {"points": P}, "crops": {"intrinsics": INTR, "camera_pose": EYE}}, 422,
     "crops"),
    ("crops bad png", {"cloud": {"points": P}, "crops": {"image_png": "iVBORw0KGgoAAAA=", "intrinsics": INTR,
                                                          "camera_pose": EYE}}, 422, "crops.image_png"),
    ("crops not png", {"cloud": {"points": P}, "crops": {"image_png": base64.b64encode(b"GIF89a").decode(),
                                                          "intrinsics": INTR, "camera_pose": EYE}}, 422,
     "crops.image_png"),
    ("crops bad pose", {"cloud": {"points": P}, "crops": {"image": encode_array(np.zeros((4, 4, 3), np.uint8)),
                                                           "intrinsics": INTR, "camera_pose": [[2, 0, 0, 0]] * 4}},
     422, "crops.camera_pose"),
    ("crops grey image", {"cloud": {"points": P}, "crops": {"image": encode_array(np.zeros((4, 4), np.uint8)),
                                                             "intrinsics": INTR, "camera_pose": EYE}},
     422, "crops.image"),
    ("crops negative fx", {"cloud": {"points": P}, "crops": {"image": encode_array(np.zeros((4, 4, 3), np.uint8)),
                                                              "intrinsics": {**INTR, "fx": -1}, "camera_pose": EYE}},
     422, "crops.intrinsics.fx"),
    ("crop size", {"cloud": {"points": P}, "crops": {"image": encode_array(np.zeros((4, 4, 3), np.uint8)),
                                                      "intrinsics": INTR, "camera_pose": EYE, "size": 10**6}},
     422, "crops.size"),
    ("not an object", [1, 2, 3], 422, "body"),
]


@pytest.mark.parametrize(("name", "payload", "status", "field"), BAD, ids=[b[0] for b in BAD])
def test_bad_json_names_the_field(client: TestClient, name: str, payload: Any, status: int, field: str) -> None:
    r = client.post("/detect", content=json.dumps(payload), headers={"Content-Type": "application/json"})
    assert r.status_code == status, r.text
    body = r.json()
    assert body["field"] == field, body
    assert body["error"].startswith(field)


def test_server_keeps_serving_after_bad_input(client: TestClient, body: dict[str, Any]) -> None:
    for name, payload, status, _ in BAD[:8]:
        bad = client.post("/detect", content=json.dumps(payload), headers={"Content-Type": "application/json"})
        assert bad.status_code == status, name
    good = client.post("/detect", json=body)
    assert good.status_code == 200
    assert good.json()["grasps"], "the server still detects after the bad requests"


@pytest.mark.parametrize(
    ("content", "ctype", "query", "status", "field"),
    [
        (b"{not json", "application/json", "", 400, "body"),
        (b"\x00\x01garbage", "application/octet-stream", "", 415, "body"),
        (b"# .PCD v0.7\nFIELDS x y\nSIZE 4 4\nTYPE F F\nCOUNT 1 1\nWIDTH 1\nHEIGHT 1\nPOINTS 1\nDATA ascii\n1 2\n",
         "application/octet-stream", "", 422, "body"),
        (b"# .PCD v0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH 1\nHEIGHT 1\nPOINTS 1\n"
         b"DATA ascii\n0 0 1\n", "application/octet-stream", "viewpoint=1,2", 422, "viewpoint"),
        (b"# .PCD v0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH 1\nHEIGHT 1\nPOINTS 1\n"
         b"DATA ascii\n0 0 1\n", "application/octet-stream", "num_samples=1000000000", 422, "num_samples"),
        (b"# .PCD v0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH 1\nHEIGHT 1\nPOINTS 1\n"
         b"DATA ascii\n0 0 1\n", "application/octet-stream", "bogus=1", 422, "bogus"),
        (b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nend_header\n1\n", "application/ply",
         "", 422, "cloud.points"),
    ],
)
def test_bad_uploads(client: TestClient, content: bytes, ctype: str, query: str, status: int, field: str) -> None:
    r = client.post(f"/detect?{query}", content=content, headers={"Content-Type": ctype})
    assert r.status_code == status, r.text
    assert r.json()["field"] == field


def test_oversized_payload_is_413(make_settings: Callable[..., Settings], body: dict[str, Any]) -> None:
    with TestClient(create_app(make_settings(max_body_bytes=10_000))) as c:
        r = c.post("/detect", json=body)
        assert r.status_code == 413 and r.json()["field"] == "body"

        def chunks() -> Any:  # no Content-Length: the cap applies while streaming
            for _ in range(20):
                yield bytes(1000)

        r = c.post("/detect", content=chunks(), headers={"Content-Type": "application/octet-stream"})
        assert r.status_code == 413
        assert c.post("/detect", json={"cloud": {"points": P}, "num_samples": 5}).status_code == 200


def test_bearer_token(make_settings: Callable[..., Settings], body: dict[str, Any]) -> None:
    with TestClient(create_app(make_settings(token="s3cret"))) as c:
        r = c.post("/detect", json=body)
        assert r.status_code == 401 and r.json()["field"] == "Authorization"
        assert c.post("/detect", json=body, headers={"Authorization": "Bearer wrong"}).status_code == 401
        assert c.post("/detect", json=body, headers={"Authorization": "Bearer s3cret"}).status_code == 200
        assert c.get("/models").status_code == 401
        assert c.get("/healthz").status_code == 200


def test_full_queue_is_503_with_retry_after(make_settings: Callable[..., Settings], krylon: Any,
                                            small_body: Callable[..., dict[str, Any]]) -> None:
    with TestClient(create_app(make_settings(detect_workers=1, queue_size=0))) as c:
        engine = c.app.state.service.engine  # type: ignore[attr-defined]
        slow, _ = engine.submit(parse_request(small_body(krylon, num_samples=3000)), {})
        r = c.post("/detect", json=small_body(krylon))
        slow.result(timeout=60)
        assert r.status_code == 503, r.text
        assert int(r.headers["Retry-After"]) >= 1
        assert c.post("/detect", json=small_body(krylon)).status_code == 200
        assert 'graspd_requests_total{outcome="busy",transport="http"} 1.0' in c.get("/metrics").text


def test_deadline_is_504(make_settings: Callable[..., Settings], body: dict[str, Any]) -> None:
    with TestClient(create_app(make_settings(deadline_s=0.001))) as c:
        r = c.post("/detect", json={**body, "num_samples": 2000})
        assert r.status_code == 504 and r.json()["field"] == "deadline"


JSONISH = st.recursive(
    st.none() | st.booleans() | st.integers(-10**12, 10**12) | st.floats(allow_nan=False, allow_infinity=False)
    | st.text(max_size=8),
    lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=8), inner, max_size=4),
    max_leaves=12,
)


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(cloud=JSONISH, extra=st.dictionaries(st.sampled_from(["num_samples", "max_grasps", "hand", "workspace",
                                                              "model", "approach", "min_score", "seed", "crops"]),
                                            JSONISH, max_size=3))
def test_random_bodies_never_crash(client: TestClient, cloud: Any, extra: dict[str, Any]) -> None:
    r = client.post("/detect", json={"cloud": cloud, **extra})
    assert r.status_code in (200, 400, 422), r.text
    if r.status_code != 200:
        assert r.json()["field"]


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(points=st.lists(st.tuples(*[st.floats(-1, 1, allow_nan=False)] * 3), min_size=1, max_size=40),
       source=st.lists(st.integers(-2, 3), max_size=41))
def test_random_small_clouds(client: TestClient, points: list[tuple[float, float, float]], source: list[int]) -> None:
    body = {"cloud": {"points": points, "viewpoints": [[0, 0, 2], [0, 2, 0]], "camera_source": source or None},
            "num_samples": 20}
    r = client.post("/detect", json=body)
    ok = len(source) in (0, len(points)) and all(0 <= s <= 1 for s in source)
    assert r.status_code == (200 if ok else 422), r.text
