"""Slow clients cannot starve anyone, on a real uvicorn socket: a body trickling below the minimum
upload rate gets 408 naming body; connections over the per-address or the total cap close the oldest connection
still waiting for its headers, so /healthz answers while a flood of slow-header connections is open."""

from __future__ import annotations

import json
import socket
import time
from collections.abc import Callable
from contextlib import ExitStack

from fixtures import connect, read_response
from graspd.server.runner import serve_in_thread
from graspd.server.settings import Settings


def healthz_seconds(url: str) -> float:
    t0 = time.monotonic()
    with connect(url, timeout=5) as s:
        s.sendall(b"GET /healthz HTTP/1.1\r\nHost: x\r\n\r\n")
        status, _, body = read_response(s)
    assert status == 200 and json.loads(body) == {"status": "ok"}
    return time.monotonic() - t0


def is_closed(s: socket.socket) -> bool:
    s.settimeout(0.05)
    try:
        return s.recv(1) == b""
    except TimeoutError:
        return False
    except OSError:
        return True


def test_a_body_below_the_minimum_rate_is_408(make_settings: Callable[..., Settings]) -> None:
    settings = make_settings(port=0, http_min_upload_rate=2000, http_upload_grace_s=0.5, http_body_timeout_s=60)
    with serve_in_thread(settings) as url, connect(url) as s:
        t0 = time.monotonic()
        s.sendall(b"POST /detect HTTP/1.1\r\nHost: x\r\nContent-Type: application/json\r\nContent-Length: 100000\r\n"
                  b"\r\n{\"cloud\": " + b" " * 100)
        s.settimeout(0.2)
        reply = b""
        while time.monotonic() - t0 < 10 and b"\r\n\r\n" not in reply:
            try:
                reply += s.recv(65536)
            except TimeoutError:
                s.sendall(b" " * 10)  # 50 bytes/s, far below 2000
        status, _, rest = reply.partition(b"\r\n\r\n")
        assert b" 408 " in status, reply
        assert time.monotonic() - t0 < 3.0  # the 60 s body deadline is not what ended it
        s.settimeout(5)
        while rest.count(b"}") < 1:
            rest += s.recv(65536)
        body = json.loads(rest[rest.index(b"{"):])
        assert body["field"] == "body" and "too slowly" in body["error"]


def test_healthz_answers_through_a_slow_header_flood(make_settings: Callable[..., Settings]) -> None:
    """60 connections that never finish their headers (header timeout 30 s, so only the caps can free them):
    over the per-address cap of 8 the oldest are closed, and /healthz answers in well under 2 s every time."""
    settings = make_settings(port=0, http_header_timeout_s=30, http_max_connections_per_peer=8,
                             http_max_connections=32)
    with serve_in_thread(settings) as url, ExitStack() as stack:
        flood = []
        for _ in range(60):
            s = stack.enter_context(connect(url))
            s.sendall(b"GET /healthz HTTP/1.1\r\nHost: x\r\nX-Slow: ")
            flood.append(s)
        time.sleep(0.3)
        times = [healthz_seconds(url) for _ in range(10)]
        assert max(times) < 1.0, times
        closed = sum(is_closed(s) for s in flood)
        assert closed >= 60 - 8, closed  # the oldest went first (and each /healthz evicted one more)


def test_the_total_cap_evicts_header_waiting_connections(make_settings: Callable[..., Settings]) -> None:
    settings = make_settings(port=0, http_header_timeout_s=30, http_max_connections_per_peer=1000,
                             http_max_connections=16)
    with serve_in_thread(settings) as url, ExitStack() as stack:
        flood = [stack.enter_context(connect(url)) for _ in range(40)]
        for s in flood:
            s.sendall(b"GET / HTTP/1.1\r\n")
        time.sleep(0.3)
        assert healthz_seconds(url) < 1.0
        assert sum(is_closed(s) for s in flood) >= 40 - 16
