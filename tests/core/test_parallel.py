"""The process thread budget (graspd.core.parallel): shares, mapping, and detections that do not depend on it."""

from __future__ import annotations

import threading

import numpy as np
import pytest
from numpy.typing import NDArray

import graspd.core.parallel as parallel
from graspd.core.parallel import ThreadBudget
from graspd.gpd.detector import DetectionParams, GraspDetector
from graspd.gpd.environment import EnvironmentParams
from graspd.server.services.warmup import warmup_cloud


def test_share_divides_the_cores_among_running_requests() -> None:
    b = ThreadBudget(cores=4)
    assert b.share() == 4  # a lone caller outside any request: every core
    with b.request():
        assert b.share() == 4
        with b.request(), b.request():
            assert b.running == 3 and b.share() == 1
        assert b.share() == 4
    assert b.running == 0


def test_map_keeps_order_uses_helpers_and_raises() -> None:
    b = ThreadBudget(cores=3)
    seen: set[str] = set()

    def f(x: int) -> int:
        seen.add(threading.current_thread().name)
        return x * x

    assert b.map(f, list(range(50))) == [x * x for x in range(50)]
    assert b.map(f, []) == []
    assert b.map(f, [1, 2], threads=1) == [1, 4]

    def bad(x: int) -> int:
        if x == 7:
            raise ValueError("seven")
        return x

    with pytest.raises(ValueError, match="seven"):
        b.map(bad, list(range(20)))


class MeanScorer:
    """A deterministic stand-in classifier: the mean pixel of each image."""

    name = "mean"
    representation = "15"

    def score(self, images: NDArray[np.uint8]) -> NDArray[np.float32]:
        return (images.reshape(len(images), -1).mean(axis=1) / 255.0).astype(np.float32)


@pytest.mark.parametrize("cores", [2, 5])
def test_detection_does_not_depend_on_the_thread_budget(monkeypatch: pytest.MonkeyPatch, cores: int) -> None:
    cloud = warmup_cloud()
    # no environment model: open3d's RANSAC plane fit runs on OpenMP threads and varies a little between runs
    params = DetectionParams(num_samples=200, score_batch=300, environment=EnvironmentParams(mode="none"))
    monkeypatch.setattr(parallel.THREADS, "cores", 1)
    serial = GraspDetector(MeanScorer()).detect(cloud, params)
    monkeypatch.setattr(parallel.THREADS, "cores", cores)
    threaded = GraspDetector(MeanScorer()).detect(cloud, params)
    assert serial.num_candidates == threaded.num_candidates > 100
    for name in ("positions", "rotations", "widths", "scores"):
        assert np.array_equal(getattr(serial.grasps, name), getattr(threaded.grasps, name)), name
