"""Run the service in a background thread of this process (tests, notebooks): a real uvicorn server on
a real socket, stopped gracefully on exit."""

from __future__ import annotations

import socket
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager

from .settings import Settings


def free_port(host: str = "127.0.0.1") -> int:
    """A TCP port nobody listens on right now."""
    with socket.socket() as s:
        s.bind((host, 0))
        return int(s.getsockname()[1])


@contextmanager
def serve_in_thread(settings: Settings, startup_timeout: float = 60.0) -> Iterator[str]:
    """Serve create_app(settings) on settings.host:port (0 = a free port); yields the base URL."""
    import uvicorn

    from .app import create_app

    port = settings.port or free_port(settings.host)
    config = uvicorn.Config(create_app(settings), host=settings.host, port=port, log_config=None,
                            access_log=False, lifespan="on")
    server = uvicorn.Server(config)
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
