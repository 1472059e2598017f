"""One thread budget for the whole process: a lone detection uses every core, concurrent ones share them.

Stages that split into independent chunks (hand search over samples, image encoding over grasps, scoring
over images) hand them to THREADS.map: the calling thread works through the chunks together with up to
share() - 1 helpers from one process-wide pool, where share() = max(1, cores // running detections).  A
detection counts as running inside THREADS.running() (the service's engine wraps each request in it; a lone
caller such as the CLI does not need to).  numpy, scipy's KD-tree and onnxruntime release the GIL in their
large operations, which is where the chunks spend their time.  Chunks are the same whatever the share, so
results do not depend on it."""

from __future__ import annotations

import os
import threading
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from contextlib import contextmanager
from typing import TypeVar

T = TypeVar("T")
R = TypeVar("R")


def available_cores() -> int:
    """CPU cores this process may run on (affinity-aware)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover - non-Linux
        return max(1, os.cpu_count() or 1)


class ThreadBudget:
    """cores threads for the process, shared by the running detections (see the module docstring)."""

    def __init__(self, cores: int | None = None) -> None:
        self.cores = max(1, cores or available_cores())
        self._lock = threading.Lock()
        self._running = 0
        self._pool: ThreadPoolExecutor | None = None

    @property
    def running(self) -> int:
        return self._running

    @contextmanager
    def request(self) -> Iterator[None]:
        """Count a detection as running for the duration of the block."""
        with self._lock:
            self._running += 1
        try:
            yield
        finally:
            with self._lock:
                self._running -= 1

    def share(self) -> int:
        """Threads a detection may use now: all cores when it runs alone, cores // running otherwise (>= 1)."""
        return max(1, self.cores // max(1, self._running))

    def _executor(self) -> ThreadPoolExecutor:
        with self._lock:
            if self._pool is None:
                self._pool = ThreadPoolExecutor(self.cores, thread_name_prefix="graspd-chunk")
            return self._pool

    def map(self, fn: Callable[[T], R], items: Sequence[T], threads: int | None = None) -> list[R]:
        """[fn(x) for x in items], computed by this thread and up to share() - 1 (or threads - 1) pool threads
        taking the next item in turn; the first exception is raised after all have stopped."""
        k = min(len(items), self.share() if threads is None else max(1, threads))
        if k <= 1:
            return [fn(x) for x in items]
        results: list[R | None] = [None] * len(items)
        errors: list[BaseException] = []
        next_item = iter(range(len(items)))
        take = threading.Lock()

        def work() -> None:
            while True:
                with take:
                    if errors:
                        return
                    i = next(next_item, None)
                if i is None:
                    return
                try:
                    results[i] = fn(items[i])
                except BaseException as exc:  # re-raised in the caller
                    with take:
                        errors.append(exc)
                    return

        pool = self._executor()
        helpers: list[Future[None]] = [pool.submit(work) for _ in range(k - 1)]
        work()
        for f in helpers:
            if not f.cancel():  # a helper still queued behind other requests' chunks has nothing left to do
                f.result()
        if errors:
            raise errors[0]
        return results  # type: ignore[return-value]


#: The process's budget: the service's engine counts its requests in it, the pipeline stages map over it.
THREADS = ThreadBudget()
