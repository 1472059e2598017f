"""The service's cascade: the configured first-pass model prefilters for every model made for its hand, and a
request can switch it off."""

from __future__ import annotations

import json
import shutil
from collections.abc import Callable
from pathlib import Path
from typing import Any

from fastapi.testclient import TestClient

from graspd.core.cloud import ViewpointCloud
from graspd.core.hand import HAND_PRESETS
from graspd.gpd.classifier import default_models_dir
from graspd.server.app import create_app
from graspd.server.services.registry import ModelRegistry
from graspd.server.settings import Settings

SHIPPED = default_models_dir()


def _folder(tmp_path: Path) -> Path:
    """generic15, a 3-channel first pass (the shipped rep3-view) and a copy of generic15 whose card says panda."""
    out = tmp_path / "models"
    out.mkdir(parents=True)
    for src, name in ((SHIPPED / "generic15", "generic15"), (SHIPPED / "comparison" / "rep3-view", "first3")):
        shutil.copy(src.with_suffix(".onnx"), out / f"{name}.onnx")
        card = json.loads(src.with_suffix(".json").read_text())
        (out / f"{name}.json").write_text(json.dumps({**card, "name": name}))
    card = json.loads((SHIPPED / "generic15.json").read_text())
    shutil.copy(SHIPPED / "generic15.onnx", out / "panda15.onnx")
    (out / "panda15.json").write_text(json.dumps({**card, "name": "panda15", "hand": HAND_PRESETS["panda"].to_dict()}))
    return out


def test_the_first_pass_serves_only_models_of_its_own_hand(tmp_path: Path) -> None:
    reg = ModelRegistry.load(_folder(tmp_path), "generic15", cascade="first3")
    assert reg.detector("generic15").prefilter is reg.classifiers["first3"]
    assert reg.detector("first3").prefilter is None  # never its own first pass
    assert reg.detector("panda15").prefilter is None  # made for another hand
    assert ModelRegistry.load(_folder(tmp_path / "b"), "generic15", cascade="missing").cascade is None


def test_a_request_can_switch_the_cascade_off(tmp_path: Path, make_settings: Callable[..., Settings],
                                              krylon: ViewpointCloud,
                                              small_body: Callable[..., dict[str, Any]]) -> None:
    settings = make_settings(models_dir=_folder(tmp_path), default_model="generic15", cascade_model="first3")
    with TestClient(create_app(settings)) as c:
        assert c.get("/models").json()["cascade"] == "first3"
        body = small_body(krylon, num_samples=200)
        on = c.post("/detect", json=body).json()
        off = c.post("/detect", json={**body, "cascade": False}).json()
    assert on["model"] == off["model"] == "generic15"
    assert off["num_candidates"] > 200, "enough candidates for the first pass to cut"
    assert on["num_candidates"] == max(200, -(-3 * off["num_candidates"] // 10))
    assert "prefilter" in on["timings"] and "prefilter" not in off["timings"]
