"""The one way graspd compiles a hot loop: numba's njit, cached on disk and releasing the GIL.

Kernels are plain loops over numpy arrays with fixed dtypes (callers cast first, so each kernel compiles once:
float32 points, float64 frames, int64 indices).  `nogil` lets the process's thread budget (graspd.core.parallel)
run them on every core; `cache` keeps the machine code on disk, so a new process loads it (well under a second)
instead of compiling (seconds).  The cache lives beside the modules, or where NUMBA_CACHE_DIR says; when the
package is read-only and that is unset (an installed image run as another user), in a per-user folder of the
temporary directory.  The service's warm-up detection runs every kernel a request runs before it says ready."""

from __future__ import annotations

import os
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import Any, TypeVar

F = TypeVar("F", bound=Callable[..., Any])


def _cache_dir() -> None:
    """Point numba's cache at a writable folder when neither the package nor NUMBA_CACHE_DIR offers one."""
    if os.environ.get("NUMBA_CACHE_DIR") or os.access(Path(__file__).resolve().parents[1], os.W_OK):
        return
    home = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache")
    folder = home / "graspd" / "numba"
    try:
        folder.mkdir(parents=True, exist_ok=True)
        writable = os.access(folder, os.W_OK)
    except OSError:
        writable = False
    if not writable:
        folder = Path(tempfile.gettempdir()) / f"graspd-numba-{os.getuid()}"
        folder.mkdir(mode=0o700, exist_ok=True)
    os.environ["NUMBA_CACHE_DIR"] = str(folder)


_cache_dir()

import numba  # noqa: E402 - after the cache folder is chosen: numba reads NUMBA_CACHE_DIR when imported


def kernel(fn: F) -> F:
    """Compile fn with numba (nopython, cached, GIL released, no fast-math: results match numpy's arithmetic)."""
    return numba.njit(cache=True, nogil=True, fastmath=False, error_model="numpy")(fn)  # type: ignore[no-any-return,return-value]
