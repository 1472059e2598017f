"""The memory budget of detection (issue 23 item 2): admission by a request's estimated cost.

A detection's working set is estimated from what the request asks for (measured on this service: see
bench/hostile.py and the README's hardening section):

- BASE_MB for any detection (candidate geometry, thread buffers, the response),
- SAMPLE_MB per sample (num_samples: candidates, their grasp images and scores),
- POINT_BYTES per cloud point (the decoded arrays, normals, the preprocessed copies),
- the crops' image and windows, when crops are asked for.

The budget (GRASPD_DETECT_MEMORY_MB) caps the sum over the detections running at once.  A request that can never
fit gets 413 naming the field that costs most (and how far it must shrink); one that cannot fit now waits on its
worker up to GRASPD_DETECT_MEMORY_WAIT_S for running detections to finish, then gets 503 with Retry-After.
HTTP checks the body's size before reading it (BudgetGate in graspd.server.api.guards: the densest cloud is 12 bytes
a point), and every transport (HTTP, Zenoh, the ROS streams) takes its exact share on the worker
right after the request is parsed, before any detection work.

The same place refuses (503, Retry-After) a request whose expected time (work_units x the learned seconds per
unit) would pass its deadline, and a request that waited in the queue past its deadline gets 503 rather than 504
when the typical request fits the deadline (the queue, not the request, was the problem): under a flood of
5M-point clouds every request is answered 200, 413 or 503 within the deadline instead of 504 after it.
"""

from __future__ import annotations

import threading
from typing import Any

from graspd.server.problems import Problem

MB = float(1 << 20)
#: Working set of any detection (MiB), per sample (MiB), per cloud point (bytes); measured on 100k-5M point
#: clouds, unscored (2026-11, peak RSS above an idle warm process: one detection of 300 samples +475-520 MiB,
#: four at once +1501 MiB, 1000 samples +821 MiB, 3000 samples +896 MiB; 100k to 5M points +90 MiB).
BASE_MB = 350.0
SAMPLE_MB = 0.25
POINT_BYTES = 40.0
#: The densest cloud encoding (binary float32 x, y, z): the most points a body of n bytes can hold is n / 12.
DENSEST_POINT_BYTES = 12


def request_cost(points: int, samples: int, crops: int = 0, crop_size: int = 0,
                 image_pixels: int = 0) -> dict[str, float]:
    """Estimated MiB by request field: cloud (points), num_samples, crops (the decoded image and one RGB window
    per grasp), plus "base"."""
    return {"base": BASE_MB, "cloud": points * POINT_BYTES / MB, "num_samples": samples * SAMPLE_MB,
            "crops": (image_pixels * 3 * 2 + crops * crop_size * crop_size * 3 * 2) / MB}


#: Copies of a ROS 2 service request alive while the node decodes it: the sample DDS hands over and the bytes the
#: node keeps (graspd.io.ros decodes in place, on views of them).
MESSAGE_COPIES = 2


def message_cost(message_bytes: int, work_mb: float = 0.0) -> dict[str, float]:
    """Estimated MiB of a ROS 2 service request while its message is decoded, before its detection (which takes
    cost_of): the message's copies ("message") plus work_mb of bounded work arrays ("base")."""
    return {"base": work_mb, "message": MESSAGE_COPIES * message_bytes / MB}


def cost_of(req: Any) -> dict[str, float]:
    """request_cost of a parsed DetectRequest."""
    crops = getattr(req, "crops", None)
    image = getattr(crops, "image", None) if crops is not None else None
    pixels = int(image.shape[0] * image.shape[1]) if image is not None and getattr(image, "ndim", 0) >= 2 else 0
    return request_cost(len(req.cloud.points), int(req.num_samples),
                        int(req.max_grasps) if crops is not None else 0,
                        int(getattr(crops, "size", 0) or 0), pixels)


#: A detection's work units: 1 + points / POINTS_PER_UNIT + samples / SAMPLES_PER_UNIT.  Measured on 2 shared
#: cores (2026-11): 66k points, 300 samples (2.3 units) in 0.66 s; 5M points, 300 samples (26 units) in 12-17 s.
POINTS_PER_UNIT = 200_000
SAMPLES_PER_UNIT = 300
#: Seconds per work unit of a detection running alone, before any detection was timed (the measurements above,
#: rounded up); the engine multiplies by the detections sharing the cores at its start.
UNIT_SECONDS = 0.6
#: Under load (other detections running, or a queue wait over 1 s) expected seconds are multiplied by this before
#: they are compared with the time left: a detection's time varies with the machine's load, and a refusal costs a
#: retry where an overrun costs a 504 and wasted cores.  A lone request fits if its plain estimate does.
TIME_MARGIN = 1.5


