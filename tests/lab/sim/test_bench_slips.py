"""bench/slips.py measures an executed grasp against the true object (its mass, how far the fingertips reach past
its centre of mass, the closing line's distance from it) and bins attempts by reach and by mass."""

from __future__ import annotations

from types import ModuleType

import numpy as np
import pybullet as pb
import pytest

from graspd.core.grasp import GraspSet
from graspd_lab.sim.world import SimWorld
from repo_module import load_bench


def _bench() -> ModuleType:
    return load_bench("slips")


def test_a_top_down_grasp_is_measured_against_the_box_it_closes_on() -> None:
    bench = _bench()
    world = SimWorld.create(has_tray=False)
    with world:
        body = world._box([0.04, 0.02, 0.03], [0.05, 0.0, 0.03], mass=0.3)  # 8 x 4 x 6 cm, centre 3 cm up
        world.objects[body] = 7  # a catalogue id, named by its number
        world.settle()
        com = np.asarray(pb.getBasePositionAndOrientation(body, physicsClientId=world.client)[0])
        rot = np.array([[0.0, 0.0, 1.0], [0.0, 1.0, 0.0], [-1.0, 0.0, 0.0]])  # approach -z, closing along y
        # fingertips 1 cm above the table, 4.5 cm fingers: the base 5.5 cm up, 2 cm along x from the centre
        grasp = GraspSet(positions=np.array([[0.03, 0.0, 0.055]]), rotations=rot[None], widths=np.array([0.04]),
                         scores=np.array([0.9]), samples=np.zeros((1, 3)))
        row = bench.measure(world, grasp, 0, hand_depth=0.045, init_bite=0.01)
    assert row["object"] == "7" and row["mass"] == pytest.approx(0.3)
    assert row["reach_past_com"] == pytest.approx(com[2] - 0.01, abs=1e-6)  # tips 2 cm past the 3 cm centre
    assert row["line_from_com"] == pytest.approx(np.hypot(com[0] - 0.03, com[2] - 0.02), abs=1e-6)
    assert row["approach_from_down"] == pytest.approx(0.0, abs=1e-6)


def test_the_report_bins_attempts_by_reach_and_by_mass() -> None:
    bench = _bench()
    records = [{"object": "a", "mass": 2.0, "reach_past_com": -0.015, "outcome": "slipped"},
               {"object": "a", "mass": 2.0, "reach_past_com": 0.015, "outcome": "success"},
               {"object": "b", "mass": 0.1, "reach_past_com": -0.005, "outcome": "success"}]
    md = bench.report(records, {"command": "c", "commit": "x", "date": "d", "model": "m"})
    assert "| < -1 cm | 1 | 0% | slipped 1 |" in md
    assert "| >= 1 cm | 1 | 100% | success 1 |" in md
    assert "| -1 to 0 cm | 1 | 100% | success 1 |" in md
    assert "| >= 1.5 kg | 2 | 50% |" in md and "| 0.05 to 0.5 kg | 1 | 100% |" in md
    assert "| a | 2.000 | 2 | 1 | -1.5 |" in md
