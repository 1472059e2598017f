"""Prometheus metrics of one service instance (own registry, so several apps can live in one process)."""

from __future__ import annotations

from prometheus_client import CollectorRegistry, Counter, Gauge, Histogram

STAGE_BUCKETS = (0.001, 0.0025, 0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1.0, 2.5, 5.0, 10.0, 30.0)
COUNT_BUCKETS = (0, 1, 10, 30, 100, 300, 1000, 3000, 10000, 30000, 100000)


class Metrics:
    """Request counts by transport and outcome, per-stage latency, candidates per request, queue depth."""

    def __init__(self) -> None:
        self.registry = CollectorRegistry()
        r = self.registry
        self.requests = Counter("graspd_requests", "detect requests by transport and outcome",
                                ["transport", "outcome"], registry=r)
        self.request_seconds = Histogram("graspd_request_seconds", "detect wall time per request (s)",
                                         ["transport"], buckets=STAGE_BUCKETS, registry=r)
        self.stage_seconds = Histogram("graspd_stage_seconds", "time per pipeline stage (s)", ["stage"],
                                       buckets=STAGE_BUCKETS, registry=r)
        self.candidates = Histogram("graspd_candidates", "grasp candidates per request", buckets=COUNT_BUCKETS,
                                    registry=r)
        self.grasps = Histogram("graspd_grasps", "grasps returned per request", buckets=COUNT_BUCKETS, registry=r)
        self.points = Histogram("graspd_points", "points per request after preprocessing",
                                buckets=COUNT_BUCKETS + (300000, 1000000), registry=r)
        self.queue_depth = Gauge("graspd_queue_depth", "detect requests waiting for a worker", registry=r)
        self.running = Gauge("graspd_running", "detect requests being worked on", registry=r)
        self.stream_dropped = Counter("graspd_stream_dropped", "streamed clouds replaced by a newer one "
                                      "before they were processed", registry=r)

    def observe_timings(self, timings: dict[str, float]) -> None:
        for stage, seconds in timings.items():
            self.stage_seconds.labels(stage).observe(seconds)