def work_units(req: Any) -> float:
    """How much detection work a parsed DetectRequest asks for (see POINTS_PER_UNIT): its expected seconds are
    units x MemoryBudget.unit_seconds x the detections sharing the cores, learned from the detections that ran."""
    return 1.0 + len(req.cloud.points) / POINTS_PER_UNIT + int(req.num_samples) / SAMPLES_PER_UNIT


class MemoryBudget:
    """MiB held by the detections admitted now, at most budget_mb (0: no budget)."""

    def __init__(self, budget_mb: float) -> None:
        self.budget_mb = float(budget_mb)
        self.used_mb = 0.0
        self.waiters = 0  # requests waiting in take() for memory to be given back
        self._cond = threading.Condition()
        self.unit_seconds = UNIT_SECONDS  # EWMA of a detection's seconds per work unit (observe())

    def observe(self, units: float, seconds: float) -> None:
        """Learn seconds per work unit from a detection that ran (units 0: it was refused before parsing)."""
        if units > 0 and seconds > 0.05:
            with self._cond:
                self.unit_seconds = 0.8 * self.unit_seconds + 0.2 * seconds / units

    def _too_big(self, parts: dict[str, float]) -> Problem:
        total = sum(parts.values())
        field = max((k for k in parts if k != "base"), key=lambda k: parts[k])
        over = total - self.budget_mb
        cloud, samples = parts.get("cloud", 0.0), parts.get("num_samples", 0.0)
        hint = {"cloud": f"at most about {int(max(0.0, cloud - over) * MB / POINT_BYTES)} points (or a "
                         "coarser voxel_size before sending)",
                "num_samples": f"num_samples at most {int(max(0.0, samples - over) / SAMPLE_MB)}",
                "crops": "fewer grasps (max_grasps) or a smaller crops.size or image"}.get(field, f"a smaller {field}")
        return Problem(413, f"this request needs about {total:.0f} MiB of detection memory, more than the server's "
                            f"budget of {self.budget_mb:.0f} MiB (GRASPD_DETECT_MEMORY_MB): send {hint}", field)

    def take(self, parts: dict[str, float], retry_after: float, wait_s: float = 0.0) -> float:
        """Hold the request's estimated MiB: Problem 413 naming the costliest field when it exceeds the whole
        budget; when the detections running now leave too little, wait up to wait_s seconds for them to give
        some back, then 503 with Retry-After.  Returns the MiB to give back."""
        total = sum(parts.values())
        if self.budget_mb <= 0:
            return 0.0
        if total > self.budget_mb:
            raise self._too_big(parts)
        with self._cond:
            if not self._fits(total):
                self.waiters += 1
                try:
                    fits = self._cond.wait_for(lambda: self._fits(total), max(0.0, wait_s))
                finally:
                    self.waiters -= 1
                if not fits:
                    raise Problem(503, f"server busy: detections running now hold {self.used_mb:.0f} of "
                                       f"{self.budget_mb:.0f} MiB and this request needs about {total:.0f}",
                                  retry_after=retry_after)
            self.used_mb += total
        return total

    def _fits(self, total: float) -> bool:
        return self.used_mb <= 0 or self.used_mb + total <= self.budget_mb

    def give(self, mb: float) -> None:
        """Give back what take() returned (and wake the requests waiting for memory)."""
        if mb:
            with self._cond:
                self.used_mb = max(0.0, self.used_mb - mb)
                self._cond.notify_all()

    def check_body(self, body_bytes: int, retry_after: float) -> None:
        """Before a body of body_bytes is read: 413 (field body) when even its least costly reading (the densest
        cloud, one sample) cannot fit the budget, 503 when it cannot fit now and other requests already wait for
        memory."""
        if self.budget_mb <= 0:
            return
        parts = request_cost(body_bytes // DENSEST_POINT_BYTES, 1)
        total = sum(parts.values())
        if total > self.budget_mb:
            raise Problem(413, f"a body of {body_bytes} bytes holds up to {body_bytes // DENSEST_POINT_BYTES} points, "
                               f"about {total:.0f} MiB of detection memory, more than the server's budget of "
                               f"{self.budget_mb:.0f} MiB (GRASPD_DETECT_MEMORY_MB)", "body")
        with self._cond:
            if self.waiters and not self._fits(total):  # requests already wait for memory: do not hold a body too
                raise Problem(503, f"server busy: detections running now hold {self.used_mb:.0f} of "
                                   f"{self.budget_mb:.0f} MiB and {self.waiters} more wait for memory",
                              retry_after=retry_after)
