"""bench/clutter.py writes the Table 3 markdown, the PNG and the JSON (with the commit) for a tiny run."""

import json
from dataclasses import replace
from pathlib import Path
from types import ModuleType

import pytest

from graspd_lab.sim.object_sets import object_set_hand, object_set_ids, object_set_stop
from graspd_lab.sim.objects import TEST_OBJECT_IDS
from graspd_lab.sim.world import SimWorld
from graspd_lab.world import household
from graspd_lab.world.objects import BROKEN_URDFS, TRAINING_URDFS
from repo_module import load_bench


def _bench() -> ModuleType:
    return load_bench("clutter")


def test_tiny_run_writes_table_chart_and_json(tmp_path: Path) -> None:
    bench = _bench()
    assert bench.main(["--rounds", "1", "--objects", "2", "--settings", "baseline@pile-side",
                       "--out", str(tmp_path), "--tag", "t"]) == 0
    md = (tmp_path / "t.md").read_text()
    assert "% grasps successful" in md and "baseline@pile-side" in md
    data = json.loads((tmp_path / "t.json").read_text())
    assert len(data["meta"]["commit"]) >= 7
    assert data["summaries"]["baseline@pile-side"]["rounds"] == 1
    assert (tmp_path / "t.png").read_bytes()[:4] == b"\x89PNG"


def test_unknown_setting_is_named() -> None:
    bench = _bench()
    with pytest.raises(SystemExit):
        bench.main(["--settings", "magic@pour-passive"])
    with pytest.raises(ValueError, match="scene"):
        bench.parse_setting("baseline@shelf")


def test_household_option_loads_only_held_out_household_models(tmp_path: Path,
                                                                monkeypatch: pytest.MonkeyPatch) -> None:
    loaded: list[int] = []
    add = SimWorld.add_object

    def spy(self: SimWorld, object_id: int, *args: object) -> int:
        loaded.append(int(object_id))
        return add(self, object_id, *args)  # type: ignore[arg-type]

    monkeypatch.setattr(SimWorld, "add_object", spy)
    bench = _bench()
    assert bench.main(["--rounds", "2", "--settings", "baseline@pile-side", "baseline@packed-side",
                       "--object-set", "household", "--out", str(tmp_path), "--tag", "h"]) == 0
    held_out = {household.household_id(n) for n in household.HELD_OUT}
    assert len(loaded) >= 10 and set(loaded) <= held_out
    assert all(household.household_name(i) in household.HELD_OUT for i in loaded)
    assert "held-out household models" in (tmp_path / "h.md").read_text()
    rows = [json.loads(line) for line in (tmp_path / "h.rounds.jsonl").read_text().splitlines()]
    assert {r["setting"] for r in rows} == {"baseline@pile-side/5/household/stop-standard",
                                            "baseline@packed-side/5/household/stop-standard"}
    assert "2 failed attempts in a row" in (tmp_path / "h.md").read_text()
    for row in rows:  # what a round left is named; it did not clear them (some may have fallen off the table)
        r = row["round"]
        assert all(name in household.HELD_OUT for name in r["left"])
        assert len(r["left"]) <= r["num_objects"] - r["cleared"] and (r["left"] or r["end_reason"] == "tray empty")


def test_the_objects_rounds_without_a_grasp_left_are_listed() -> None:
    bench = _bench()
    rounds = [{"end_reason": "no grasp found", "left": ["stapler", "tube"]},
              {"end_reason": "2 failures in a row", "left": ["vase"]},  # left by failures: not the detector's
              {"end_reason": "no grasp found 3 times", "left": ["stapler"]}]
    assert bench.left_unfound(rounds) == {"stapler": 2, "tube": 1}


def test_object_sets_are_held_out_and_household_gets_the_panda_like_hand() -> None:
    assert object_set_ids("scaled") == TEST_OBJECT_IDS
    names = {household.household_name(i) for i in object_set_ids("household")}
    assert names == set(household.HELD_OUT) and not names & set(household.training_names())
    assert object_set_hand("household").max_aperture == pytest.approx(0.075)
    with pytest.raises(ValueError, match="object set"):
        object_set_ids("ycb")


def test_the_tuning_set_is_the_household_training_models_and_never_a_held_out_one() -> None:
    names = {household.household_name(i) for i in object_set_ids("household-training")}
    assert names == set(household.training_names()) and not names & set(household.HELD_OUT)
    assert object_set_hand("household-training") == object_set_hand("household")
    heavy = {household.household_name(i) for i in object_set_ids("household-training-heavy")}
    assert heavy < names and all(household.household_mass_properties(n).mass >= household.HEAVY_MASS for n in heavy)


def test_the_scaled_tuning_set_is_the_training_urdfs_with_the_scaled_sets_hand_and_rule() -> None:
    ids = set(object_set_ids("scaled-training"))
    assert ids and ids <= set(TRAINING_URDFS) and not ids & set(TEST_OBJECT_IDS) and not ids & BROKEN_URDFS
    assert object_set_hand("scaled-training") == object_set_hand("scaled")
    assert object_set_stop("scaled-training") == object_set_stop("scaled") == "ijrr"


def test_a_hand_preset_replaces_the_object_sets_hand_and_is_named(tmp_path: Path) -> None:
    """--hand: the preset in every request and in the simulated fingers, said in the results file, and its rounds
    never resumed as those of the set's own hand."""
    bench = _bench()
    assert bench.main(["--rounds", "1", "--objects", "2", "--settings", "baseline@pile-side", "--object-set",
                       "household-training", "--hand", "panda", "--out", str(tmp_path), "--tag", "p"]) == 0
    md = (tmp_path / "p.md").read_text()
    assert "- hand: the `panda` preset (8.0 cm opening" in md
    data = json.loads((tmp_path / "p.json").read_text())
    assert data["meta"]["hand"] == "panda"
    (row,) = [json.loads(line) for line in (tmp_path / "p.rounds.jsonl").read_text().splitlines()]
    assert row["setting"].startswith("baseline@pile-side/2/household-training/") and "/hand-" in row["setting"]
    own = replace(bench.SCENES["pile-side"], num_objects=2, objects="household-training",
                  hand=object_set_hand("household-training"))
    assert "/hand-" not in bench._setting_key("baseline@pile-side", own)
