"""Print the service's OpenAPI document: `python -m graspd.server.openapi > openapi/openapi.json`."""

from __future__ import annotations

import json
import sys

from graspd.server.app import create_app
from graspd.server.settings import Settings


def openapi_text() -> str:
    """The OpenAPI JSON of the app (stable key order, trailing newline)."""
    app = create_app(Settings(zenoh_enabled=False))
    return json.dumps(app.openapi(), indent=1, sort_keys=True) + "\n"


if __name__ == "__main__":
    sys.stdout.write(openapi_text())
