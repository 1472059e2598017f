"""glibc malloc settings for a server that receives megabyte-sized request bodies on one thread and frees
them on others: at most two arenas (bounded per-thread heaps), and free heap memory handed back to the OS
after each request (malloc_trim), so fragmentation does not look like growth.  No effect elsewhere than
glibc.  (A fixed low mmap threshold also stops the growth but slows numpy-heavy detection by ~50%.)"""

from __future__ import annotations

import ctypes
import ctypes.util
import threading
import time
from collections.abc import Callable
from functools import lru_cache
from typing import Any

M_ARENA_MAX = -8  # glibc mallopt parameter number (malloc.h)


@lru_cache(maxsize=1)
def _libc() -> Any:
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        libc.mallopt  # noqa: B018  (glibc only)
        libc.malloc_trim  # noqa: B018
    except (OSError, AttributeError):
        return None
    return libc


def tune_malloc(arenas: int = 2) -> bool:
    """Cap the number of malloc arenas (call before threads start); False when the C library is not glibc."""
    libc = _libc()
    return bool(libc is not None and libc.mallopt(M_ARENA_MAX, arenas) == 1)


def trim_function() -> Callable[[], None]:
    """A callable that returns free heap memory to the OS (a no-op without glibc)."""
    libc = _libc()
    if libc is None:
        return lambda: None

    def trim() -> None:
        libc.malloc_trim(0)

    return trim


class IdleTrimmer:
    """Runs trim on its own thread once the server has been idle for idle_s seconds after a request (busy()
    false), or after max_interval_s of continuous load: malloc_trim holds the allocator's locks for
    milliseconds, so running it right after a reply delays the next request's (and the reply's) allocations."""

    def __init__(self, trim: Callable[[], None], busy: Callable[[], bool], idle_s: float = 0.05,
                 max_interval_s: float = 2.0) -> None:
        self._trim = trim
        self._busy = busy
        self.idle_s = idle_s
        self.max_interval_s = max_interval_s
        self._cond = threading.Condition()
        self._last_done = 0.0  # monotonic time of the latest finished request
        self._dirty_since: float | None = None  # first finished request since the last trim
        self._closed = False
        self.trims = 0
        self._thread = threading.Thread(target=self._run, name="graspd-trim", daemon=True)
        self._thread.start()

    def request_done(self) -> None:
        """A request finished: trim once the server is idle (or after max_interval_s)."""
        with self._cond:
            now = time.monotonic()
            self._last_done = now
            if self._dirty_since is None:
                self._dirty_since = now
            self._cond.notify()

    def _run(self) -> None:
        with self._cond:
            while not self._closed:
                if self._dirty_since is None:
                    self._cond.wait()
                    continue
                now = time.monotonic()
                idle_at = self._last_done + self.idle_s
                overdue = now - self._dirty_since >= self.max_interval_s
                if not overdue and (now < idle_at or self._busy()):
                    self._cond.wait(timeout=max(idle_at - now, self.idle_s))
                    continue
                self._dirty_since = None
                self._cond.release()
                try:
                    self._trim()
                    self.trims += 1
                finally:
                    self._cond.acquire()

    def close(self) -> None:
        """Stop the trimming thread (a pending trim is dropped)."""
        with self._cond:
            self._closed = True
            self._cond.notify()
        self._thread.join(timeout=5)
