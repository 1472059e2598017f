"""One limits table: every entrance reads graspd.core.limits, and the robot-side client's copy (its checks
before sending) holds the same numbers, so a request the client lets through is never refused for a limit."""

from __future__ import annotations

import graspd_client.wire as wire
from graspd.core import limits
from graspd.gpd.detector import DetectionParams
from graspd.io import cloud_files, depth
from graspd.io.ros import decode
from graspd.server.wire.detect import DetectRequest


def test_the_client_checks_the_same_limits_as_the_server() -> None:
    for name in ("MAX_NUM_SAMPLES", "MAX_GRASPS", "MAX_VIEWPOINTS", "MAX_TARGET_INDICES", "MAX_TARGET_POINTS",
                 "MAX_TARGET_RLE_CHARS", "MAX_OBJECT_ID", "MAX_PER_OBJECT", "MAX_ROBUST_COPIES"):
        assert getattr(wire, name) == getattr(limits, name), name


def test_every_entrance_caps_points_and_samples_at_the_table() -> None:
    assert cloud_files.MAX_FILE_POINTS == depth.MAX_DEPTH_PIXELS == decode.MAX_POINTS == limits.MAX_POINTS
    assert decode.MAX_SAMPLES == limits.MAX_NUM_SAMPLES
    schema = DetectRequest.model_json_schema()["properties"]
    assert schema["num_samples"]["maximum"] == limits.MAX_NUM_SAMPLES
    assert schema["max_grasps"]["maximum"] == limits.MAX_GRASPS
    DetectionParams(num_samples=limits.MAX_NUM_SAMPLES)  # the detector accepts the cap and refuses one more
    try:
        DetectionParams(num_samples=limits.MAX_NUM_SAMPLES + 1)
    except ValueError as exc:
        assert str(limits.MAX_NUM_SAMPLES) in str(exc)
    else:
        raise AssertionError("DetectionParams took num_samples beyond the limit")
