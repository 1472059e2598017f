"""A robot that acts on the answer (Setting.relook, flat_retry): after a detection without a grasp that warns of
unseen floor, one view from straight above finds the packet the passive cameras could not see; after one that
warns of objects lying flat, a request with flat_objects on grasps the packet.  The standard protocol ends the
round at either answer."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from graspd.core.camera import overhead_camera
from graspd_lab.sim.detectors import InProcessGPD, TopDownBaseline
from graspd_lab.sim.object_sets import object_set_hand
from graspd_lab.sim.protocol import Setting, run_round, with_options

#: A deep bin of the training ranges holding one flat training object that the two passive cameras do not see
#: between its walls (seed 7: the passive answer has no grasp and warns unseen_floor).
SETTING = Setting(scene="container", container="deep_bin", container_split="training", num_objects=1,
                  objects="household-training-flat", hand=object_set_hand("household-training-flat"))
SEED = 7


def test_overhead_camera_sees_the_whole_workspace_floor_from_above() -> None:
    box = (-0.2, 0.3, -0.15, 0.15, 0.0, 0.25)
    cam = overhead_camera(box)
    assert cam.position[:2] == pytest.approx((0.05, 0.0)) and cam.position[2] >= 0.4
    corners = np.array([[x, y, 0.0] for x in box[:2] for y in box[2:4]])
    uvz = cam.project(corners)
    assert np.all(uvz[:, 2] > 0)
    assert np.all((uvz[:, 0] >= 0) & (uvz[:, 0] < cam.width) & (uvz[:, 1] >= 0) & (uvz[:, 1] < cam.height))


def test_the_standard_protocol_ends_the_round_on_the_unseen_floor() -> None:
    result = run_round(InProcessGPD(), SETTING, SEED)
    assert result.attempts == 0 and result.relooks == 0
    assert result.end_reason == "no grasp found"


def test_a_robot_that_looks_again_from_above_grasps_what_the_passive_cameras_missed() -> None:
    result = run_round(InProcessGPD(), replace(SETTING, relook=True), SEED)
    assert result.relooks >= 1
    assert result.attempts >= 1


#: The same bin, seed 14: one packet lying flat in plain view; the passive answer has no grasp and warns
#: flat_objects (its hands would need more bite than the packet's height gives).
FLAT_SEED = 14


def test_a_robot_that_asks_again_with_flat_objects_grasps_the_flat_packet() -> None:
    standard = run_round(InProcessGPD(), SETTING, FLAT_SEED)
    assert standard.attempts == 0 and standard.end_reason == "no grasp found"
    result = run_round(InProcessGPD(), replace(SETTING, flat_retry=True), FLAT_SEED)
    assert result.flat_retries >= 1 and result.relooks == 0
    assert result.attempts >= 1


def test_only_detectors_with_request_options_can_ask_again() -> None:
    assert with_options(TopDownBaseline(), flat_objects=True) is None
    again = with_options(InProcessGPD(options={"num_samples": 300}), flat_objects=True)
    assert isinstance(again, InProcessGPD) and again.options == {"num_samples": 300, "flat_objects": True}
