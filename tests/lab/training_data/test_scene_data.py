"""Scene training data: the benchmark's scenes with training objects only, labelled against their meshes,
split by objects, resumable."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from graspd.core.hand import HAND_PRESETS
from graspd_lab.training.dataset import iter_chunks, read_split
from graspd_lab.training.scene_data import (
    HOUSEHOLD_MIX,
    SENSOR_MIXES,
    SceneParams,
    generate_scene_dataset,
    scene_spec,
    scene_views,
)
from graspd_lab.training.scene_eval import precision_at_k
from graspd_lab.world import household
from graspd_lab.world.objects import HELD_OUT_URDFS, HeldOutObjectError

TINY = SceneParams(scenes=3, views_per_scene=2, objects=(2, 3), num_samples=20, per_view=40, scenes_per_chunk=2)
#: Household models and the three sensors: seed 2's three scenes are a pile and two packed scenes, one per sensor.
MIXED = SceneParams(seed=2, scenes=3, views_per_scene=1, objects=(2, 3), num_samples=20, per_view=40,
                    scenes_per_chunk=3, scene_mix=HOUSEHOLD_MIX, household_share=0.5,
                    sensor_mix=SENSOR_MIXES["mixed"])


@pytest.fixture(scope="module")
def tiny(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("scenes")
    generate_scene_dataset(out, TINY, workers=1)
    return out


def test_training_scenes_refuse_held_out_objects() -> None:
    with pytest.raises(HeldOutObjectError):
        scene_views("pile", [HELD_OUT_URDFS[0]], 0, 1, TINY.hand, TINY.noise)


def test_object_parts_are_disjoint_and_never_hold_held_out_objects() -> None:
    parts = TINY.object_parts()
    sets = [set(parts[p]) for p in ("train", "val", "test")]
    assert not (sets[0] & sets[1]) and not (sets[0] & sets[2]) and not (sets[1] & sets[2])
    assert not set().union(*sets) & set(HELD_OUT_URDFS)


def test_scene_rows_are_labelled_candidates_of_the_scenes(tiny: Path) -> None:
    manifest = json.loads((tiny / "manifest.json").read_text())
    labels = np.concatenate([c["labels"] for c in iter_chunks(tiny, verify=True)])
    assert manifest["counts"]["total"] == len(labels) > 0
    assert 0 < labels.sum() < len(labels)  # both classes occur in clutter
    for view in manifest["views"]:
        assert view["kept"] <= TINY.per_view and view["num_positive"] + view["num_negative"] == view["num_candidates"]
    parts = TINY.object_parts()
    split = read_split(tiny, "object")
    for scene in manifest["objects"]:
        assert set(scene["objects"]) <= set(parts[scene["part"]])
        assert scene["id"] in split[scene["part"]]


def test_an_interrupted_run_resumes_from_its_chunks(tiny: Path, tmp_path: Path) -> None:
    manifest = json.loads((tiny / "manifest.json").read_text())
    again = tmp_path / "again"
    again.mkdir()
    # a run interrupted after its first chunk: the chunk and its record are on disk, no manifest
    for name in ("chunk_00000.npz", "chunk_00000.npz.json", "params.json"):
        (again / name).write_bytes((tiny / name).read_bytes())
    resumed = generate_scene_dataset(again, TINY, workers=1)
    assert resumed["dataset_sha256"] == manifest["dataset_sha256"]
    with pytest.raises(FileExistsError):
        generate_scene_dataset(again, TINY, workers=1)


def test_scenes_draw_household_models_and_sensors_only_when_asked() -> None:
    plain_parts = TINY.object_parts()
    plain = [scene_spec(i, TINY, plain_parts) for i in range(50)]
    assert {s["sensor"] for s in plain} == {"kinect"}
    assert not any(household.is_household_id(i) for s in plain for i in s["objects"])
    parts = MIXED.object_parts()
    mixed = [scene_spec(i, MIXED, parts) for i in range(300)]
    sensors = [s["sensor"] for s in mixed]
    assert all(60 < sensors.count(k) < 140 for k in ("kinect", "stereo", "tof"))
    ids = [i for s in mixed for i in s["objects"]]
    share = np.mean([household.is_household_id(i) for i in ids])
    assert 0.35 < share < 0.65
    held = {household.household_id(n) for n in household.HELD_OUT}
    assert not held & set(ids) and not held & set().union(*map(set, parts.values()))


def test_a_heavy_share_weights_the_household_draw_toward_the_models_that_slip() -> None:
    parts = MIXED.object_parts()
    heavy = {household.household_id(n) for n in household.heavy_training_names()}
    plain = [i for k in range(300) for i in scene_spec(k, MIXED, parts)["objects"] if household.is_household_id(i)]
    weighted_params = replace(MIXED, heavy_share=0.8)
    weighted = [scene_spec(k, weighted_params, parts) for k in range(300)]
    drawn = [i for s in weighted for i in s["objects"] if household.is_household_id(i)]
    assert np.mean([i in heavy for i in plain]) < 0.35 < 0.65 < np.mean([i in heavy for i in drawn])
    assert all(len(set(s["objects"])) == len(s["objects"]) for s in weighted)  # no model twice in a scene
    held = {household.household_id(n) for n in household.HELD_OUT}
    assert not held & set(drawn)
    assert "heavy_share" not in MIXED.to_dict() and weighted_params.to_dict()["heavy_share"] == 0.8


def test_training_scenes_refuse_held_out_household_models() -> None:
    with pytest.raises(HeldOutObjectError):
        scene_views("pile", [household.household_id(household.HELD_OUT[0])], 0, 1, TINY.hand, TINY.noise)


def test_scene_data_with_household_models_and_mixed_sensors_is_the_same_for_a_seed(tmp_path: Path) -> None:
    a = generate_scene_dataset(tmp_path / "a", MIXED, workers=1)
    b = generate_scene_dataset(tmp_path / "b", MIXED, workers=1)
    assert a["dataset_sha256"] == b["dataset_sha256"] and a["counts"]["total"] > 0
    assert {s["sensor"] for s in a["objects"]} == {"kinect", "stereo", "tof"}
    assert {v["sensor"] for v in a["views"]} == {"kinect", "stereo", "tof"}
    assert any(household.is_household_id(i) for s in a["objects"] for i in s["objects"])


def test_precision_at_k_counts_the_first_k_returned() -> None:
    ranked = np.array([1.0, 0.0, 1.0, 1.0, 0.0, 1.0])
    p = precision_at_k(ranked)
    assert p["p@1"] == 1.0 and p["p@5"] == pytest.approx(0.6) and p["p@10"] == pytest.approx(4 / 6)
    assert np.isnan(precision_at_k(np.zeros(0))["p@1"])


def test_a_hand_opening_makes_the_household_benchmarks_hand_and_a_bad_one_is_refused(tmp_path: Path) -> None:
    """--hand panda --hand-opening 0.075 is the hand the household benchmarks execute with: same fingers, a
    7.5 cm opening; an opening outside (0, 0.3] m stops the command before it writes anything."""
    from graspd_lab.sim.object_sets import PANDA_LIKE  # noqa: PLC0415
    from graspd_lab.training.scene_data import hand_with_opening, main  # noqa: PLC0415

    hand = hand_with_opening("panda", 0.075)
    assert hand == PANDA_LIKE and hand.max_aperture == pytest.approx(0.075)
    assert hand_with_opening("panda", None) == HAND_PRESETS["panda"]
    with pytest.raises(SystemExit) as refused:
        main(["--out", str(tmp_path / "out"), "--hand", "panda", "--hand-opening", "0"])
    assert refused.value.code == 2 and not (tmp_path / "out").exists()
