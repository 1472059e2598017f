"""A bounded stateful schemathesis run against the live app: sequences of calls that follow the
OpenAPI links (POST /detect -> POST /feedback on the best grasp's id) and random calls in between; no 5xx."""

from __future__ import annotations

import collections
import json
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
from hypothesis import HealthCheck, settings

from graspd.server.runner import serve_in_thread
from graspd.server.settings import Settings

SPEC = Path(__file__).resolve().parents[2] / "openapi" / "openapi.json"


def test_stateful_fuzz_finds_no_server_error(make_settings: Callable[..., Settings]) -> None:
    schemathesis = pytest.importorskip("schemathesis")  # dev dependency; installed in CI

    schema = schemathesis.openapi.from_path(str(SPEC))
    seen: collections.Counter[str] = collections.Counter()
    failures: list[str] = []
    with serve_in_thread(make_settings(port=0)) as url:

        class Machine(schema.as_state_machine()):  # type: ignore[misc]
            def get_call_kwargs(self, case: Any) -> dict[str, Any]:
                return {"base_url": url, "timeout": 60}

            def validate_response(self, response: Any, case: Any, **kwargs: Any) -> None:
                seen[f"{case.method} {case.path} {response.status_code}"] += 1
                if response.status_code >= 500:
                    failures.append(f"{case.method} {case.path} -> {response.status_code}: {response.text[:300]}")
                elif response.status_code >= 400:
                    body = json.loads(response.text)
                    assert "error" in body and "field" in body

        Machine.run(settings=settings(max_examples=100, stateful_step_count=5, deadline=None, derandomize=True,
                                      database=None, suppress_health_check=list(HealthCheck)))
    assert not failures, failures
    assert sum(seen.values()) > 40 and any(k.startswith("POST /detect") for k in seen), seen
