"""With a real classifier (the tiny model the training pipeline makes for tests, ~1 min on 2 cores) the
service scores and ranks grasps, names the model, and lists it with its card."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from fastapi.testclient import TestClient

from graspd.cloud import ViewpointCloud
from graspd.server.app import create_app
from graspd.server.settings import Settings


@pytest.fixture(scope="session")
def tiny_models_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A folder holding one real model the project trained: the tiny test model (~1 min to make)."""
    from graspd.training.train import train_tiny_model

    return train_tiny_model(tmp_path_factory.mktemp("tiny-model"), seed=0).parent


@pytest.fixture
def scored_client(make_settings: Callable[..., Settings], tiny_models_dir: Path) -> Iterator[TestClient]:
    with TestClient(create_app(make_settings(models_dir=tiny_models_dir))) as c:
        yield c


def test_scored_detection(scored_client: TestClient, krylon: ViewpointCloud,
                          small_body: Callable[..., dict[str, Any]]) -> None:
    ready = scored_client.get("/readyz").json()
    assert ready["scoring"] is True and ready["default_model"] == "tiny15"
    models = scored_client.get("/models").json()
    assert models["default"] == "tiny15" and models["models"][0]["card"]["representation"] == "15"
    out = scored_client.post("/detect", json=small_body(krylon, selection=False, max_grasps=1000)).json()
    assert out["scored"] is True and out["model"] == "tiny15" and out["timings"]["score"] > 0
    scores = np.array([g["score"] for g in out["grasps"]], float)
    assert len(scores) > 5 and ((scores >= 0) & (scores <= 1)).all()
    assert scores.std() > 0, "a trained model separates candidates"
    ranked = scored_client.post("/detect", json=small_body(krylon)).json()
    top = np.array([g["score"] for g in ranked["grasps"][:5]], float)
    assert top.mean() > scores.mean(), "selection ranks high-scoring grasps first"
    named = scored_client.post("/detect", json=small_body(krylon, model="tiny15")).json()
    assert named["model"] == "tiny15"
    r = scored_client.post("/detect", json=small_body(krylon, model="generic99"))
    assert r.status_code == 422 and "tiny15" in r.json()["error"]
    kept = scored_client.post("/detect", json=small_body(krylon, selection=False, min_score=0.5)).json()
    assert all(g["score"] >= 0.5 for g in kept["grasps"])
