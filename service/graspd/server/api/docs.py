"""The API documentation, offline and guarded: /openapi.json, /docs (Swagger UI) and /redoc served from assets
shipped in the fastapi-offline wheel (no CDN, no font or favicon fetched from anywhere), and, when the server
sets GRASPD_TOKEN, readable only with the bearer token unless GRASPD_PUBLISH_DOCS publishes them (the schema
tells an attacker every route and limit)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import fastapi_offline
from fastapi import APIRouter, Request
from fastapi.openapi.docs import get_redoc_html, get_swagger_ui_html
from fastapi.responses import HTMLResponse, JSONResponse, Response

from graspd.server.api.access import require_bearer
from graspd.server.api.deps import State
from graspd.server.problems import Problem

router = APIRouter(include_in_schema=False)

#: Where the docs assets are served from, and the files (name -> media type) served there.
ASSETS_URL = "/docs-assets"
ASSETS = {"swagger-ui-bundle.js": "text/javascript", "swagger-ui.css": "text/css",
          "redoc.standalone.js": "text/javascript", "favicon.png": "image/png"}
ASSETS_DIR = Path(fastapi_offline.__file__).resolve().parent / "static"


@router.get("/openapi.json")
def openapi_json(request: Request, state: State) -> Any:
    require_bearer(state.settings, request, state.settings.publish_docs)
    return JSONResponse(request.app.openapi())


@router.get("/docs")
def swagger(request: Request, state: State) -> HTMLResponse:
    require_bearer(state.settings, request, state.settings.publish_docs)
    return get_swagger_ui_html(openapi_url="/openapi.json", title="graspd - Swagger UI",
                               swagger_js_url=f"{ASSETS_URL}/swagger-ui-bundle.js",
                               swagger_css_url=f"{ASSETS_URL}/swagger-ui.css",
                               swagger_favicon_url=f"{ASSETS_URL}/favicon.png")


@router.get("/redoc")
def redoc(request: Request, state: State) -> HTMLResponse:
    require_bearer(state.settings, request, state.settings.publish_docs)
    return get_redoc_html(openapi_url="/openapi.json", title="graspd - ReDoc",
                          redoc_js_url=f"{ASSETS_URL}/redoc.standalone.js",
                          redoc_favicon_url=f"{ASSETS_URL}/favicon.png", with_google_fonts=False)


@router.get(ASSETS_URL + "/{name}")
def asset(name: str) -> Response:
    """One of the four static files (public: they are the published Swagger UI / ReDoc bundles)."""
    media = ASSETS.get(name)
    if media is None:
        raise Problem(404, "no such documentation asset", "name")
    return Response((ASSETS_DIR / name).read_bytes(), media_type=media,
                    headers={"Cache-Control": "public, max-age=86400", "X-Content-Type-Options": "nosniff"})
