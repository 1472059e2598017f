"""The whole classifier pipeline on a tiny generated dataset: data -> train -> ONNX + card -> load -> score."""

import argparse
import json
from pathlib import Path

import numpy as np
import pytest
import torch

from graspd.gpd.classifier import GraspClassifier, load_model
from graspd.store.outcomes import OutcomeStore
from graspd_lab.training import cli
from graspd_lab.training.config import TrainConfig
from graspd_lab.training.dataset import read_manifest
from graspd_lab.training.evaluate import classification_metrics
from graspd_lab.training.export import check_parity
from graspd_lab.training.loop import grasp_probability, load_checkpoint, predict_logits, train
from graspd_lab.training.plans import prefix_dataset
from graspd_lab.training.rows import load_rows


@pytest.fixture
def tiny(tiny_model: Path) -> Path:
    return tiny_model


def test_tiny_model_beats_chance_on_held_out_views(tiny: Path) -> None:
    root = tiny.parent.parent
    clf = load_model(tiny)
    assert isinstance(clf, GraspClassifier) and clf.name == "tiny15" and clf.representation == "15"
    images, labels, _ = load_rows(root / "dataset", "view", "test", "15")
    scores = clf.score(images)
    m = classification_metrics(scores, labels)
    n = len(labels)
    assert n >= 100 and 0.3 < labels.mean() < 0.7
    assert m["accuracy"] > 0.5 + 3.0 * np.sqrt(0.25 / n), m  # three standard errors above a coin flip
    assert m["average_precision"] > 0.7, m
    # the card reports what we just measured, on the exported model
    card = clf.card
    assert card["metrics"]["view_test"]["accuracy"] == pytest.approx(m["accuracy"])
    assert card["training"]["dataset_manifest_sha256"] == read_manifest(root / "dataset")["dataset_sha256"]
    assert card["hand"]["hand_depth"] == 0.06 and card["output"]["range"] == [0.0, 1.0]
    assert card["input"]["scale"] == pytest.approx(1 / 255) and "train_tiny_model" in card["command"]


def test_onnx_matches_the_trained_checkpoint(tiny: Path) -> None:
    root = tiny.parent.parent
    net, config = load_checkpoint(root / "work" / "checkpoint.pt")
    images, _, _ = load_rows(root / "dataset", "view", "test", "15", limit=64)
    clf = load_model(tiny)
    assert check_parity(net, tiny, clf.card, images) <= 1e-4
    assert config.name == "tiny15" and config.seed == 0


def test_training_is_reproducible_from_config_and_seed(tiny: Path, tmp_path: Path) -> None:
    data = str(tiny.parent.parent / "dataset")
    config = TrainConfig(dataset=data, name="rep", representation="herzog", epochs=1, max_train=96, seed=5)
    train(config, tmp_path / "a", log=lambda *a: None)
    train(config, tmp_path / "b", log=lambda *a: None)
    a = torch.load(tmp_path / "a" / "checkpoint.pt", weights_only=True)["state_dict"]
    b = torch.load(tmp_path / "b" / "checkpoint.pt", weights_only=True)["state_dict"]
    assert all(torch.equal(a[k], b[k]) for k in a)
    metrics = json.loads((tmp_path / "a" / "train_metrics.json").read_text())
    assert metrics["num_train"] == 96 and len(metrics["history"]) == 1


