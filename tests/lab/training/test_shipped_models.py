"""The models shipped in models/: each loads by name, its card is complete, it scores real grasp images."""

from pathlib import Path

import numpy as np
import pytest

from graspd.core.cloud import ViewpointCloud
from graspd.core.hand import HAND_PRESETS, HandGeometry
from graspd.gpd.candidates import SamplingParams, search_hands
from graspd.gpd.classifier import (
    available_models,
    card_fits_hand,
    default_model_name,
    default_models_dir,
    load_model,
    read_card,
)
from graspd.gpd.images import channel_layout, encode_images
from graspd.gpd.preprocess import PreprocessParams, preprocess
from graspd.gpd.scene import Scene

MODELS = default_models_dir()
SHIPPED = available_models(MODELS)


def test_models_folder_is_small_and_has_the_default() -> None:
    size = sum(p.stat().st_size for p in MODELS.rglob("*") if p.is_file())
    assert size < 60 * 2**20, f"models/ is {size / 2**20:.1f} MB"
    assert default_model_name() in SHIPPED


@pytest.fixture(scope="module")
def scene_and_grasps():
    """A 6 cm sphere on a table seen from two cameras 53 degrees apart."""
    rng = np.random.default_rng(0)
    u = rng.normal(size=(6000, 3))
    sphere = 0.03 * u / np.linalg.norm(u, axis=1, keepdims=True) + [0, 0, 0.03]
    g = np.arange(-0.12, 0.12, 0.003)
    x, y = np.meshgrid(g, g)
    table = np.stack([x.ravel(), y.ravel(), np.zeros(x.size)], 1)
    table = table[np.hypot(table[:, 0], table[:, 1]) > 0.02]
    cams = np.array([[0.5, 0.0, 0.45], [0.5 * np.cos(0.925), 0.5 * np.sin(0.925), 0.45]])
    pts = np.concatenate([sphere, table])
    outward = np.concatenate([(sphere - [0, 0, 0.03]) / 0.03, np.tile([0, 0, 1.0], (len(table), 1))])
    src = np.argmax(np.stack([np.einsum("ij,ij->i", outward, c - pts) for c in cams], 1), axis=1)
    seen = np.einsum("ij,ij->i", outward, cams[src] - pts) > 0
    cloud = ViewpointCloud(points=pts[seen].astype(np.float32), viewpoints=cams.astype(np.float32),
                           camera_source=src[seen].astype(np.int32))
    hand = HandGeometry()
    pre = preprocess(cloud, PreprocessParams(voxel_size=0.003))
    scene = Scene.build(pre, hand)
    grasps, _ = search_hands(scene, hand, SamplingParams(num_samples=20, sample_pool=pre.points[:, 2] > 0.01))
    assert len(grasps) > 0
    return scene, grasps, hand


@pytest.mark.parametrize("name", SHIPPED)
def test_shipped_model_card_and_scores(name: str, scene_and_grasps) -> None:
    card = read_card(Path(MODELS) / f"{name}.json")
    assert card["name"] == name
    assert card["channel_layout"] == channel_layout(card["representation"])
    # the card records the hand the images were made for (a preset); palm_depth (the body behind the finger roots)
    # is not part of a grasp image, so cards made before it existed match their hand on every image field
    hand = next(h.to_dict() for h in HAND_PRESETS.values() if card_fits_hand(card, h.to_dict()))
    assert set(hand) - set(card["hand"]) <= {"palm_depth"}
    assert card["hand"] == {k: hand[k] for k in card["hand"]}
    assert card["output"]["range"] == [0.0, 1.0]
    if "bench/reranker.py" in card["command"]:  # a fine-tune on the oracle's tried grasps: its data are records
        assert card["training"]["init_from"] in SHIPPED and card["training"]["images"] >= 500
        records = card["training"]["records"]  # training objects only: household or scaled
        assert records and all("household-training" in r or "scaled-training" in r for r in records)
        choices = card["metrics"]["cross_validated_choice"].values()
        assert all(c["detections"] >= 100 and 0.0 <= c["held"] <= 1.0 for c in choices)
    else:
        assert card["training"]["dataset_manifest_sha256"] and card["command"].startswith("graspd train")
        for metrics in card["metrics"].values():
            assert metrics["n"] >= 500 and 0.0 <= metrics["ra99p"] <= 1.0 and metrics["accuracy"] > 0.6
    scene, grasps, hand = scene_and_grasps
    clf = load_model(name, MODELS, threads=1)
    scores = clf.score(encode_images(scene, grasps, hand, clf.representation))
    assert scores.shape == (len(grasps),) and scores.dtype == np.float32
    assert np.all((scores >= 0.0) & (scores <= 1.0)) and np.ptp(scores) > 0.0
