"""Table 1 stopping rules, feasibility and the statistics over rounds."""

import numpy as np
import pytest

from graspd.core.grasp import GraspSet
from graspd_lab.sim.gripper import Attempt, Outcome
from graspd_lab.sim.protocol import RoundResult, Setting, StopRule, feasible, summarize


def test_three_detections_without_grasp_in_a_row_stop() -> None:
    rule = StopRule()
    assert rule.update(Attempt(Outcome.NO_GRASP, None)) == ""
    assert rule.update(Attempt(Outcome.NO_GRASP, None)) == ""
    assert rule.update(Attempt(Outcome.SUCCESS, 5)) == ""  # a found grasp resets the count
    assert rule.update(Attempt(Outcome.NO_GRASP, None)) == ""
    assert rule.update(Attempt(Outcome.NO_GRASP, None)) == ""
    assert "no grasp" in rule.update(Attempt(Outcome.NO_GRASP, None))


def test_same_failure_on_same_object_three_times_stops() -> None:
    rule = StopRule()
    for target in (4, 4, 7, 4, 4):  # another object breaks the streak
        assert rule.update(Attempt(Outcome.SLIPPED, target)) == ""
    assert rule.update(Attempt(Outcome.EMPTY, 4)) == ""  # another failure breaks it too
    assert rule.update(Attempt(Outcome.EMPTY, 4)) == ""
    assert "same failure" in rule.update(Attempt(Outcome.EMPTY, 4))


def test_standard_rule_stops_after_two_failures_in_a_row_whatever_they_failed_on() -> None:
    rule = StopRule("standard")
    assert rule.update(Attempt(Outcome.SLIPPED, 4)) == ""
    assert rule.update(Attempt(Outcome.SUCCESS, 4)) == ""  # a success resets the count
    assert rule.update(Attempt(Outcome.COLLISION, 2)) == ""
    assert "2 failures" in rule.update(Attempt(Outcome.EMPTY, 7))  # another object, another failure: still two
    assert "no grasp" in StopRule("standard").update(Attempt(Outcome.NO_GRASP, None))  # one empty detection ends it


def test_household_sets_take_the_standard_rule_and_an_explicit_rule_wins() -> None:
    assert Setting(objects="household").stop_rule == "standard"
    assert Setting(objects="household-training").stop_rule == "standard"
    assert Setting().stop_rule == "ijrr"  # the scaled set's figures were always measured with it
    assert Setting(objects="household", stop="ijrr").stop_rule == "ijrr"
    with pytest.raises(ValueError, match="stop"):
        Setting(stop="vgn")


def test_the_only_protocol_filter_is_the_arms_approach_cone() -> None:
    down = np.column_stack([[0, 0, -1.0], [1.0, 0, 0], [0, 1.0, 0]])
    up = np.column_stack([[0, 0, 1.0], [1.0, 0, 0], [0, -1.0, 0]])
    pos = np.array([[0, 0, 0.1], [0, 0, 0.1], [0.3, 0, 0.1], [0, 0, 0.1], [0, 0, 0.03]])
    grasps = GraspSet(positions=pos, rotations=np.array([down, up, down, down, down]),
                      widths=np.array([0.03, 0.03, 0.03, 0.2, 0.03]), scores=np.full(5, np.nan),
                      samples=pos + [0, 0, -0.05])
    ok = feasible(grasps, 80.0)
    # from below is out of the arm's reach; outside the tray, too wide or under the floor is the detector's
    # business, never filtered by the benchmark
    assert ok.tolist() == [True, False, True, True, True]
    tilted = np.column_stack([[np.sin(np.radians(85)), 0, -np.cos(np.radians(85))], [0, 1.0, 0],
                              [np.cos(np.radians(85)), 0, np.sin(np.radians(85))]])
    assert feasible(GraspSet(positions=pos[:1], rotations=tilted[None], widths=np.array([0.03]),
                             scores=np.array([np.nan]), samples=pos[:1]), 80.0).tolist() == [False]


def test_summary_pools_rounds_with_intervals() -> None:
    rounds = [RoundResult(seed=i, num_objects=10, successes=s, attempts=a, cleared=s,
                          outcomes=["success"] * s + ["slipped"] * (a - s)) for i, (s, a) in
              enumerate([(9, 10), (8, 10), (10, 11)])]
    s = summarize(rounds)
    assert s.success_rate == pytest.approx(27 / 31)
    assert s.cleared_rate == pytest.approx(27 / 30)
    assert s.success_ci[0] <= s.success_rate <= s.success_ci[1]
    assert s.failures == {"slipped": 4}
    with pytest.raises(ValueError):
        summarize([])


def test_bad_settings_name_the_field() -> None:
    with pytest.raises(ValueError, match="sensing"):
        Setting(sensing="lidar")
    with pytest.raises(ValueError, match="choice"):
        Setting(choice="worst")
