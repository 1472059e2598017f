"""The classifier's execution provider (a CUDA GPU when onnxruntime offers one, else the CPU) and the service's
warm-up taking the path of a real request: the model cascade, full batches, the response."""

from __future__ import annotations

import json
import threading
from pathlib import Path

import numpy as np
import pytest

from graspd.gpd import classifier
from graspd.gpd.classifier import CPU_PROVIDER, choose_providers, load_model
from graspd.server.metrics import Metrics
from graspd.server.services import warmup
from graspd.server.services.engine import DetectionEngine
from graspd.server.services.registry import ModelRegistry
from graspd.server.services.warmup import WARMUP_SAMPLES, warm_detection, warmup_body
from graspd.server.settings import Settings

SHIPPED = Path(__file__).resolve().parents[2] / "models"


def test_a_gpu_provider_is_chosen_when_offered_with_the_cpu_behind_it(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv(classifier.PROVIDER_ENV, raising=False)
    assert choose_providers(["CUDAExecutionProvider", CPU_PROVIDER]) == ["CUDAExecutionProvider", CPU_PROVIDER]
    assert choose_providers(["AzureExecutionProvider", CPU_PROVIDER]) == [CPU_PROVIDER]
    monkeypatch.setenv(classifier.PROVIDER_ENV, "cpu")
    assert choose_providers(["CUDAExecutionProvider", CPU_PROVIDER]) == [CPU_PROVIDER]


def test_the_classifier_reports_its_provider_and_scores_as_before() -> None:
    model = load_model("scene3", SHIPPED)
    assert model.provider in model.session.get_providers()
    assert model.card["runtime"]["provider"] == model.provider
    assert "runtime" not in json.loads((SHIPPED / "scene3.json").read_text())  # the file's card is untouched
    images = (np.random.default_rng(0).random((70, 3, 60, 60)) < 0.1).astype(np.uint8) * 200
    x = images.astype(np.float32) * model.scale + model.offset
    expected = np.clip(model.session.run(None, {model.input_name: x})[0].reshape(-1), 0.0, 1.0)
    np.testing.assert_array_equal(model.score(images), expected)


def test_the_warm_up_runs_the_cascade_a_full_batch_and_the_response() -> None:
    registry = ModelRegistry.load(SHIPPED, cascade="scene3")
    assert registry.default is not None
    assert registry.detector(registry.default).prefilter is not None
    assert warmup_body()["num_samples"] == WARMUP_SAMPLES
    det, body = warm_detection(registry)
    assert det.model == registry.default
    assert "prefilter" in det.timings and det.timings["prefilter"] > 0.0  # both stages of the cascade ran
    assert det.num_candidates > 0 and len(det.grasps) > 0
    assert json.loads(body)["num_candidates"] == det.num_candidates


def test_the_engine_warms_each_detect_worker_once(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    threads: list[str] = []
    def record(registry: ModelRegistry) -> None:
        threads.append(threading.current_thread().name)

    monkeypatch.setattr(warmup, "warm_detection", record)
    registry = ModelRegistry.load(SHIPPED, cascade="scene3")
    engine = DetectionEngine(Settings(warmup=True, detect_workers=2, data_dir=tmp_path), registry, Metrics())
    try:
        assert len(threads) == 2 and len(set(threads)) == 2  # one warm-up on each worker thread
        assert all(name.startswith("graspd-detect") for name in threads)
    finally:
        engine.close()
    cold = DetectionEngine(Settings(warmup=False, detect_workers=2, data_dir=tmp_path), registry, Metrics())
    cold.close()
    assert len(threads) == 2  # GRASPD_WARMUP=false: none
