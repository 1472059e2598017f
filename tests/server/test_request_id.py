"""X-Request-ID: a client's valid id is kept, echoed in the header and the body, and carried
by every log line of its request; an invalid one is replaced; grasp ids stay the server's (feedback names the
right detection even when a client reuses its ids)."""

from __future__ import annotations

import logging
from typing import Any

import pytest
from fastapi.testclient import TestClient

from graspd.server.logs import MAX_REQUEST_ID, RequestIdFilter, valid_request_id


def test_valid_ids() -> None:
    for good in ("robot-7.pick-42", "550e8400-e29b-41d4-a716-446655440000", "Root=1-5759e988;Parent=53995c3f",
                 "a" * MAX_REQUEST_ID, "b64+/=@:x"):
        assert valid_request_id(good) == good
    for bad in ("", "a" * (MAX_REQUEST_ID + 1), "two words", "quote\"", "new\nline", "tab\t", "caf\u00e9", "<x>",
                None):
        assert valid_request_id(bad) is None


def test_the_client_id_is_echoed_in_header_body_and_log_lines(client: TestClient, body: dict[str, Any],
                                                             caplog: pytest.LogCaptureFixture) -> None:
    caplog.handler.addFilter(RequestIdFilter())
    rid = "robot-7.pick-42"
    with caplog.at_level(logging.INFO):
        r = client.post("/detect", json=body, headers={"X-Request-ID": rid})
    assert r.status_code == 200, r.text
    out = r.json()
    assert r.headers["X-Request-ID"] == rid and out["request_id"] == rid
    detect_lines = [rec for rec in caplog.records if rec.getMessage() == "detect"]
    assert detect_lines and all(rec.request_id == rid for rec in detect_lines)  # type: ignore[attr-defined]
    # the grasp ids name the detection with the server's own id, not the client's
    ids = [g["id"] for g in out["grasps"]]
    prefix = ids[0].rsplit("-", 1)[0]
    assert len(prefix) == 16 and all(i == f"{prefix}-{k}" for k, i in enumerate(ids))
    # the same client id again: a new detection, new grasp ids, and feedback on the first still names the first
    again = client.post("/detect", json=body, headers={"X-Request-ID": rid}).json()
    assert again["request_id"] == rid and again["grasps"][0]["id"] != ids[0]
    fb = client.post("/feedback", json={"grasp_id": ids[0], "success": True})
    assert fb.status_code == 200, fb.text
    assert fb.json()["grasp_id"] == ids[0]


def test_errors_echo_the_client_id_too(client: TestClient) -> None:
    r = client.post("/detect", json={"cloud": {"points": []}}, headers={"X-Request-ID": "bad-request-1"})
    assert r.status_code == 422 and r.headers["X-Request-ID"] == "bad-request-1"


def test_an_invalid_id_is_replaced_and_logged(client: TestClient, body: dict[str, Any],
                                              caplog: pytest.LogCaptureFixture) -> None:
    with caplog.at_level(logging.INFO):
        r = client.post("/detect", json=body, headers={"X-Request-ID": "two words"})
    assert r.status_code == 200
    made = r.headers["X-Request-ID"]
    assert made != "two words" and len(made) == 16 and r.json()["request_id"] == made
    assert any("X-Request-ID refused" in rec.getMessage() for rec in caplog.records)


def test_without_a_client_id_the_grasp_ids_start_with_the_request_id(client: TestClient,
                                                                     body: dict[str, Any]) -> None:
    r = client.post("/detect", json=body)
    out = r.json()
    assert r.headers["X-Request-ID"] == out["request_id"] and len(out["request_id"]) == 16
    assert out["grasps"][0]["id"] == f"{out['request_id']}-0"
