"""Warm start: the service runs one detection on a bundled cloud before it answers (GRASPD_WARMUP)."""

from __future__ import annotations

import logging
from collections.abc import Callable
from pathlib import Path

import pytest
from fastapi.testclient import TestClient

from graspd.core.parallel import THREADS, available_cores
from graspd.gpd.detector import DetectionParams, GraspDetector
from graspd.server.app import create_app
from graspd.server.services.registry import ModelRegistry
from graspd.server.services.warmup import WARMUP_SAMPLES, warm_up, warmup_cloud
from graspd.server.settings import Settings


def test_warmup_cloud_exercises_the_whole_pipeline() -> None:
    det = GraspDetector().detect(warmup_cloud(), DetectionParams(num_samples=WARMUP_SAMPLES))
    assert det.environment is not None and det.environment.support is not None  # the table is found
    assert det.num_candidates > 0 and len(det.grasps) > 0


def test_warm_up_never_raises(monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture) -> None:
    reg = ModelRegistry(allow_unscored=True)

    def broken(*_: object, **__: object) -> None:
        raise RuntimeError("boom")

    monkeypatch.setattr(GraspDetector, "detect", broken)
    with caplog.at_level(logging.WARNING, logger="graspd.server"):
        assert warm_up(reg) >= 0.0
    assert "warm-up detection failed" in caplog.text


@pytest.mark.parametrize("warmup", [True, False])
def test_service_warms_up_before_it_answers(make_settings: Callable[..., Settings],
                                            models_and_default: tuple[Path, str], warmup: bool,
                                            caplog: pytest.LogCaptureFixture) -> None:
    with caplog.at_level(logging.INFO, logger="graspd.server"), \
            TestClient(create_app(make_settings(models_dir=models_and_default[0], warmup=warmup))) as c:
        done = [r for r in caplog.records if r.getMessage() == "warm-up detection done"]
        assert c.get("/readyz").status_code == 200
    assert len(done) == (1 if warmup else 0)
    if warmup:
        assert getattr(done[0], "model", None) == models_and_default[1]  # scored with the default model
        assert getattr(done[0], "candidates", 0) > 0


def test_warmup_setting_from_environment(monkeypatch: pytest.MonkeyPatch) -> None:
    assert Settings().warmup is True
    monkeypatch.setenv("GRASPD_WARMUP", "false")
    assert Settings().warmup is False


def test_threads_setting_sizes_the_process_budget(make_settings: Callable[..., Settings],
                                                  monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(THREADS, "cores", THREADS.cores)  # restored after the test
    with TestClient(create_app(make_settings(threads=1, warmup=False))):
        assert THREADS.cores == 1 and THREADS.share() == 1
    with TestClient(create_app(make_settings(warmup=False))):
        assert THREADS.cores == available_cores()
