"""The one way graspd compiles a hot loop: numba's njit, cached on disk and releasing the GIL.

Kernels are plain loops over numpy arrays with fixed dtypes (callers cast first, so each kernel compiles once:
float32 points, float64 frames, int64 indices).  `nogil` lets the process's thread budget (graspd.core.parallel)
run them on every core; `cache` keeps the machine code beside the module (or in numba's per-user cache where the
package is read-only), so a new process loads it instead of compiling.  The service's warm-up detection runs
every kernel a request runs before it says ready."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, TypeVar

import numba

F = TypeVar("F", bound=Callable[..., Any])


def kernel(fn: F) -> F:
    """Compile fn with numba (nopython, cached, GIL released, no fast-math: results match numpy's arithmetic)."""
    return numba.njit(cache=True, nogil=True, fastmath=False, error_model="numpy")(fn)  # type: ignore[no-any-return,return-value]
