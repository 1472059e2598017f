"""No secret in any answer or log: a template library URL with a password that cannot be opened answers 503
naming template_library over HTTP and Zenoh, and neither those bodies nor the captured logs hold the password
(raw or %-encoded); the redaction helpers mask URL and DSN passwords in driver messages."""

from __future__ import annotations

import json
import logging
from collections.abc import Callable
from typing import Any

import pytest
from fastapi.testclient import TestClient

from graspd.database import redact_text, redact_url
from graspd.server.app import create_app
from graspd.server.settings import Settings
from graspd.templates import TemplateError, TemplateLibrary
from graspd_client.zenoh_client import zenoh_config

from .conftest import free_port

PASSWORD = "Hunter2-l1brary/pa@ss"  # "/" and "@" must be %-encoded in a URL
ENCODED = "Hunter2-l1brary%2Fpa%40ss"


def _urls() -> dict[str, str]:
    """Library URLs that cannot be opened, each carrying the password."""
    return {
        "refused": f"postgresql+psycopg://graspd:{ENCODED}@127.0.0.1:{free_port()}/library",
        "unparsable": f"postgres ql://graspd:{ENCODED}@db.example/library",
        "unknown-driver": f"postgresql+nosuchdriver://graspd:{ENCODED}@127.0.0.1/library",
    }


def _assert_clean(text: str) -> None:
    for secret in (PASSWORD, ENCODED, "Hunter2"):
        assert secret not in text, text


@pytest.mark.parametrize("case", ["refused", "unparsable", "unknown-driver"])
def test_library_503_hides_the_password(make_settings: Callable[..., Settings], case: str,
                                        caplog: pytest.LogCaptureFixture) -> None:
    """GET /library and its Zenoh twin answer 503 naming template_library, with the URL's password masked,
    and the log lines (with their exception texts) do not hold it either."""
    import zenoh  # noqa: PLC0415

    caplog.set_level(logging.DEBUG)
    url = _urls()[case]
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    settings = make_settings(template_library=url, zenoh_enabled=True, zenoh_listen=[endpoint],
                             zenoh_stream=False)
    with TestClient(create_app(settings)) as http:
        r = http.get("/library")
        assert r.status_code == 503, r.text
        assert r.json()["field"] == "template_library"
        _assert_clean(r.text)
        assert "graspd:***@" in r.json()["error"]  # the URL is still there to debug with, masked
        with zenoh.open(zenoh_config(connect=[endpoint])) as session:
            replies = list(session.get("graspd/library", timeout=30))
        assert len(replies) == 1 and replies[0].err is not None
        raw = replies[0].err.payload.to_bytes().decode()
        assert json.loads(raw)["status"] == 503 and json.loads(raw)["field"] == "template_library"
        _assert_clean(raw)
    logged = caplog.text + "".join(repr(r.__dict__) for r in caplog.records)
    assert "template library unavailable" in logged
    _assert_clean(logged)


def test_store_errors_mask_the_password() -> None:
    """TemplateLibrary's own errors quote the URL masked."""
    with pytest.raises(TemplateError) as info:
        TemplateLibrary(f"postgres ql://graspd:{ENCODED}@db.example/library")
    assert "library_url" in str(info.value)
    _assert_clean(str(info.value))


@pytest.mark.parametrize(("text", "expected"), [
    (f"postgresql+psycopg://graspd:{ENCODED}@h/db", "postgresql+psycopg://graspd:***@h/db"),
    (f"dsn: host=h user=graspd password={PASSWORD} dbname=x", "dsn: host=h user=graspd password=*** dbname=x"),
    (f"connection 'password=\"{PASSWORD}\" host=h'", "connection 'password=*** host=h'"),
    (f"failed for {PASSWORD!r} and {ENCODED}", "failed for '***' and ***"),
])
def test_redact_text(text: str, expected: str) -> None:
    assert redact_text(text, f"postgresql+psycopg://graspd:{ENCODED}@h/db") == expected


def test_redact_url_keeps_the_rest() -> None:
    url: dict[str, Any] = {"with": f"postgresql+psycopg://graspd:{ENCODED}@db:5432/lib?sslmode=require",
                           "without": "sqlite:////var/lib/graspd/templates.db"}
    assert redact_url(url["with"]) == "postgresql+psycopg://graspd:***@db:5432/lib?sslmode=require"
    assert redact_url(url["without"]) == url["without"]
