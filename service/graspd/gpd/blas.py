"""BLAS threads: one per call in a process that parallelises detections itself (graspd.core.parallel).

numpy's and scipy's OpenBLAS start a thread per core for a large enough matrix product and let those threads spin
between calls; beside the process's own thread budget they compete with the detection's chunks for the same cores
and burn CPU while waiting.  set_blas_threads finds the OpenBLAS libraries loaded in this process (Linux: from
/proc/self/maps) and sets their thread count, as threadpoolctl does, without the dependency.  Results do not
change: OpenBLAS splits a product over threads by output blocks, each summed the same way."""

from __future__ import annotations

import ctypes
import logging
from pathlib import Path

log = logging.getLogger("graspd.gpd")

#: The setters the OpenBLAS builds of numpy and scipy wheels export (64-bit-integer builds carry a suffix).
_SETTERS = ("scipy_openblas_set_num_threads64_", "scipy_openblas_set_num_threads", "openblas_set_num_threads64_",
            "openblas_set_num_threads")


def loaded_openblas() -> list[str]:
    """Paths of the OpenBLAS shared libraries mapped into this process (empty where /proc is absent)."""
    try:
        maps = Path("/proc/self/maps").read_text()
    except OSError:
        return []
    paths = {line.split(None, 5)[-1] for line in maps.splitlines() if "openblas" in line.lower() and "/" in line}
    return sorted(p for p in paths if ".so" in p)


def set_blas_threads(threads: int = 1) -> int:
    """Set the thread count of every loaded OpenBLAS (numpy's, scipy's) to `threads`; how many were set.  Never
    raises: a library without a known setter is left as it is."""
    import numpy  # noqa: F401, PLC0415 - numpy's BLAS is loaded with numpy
    import scipy.linalg  # noqa: F401, PLC0415 - scipy's with its linear algebra

    done = 0
    for path in loaded_openblas():
        try:
            lib = ctypes.CDLL(path)
        except OSError:
            continue
        for name in _SETTERS:
            setter = getattr(lib, name, None)
            if setter is not None:
                setter(ctypes.c_int(threads))
                done += 1
                break
    log.debug("BLAS threads set", extra={"threads": threads, "libraries": done})
    return done
