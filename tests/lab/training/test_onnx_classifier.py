"""ONNX export with a dynamic batch axis, onnxruntime/torch parity, and loading models by name with cards."""

from pathlib import Path

import numpy as np
import pytest
import torch

from graspd.gpd.classifier import (
    GraspClassifier,
    ModelError,
    OnnxGraspClassifier,
    available_models,
    load_model,
    load_models,
)
from graspd.gpd.images import channel_layout
from graspd_lab.training.export import base_card, check_parity, export_onnx, torch_scores, write_card
from graspd_lab.training.network import build_network

HAND = {"finger_width": 0.01, "hand_outer_diameter": 0.12, "hand_depth": 0.06, "hand_height": 0.02,
        "init_bite": 0.01}


def _sparse_images(m: int, channels: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    on = rng.random((m, channels, 60, 60)) < 0.1
    return (on * rng.integers(1, 256, (m, channels, 60, 60))).astype(np.uint8)


def _export(tmp: Path, name: str, architecture: str, representation: str = "15") -> tuple[torch.nn.Module, dict]:
    torch.manual_seed(1)
    channels = len(channel_layout(representation))
    net = build_network(architecture, channels).eval()
    path = export_onnx(net, tmp / f"{name}.onnx", channels)
    card = base_card(name, representation, channels, 60, architecture, HAND, channel_layout(representation))
    write_card(path.with_suffix(".json"), card)
    return net, card


@pytest.mark.parametrize(("architecture", "representation"), [("fast", "15"), ("lenet", "3"), ("fast", "herzog")])
def test_parity_and_dynamic_batch(tmp_path: Path, architecture: str, representation: str) -> None:
    net, card = _export(tmp_path, "m", architecture, representation)
    images = _sparse_images(37, card["channels"])
    assert check_parity(net, tmp_path / "m.onnx", card, images) <= 1e-4
    clf = load_model("m", tmp_path, threads=1, batch_size=8)
    scores = clf.score(images)
    assert scores.dtype == np.float32 and scores.shape == (37,)
    assert np.all((scores >= 0) & (scores <= 1))
    np.testing.assert_allclose(scores, torch_scores(net, images), atol=1e-5)
    np.testing.assert_allclose(clf.score(images[:1]), scores[:1], atol=1e-6)
    assert clf.score(images[:0]).shape == (0,)
    assert isinstance(clf, GraspClassifier)


def test_load_by_name_path_and_folder(tmp_path: Path) -> None:
    _export(tmp_path, "alpha", "fast")
    _export(tmp_path, "beta", "fast", "12")
    (tmp_path / "orphan.onnx").write_bytes((tmp_path / "alpha.onnx").read_bytes())  # no card: not a model
    assert available_models(tmp_path) == ["alpha", "beta"]
    models = load_models(tmp_path, threads=1)
    assert set(models) == {"alpha", "beta"}
    assert models["beta"].representation == "12" and models["beta"].card["channels"] == 12
    by_path = load_model(tmp_path / "alpha.onnx")
    assert by_path.name == "alpha"


def test_unknown_model_names_the_known_ones(tmp_path: Path) -> None:
    _export(tmp_path, "alpha", "fast")
    with pytest.raises(ModelError, match=r"unknown model 'nope'.*\['alpha'\]"):
        load_model("nope", tmp_path)


def test_bad_images_name_the_field(tmp_path: Path) -> None:
    _export(tmp_path, "alpha", "fast")
    clf = OnnxGraspClassifier(tmp_path / "alpha.onnx", threads=1)
    with pytest.raises(ValueError, match="images must have shape"):
        clf.score(np.zeros((2, 12, 60, 60), np.uint8))
    with pytest.raises(ValueError, match="images must be a uint8"):
        clf.score(np.zeros((2, 15, 60, 60), np.float32))  # type: ignore[arg-type]


def test_malformed_card_is_a_model_error(tmp_path: Path) -> None:
    _export(tmp_path, "alpha", "fast")
    (tmp_path / "alpha.json").write_text('{"name": "alpha"}')
    with pytest.raises(ModelError, match="lacks"):
        load_model("alpha", tmp_path)
    (tmp_path / "alpha.json").write_text("{not json")
    with pytest.raises(ModelError, match="not valid JSON"):
        load_model("alpha", tmp_path)
