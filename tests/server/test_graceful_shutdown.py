"""Graceful shutdown under load on a real uvicorn socket: once the server is told to stop, it accepts no new
connections and closes idle keep-alive ones, but the detections already admitted (running or queued) all finish
and are answered, then the engine closes."""

from __future__ import annotations

import json
import socket
import threading
import time
from collections.abc import Callable
from typing import Any

import uvicorn

from graspd.server.app import create_app
from graspd.server.runner import free_port, uvicorn_config
from graspd.server.settings import Settings

IN_FLIGHT = 3


def _read_response(s: socket.socket) -> tuple[int, dict[str, str], bytes]:
    data = b""
    while b"\r\n\r\n" not in data:
        data += s.recv(65536)
    head, _, rest = data.partition(b"\r\n\r\n")
    lines = head.decode().split("\r\n")
    headers = {k.lower(): v.strip() for k, _, v in (line.partition(":") for line in lines[1:])}
    while len(rest) < int(headers["content-length"]):
        chunk = s.recv(65536)
        if not chunk:
            break
        rest += chunk
    return int(lines[0].split()[1]), headers, rest


def _post(port: int, body: bytes, out: list[tuple[int, bytes, bool]]) -> None:
    """POST /detect on a connection of its own; (status, body, whether the server then closed the connection)
    appended to out."""
    with socket.create_connection(("127.0.0.1", port), timeout=60) as s:
        s.sendall(b"POST /detect HTTP/1.1\r\nHost: x\r\nContent-Type: application/json\r\nContent-Length: "
                  + str(len(body)).encode() + b"\r\n\r\n" + body)
        status, _, raw = _read_response(s)
        s.settimeout(10)
        out.append((status, raw, s.recv(1) == b""))


def _refused(port: int) -> bool:
    try:
        with socket.create_connection(("127.0.0.1", port), timeout=1):
            return False
    except OSError:  # ConnectionRefusedError: nobody listens any more
        return True


def test_shutdown_finishes_admitted_detections_and_accepts_no_more(
        make_settings: Callable[..., Settings], krylon: Any, small_body: Callable[..., dict[str, Any]]) -> None:
    settings = make_settings(port=0, detect_workers=1, queue_size=IN_FLIGHT, shutdown_grace_s=30.0)
    app = create_app(settings)
    port = free_port()
    server = uvicorn.Server(uvicorn_config(app, settings, port))
    thread = threading.Thread(target=server.run, name="graspd-uvicorn", daemon=True)
    thread.start()
    deadline = time.monotonic() + 30
    while not server.started:
        assert thread.is_alive() and time.monotonic() < deadline, "the server did not start"
        time.sleep(0.02)
    engine = app.state.service.engine
    body = json.dumps(small_body(krylon, num_samples=1500)).encode()  # ~1 s each on one worker
    answers: list[tuple[int, bytes, bool]] = []
    clients = [threading.Thread(target=_post, args=(port, body, answers)) for _ in range(IN_FLIGHT)]
    idle = socket.create_connection(("127.0.0.1", port), timeout=10)  # a kept-alive connection, idle
    try:
        idle.sendall(b"GET /healthz HTTP/1.1\r\nHost: x\r\n\r\n")
        assert _read_response(idle)[0] == 200
        for c in clients:
            c.start()
        while engine.pending < IN_FLIGHT:  # all admitted: one running, the others queued
            assert time.monotonic() < deadline, "the requests were not admitted"
            time.sleep(0.01)

        server.should_exit = True  # what SIGTERM does
        t0 = time.monotonic()
        while not _refused(port):
            assert time.monotonic() - t0 < 3, "still accepting connections after shutdown began"
            time.sleep(0.05)
        assert engine.pending > 0, "the detections ended before the listener closed: the test proves nothing"
        idle.settimeout(3)
        assert idle.recv(65536) == b""  # the idle keep-alive connection is closed, not kept to the end
    finally:
        idle.close()
        for c in clients:
            c.join(timeout=60)
        thread.join(timeout=60)
    assert not thread.is_alive()
    assert len(answers) == IN_FLIGHT
    for status, raw, closed in answers:  # every admitted request answered in full
        assert status == 200, raw
        assert closed  # then its connection ends (no keep-alive while shutting down)
        assert json.loads(raw)["grasps"] is not None
    assert engine.closed and engine.pending == 0
