"""With a real classifier the project trained (the shipped default model, or the tiny test model) the
service scores and ranks grasps, names the model, and lists it with its card."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
from fastapi.testclient import TestClient

from graspd.core.cloud import ViewpointCloud


def test_scored_detection(scored_client: TestClient, krylon: ViewpointCloud, models_and_default: tuple[Path, str],
                          small_body: Callable[..., dict[str, Any]]) -> None:
    name = models_and_default[1]
    ready = scored_client.get("/readyz").json()
    assert ready["scoring"] is True and ready["default_model"] == name
    models = scored_client.get("/models").json()
    card = {m["name"]: m for m in models["models"]}[name]["card"]
    # where the default model runs, the same in /readyz and its card (no GPU in CI: the CPU)
    assert ready["provider"] == card["runtime"]["provider"] in ("CPUExecutionProvider", "CUDAExecutionProvider")
    assert models["default"] == name and card["name"] == name and "representation" in card
    out = scored_client.post("/detect", json=small_body(krylon, selection=False, max_grasps=1000)).json()
    assert out["scored"] is True and out["model"] == name and out["timings"]["score"] > 0
    scores = np.array([g["score"] for g in out["grasps"]], float)
    assert len(scores) > 5 and ((scores >= 0) & (scores <= 1)).all()
    assert scores.std() > 0, "a trained model separates candidates"
    ranked = scored_client.post("/detect", json=small_body(krylon)).json()
    top = np.array([g["score"] for g in ranked["grasps"][:5]], float)
    assert top.mean() > scores.mean(), "selection ranks high-scoring grasps first"
    named = scored_client.post("/detect", json=small_body(krylon, model=name)).json()
    assert named["model"] == name
    r = scored_client.post("/detect", json=small_body(krylon, model="generic99"))
    assert r.status_code == 422 and name in r.json()["error"] and r.json()["field"] == "model"
    kept = scored_client.post("/detect", json=small_body(krylon, selection=False, min_score=0.5)).json()
    assert all(g["score"] >= 0.5 for g in kept["grasps"])
