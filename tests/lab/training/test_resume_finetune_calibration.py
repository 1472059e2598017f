"""Training on scenes: training that survives interruptions (last.pt, --resume), fine-tuning from shipped weights
(init_from, models/NAME.pt), hard-negative mining, and scores calibrated on the validation rows."""

import argparse
import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import torch

from graspd.gpd.classifier import default_models_dir, load_model
from graspd_lab.training import cli
from graspd_lab.training.config import TrainConfig
from graspd_lab.training.evaluate import expected_calibration_error, fit_platt
from graspd_lab.training.export import base_card, check_parity, export_onnx
from graspd_lab.training.loop import LAST, load_weights, predict_logits, sample_negatives, train
from graspd_lab.training.network import build_network, fold_logit_affine
from graspd_lab.training.plans import plan_budget
from graspd_lab.training.rows import load_rows

QUIET = lambda *a: None  # noqa: E731


class Interrupted(Exception):
    pass


def _interrupt_after(epoch: int):
    def log(line: str) -> None:
        if f"epoch {epoch}:" in line:
            raise Interrupted(line)
    return log


def _weights(path: Path) -> dict[str, torch.Tensor]:
    return torch.load(path, map_location="cpu", weights_only=True)["state_dict"]


def _same_row(a: dict, b: dict) -> bool:
    skip = {"seconds", "resumed"}
    return {k: v for k, v in a.items() if k not in skip} == {k: v for k, v in b.items() if k not in skip}


def test_interrupted_run_resumes_to_the_same_weights(tiny_model: Path, tmp_path: Path) -> None:
    """Two epochs in one call, or one epoch, a kill, and --resume for the second: the same network (dropout,
    batch order, augmentation, Adam moments and the hard-negative draw all continue from last.pt)."""
    data = str(tiny_model.parent.parent / "dataset")
    config = TrainConfig(dataset=data, name="res", epochs=2, batch_size=32, max_train=128, patience=5, seed=3,
                         hard_negatives=0.2)
    whole = train(config, tmp_path / "whole", log=QUIET)
    with pytest.raises(Interrupted):
        train(config, tmp_path / "cut", log=_interrupt_after(1))
    assert not (tmp_path / "cut" / "checkpoint.pt").exists()
    last = torch.load(tmp_path / "cut" / LAST, weights_only=True)
    assert last["epoch"] == 1 and last["stopped"] is None and not list((tmp_path / "cut").glob("*.tmp"))
    resumed = train(replace(config, resume=True, max_minutes=30.0), tmp_path / "cut", log=QUIET)
    a, b = _weights(tmp_path / "whole" / "checkpoint.pt"), _weights(tmp_path / "cut" / "checkpoint.pt")
    assert all(torch.equal(a[k], b[k]) for k in a)
    assert resumed["resumed_from_epoch"] == 1 and whole["resumed_from_epoch"] is None
    assert [r["resumed"] for r in resumed["history"]] == [False, True]
    assert all(_same_row(x, y) for x, y in zip(whole["history"], resumed["history"], strict=True))
    assert resumed["calibration"] == whole["calibration"] and resumed["stopped"] == "epochs"
    # hard negatives: none in epoch 1, from epoch 2 the top 20% of the negatives by score
    first, second = whole["history"]
    assert "hard_negatives" not in first
    assert second["hard_negatives"] == int(np.ceil(0.2 * second["scored_negatives"]))
    assert second["hard_negatives_drawn"] == round(0.5 * second["scored_negatives"])
    assert 0.0 <= second["hard_negative_mean_score"] <= 1.0
    assert second["exemplars_seen"] == first["exemplars_seen"]  # same epoch size
    # resuming a finished run trains nothing more; a changed config is refused
    again = train(replace(config, resume=True), tmp_path / "cut", log=QUIET)
    assert len(again["history"]) == 2 and again["best_val_loss"] == resumed["best_val_loss"]
    with pytest.raises(ValueError, match=r"cannot resume .*learning_rate"):
        train(replace(config, resume=True, learning_rate=0.01), tmp_path / "cut", log=QUIET)


def test_sample_negatives_oversamples_the_high_scores() -> None:
    rng = np.random.default_rng(0)
    negatives = np.arange(1000, 2000)
    scores = np.linspace(0.0, 1.0, 1000)
    scores[::7] = np.nan  # not scored (beyond the cap): drawn only uniformly
    drawn, hard = sample_negatives(negatives, scores, 0.1, rng)
    assert len(drawn) == len(negatives)
    scored = np.flatnonzero(~np.isnan(scores))
    assert len(hard) == int(np.ceil(0.1 * len(scored)))
    assert np.all(scores[hard] >= np.nanquantile(scores, 0.89))
    top = np.isin(drawn, negatives[hard])
    assert 0.5 <= top.mean() < 0.6  # half from the hard tenth, plus its share of the uniform half
    assert len(set(drawn[~top].tolist())) == (~top).sum()  # the uniform part has no repeats
    plain, _ = sample_negatives(negatives, np.full(1000, np.nan), 0.1, rng)
    assert sorted(plain.tolist()) == negatives.tolist()


