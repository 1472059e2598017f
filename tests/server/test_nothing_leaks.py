"""Errors give nothing away: a hostile run against a server with a token, an unreachable
database and a models folder of its own, then every answer and every log line is grepped for the token, the
database's user, password, name, host and port, and the server's folders."""

from __future__ import annotations

import logging
import re
import shutil
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
from fastapi.testclient import TestClient

from graspd.core.cloud import ViewpointCloud
from graspd.server.app import create_app
from graspd.server.settings import Settings

from .conftest import free_port

TOKEN = "leak-check-token-9d8c7b6a"
DB_USER, DB_PASSWORD, DB_NAME, DB_HOST = "cellops", "Tr0ub4dor-db", "graspdtemplates", "localhost"
LYING_PLY = (b"ply\nformat ascii 1.0\nelement vertex 1000000000\nproperty float x\nproperty float y\n"
             b"property float z\nend_header\n0 0 0\n")


def test_no_answer_or_log_line_holds_a_secret(make_settings: Callable[..., Settings], tmp_path: Path,
                                              models_and_default: tuple[Path, str], krylon: ViewpointCloud,
                                              small_body: Callable[..., dict[str, Any]],
                                              caplog: pytest.LogCaptureFixture) -> None:
    src, name = models_and_default
    models = tmp_path / "secret-models-folder"
    models.mkdir()
    for suffix in (".onnx", ".json"):
        shutil.copy(src / f"{name}{suffix}", models / f"{name}{suffix}")
    port = free_port()
    settings = make_settings(token=TOKEN, models_dir=models, data_dir=tmp_path / "secret-data-folder",
                             template_library=f"postgresql+psycopg://{DB_USER}:{DB_PASSWORD}@{DB_HOST}:{port}/"
                                              f"{DB_NAME}", detect_memory_mb=600)
    auth = {"Authorization": f"Bearer {TOKEN}"}
    caplog.set_level(logging.DEBUG)
    answers = []
    with TestClient(create_app(settings)) as client:
        replies = [
            client.get("/library", headers=auth),                                    # the database: 503
            client.post("/feedback", json={"grasp_id": "0123456789abcdef-0", "success": False}, headers=auth),
            client.post("/models", files={"mesh": ("lie.ply", LYING_PLY)}, data={"name": "lie"}, headers=auth),
            client.post("/models", files={"mesh": ("x.ply", b"ply\n")}, data={"name": name}, headers=auth),
            client.post("/detect", json=small_body(krylon, num_samples=4000), headers=auth),  # over the budget
            client.post("/detect", json=small_body(krylon), headers={"Authorization": "Bearer " + TOKEN[:-1]}),
            client.post("/detect", content=b"\x00" * 100, headers={**auth, "Content-Type": "text/plain"}),
            client.get("/metrics"), client.get("/openapi.json"), client.get("/readyz"), client.get("/models"),
            client.get("/readyz", headers=auth), client.get("/models", headers=auth),
        ]
        statuses = [r.status_code for r in replies]
        answers = [r.text + repr(dict(r.headers)) for r in replies]
    assert statuses[:5] == [503, 404, 422, 409, 413] and statuses[5] == 401 and 500 not in statuses, statuses
    logs = [caplog.text, *(repr(r.__dict__) for r in caplog.records)]
    secrets = {"token": TOKEN, "db password": DB_PASSWORD, "db user": DB_USER, "db name": DB_NAME,
               "db host": DB_HOST, "db port": str(port), "models folder": "secret-models-folder",
               "data folder": "secret-data-folder", "tmp path": str(tmp_path)}
    leaks = {what: [t[:300] for t in (*answers, *logs) if _holds(t, value, digits=what == "db port")][:2]
             for what, value in secrets.items()}
    assert not any(leaks.values()), {k: v for k, v in leaks.items() if v}
    assert any("template library unavailable" in r.getMessage() for r in caplog.records)  # the log says what failed


def _holds(text: str, value: str, digits: bool = False) -> bool:
    """Whether text holds value; digits (a port): as a whole number, not inside a timestamp's or an id's digits."""
    return re.search(rf"(?<![\d.]){re.escape(value)}(?![\d.])", text) is not None if digits else value in text
