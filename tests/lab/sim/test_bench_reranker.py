"""bench/reranker.py fine-tunes the default model on the oracle's tried grasps (their images and how many of their
lifts held) with folds by round, and compares its choice among each detection's tried grasps with the service's."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from box_scene import pose_from, render_boxes, rot_z, table_box
from graspd.gpd.classifier import load_model
from graspd.gpd.detector import DetectionParams, GraspDetector
from graspd_lab.sim.object_sets import PANDA_LIKE
from graspd_lab.training.export import torch_scores
from graspd_lab.training.loop import load_weights, resolve_weights
from repo_module import load_bench


def tried(tmp_path: Path, scenes: str) -> tuple[Path, Path]:
    """A run's files as bench/oracle.py --perturb 4 --images writes them: 4 rounds of one detection with 3 tried
    grasps each, real images of a box on a table; the second grasp of each detection is the one that holds."""
    oracle = load_bench("oracle")
    box = ((0.05, 0.04, 0.08), pose_from(rot_z(0.3), [0.0, 0.0, 0.04]))
    cloud = render_boxes([table_box(), box], np.array([[0.5, -0.3, 0.5], [-0.4, -0.4, 0.5]]),
                         look_at=[0.0, 0.0, 0.03], noise=0.0005)
    workspace = (-0.2, 0.2, -0.2, 0.2, -0.02, 0.3)
    grasps = GraspDetector(load_model("household15", threads=1), PANDA_LIKE).detect(
        cloud, DetectionParams(workspace=workspace, num_samples=100), hand=PANDA_LIKE).grasps
    detections: list[dict[str, Any]] = []
    shots = []
    for k in range(4):
        g = grasps[3 * k : 3 * k + 3]
        shots.append(oracle.tried_images(cloud, workspace, g, PANDA_LIKE))
        detections.append({"tried": 3, "trial_objects": [k, k, 10 + k],
                           "trial_outcomes": ["slipped", "success", "empty_close"],
                           "trial_robust": [0.25, 1.0, 0.0], "trial_scores": [float(s) for s in g.scores],
                           "trial_seen": [{"ranking": {"key": 0.5 * float(s)}} for s in g.scores], "seed": 100 + k})
    oracle.save_images(tmp_path / "t.npz", shots, detections)
    records = tmp_path / "t.json"
    records.write_text(json.dumps({"meta": {"scenes": scenes, "perturb": 4}, "detections": detections}))
    return tmp_path / "t.npz", records


def test_the_table_compares_the_services_first_grasp_with_the_fine_tuned_choice(tmp_path: Path) -> None:
    bench = load_bench("reranker")
    images, records = tried(tmp_path, "pile-side, household-training objects, seeds 100-103")
    data = bench.load_tried([images], [records])
    assert np.allclose(data["target"], np.tile([0.2, 1.0, 0.0], 4))  # (held + 4 x robust) / 5
    assert np.allclose(data["terms"], 0.5, atol=1e-3)  # the key over the score: the other ranking terms
    table, kinds, tuned = bench.evaluate(data, "household15", folds=2)
    assert list(kinds) == ["pile-side"] and kinds["pile-side"] == table
    assert list(table) == ["the service's first grasp",
                           "the model's own score x the other terms (from the saved images)",
                           "the fine-tuned score x the other terms", "the most robust tried grasp (oracle)"]
    first, best = table["the service's first grasp"], table["the most robust tried grasp (oracle)"]
    assert first == {"detections": 4, "held": 0.0, "robust": 0.25, "target": pytest.approx(0.2)}
    assert best == {"detections": 4, "held": 1.0, "robust": 1.0, "target": 1.0}
    assert np.isfinite(tuned).all() and ((tuned > 0) & (tuned < 1)).all()


def test_fine_tuning_moves_the_scores_toward_the_targets(tmp_path: Path) -> None:
    bench = load_bench("reranker")
    data = bench.load_tried(*map(lambda p: [p], tried(tmp_path, "pile-side, household-training objects, seeds 0-3")))
    weights = resolve_weights("household15")
    before = torch_scores(load_weights(weights), data["images"])
    after = torch_scores(bench.fine_tune(load_weights(weights), data["images"], np.zeros(12), seed=0), data["images"])
    assert after.mean() < before.mean() - 0.05


def test_an_exported_model_scores_as_its_fine_tuned_network_and_says_what_it_learned(tmp_path: Path) -> None:
    bench = load_bench("reranker")
    data = bench.load_tried(*map(lambda p: [p], tried(tmp_path, "pile-side, household-training objects, seeds 0-3")))
    meta = {"records": ["t.json"], "images": 12, "detections": 4, "folds": 2, "folds_by": "seed", "epochs": 15,
            "learning_rate": 3e-4, "mix": 0.5, "command": "made by the test"}
    card_path = bench.export(data, "household15", "tried-test", tmp_path, meta, {"rows": "table"})
    card = json.loads(card_path.read_text())
    assert card["name"] == "tried-test" and card["training"]["init_from"] == "household15"
    assert card["training"]["mix"] == 0.5
    assert card["metrics"]["cross_validated_choice"] == {"rows": "table"} and "calibration" not in card
    model = load_model(tmp_path / "tried-test.onnx", threads=1)
    tuned = torch_scores(load_weights(tmp_path / "tried-test.pt"), data["images"])
    assert np.allclose(model.score(data["images"]), tuned, atol=1e-4)
    assert not np.allclose(tuned, load_model("household15", threads=1).score(data["images"]), atol=1e-3)


def test_replayed_rows_hold_the_scores_the_tried_targets_would_pull_away(tmp_path: Path) -> None:
    bench = load_bench("reranker")
    data = bench.load_tried(*map(lambda p: [p], tried(tmp_path, "pile-side, household-training objects, seeds 0-3")))
    weights = resolve_weights("household15")
    zeros = np.zeros(12)
    alone = torch_scores(bench.fine_tune(load_weights(weights), data["images"], zeros, seed=0), data["images"])
    replay = (data["images"][::-1].copy(), np.ones(12))  # the same images, labelled as grasps
    held = torch_scores(bench.fine_tune(load_weights(weights), data["images"], zeros, seed=0, replay=replay),
                        data["images"])
    assert held.mean() > alone.mean() + 0.1
    images, labels = bench.load_replay([])
    assert images.shape == (0, 15, 60, 60) and labels.shape == (0,)


def test_a_mix_sets_every_weight_between_the_starting_models_and_the_fine_tunes(tmp_path: Path) -> None:
    bench = load_bench("reranker")
    data = bench.load_tried(*map(lambda p: [p], tried(tmp_path, "pile-side, household-training objects, seeds 0-3")))
    weights = resolve_weights("household15")
    start = load_weights(weights).state_dict()
    tuned = bench.fine_tune(load_weights(weights), data["images"], np.zeros(12), seed=0)
    full = {k: v.clone() for k, v in tuned.state_dict().items()}
    half = bench.mix_weights(load_weights(weights), tuned, 0.5).state_dict()
    moved = [k for k, v in full.items() if v.is_floating_point() and not np.allclose(v.numpy(), start[k].numpy())]
    assert moved  # the fine-tune changed weights, and the mix puts each of them halfway
    for k in moved:
        assert np.allclose(half[k].numpy(), 0.5 * (start[k].numpy() + full[k].numpy()), atol=1e-6)
    scores = [torch_scores(n, data["images"]).mean() for n in (load_weights(weights), tuned)]
    assert scores[1] < scores[0]  # the half mix scores below the start, toward the fine-tune's zero targets


def test_a_soup_is_the_weight_average_of_fine_tunes_from_different_seeds(tmp_path: Path) -> None:
    bench = load_bench("reranker")
    data = bench.load_tried(*map(lambda p: [p], tried(tmp_path, "pile-side, household-training objects, seeds 0-3")))
    weights = resolve_weights("household15")
    target = np.linspace(0.0, 1.0, 12)
    runs = [bench.fine_tune(load_weights(weights), data["images"], target, seed=s, epochs=2).state_dict()
            for s in (3, 1003)]
    soup = bench.fine_tune_soup(weights, data["images"], target, seed=3, seeds=2, epochs=2).state_dict()
    differ = [k for k, v in runs[0].items() if v.is_floating_point() and not np.allclose(v.numpy(), runs[1][k].numpy())]
    assert differ  # the two seeds' fine-tunes differ, and the soup sits at their mean
    for k in differ:
        assert np.allclose(soup[k].numpy(), 0.5 * (runs[0][k].numpy() + runs[1][k].numpy()), atol=1e-6)
    one = bench.fine_tune_soup(weights, data["images"], target, seed=3, seeds=1, epochs=2).state_dict()
    assert all(np.allclose(one[k].numpy(), runs[0][k].numpy()) for k in differ)


@pytest.mark.parametrize("scenes", ["pile-side, household objects, seeds 0-29",
                                    "tray (training ranges), household objects, seeds 0-9"])
def test_records_of_held_out_objects_are_refused(tmp_path: Path, scenes: str) -> None:
    bench = load_bench("reranker")
    images, records = tried(tmp_path, scenes)
    with pytest.raises(SystemExit, match="only training objects"):
        bench.load_tried([images], [records])


def test_folds_by_object_keep_every_object_out_of_the_model_that_scores_it(tmp_path: Path) -> None:
    bench = load_bench("reranker")
    data = bench.load_tried(*map(lambda p: [p], tried(tmp_path, "pile-side, household-training objects, seeds 0-3")))
    assert list(data["object"]) == [0, 0, 10, 1, 1, 11, 2, 2, 12, 3, 3, 13]
    fold = bench.fold_of_rows(data, 3, "object")
    for obj in np.unique(data["object"]):  # one object, one fold: never in training and test at once
        assert len(set(fold[data["object"] == obj])) == 1
    assert len(set(fold)) == 3
    by_seed = bench.fold_of_rows(data, 2, "seed")
    assert all(len(set(by_seed[data["seed"] == s])) == 1 for s in np.unique(data["seed"]))


def test_a_chunk_folder_pairs_each_finished_chunks_records_with_its_images(tmp_path: Path) -> None:
    bench = load_bench("reranker")
    images, records = tried(tmp_path, "tray (training ranges), household-training objects, seeds 0-3")
    folder = tmp_path / "chunks"
    folder.mkdir()
    images.rename(folder / "tried-tray-s0.npz")
    records.rename(folder / "oracle-tray-s0.json")
    (folder / "tried-tray-s10.npz").write_bytes(b"")  # a chunk still being collected: no records yet
    found = bench.chunk_files(folder)
    assert found == ([folder / "tried-tray-s0.npz"], [folder / "oracle-tray-s0.json"])
    assert set(bench.load_tried(*found)["kind"]) == {"tray"}
