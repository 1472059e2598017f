"""bench/foresight.py fits a hold estimate on some rounds' tried grasps and picks with it in others: where what the
answer said of a grasp decides whether it held, the pick holds every time (and its perturbed copies too); records of
held-out objects are refused."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest

from repo_module import load_bench


def detection(seed: int, short_first: bool) -> dict[str, Any]:
    """Two tried grasps of equal score on a 0.4 kg box: the one whose fingertips stop 4 cm short of the box's
    centre slipped, the one that reaches it held."""
    reach = {"centre_approach": 0.0, "centre_binormal": 0.002, "centre_axis": 0.01, "extent": [0.05, 0.06, 0.12]}
    short = {**reach, "centre_approach": -0.04}
    truth = [{"mass": 0.4, "com_approach": t["centre_approach"], "com_binormal": 0.0, "com_axis": 0.0}
             for t in (short, reach)]
    seen, outcomes, robust = [short, reach], ["slipped", "success"], [0.25, 1.0]
    if not short_first:
        seen, outcomes, truth, robust = seen[::-1], outcomes[::-1], truth[::-1], robust[::-1]
    return {"tried": 2, "seed": seed, "trial_scores": [0.9, 0.9], "trial_outcomes": outcomes, "trial_seen": seen,
            "trial_truth": truth, "trial_robust": robust}


def write(path: Path, scenes: str, detections: list[dict[str, Any]]) -> Path:
    path.write_text(json.dumps({"meta": {"command": "made by the test", "commit": "test", "scenes": scenes},
                                "detections": detections}))
    return path


def test_a_hold_estimate_that_sees_the_cause_picks_the_grasp_that_holds(tmp_path: Path) -> None:
    bench = load_bench("foresight")
    records = write(tmp_path / "r.json", "pile-side, household-training objects, seeds 0-39",
                    [detection(seed, short_first=seed % 2 == 0) for seed in range(40)])
    assert bench.main(["--records", str(records), "--tag", "t", "--out", str(tmp_path)]) == 0
    row = json.loads((tmp_path / "foresight-t.json").read_text())["rows"][0]
    assert row["detections"] == 40 and row["first"] == 20 and row["any"] == 40
    assert row["picked"]["seen"] == 40 and row["picked"]["truth"] == 40
    assert row["picked"]["score"] == 20  # equal scores: the first, as ranked
    # the perturbed copies: a quarter of the short grasp's held, all of the other's
    assert row["robust"]["first"] == row["robust"]["score"] == 0.625
    assert row["robust"]["seen"] == row["robust"]["best"] == 1.0
    assert "| 5 folds by round over the records | 40 | 50.0% |" in (tmp_path / "foresight-t.md").read_text()


@pytest.mark.parametrize("scenes", ["pile-side, household objects, seeds 0-29",
                                    "tray (training ranges), household objects, seeds 0-9",
                                    "tray (training ranges), scaled objects, seeds 0-9"])
def test_records_of_held_out_objects_are_refused(tmp_path: Path, scenes: str) -> None:
    bench = load_bench("foresight")
    records = write(tmp_path / "h.json", scenes, [detection(0, True)])
    with pytest.raises(SystemExit, match="only training objects"):
        bench.main(["--records", str(records), "--out", str(tmp_path)])


@pytest.mark.parametrize("scenes", ["pile-side, household-training objects, seeds 0-29",
                                    "tray (training ranges), scaled-training objects, seeds 0-9"])
def test_records_of_training_objects_are_fitted_on(scenes: str) -> None:
    assert load_bench("foresight").training_objects({"scenes": scenes})
