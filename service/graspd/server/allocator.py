"""glibc malloc settings for a server that receives megabyte-sized request bodies on one thread and frees
them on another: a fixed mmap threshold sends every large buffer to mmap (returned to the OS on free)
instead of letting glibc raise the threshold and grow fragmented heaps, and two arenas bound the
per-thread heaps.  No effect elsewhere than glibc."""

from __future__ import annotations

import ctypes
import ctypes.util

M_MMAP_THRESHOLD = -3  # glibc mallopt parameter numbers (malloc.h)
M_ARENA_MAX = -8


def tune_malloc(mmap_threshold: int = 128 * 1024, arenas: int = 2) -> bool:
    """Apply the settings (call before threads start); False when the C library is not glibc."""
    name = ctypes.util.find_library("c")
    try:
        libc = ctypes.CDLL(name or "libc.so.6")
        mallopt = libc.mallopt
    except (OSError, AttributeError):
        return False
    return bool(mallopt(M_MMAP_THRESHOLD, mmap_threshold) == 1 and mallopt(M_ARENA_MAX, arenas) == 1)
