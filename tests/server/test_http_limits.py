"""The HTTP entrance on a real uvicorn socket: idle and trickling connections
close, slow bodies get 408, admission is decided before the body is read, a 500 says nothing internal and keeps
the keep-alive connection, a client that disconnects is logged at INFO without a traceback."""

from __future__ import annotations

import json
import logging
import socket
import time
from collections.abc import Callable
from typing import Any

import pytest

from fixtures import connect, read_response
from graspd.server.app import create_app
from graspd.server.logs import RequestIdFilter
from graspd.server.requests import parse_request
from graspd.server.runner import serve_in_thread
from graspd.server.settings import Settings

FAST = {"http_keep_alive_s": 1.0, "http_header_timeout_s": 1.5, "http_body_timeout_s": 1.0}


def closed_after(s: socket.socket, limit: float) -> float:
    """Seconds until the server closes the connection (recv gives b''), at most limit."""
    t0 = time.monotonic()
    s.settimeout(limit)
    try:
        while s.recv(4096):
            pass
    except TimeoutError:
        return float("inf")
    except ConnectionResetError:
        pass
    return time.monotonic() - t0


GET = b"GET /healthz HTTP/1.1\r\nHost: x\r\n\r\n"


def test_idle_connections_close(make_settings: Callable[..., Settings]) -> None:
    with serve_in_thread(make_settings(port=0, **FAST)) as url:
        with connect(url) as s:  # keep-alive after a response: closed after http_keep_alive_s
            s.sendall(GET)
            assert read_response(s)[0] == 200
            assert 0.5 < closed_after(s, 10) < 4
        with connect(url) as s:  # never sends a byte: closed after the header timeout
            assert 1.0 < closed_after(s, 10) < 5


def test_trickling_headers_are_cut_off(make_settings: Callable[..., Settings]) -> None:
    with serve_in_thread(make_settings(port=0, **FAST)) as url, connect(url) as s:
        t0 = time.monotonic()
        request = b"GET /healthz HTTP/1.1\r\nHost: x\r\nX-Slow: " + b"a" * 40 + b"\r\n\r\n"
        try:
            for byte in request:  # one byte every 0.1 s: 4 s for the whole header if it were allowed
                s.sendall(bytes([byte]))
                time.sleep(0.1)
        except (BrokenPipeError, ConnectionResetError):
            pass
        assert closed_after(s, 10) < 10 and time.monotonic() - t0 < 4


def test_slow_body_is_408(make_settings: Callable[..., Settings]) -> None:
    with serve_in_thread(make_settings(port=0, **FAST)) as url, connect(url) as s:
        s.sendall(b"POST /detect HTTP/1.1\r\nHost: x\r\nContent-Type: application/json\r\nContent-Length: 1000\r\n"
                  b"\r\n{\"cloud\"")
        status, headers, body = read_response(s)
        assert status == 408 and json.loads(body)["field"] == "body" and headers["connection"] == "close"


def test_a_500_hides_internals_and_keeps_the_connection(make_settings: Callable[..., Settings],
                                                        caplog: pytest.LogCaptureFixture) -> None:
    settings = make_settings(port=0)
    app = create_app(settings)

    def boom() -> None:
        raise RuntimeError("secret internal state 0xdeadbeef")

    app.add_api_route("/boom", boom)  # a route with a bug: the guard is what is tested
    with caplog.at_level(logging.INFO), serve_in_thread(settings, app=app) as url, connect(url) as s:
        s.sendall(b"GET /boom HTTP/1.1\r\nHost: x\r\n\r\n")
        status, headers, body = read_response(s)
        assert status == 500 and b"deadbeef" not in body and b"RuntimeError" not in body
        assert headers["x-request-id"] in json.loads(body)["error"]
        s.sendall(GET)  # the same connection still serves
        assert read_response(s)[0] == 200
    errors = [r for r in caplog.records if r.getMessage() == "unhandled error"]
    assert errors and errors[0].exc_info is not None  # the traceback is in the log, not the answer


