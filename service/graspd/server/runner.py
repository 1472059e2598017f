"""Run the service with uvicorn: the limits that guard the HTTP entrance (keep-alive, request-header and body
timeouts, connection limit, header size, graceful shutdown), shared by `graspd serve` and serve_in_thread, a
real server on a real socket in a background thread of this process (tests, benches)."""

from __future__ import annotations

import asyncio
import collections
import socket
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

import uvicorn
from uvicorn.protocols.http.h11_impl import H11Protocol

from graspd.server.app import create_app
from graspd.server.settings import Settings


def free_port(host: str = "127.0.0.1") -> int:
    """A TCP port nobody listens on right now."""
    with socket.socket() as s:
        s.bind((host, 0))
        return int(s.getsockname()[1])


def guarded_h11_protocol(header_timeout_s: float, max_connections: int = 1 << 30,
                         max_per_peer: int = 1 << 30) -> type[asyncio.Protocol]:
    """uvicorn's h11 protocol with a request-header deadline: from the moment a connection opens, or a kept-alive
    connection receives the first byte of its next request, the request line and headers must be complete
    within header_timeout_s, else the connection is closed.  uvicorn's own keep-alive timer only runs after a
    response and restarts on every byte, so a client trickling headers (or never sending any) held a
    connection forever.  Bodies are timed by the routes (routers.detect.read_capped) and by
    guards.UploadRateGuard (minimum rate).

    Connection caps: at most max_connections open connections, at most max_per_peer from one client
    address.  A connection over a cap closes the oldest connection (of that address, for the per-peer cap) that
    is still waiting for its request headers; only when none is waiting is the new one refused (closed).  So
    300 slow-header connections cannot lock out a load balancer's /healthz: they are the first to go."""

    open_per_peer: collections.Counter[str] = collections.Counter()
    waiting: dict[Any, None] = {}  # protocols waiting for request headers, oldest first (insertion order)

    class GuardedH11Protocol(H11Protocol):
        _header_timer: asyncio.TimerHandle | None = None
        _armed_cycle: Any = None
        _peer: str | None = None

        def _arm(self) -> None:
            self._armed_cycle = self.cycle
            self._header_timer = self.loop.call_later(header_timeout_s, self._header_timeout)
            waiting[self] = None

        def _disarm(self) -> None:
            waiting.pop(self, None)
            if self._header_timer is not None:
                self._header_timer.cancel()
                self._header_timer = None

        def _evict(self, peer: str | None) -> bool:
            """Close the oldest header-waiting connection (of peer, if given); False when there is none."""
            for other in waiting:
                if other is not self and (peer is None or other._peer == peer):
                    other._disarm()
                    other.transport.close()
                    return True
            return False

        def _admit(self) -> bool:
            """Make room for this new connection under both caps; False: refuse it."""
            if self._peer is not None and open_per_peer[self._peer] > max_per_peer and not self._evict(self._peer):
                return False
            return len(self.connections) <= max_connections or self._evict(None)

        def _header_timeout(self) -> None:
            self._header_timer = None
            if self.cycle is self._armed_cycle and not self.transport.is_closing():  # headers still incomplete
                self.logger.info("closing a connection whose request headers did not arrive in %.3g s",
                                 header_timeout_s)
                self.transport.close()

        def connection_made(self, transport: asyncio.Transport) -> None:  # type: ignore[override]
            super().connection_made(transport)
            peer = transport.get_extra_info("peername")
            self._peer = str(peer[0]) if isinstance(peer, tuple) and peer else None
            if self._peer is not None:
                open_per_peer[self._peer] += 1
            if not self._admit():
                self.logger.info("refusing a connection: %d open (at most %d; %d per address), none waiting for "
                                 "headers", len(self.connections), max_connections, max_per_peer)
                transport.close()
                return
            self._arm()

        def data_received(self, data: bytes) -> None:
            if self._header_timer is None and (self.cycle is None or self.cycle.response_complete):
                self._arm()  # the next request on a kept-alive connection begins
            super().data_received(data)
            if self.cycle is not self._armed_cycle:  # a new request's headers were parsed
                self._disarm()

        def connection_lost(self, exc: Exception | None) -> None:
            self._disarm()
            if self._peer is not None:
                open_per_peer[self._peer] -= 1
                if open_per_peer[self._peer] <= 0:
                    del open_per_peer[self._peer]
                self._peer = None
            super().connection_lost(exc)

    return GuardedH11Protocol


def uvicorn_config(app: Any, settings: Settings, port: int | None = None) -> Any:
    """A uvicorn.Config for app with the settings' HTTP limits (see Settings.http_*, shutdown_grace_s)."""

    return uvicorn.Config(
        app, host=settings.host, port=settings.port if port is None else port, log_config=None, access_log=False,
        lifespan="on",
        http=guarded_h11_protocol(settings.http_header_timeout_s, settings.http_max_connections,  # type: ignore[arg-type]
                                  settings.http_max_connections_per_peer),
        timeout_keep_alive=max(1, round(settings.http_keep_alive_s)),
        # the protocol keeps connections within http_max_connections; uvicorn's own 503 caps running requests
        limit_concurrency=settings.http_max_connections + 1,
        h11_max_incomplete_event_size=settings.http_max_header_bytes,
        timeout_graceful_shutdown=max(1, round(settings.shutdown_grace_s)),
    )


@contextmanager
def serve_in_thread(settings: Settings, startup_timeout: float = 60.0, app: Any = None) -> Iterator[str]:
    """Serve app (default: create_app(settings)) on settings.host:port (0 = a free port) with the settings'
    HTTP limits; yields the base URL."""

    port = settings.port or free_port(settings.host)
    server = uvicorn.Server(uvicorn_config(app if app is not None else create_app(settings), settings, port))
    thread = threading.Thread(target=server.run, name="graspd-uvicorn", daemon=True)
    thread.start()
    deadline = time.monotonic() + startup_timeout
    while not server.started:
        if not thread.is_alive() or time.monotonic() > deadline:
            server.should_exit = True
            raise RuntimeError(f"graspd server did not start on {settings.host}:{port}")
        time.sleep(0.02)
    try:
        yield f"http://{settings.host}:{port}"
    finally:
        server.should_exit = True
        thread.join(timeout=60)
