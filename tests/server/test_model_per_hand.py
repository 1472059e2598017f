"""A model scores grasp images of the hand it was trained for: the response says whether the request's hand
is that hand, and a request naming no model gets a loaded model made for its hand when the default is not."""

from __future__ import annotations

import json
import shutil
from collections.abc import Callable
from pathlib import Path
from typing import Any

from fastapi.testclient import TestClient

from graspd.core.cloud import ViewpointCloud
from graspd.core.hand import HAND_PRESETS
from graspd.gpd.classifier import card_fits_hand, read_card
from graspd.server.app import create_app
from graspd.server.services.registry import ModelRegistry
from graspd.server.settings import Settings


def test_the_default_hand_fits_the_default_model_and_a_hand_without_a_model_does_not(
        scored_client: TestClient, krylon: ViewpointCloud, models_and_default: tuple[Path, str],
        small_body: Callable[..., dict[str, Any]]) -> None:
    name = models_and_default[1]
    same = scored_client.post("/detect", json=small_body(krylon)).json()
    assert same["model"] == name and same["model_fits_hand"] is True
    wide = {"finger_width": 0.01, "hand_outer_diameter": 0.14, "hand_depth": 0.06, "hand_height": 0.02}
    other = scored_client.post("/detect", json=small_body(krylon, hand=wide)).json()
    assert other["model"] == name and other["model_fits_hand"] is False, "no model made for this hand: said so"
    unscored = scored_client.post("/detect", json=small_body(krylon, use_classifier=False)).json()
    assert "model_fits_hand" not in unscored


def test_a_request_gets_the_model_made_for_its_hand(tmp_path: Path, models_and_default: tuple[Path, str],
                                                   make_settings: Callable[..., Settings],
                                                   krylon: ViewpointCloud,
                                                   small_body: Callable[..., dict[str, Any]]) -> None:
    """Routing by card: the default model, and a copy of it whose card says it was made for the panda hand
    (the registry reads nothing but the card to choose)."""
    src, name = models_and_default
    folder = tmp_path / "models"
    folder.mkdir()
    for suffix in (".onnx", ".json"):
        shutil.copy(src / f"{name}{suffix}", folder / f"{name}{suffix}")
    card = read_card(src / f"{name}.json")
    panda = HAND_PRESETS["panda"].to_dict()
    card.update(name="panda15", hand=panda)
    shutil.copy(src / f"{name}.onnx", folder / "panda15.onnx")
    (folder / "panda15.json").write_text(json.dumps(card))
    assert card_fits_hand(card, panda) and not card_fits_hand(read_card(src / f"{name}.json"), panda)

    registry = ModelRegistry.load(folder, default=name)
    assert registry.resolve(None, True, HAND_PRESETS["panda"]) == "panda15"
    assert registry.resolve(None, True, HAND_PRESETS["gpd"]) == name
    assert registry.resolve(name, True, HAND_PRESETS["panda"]) == name, "a named model is always honoured"
    with TestClient(create_app(make_settings(models_dir=folder, default_model=name))) as c:
        out = c.post("/detect", json=small_body(krylon, hand="panda")).json()
    assert out["model"] == "panda15" and out["model_fits_hand"] is True
