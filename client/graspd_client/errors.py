"""Client-side errors: each says what went wrong and, where the server named one, which field."""

from __future__ import annotations

from typing import Any


class GraspdError(Exception):
    """Base class of everything the client raises."""


class RequestRejected(GraspdError):
    """The server refused the request (4xx); field is the offending request field when it named one."""

    def __init__(self, status: int, message: str, field: str | None = None, body: Any = None) -> None:
        self.status = status
        self.field = field
        self.body = body
        super().__init__(f"HTTP {status}: {message}")


class ServerBusy(GraspdError):
    """The server stayed overloaded (503) through every retry."""


class ServerError(GraspdError):
    """The server failed (5xx other than 503) or its answer could not be parsed."""


class TransportError(GraspdError):
    """The server could not be reached or did not answer in time."""
