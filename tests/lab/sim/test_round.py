"""End to end: the hand executes real grasps, and one short round of the protocol runs."""

import numpy as np
import pytest

from graspd.core.camera import side_camera
from graspd.core.grasp import GraspSet
from graspd.core.hand import HandGeometry
from graspd_lab.sim.detectors import InProcessGPD, TopDownBaseline
from graspd_lab.sim.gripper import Gripper, Outcome
from graspd_lab.sim.protocol import Setting, run_round
from graspd_lab.sim.sensing import NO_NOISE, observe
from graspd_lab.sim.world import build_scene

WORKSPACE = (-0.15, 0.15, -0.15, 0.15, 0.0, 0.4)
REGION = (-0.17, 0.17, -0.17, 0.17, -0.005, 0.4)


def test_gripper_lifts_a_standing_object_closes_on_air_and_hits_the_floor() -> None:
    hand = HandGeometry()
    # seed 1: a 10 cm object standing (the first baseline grasp lifts it with 50 and with 150 solver iterations)
    with build_scene("packed", 1, seed=1, hand=hand) as world:
        cloud = observe(world.client, side_camera(), NO_NOISE, np.random.default_rng(0), REGION)
        grasps = TopDownBaseline().detect(cloud, WORKSPACE, hand, seed=0)
        assert len(grasps) >= 1
        gripper = Gripper(world, hand)
        (body,) = world.objects
        outcomes = []
        for i in range(min(3, len(grasps))):  # a robot may retry: one of the three best must lift it
            attempt = gripper.execute(grasps, i)
            outcomes.append(attempt.outcome)
            if attempt.outcome is Outcome.SUCCESS:
                break
        assert outcomes[-1] is Outcome.SUCCESS, outcomes
        assert attempt.target == body and not world.objects
        g = grasps[[i]]
        beside = GraspSet(positions=g.positions + 0.12 * g.binormal, rotations=g.rotations, widths=g.widths,
                          scores=g.scores, samples=g.samples)
        assert gripper.execute(beside).outcome is Outcome.EMPTY
        into_floor = GraspSet(positions=g.positions - [0.0, 0.0, 0.2], rotations=g.rotations, widths=g.widths,
                              scores=g.scores, samples=g.samples)
        assert gripper.execute(into_floor).outcome is Outcome.COLLISION

def test_one_short_baseline_round_is_deterministic() -> None:
    setting = Setting(scene="pour", num_objects=3, sensing="passive")
    result = run_round(TopDownBaseline(), setting, seed=0)
    assert result.num_objects >= 1
    assert 0 <= result.successes <= result.attempts
    assert result.cleared <= result.num_objects
    assert result.end_reason
    assert len(result.outcomes) >= result.attempts
    again = run_round(TopDownBaseline(), setting, seed=0)
    assert again.outcomes == result.outcomes and again.cleared == result.cleared


@pytest.mark.slow
def test_gpd_round_without_classification() -> None:
    result = run_round(InProcessGPD(), Setting(scene="pile", num_objects=3, sensing="side"), seed=0)
    assert result.attempts >= 1 and result.end_reason
    assert result.cleared <= result.num_objects
