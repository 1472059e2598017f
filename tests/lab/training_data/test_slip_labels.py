"""Scene data with slip labels: the same rows as the analytic labels, each kept positive lifted in physics and
relabelled 0 unless it holds; negatives stay 0."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np

from graspd_lab.training.dataset import iter_chunks
from graspd_lab.training.scene_data import HOUSEHOLD_MIX, SENSOR_MIXES, SceneParams, generate_scene_dataset

#: Two household scenes of seed 0 (a pour and a pile: true-size household models beside random_urdfs), one view
#: each, few candidates: seconds of lifts.
HOUSE = SceneParams(seed=0, scenes=2, views_per_scene=1, objects=(3, 5), num_samples=20, per_view=40,
                    scenes_per_chunk=2, scene_mix=HOUSEHOLD_MIX, household_share=0.5,
                    sensor_mix=SENSOR_MIXES["mixed"])


def test_slip_labels_relabel_the_analytic_positives_that_do_not_hold_in_physics(tmp_path: Path) -> None:
    analytic = generate_scene_dataset(tmp_path / "analytic", HOUSE, workers=1)
    lifted = generate_scene_dataset(tmp_path / "lifted", replace(HOUSE, slip_labels=True), workers=1)
    a = [c for c in iter_chunks(tmp_path / "analytic", verify=True)]
    b = [c for c in iter_chunks(tmp_path / "lifted", verify=True)]
    # the lifts happen in a replica of each scene: the scenes, views, candidates and rows are the same
    for ca, cb in zip(a, b, strict=True):
        for key in ("images", "positions", "rotations", "object_ids", "view_ids"):
            np.testing.assert_array_equal(ca[key], cb[key])
    la = np.concatenate([c["labels"] for c in a])
    lb = np.concatenate([c["labels"] for c in b])
    assert la.sum() > 0
    assert not (lb & ~la).any()  # negatives stay 0; positives keep 1 only if they hold
    assert 0 < lb.sum() < la.sum()  # in these true-size piles some analytic positives slip, others hold
    lifts = [v.get("lifts", {}) for v in lifted["views"]]  # a view with no candidates lifts none
    assert sum(sum(c.values()) for c in lifts) == la.sum()  # every kept positive was lifted once
    assert sum(c.get("success", 0) for c in lifts) == lb.sum()  # exactly those that held stay positive
    assert lifted["parameters"]["slip_labels"] is True
    # without the option the parameters read as before it existed (earlier datasets resume)
    assert "slip_labels" not in analytic["parameters"]
    assert "slip_labels" not in json.loads((tmp_path / "analytic" / "params.json").read_text())