def test_full_queue_answers_503_before_the_body(make_settings: Callable[..., Settings], krylon: Any,
                                                small_body: Callable[..., dict[str, Any]]) -> None:
    settings = make_settings(port=0, detect_workers=1, queue_size=0)
    app = create_app(settings)
    with serve_in_thread(settings, app=app) as url, connect(url) as s:
        engine = app.state.service.engine
        slow, _ = engine.submit(parse_request(small_body(krylon, num_samples=3000)), {})
        t0 = time.monotonic()  # a 10 MB body is announced and never sent: the answer cannot wait for it
        s.sendall(b"POST /detect HTTP/1.1\r\nHost: x\r\nContent-Type: application/json\r\n"
                  b"Content-Length: 10000000\r\n\r\n")
        status, headers, body = read_response(s)
        assert status == 503 and time.monotonic() - t0 < 1.0 and not slow.done()
        assert 1 <= int(headers["retry-after"]) <= settings.max_retry_after_s
        slow.result(timeout=120)


def test_template_writers_answer_503_before_the_body_when_full(make_settings: Callable[..., Settings]) -> None:
    """/demonstrations and /feedback are bounded as /detect is: with workers + queue places all taken (here
    one, held by a demonstration whose body has not arrived), the next writer gets 503 before its body is
    read; once the holder goes away its place comes back."""
    settings = make_settings(port=0, detect_workers=1, queue_size=0, http_body_timeout_s=30.0)
    feedback = json.dumps({"grasp_id": "0123456789abcdef-0", "success": False}).encode()
    post = (b"POST /feedback HTTP/1.1\r\nHost: x\r\nContent-Type: application/json\r\nContent-Length: "
            + str(len(feedback)).encode() + b"\r\n\r\n" + feedback)
    with serve_in_thread(settings) as url:
        with connect(url) as holder:
            holder.sendall(b"POST /demonstrations HTTP/1.1\r\nHost: x\r\nContent-Type: application/json\r\n"
                           b"Content-Length: 1000\r\n\r\n{")
            time.sleep(0.3)  # the holder's place is taken while its body is awaited
            with connect(url) as s:
                t0 = time.monotonic()
                s.sendall(post)
                status, headers, body = read_response(s)
            assert status == 503 and time.monotonic() - t0 < 1.0, body
            assert 1 <= int(headers["retry-after"]) <= settings.max_retry_after_s
        deadline = time.monotonic() + 5  # the holder hung up: its place is given back
        while True:
            with connect(url) as s:
                s.sendall(post)
                status, _, body = read_response(s)
            if status != 503 or time.monotonic() > deadline:
                break
            time.sleep(0.1)
        assert status == 404 and json.loads(body)["field"] == "grasp_id", body  # parsed and looked up


def test_client_disconnect_is_info_without_traceback(make_settings: Callable[..., Settings],
                                                     caplog: pytest.LogCaptureFixture) -> None:
    caplog.handler.addFilter(RequestIdFilter())
    with caplog.at_level(logging.INFO), serve_in_thread(make_settings(port=0)) as url:
        with connect(url) as s:
            s.sendall(b"POST /detect HTTP/1.1\r\nHost: x\r\nContent-Type: application/json\r\n"
                      b"Content-Length: 1000\r\n\r\n{\"cloud\"")
            time.sleep(0.3)
        deadline = time.monotonic() + 5
        while time.monotonic() < deadline and not any("disconnected" in r.getMessage() for r in caplog.records):
            time.sleep(0.05)
        with connect(url) as s:  # a 422 logs why, with the request id the response returns
            s.sendall(b"POST /detect HTTP/1.1\r\nHost: x\r\nContent-Type: application/json\r\nContent-Length: 2\r\n"
                      b"\r\n[]")
            status, headers, _ = read_response(s)
            assert status == 422
        time.sleep(0.2)
    gone = [r for r in caplog.records if "disconnected" in r.getMessage()]
    assert gone and all(r.levelno == logging.INFO and r.exc_info is None for r in gone)
    assert not [r for r in caplog.records if r.levelno >= logging.ERROR]
    lines = [r for r in caplog.records if r.getMessage() == "detect" and getattr(r, "status", 0) == 422]
    assert lines and lines[-1].request_id == headers["x-request-id"]  # type: ignore[attr-defined]
    assert lines[-1].field == "body" and "JSON object" in lines[-1].error  # type: ignore[attr-defined]