def test_cli_trains_evaluates_and_exports(tiny: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    parser = argparse.ArgumentParser()
    cli.register(parser.add_subparsers())
    data = str(tiny.parent.parent / "dataset")
    args = parser.parse_args(["train", "--dataset", data, "--name", "box3", "--representation", "3",
                              "--categories", "box", "--epochs", "1", "--models-dir", str(tmp_path / "m")])
    assert args.func(args) == 0
    card = json.loads((tmp_path / "m" / "box3.json").read_text())
    assert card["representation"] == "3" and card["channels"] == 3 and card["categories"] == ["box"]
    assert set(card["metrics"]) == {"view_test", "view_test_box"}
    assert card["metrics"]["view_test_box"]["n"] < card["metrics"]["view_test"]["n"]
    assert "box3" in capsys.readouterr().out
    bad = parser.parse_args(["train", "--dataset", data, "--representation", "15", "--split", "view",
                             "--categories", "bowl"])
    assert bad.func(bad) == 2
    assert "categories must be among" in capsys.readouterr().err


def test_prefix_dataset_keeps_the_generators_view_split(tiny: Path, tmp_path: Path) -> None:
    data = tiny.parent.parent / "dataset"
    full = read_manifest(data)
    manifest = prefix_dataset(data, tmp_path / "p", 1)
    assert manifest["counts"]["total"] == full["chunks"][0]["rows"]
    ids = {o["id"] for o in manifest["objects"]}
    whole = json.loads((data / "splits" / "view.json").read_text())
    part = json.loads((tmp_path / "p" / "splits" / "view.json").read_text())
    for key in ("train", "val", "test"):
        assert sorted(map(tuple, part[key])) == sorted(tuple(p) for p in whole[key] if p[0] in ids)
    images, labels, _ = load_rows(tmp_path / "p", "view", "train", "12")
    assert images.shape[1] == 12 and len(labels) > 0
    with pytest.raises(ValueError, match="must hold"):
        prefix_dataset(data, tmp_path / "q", 5)


def test_robot_feedback_joins_training_and_moves_scores_toward_the_outcomes(tiny: Path, tmp_path: Path) -> None:
    """Outcomes stored by POST /feedback (with their grasp images) are training rows: a robot that reports the
    opposite of the simulated labels on 40 grasps pulls the retrained model's scores on them its way."""
    data = str(tiny.parent.parent / "dataset")
    images, labels, _ = load_rows(data, "view", "test", "15", limit=40, seed=3)
    outcomes = labels == 0  # what "the robot" reports: the opposite of the antipodal label
    url = f"sqlite:///{tmp_path / 'feedback.db'}"
    with OutcomeStore(url) as store:
        for i, (image, held) in enumerate(zip(images, outcomes, strict=True)):
            store.add_outcome(f"gpd{i:04d}.0", bool(held), np.eye(4), 0.05, image, "15")
        store.add_outcome("gpd9999.0", True, np.eye(4), 0.05, images[0, :3], "3")  # other representation
    common = {"dataset": data, "name": "fb", "epochs": 4, "batch_size": 32, "patience": 8, "max_val": None}
    with_fb = train(TrainConfig(**common, feedback=url, feedback_repeat=16), tmp_path / "a", log=lambda *a: None)
    without = train(TrainConfig(**common), tmp_path / "b", log=lambda *a: None)
    assert with_fb["feedback"] == {"store": url, "outcomes": 40, "successes": int(outcomes.sum()), "skipped": 1,
                                   "repeat": 16}
    assert without["feedback"] is None and with_fb["num_train"] == without["num_train"]
    errors = []
    for work in ("a", "b"):
        net, _ = load_checkpoint(tmp_path / work / "checkpoint.pt")
        errors.append(float(np.abs(grasp_probability(predict_logits(net, images)) - outcomes).mean()))
    assert errors[0] < errors[1] - 0.2, errors
    # a 3-channel model trained on the same store derives the 15-channel images and skips nothing it can use
    three = train(TrainConfig(**{**common, "epochs": 1}, representation="3", feedback=url), tmp_path / "c",
                  log=lambda *a: None)
    assert three["feedback"]["outcomes"] == 41 and three["feedback"]["skipped"] == 0


def test_feedback_store_that_does_not_exist_is_a_clear_error(tiny: Path, tmp_path: Path) -> None:
    data = str(tiny.parent.parent / "dataset")
    missing = f"sqlite:///{tmp_path / 'nope.db'}"
    with pytest.raises(ValueError, match="no such store"):
        train(TrainConfig(dataset=data, epochs=1, feedback=missing), tmp_path / "w", log=lambda *a: None)
    assert not (tmp_path / "nope.db").exists()
    with pytest.raises(ValueError, match="not a SQLAlchemy URL"):
        train(TrainConfig(dataset=data, epochs=1, feedback="::"), tmp_path / "w", log=lambda *a: None)
