"""bench/two_stage.py lets a second model re-order the service's first feasible grasps, from the service's images."""

from __future__ import annotations

from typing import cast

import numpy as np

from box_scene import pose_from, render_boxes, rot_z, table_box
from graspd.gpd.classifier import load_model
from graspd_lab.sim.detectors import InProcessGPD
from graspd_lab.sim.object_sets import PANDA_LIKE
from graspd_lab.sim.world import SimWorld
from repo_module import load_bench


def test_the_second_model_picks_among_the_first_grasps_by_its_own_score() -> None:
    bench = load_bench("two_stage")
    oracle = load_bench("oracle")
    box = ((0.05, 0.04, 0.08), pose_from(rot_z(0.3), [0.0, 0.0, 0.04]))
    cloud = render_boxes([table_box(), box], np.array([[0.5, -0.3, 0.5], [-0.4, -0.4, 0.5]]),
                         look_at=[0.0, 0.0, 0.03], noise=0.0005)
    workspace = (-0.2, 0.2, -0.2, 0.2, -0.02, 0.3)
    detector = oracle.Watched(InProcessGPD(classifier=load_model("household15", threads=1)))
    grasps = detector.detect(cloud, workspace, PANDA_LIKE, seed=0)
    second = load_model("tried15", threads=1)
    ok = np.arange(len(grasps))[::-1].copy()  # feasible grasps in the order the protocol would try them
    world = cast(SimWorld, None)  # the chooser reads no world: nothing true leaks into the choice
    pick = bench.second_stage(5, PANDA_LIKE, detector, second)(world, grasps, ok)
    scores = second.score(oracle.tried_images(cloud, workspace, grasps[ok[:5]], PANDA_LIKE))
    assert pick == ok[int(np.argmax(scores))]
    assert bench.second_stage(1, PANDA_LIKE, detector, second)(world, grasps, ok) == ok[0]
    # blend 0 weighs the first model's score alone (an in-process detector's answer gives no other terms)
    first = bench.second_stage(5, PANDA_LIKE, detector, second, blend=0.0)(world, grasps, ok)
    assert first == ok[int(np.argmax(grasps.scores[ok[:5]]))]
