"""Who may read what when the server sets GRASPD_TOKEN: the bearer check of routes that answer anonymous callers
something (a bare /readyz) and the token holder more (its details), and of the documentation and metrics routes
that settings may publish.  Constant-time comparison; the token is never logged or echoed."""

from __future__ import annotations

import secrets

from starlette.requests import HTTPConnection

from graspd.server.problems import Problem
from graspd.server.settings import Settings


def bearer_ok(settings: Settings, request: HTTPConnection) -> bool:
    """True when the server sets no token, or the request's Authorization header is `Bearer <token>`."""
    token = settings.token
    if token is None:
        return True
    scheme, _, given = request.headers.get("authorization", "").partition(" ")
    return scheme.lower() == "bearer" and secrets.compare_digest(given.strip().encode(),
                                                                 token.get_secret_value().encode())


def require_bearer(settings: Settings, request: HTTPConnection, published: bool = False) -> None:
    """Problem 401 naming Authorization unless the route is published (a setting) or bearer_ok."""
    if not published and not bearer_ok(settings, request):
        raise Problem(401, "missing or wrong bearer token", "Authorization")
