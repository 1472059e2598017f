"""The ROS 2 services' share of the detection engine: at most a fixed number of service calls admitted at once
(queued or running), so that a flood of detect_grasps or plan_grasps calls always leaves a detect worker and
the rest of the queue to HTTP and Zenoh.  Over the share a call is refused at once with 503 and Retry-After."""

from __future__ import annotations

import threading

from graspd.server.problems import Problem


def service_share(workers: int) -> int:
    """Service calls admitted at once on an engine of workers detect workers: all but one (at least one)."""
    return max(1, workers - 1)


class ServiceShare:
    """A counter of admitted ROS 2 service calls, at most limit."""

    def __init__(self, limit: int) -> None:
        self.limit = limit
        self.held = 0
        self._lock = threading.Lock()

    def take(self, retry_after: float) -> None:
        """Hold one place, or Problem 503 (Retry-After retry_after s) when limit calls already hold one."""
        with self._lock:
            if self.held >= self.limit:
                raise Problem(503, f"ROS 2 services busy: {self.held} calls admitted, at most {self.limit} at once "
                                   "(the other detect workers stay free for HTTP)", retry_after=retry_after)
            self.held += 1

    def give(self) -> None:
        """Give back a place taken by take()."""
        with self._lock:
            self.held = max(0, self.held - 1)
