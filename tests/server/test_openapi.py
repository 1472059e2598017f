"""openapi/openapi.json is what the app serves (regenerate: python -m graspd.server.openapi > openapi/openapi.json),
documents the conventions, and a bounded schemathesis run against it finds no server error."""

from __future__ import annotations

import collections
import json
from collections.abc import Callable
from pathlib import Path

import pytest
from fastapi.testclient import TestClient
from hypothesis import HealthCheck, given, settings

from graspd.server.openapi import openapi_text
from graspd.server.runner import serve_in_thread
from graspd.server.settings import Settings

SPEC = Path(__file__).resolve().parents[2] / "openapi" / "openapi.json"


def test_committed_openapi_is_current() -> None:
    assert SPEC.read_text() == openapi_text(), (
        "openapi/openapi.json is stale: run `PYTHONPATH=service:client python -m graspd.server.openapi "
        "> openapi/openapi.json`")


def test_served_schema_matches(client: TestClient) -> None:
    assert client.get("/openapi.json").json() == json.loads(SPEC.read_text())


def test_schema_documents_units_frames_and_convention() -> None:
    spec = json.loads(SPEC.read_text())
    text = json.dumps(spec)
    grasp = spec["components"]["schemas"]["GraspOut"]["properties"]
    assert "hand base" in grasp["position"]["description"] and "(m)" in grasp["position"]["description"]
    assert "[approach, binormal, axis]" in grasp["pose"]["description"]
    assert "little-endian" in text and "Metres" in spec["info"]["description"]
    content = spec["paths"]["/detect"]["post"]["requestBody"]["content"]
    assert {"application/json", "application/octet-stream"} <= set(content)
    assert spec["components"]["schemas"]["DetectRequest"]["properties"]["num_samples"]["maximum"] == 20000


def test_schemathesis_finds_no_server_error(make_settings: Callable[..., Settings]) -> None:
    schemathesis = pytest.importorskip("schemathesis")  # dev dependency; installed in CI

    schema = schemathesis.openapi.from_path(str(SPEC))
    failures: list[str] = []
    seen: list[str] = []
    with serve_in_thread(make_settings(port=0)) as url:
        for result in schema.get_all_operations():
            operation = result.ok()

            @settings(max_examples=50, deadline=None, derandomize=True, database=None,
                      suppress_health_check=list(HealthCheck))
            def check(case: schemathesis.Case) -> None:
                response = case.call(base_url=url, timeout=60)
                seen.append(f"{case.method} {case.path} {response.status_code}")
                if response.status_code >= 500:
                    failures.append(f"{case.method} {case.path} -> {response.status_code}: {response.text[:300]}")
                if response.status_code >= 400:
                    body = response.json()
                    assert "error" in body and "field" in body

            given(case=operation.as_strategy())(check)()
    assert not failures, failures
    counts = collections.Counter(seen)
    assert counts["POST /detect 422"] > 0 and counts["POST /detect 415"] > 0, counts  # JSON and binary bodies
    assert counts["POST /demonstrations 422"] > 0 and counts["POST /feedback 422"] > 0, counts
    assert counts["GET /library 200"] > 0, counts
