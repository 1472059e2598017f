"""With GRASPD_TOKEN set nothing is readable without it: /metrics, the details of /readyz (a bare
status stays public for load balancers), /docs, /redoc and /openapi.json (settings publish them), and the Zenoh
admin space.  The documentation pages load their assets from this server only (fastapi-offline's bundle)."""

from __future__ import annotations

import json
import re
import time
from collections.abc import Callable
from pathlib import Path

from fastapi.testclient import TestClient

from graspd.server.app import create_app
from graspd.server.settings import Settings
from graspd_client.zenoh_client import zenoh_config as client_config

from .conftest import free_port

TOKEN = "gate-token-5f1c0a77d2"
AUTH = {"Authorization": f"Bearer {TOKEN}"}
GATED = ("/metrics", "/docs", "/redoc", "/openapi.json")


def test_nothing_is_readable_without_the_token(make_settings: Callable[..., Settings]) -> None:
    with TestClient(create_app(make_settings(token=TOKEN))) as client:
        for path in GATED:
            for headers in ({}, {"Authorization": "Bearer wrong"}, {"Authorization": TOKEN}):
                reply = client.get(path, headers=headers)
                assert reply.status_code == 401, (path, headers, reply.text[:200])
                assert reply.json()["field"] == "Authorization" and TOKEN not in reply.text
            assert client.get(path, headers=AUTH).status_code == 200, path
        bare = client.get("/readyz")
        assert bare.status_code in (200, 503) and set(bare.json()) == {"status"}, bare.text
        detailed = client.get("/readyz", headers=AUTH).json()
        assert {"models", "workers", "queue_capacity", "model_errors"} <= set(detailed)
        assert client.get("/healthz").json() == {"status": "ok"}


def test_settings_publish_docs_and_metrics(make_settings: Callable[..., Settings]) -> None:
    settings = make_settings(token=TOKEN, publish_docs=True, publish_metrics=True)
    with TestClient(create_app(settings)) as client:
        for path in GATED:
            assert client.get(path).status_code == 200, path
        assert set(client.get("/readyz").json()) == {"status"}  # details stay with the token holder
    with TestClient(create_app(make_settings())) as client:  # no token: all public, as before
        for path in (*GATED, "/readyz"):
            assert client.get(path).status_code in (200, 503), path
        assert "models" in client.get("/readyz").json()


def test_docs_pages_fetch_nothing_from_elsewhere(make_settings: Callable[..., Settings]) -> None:
    with TestClient(create_app(make_settings())) as client:
        for page in ("/docs", "/redoc"):
            text = client.get(page).text
            assert not re.search(r"(https?:)?//[a-z0-9.-]+\.[a-z]{2,}", text, re.I), (page, text)
            assets = re.findall(r"(?:src|href)=['\"]?(/[^'\" >]+)", text) + re.findall(r"url: *'(/[^']+)'", text)
            assert assets, page
            for asset in assets:
                reply = client.get(asset, headers=AUTH)
                assert reply.status_code == 200 and len(reply.content) > 100, (page, asset)
        bundle = client.get("/docs-assets/swagger-ui-bundle.js")
        assert bundle.headers["content-type"].startswith("text/javascript") and len(bundle.content) > 500_000
        missing = client.get("/docs-assets/core.py")  # only the four bundle files, nothing else of the package
        assert missing.status_code == 404 and missing.json()["field"] == "name"
        assert client.get("/docs-assets/..%2Fcore.py").status_code == 404


def _admin_replies(session: object, key: str) -> list[str]:
    return [str(r.ok.key_expr) for r in session.get(key, timeout=3) if r.ok is not None]  # type: ignore[attr-defined]


def test_zenoh_admin_space_is_closed_with_a_token(make_settings: Callable[..., Settings], tmp_path: Path) -> None:
    """A Zenoh config that enables the admin space keeps it only with GRASPD_ZENOH_ADMIN_SPACE=true when a token
    is set: an anonymous peer reads nothing of the server's @/<zid>/**."""
    import zenoh  # noqa: PLC0415

    conf = tmp_path / "zenoh.json5"
    conf.write_text(json.dumps({"adminspace": {"enabled": True}}))
    for published in (False, True):
        endpoint = f"tcp/127.0.0.1:{free_port()}"
        settings = make_settings(zenoh_enabled=True, zenoh_listen=[endpoint], zenoh_config=conf, token=TOKEN,
                                 zenoh_stream=False, zenoh_admin_space=published)
        with TestClient(create_app(settings)) as client, zenoh.open(client_config(connect=[endpoint])) as peer:
            zid = str(client.app.state.service.zenoh.session.info.zid())  # type: ignore[attr-defined]
            time.sleep(0.3)
            keys = _admin_replies(peer, f"@/{zid}/**")
            assert bool(keys) is published, keys
