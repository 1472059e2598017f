"""bench/retry.py's robot-side rule: right after a failed attempt (as many objects left as before it) it executes the
first feasible grasp away from the failed one, and otherwise the service's first."""

from __future__ import annotations

from typing import Any

import numpy as np

from graspd.core.grasp import GraspSet
from graspd_lab.sim.world import SimWorld
from repo_module import load_bench


def grasps_at(*xs: float) -> GraspSet:
    m = len(xs)
    return GraspSet(positions=np.array([[x, 0.0, 0.1] for x in xs]), rotations=np.repeat(np.eye(3)[None], m, 0),
                    widths=np.full(m, 0.04), scores=np.full(m, 0.9), samples=np.zeros((m, 3)))


def test_after_a_failure_the_robot_grasps_elsewhere_and_after_a_success_as_ranked() -> None:
    bench = load_bench("retry")
    world = SimWorld.create(has_tray=False)
    with world:
        for k, x in enumerate((0.0, 0.1, 0.2)):
            world.objects[world._box([0.02, 0.02, 0.02], [x, 0.0, 0.02], mass=0.1)] = k
        records: list[dict[str, Any]] = []
        choose = bench.elsewhere_chooser(0.05, records)
        g = grasps_at(0.0, 0.01, 0.1, 0.2)
        assert choose(world, g, np.arange(4)) == 0  # the first pick of a round: as ranked
        # nothing removed since: the grasp at x = 0 failed; the next is the first more than 5 cm from it
        assert choose(world, g, np.arange(4)) == 2
        # failed again (at x = 0.1); every grasp offered lies within 5 cm of it: the first
        assert choose(world, grasps_at(0.1, 0.12), np.array([0, 1])) == 0
        body = next(iter(world.objects))
        world.remove_object(body)  # one object fewer: the last attempt held
        assert choose(world, g, np.arange(4)) == 0
    assert [r["after_failure"] for r in records] == [False, True, True, False]
    assert [r["moved"] for r in records] == [False, True, False, False]
    assert [r["rank"] for r in records] == [1, 3, 1, 1]
