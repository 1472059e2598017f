"""A model scores grasp images of the hand it was trained for, or serves a hand the benchmarks chose it for: the
response says whether the model serves the request's hand, and a request naming no model gets a loaded model made
for its hand when the default does not serve it."""

from __future__ import annotations

import json
import shutil
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
from fastapi.testclient import TestClient

from graspd.core.cloud import ViewpointCloud
from graspd.core.hand import HAND_PRESETS
from graspd.gpd.classifier import MEASURED_HANDS, card_fits_hand, read_card
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
    """Routing by card: the default model, and a copy of it whose card says it was made for a wider hand than any
    the default serves (the registry reads nothing but the cards to choose)."""
    src, name = models_and_default
    folder = tmp_path / "models"
    folder.mkdir()
    for suffix in (".onnx", ".json"):
        shutil.copy(src / f"{name}{suffix}", folder / f"{name}{suffix}")
    card = read_card(src / f"{name}.json")
    wide_hand = HAND_PRESETS["gpd"].with_opening(0.12)
    wide = wide_hand.to_dict()
    card.update(name="wide15", hand=wide)
    shutil.copy(src / f"{name}.onnx", folder / "wide15.onnx")
    (folder / "wide15.json").write_text(json.dumps(card))
    assert card_fits_hand(card, wide) and not card_fits_hand(read_card(src / f"{name}.json"), wide)

    registry = ModelRegistry.load(folder, default=name)
    assert registry.resolve(None, True, wide_hand) == "wide15"
    assert registry.resolve(None, True, HAND_PRESETS["gpd"]) == name
    assert registry.resolve(name, True, wide_hand) == name, "a named model is always honoured"
    with TestClient(create_app(make_settings(models_dir=folder, default_model=name))) as c:
        out = c.post("/detect", json=small_body(krylon, hand=wide)).json()
    assert out["model"] == "wide15" and out["model_fits_hand"] is True


def test_the_default_model_serves_the_hands_the_benchmarks_chose_it_for(
        tmp_path: Path, models_and_default: tuple[Path, str], make_settings: Callable[..., Settings],
        krylon: ViewpointCloud, small_body: Callable[..., dict[str, Any]]) -> None:
    """A Panda request keeps the default model when the benchmarks chose it over the model made for the Panda's
    images (both loaded), and its answer carries no model_hand_mismatch warning."""
    src, name = models_and_default
    if name not in MEASURED_HANDS:
        pytest.skip(f"the test model {name!r} was measured with no other hand (the shipped default was)")
    folder = tmp_path / "models"
    folder.mkdir()
    for suffix in (".onnx", ".json"):
        shutil.copy(src / f"{name}{suffix}", folder / f"{name}{suffix}")
    card = read_card(src / f"{name}.json")
    panda = HAND_PRESETS["panda"]
    card.update(name="panda15", hand=panda.to_dict())
    shutil.copy(src / f"{name}.onnx", folder / "panda15.onnx")
    (folder / "panda15.json").write_text(json.dumps(card))

    registry = ModelRegistry.load(folder, default=name)
    assert registry.fits(name, panda) is True and not card_fits_hand(read_card(src / f"{name}.json"),
                                                                      panda.to_dict())
    assert registry.resolve(None, True, panda) == name
    assert registry.fits(name, HAND_PRESETS["gpd"].with_opening(0.12)) is False, "an unmeasured hand is not served"
    with TestClient(create_app(make_settings(models_dir=folder, default_model=name))) as c:
        out = c.post("/detect", json=small_body(krylon, hand="panda")).json()
    assert out["model"] == name and out["model_fits_hand"] is True
    assert "model_hand_mismatch" not in [w["code"] for w in out.get("warnings", [])]
