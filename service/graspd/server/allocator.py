"""glibc malloc settings for a server that receives megabyte-sized request bodies on one thread and frees
them on others: at most two arenas (bounded per-thread heaps), and free heap memory handed back to the OS
after each request (malloc_trim), so fragmentation does not look like growth.  No effect elsewhere than
glibc.  (A fixed low mmap threshold also stops the growth but slows numpy-heavy detection by ~50%.)"""

from __future__ import annotations

import ctypes
import ctypes.util
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
