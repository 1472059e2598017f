"""JSON log lines: uvicorn's ANSI color_message stays out, and lines logged on a worker thread for a request
carry that request's id."""

from __future__ import annotations

import json
import logging
from typing import Any

import pytest
from fastapi.testclient import TestClient

from graspd.server.logs import JsonFormatter, RequestIdFilter, begin_request
from graspd.server.requests import parse_request
from graspd.server.services.mapping import response_json
from graspd.server.services.outcome import Parsed


def test_color_message_does_not_leak() -> None:
    record = logging.LogRecord("uvicorn.error", logging.INFO, __file__, 1, "Started server process [%d]", (42,), None)
    record.color_message = "Started server process [\x1b[36m%d\x1b[0m]"
    out = json.loads(JsonFormatter().format(record))
    assert out["msg"] == "Started server process [42]" and "color_message" not in out
    assert "\x1b" not in json.dumps(out)


def test_worker_thread_lines_carry_the_request_id(client: TestClient, body: dict[str, Any],
                                                  caplog: pytest.LogCaptureFixture) -> None:
    caplog.handler.addFilter(RequestIdFilter())
    engine = client.app.state.service.engine  # type: ignore[attr-defined]
    ctx = begin_request()
    worker_log = logging.getLogger("graspd.test")

    def parse() -> Any:
        worker_log.warning("parsing on a worker")
        return Parsed(parse_request(body))

    engine.admit()
    with caplog.at_level(logging.INFO):
        fut, _ = engine.enqueue(parse, {})
        out = json.loads(response_json(fut.result(timeout=120)))
    line = next(r for r in caplog.records if r.getMessage() == "parsing on a worker")
    assert str(line.threadName).startswith("graspd-detect")
    assert line.request_id == ctx.id == out["request_id"]  # type: ignore[attr-defined]
