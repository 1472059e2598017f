"""IdleTrimmer: malloc_trim runs once the server is idle after requests, not while it is busy (until the
longest interval passes), and not at all without requests."""

from __future__ import annotations

import threading
import time
from collections.abc import Callable

from graspd.server.services.allocator import IdleTrimmer, trim_function


def wait_for(condition: Callable[[], bool], timeout: float = 10.0) -> bool:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if condition():
            return True
        time.sleep(0.01)
    return condition()


def test_trims_when_idle_not_while_busy_and_not_without_requests() -> None:
    calls: list[float] = []
    lock = threading.Lock()
    busy = [True]

    def trim() -> None:
        trim_function()()  # the real malloc_trim (a no-op without glibc)
        with lock:
            calls.append(time.monotonic())

    trimmer = IdleTrimmer(trim, busy=lambda: busy[0], idle_s=0.02, max_interval_s=60.0)
    try:
        time.sleep(0.2)
        assert not calls, "no request finished: nothing to trim"
        trimmer.request_done()
        time.sleep(0.3)
        assert not calls, "requests still running: no trim before the longest interval"
        busy[0] = False
        assert wait_for(lambda: len(calls) == 1), "idle after a request: one trim"
        time.sleep(0.2)
        assert len(calls) == 1, "one trim per idle period"
    finally:
        trimmer.close()


def test_trims_under_continuous_load_after_the_longest_interval() -> None:
    calls: list[float] = []
    trimmer = IdleTrimmer(lambda: calls.append(time.monotonic()), busy=lambda: True, idle_s=0.02,
                          max_interval_s=0.3)
    try:
        start = time.monotonic()
        trimmer.request_done()
        assert wait_for(lambda: bool(calls)), "busy for longer than max_interval_s: trimmed anyway"
        assert calls[0] - start >= 0.3
    finally:
        trimmer.close()
    assert not trimmer._thread.is_alive()
