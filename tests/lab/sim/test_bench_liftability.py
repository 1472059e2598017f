"""bench/liftability.py drops each object of a set alone on the table, labels the detector's candidates on one view
of it and lifts up to --grasps analytic positives with the clutter benchmark's execution: per object, how many
hold; by mass band and overall."""

from __future__ import annotations

import json
from pathlib import Path
from types import ModuleType

from repo_module import load_bench


def _bench() -> ModuleType:
    return load_bench("liftability")


def test_two_heavy_objects_are_lifted_and_their_counts_add_up(tmp_path: Path) -> None:
    bench = _bench()
    argv = ["--object-set", "household-training-heavy", "--objects", "2", "--grasps", "3", "--out", str(tmp_path)]
    assert bench.main(argv) == 0
    md = tmp_path / "liftability-household-training-heavy.md"
    data = json.loads((tmp_path / "liftability-household-training-heavy.json").read_text())
    assert md.exists()
    assert "--grasps 3" in data["meta"]["command"] and data["meta"]["commit"]
    rows = data["objects"]
    assert [r["object"] for r in rows] == [name for _, name in bench.set_objects("household-training-heavy", 2)]
    for r in rows:
        assert 0 <= r["held"] <= r["tried"] <= min(3, r["positives"])
        assert r["held_in_cone"] <= r["tried_in_cone"] <= r["tried"]
        assert sum(r["outcomes"].values()) == r["tried"]
        assert r["mass"] >= 0.5  # the heavy set: 0.5 kg or more
        assert f"| {r['object']} | {r['mass']:.3f} |" in md.read_text()
    s = data["summary"]
    assert s["objects"] == 2 and s["held"] == sum(r["held"] for r in rows)
    assert s["tried"] == 0 or 0.0 <= s["held_share"] <= 1.0
    assert sum(b["objects"] for b in data["bands"]) == 2


def test_the_summary_counts_objects_with_one_and_with_half_of_their_positives_held() -> None:
    bench = _bench()
    rows = [{"mass": 0.02, "positives": 4, "tried": 4, "held": 1, "tried_in_cone": 4, "held_in_cone": 1},
            {"mass": 2.0, "positives": 9, "tried": 4, "held": 2, "tried_in_cone": 2, "held_in_cone": 2},
            {"mass": 0.7, "positives": 0, "tried": 0, "held": 0, "tried_in_cone": 0, "held_in_cone": 0}]
    s = bench.summary(rows)
    assert (s["objects"], s["no_positive"], s["at_least_one"], s["at_least_half"]) == (3, 1, 2, 1)
    assert s["held_share"] == 3 / 8
    assert [b["band"] for b in bench.bands(rows)] == ["0 to 0.05 kg", "0.5 to 1.5 kg", ">= 1.5 kg"]
    assert bench.summary(rows[2:])["held_share"] is None