def test_fine_tuning_starts_from_the_exported_weights(tiny_model: Path, tmp_path: Path) -> None:
    models = tiny_model.parent
    data = str(models.parent / "dataset")
    shipped = load_weights(models / "tiny15.pt")
    images, _, _ = load_rows(data, "view", "test", "15", limit=64)
    clf = load_model(tiny_model)
    assert check_parity(shipped, tiny_model, clf.card, images) <= 1e-4  # NAME.pt is the exported network
    config = TrainConfig(dataset=data, name="ft", epochs=1, batch_size=32, max_train=64, learning_rate=1e-12,
                         weight_decay=0.0, calibrate=False, init_from="tiny15")
    metrics = train(config, tmp_path / "ft", log=QUIET, models_dir=models)
    assert metrics["init_from"]["path"] == str(models / "tiny15.pt") and len(metrics["init_from"]["sha256"]) == 64
    tuned = load_weights(tmp_path / "ft" / "checkpoint.pt")
    assert torch.allclose(tuned.classifier[-1].weight, shipped.classifier[-1].weight, atol=1e-6)
    fresh = train(replace(config, init_from=None), tmp_path / "fresh", log=QUIET)
    assert fresh["init_from"] is None
    assert not torch.allclose(load_weights(tmp_path / "fresh" / "checkpoint.pt").classifier[-1].weight,
                              shipped.classifier[-1].weight, atol=1e-3)
    # a path works as well as a name; weights of another shape or a missing name are a clear error
    path_run = train(replace(config, init_from=str(tmp_path / "ft" / "checkpoint.pt")), tmp_path / "p", log=QUIET)
    assert path_run["init_from"]["path"].endswith("checkpoint.pt")
    with pytest.raises(ValueError, match=r"init_from 'tiny15'.* 15 channels"):
        train(replace(config, representation="3"), tmp_path / "x", log=QUIET, models_dir=models)
    with pytest.raises(ValueError, match=r"init_from 'tiny15'.*lenet"):
        train(replace(config, architecture="lenet"), tmp_path / "x", log=QUIET, models_dir=models)
    with pytest.raises(ValueError, match=r"init_from 'tiny15'.*do not fit"):
        train(replace(config, network={"width": 8}), tmp_path / "x", log=QUIET, models_dir=models)
    with pytest.raises(ValueError, match=r"init_from 'nosuch'.*no weights file"):
        train(replace(config, init_from="nosuch"), tmp_path / "x", log=QUIET, models_dir=models)


def test_exported_card_is_calibrated(tiny_model: Path) -> None:
    card = json.loads(tiny_model.with_suffix(".json").read_text())
    cal = card["calibration"]
    assert set(cal) == {"a", "b", "val_ece_before", "val_ece_after"} and cal["a"] > 0
    assert cal["val_ece_after"] <= cal["val_ece_before"] + 0.02
    assert "calibrated" in card["output"]["meaning"]
    assert all(0.0 <= m["ece"] <= 1.0 for m in card["metrics"].values())


def test_fit_platt_recovers_a_known_scaling() -> None:
    rng = np.random.default_rng(1)
    z = rng.normal(0.0, 2.0, 20000)
    labels = rng.random(20000) < 1.0 / (1.0 + np.exp(-(0.5 * z - 0.7)))
    a, b = fit_platt(z, labels)
    assert a == pytest.approx(0.5, abs=0.05) and b == pytest.approx(-0.7, abs=0.08)
    calibrated = 1.0 / (1.0 + np.exp(-(a * z + b)))
    assert expected_calibration_error(calibrated, labels) < 0.02 < expected_calibration_error(
        1.0 / (1.0 + np.exp(-z)), labels)
    a2, _ = fit_platt(-z, labels)  # anti-correlated scores: the slope stays positive
    assert a2 > 0


@pytest.mark.parametrize("architecture", ["fast", "lenet"])
def test_folded_calibration_is_what_onnx_computes(architecture: str, tmp_path: Path) -> None:
    torch.manual_seed(0)
    net = build_network(architecture, 3).eval()
    rng = np.random.default_rng(0)
    images = (rng.random((16, 3, 60, 60)) < 0.1).astype(np.uint8) * 200
    logits = predict_logits(net, images)
    z = logits[:, 1] - logits[:, 0]
    fold_logit_affine(net, 2.5, -0.4)
    after = predict_logits(net, images)
    np.testing.assert_allclose(after[:, 1] - after[:, 0], 2.5 * z - 0.4, rtol=1e-4, atol=1e-4)
    path = export_onnx(net, tmp_path / "c.onnx", 3)
    card = base_card("c", "3", 3, 60, architecture, {}, ["a", "b", "c"])
    assert check_parity(net, path, card, images) <= 1e-4


def test_cli_flags_and_plan_budget(tmp_path: Path) -> None:
    parser = argparse.ArgumentParser()
    cli.register(parser.add_subparsers())
    args = parser.parse_args(["train", "--dataset", "d", "--resume", "--init-from", "generic15", "--hard-negatives",
                              "0.1", "--no-calibrate"])
    assert (args.resume, args.init_from, args.hard_negatives, args.calibrate) == (True, "generic15", 0.1, False)
    plain = parser.parse_args(["train", "--dataset", "d"])
    assert (plain.resume, plain.init_from, plain.hard_negatives, plain.calibrate) == (None, None, None, None)
    with pytest.raises(ValueError, match="hard_negatives"):
        TrainConfig(dataset="d", hard_negatives=1.0)
    # the shipped plan and an old card's config still parse; the plan states its budget
    plan = json.loads((default_models_dir() / "plan.json").read_text())
    configs = [TrainConfig.from_dict({"dataset": "d", **plan["defaults"],
                                      **{k: v for k, v in m.items() if k != "subdir"}}) for m in plan["models"]]
    total = sum(c.max_minutes or 0.0 for c in configs)
    assert f"training budget {total:.1f} min" in plan_budget(configs)
    assert "no time limit" in plan_budget([*configs, TrainConfig(dataset="d", name="open")])
    old = json.loads((default_models_dir() / "generic15.json").read_text())["training"]["config"]
    assert TrainConfig.from_dict(old).calibrate and TrainConfig.from_dict(old).init_from is None
