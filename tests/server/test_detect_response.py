"""The /detect answer is built once, from a detection's result by services.mapping: the same keys and values the
detectors' own to_dict() reports (plus ids), validated against the model the route declares; upload query
parameters are generated from DetectRequest."""

from __future__ import annotations

import json
from typing import Any

import numpy as np
from fastapi.testclient import TestClient
from scipy.spatial.transform import Rotation

from graspd.core.grasp import GraspSet
from graspd.core.hand import HandGeometry
from graspd.gpd.detector import Detection
from graspd.gpd.environment import Environment
from graspd.server.services.mapping import detection_inputs, result_body
from graspd.server.services.outcome import GpdResult, GraspResult, TemplatesResult
from graspd.server.uploads import CLOUD_PARAMS, QUERY_PARAMS, TARGET_PARAMS, openapi_parameters
from graspd.server.wire.detect import DetectRequest
from graspd.server.wire.response import DetectResponse
from graspd.templates import TemplateDetection
from graspd_client import wire

GPD_KEYS = {"request_id", "method", "frame", "grasps", "timings", "model", "scored", "num_candidates", "num_points",
            "hand", "environment", "warnings", "objects", "max_per_object"}
#: A request's answer also counts the rows its cloud had and those dropped for a NaN or infinite value.
INPUT_KEYS = {"num_points_received", "num_points_dropped"}
TEMPLATE_KEYS = GPD_KEYS - {"environment", "objects", "max_per_object"} | {"num_entries"}


def _grasps(n: int, seed: int = 0) -> GraspSet:
    rng = np.random.default_rng(seed)
    scores = rng.random(n)
    scores[::7] = np.nan  # unscored grasps answer null
    return GraspSet(positions=rng.normal(size=(n, 3)), rotations=Rotation.random(n, random_state=seed).as_matrix(),
                    widths=rng.random(n) * 0.08, scores=scores, samples=rng.normal(size=(n, 3)))


def answer(result: GraspResult, request_id: str, timings: dict[str, float], **options: Any) -> dict[str, Any]:
    """The JSON answer of a result as every transport sends it (validated by DetectResponse, then serialised)."""
    body = result_body(result, request_id=request_id, detection_id=request_id, timings=timings, **options)
    out: dict[str, Any] = json.loads(DetectResponse.model_validate(body).to_json())
    return out


def test_gpd_response_matches_the_detection() -> None:
    det = Detection(grasps=_grasps(100), timings={"preprocess": 0.01, "total": 0.2}, model="m", scored=True,
                    num_candidates=400, num_points=4000, hand=HandGeometry(), environment=Environment.empty(4000))
    timings = {**det.timings, "queue": 0.001}
    crops = [{"png": None, "pixel": None, "in_image": False}] * 100
    out = answer(GpdResult.of(det), "0123456789abcdef", timings, crops=crops)
    expected = det.to_dict()
    for k, g in enumerate(expected["grasps"]):
        g.update(id=f"0123456789abcdef-{k}", crop=crops[k])
    assert out == {"request_id": "0123456789abcdef", "method": "gpd", "frame": "cloud", **expected, "timings": timings}
    assert set(out) == GPD_KEYS


def test_template_response_matches_the_detection() -> None:
    n = 5
    mismatch = np.array([0.5, 1.0, np.inf, 2.0, 3.0])
    det = TemplateDetection(grasps=_grasps(n, 1), grasp_ids=[f"d1.{k}" for k in range(n)],
                            entry_ids=np.arange(n, dtype=np.int64) + 1, mismatch=mismatch,
                            frames=np.tile(np.eye(4), (n, 1, 1)), timings={"total": 0.1}, num_candidates=9,
                            num_points=300, num_entries=2, detection_id="d1")
    hand = HandGeometry()
    out = answer(TemplatesResult(det, hand), "d1", dict(det.timings))
    expected = det.to_dict()
    expected.pop("detection_id")
    assert out == {"request_id": "d1", **expected, "frame": "cloud", "model": None, "scored": True,
                   "hand": hand.to_dict(), "warnings": []}
    assert set(out) == TEMPLATE_KEYS and out["grasps"][2]["mismatch"] is None


def test_zenoh_header_is_part_of_the_model() -> None:
    det = Detection(grasps=_grasps(2), timings={}, model=None, scored=False, num_candidates=2, num_points=10)
    header = {"frame_id": "cam", "stamp": {"sec": 1, "nanosec": 2}}
    out = answer(GpdResult.of(det), "r", {}, header=header)
    assert out["header"] == header and "crop" not in out["grasps"][0] and out["environment"] is None


def test_http_answers_validate_against_the_declared_model(client: TestClient, body: dict[str, Any]) -> None:
    out = client.post("/detect", json=body).json()
    # ranked by selection: the rule, each grasp's terms; GPD counts what the range window left out
    assert set(out) == GPD_KEYS | INPUT_KEYS | {"ranking_rule", "num_points_out_of_range"}
    assert out["num_points_dropped"] == 0 < out["num_points_received"]  # krylon has no NaN row
    assert all("ranking" in g for g in out["grasps"])
    assert DetectResponse.model_validate(out).model_dump(exclude_unset=True) == out


def test_upload_query_parameters_come_from_detect_request(client: TestClient) -> None:
    objects = {"cloud", "approach", "crops", "target"}  # no query form: nested objects (target: its own params)
    assert set(QUERY_PARAMS) == set(CLOUD_PARAMS) | set(DetectRequest.model_fields) - objects | set(TARGET_PARAMS)
    assert set(CLOUD_PARAMS) == {"viewpoint", "camera_pose", "points_frame", "intrinsics", "depth_scale", "topic",
                                 "index", "info_topic", "frame"}  # the file's own: a depth image's, a bag's
    documented = client.get("/openapi.json").json()["paths"]["/detect"]["post"]["parameters"]
    assert documented == openapi_parameters()
    limits = {p["name"]: p["schema"] for p in documented}
    assert limits["num_samples"]["maximum"] == wire.MAX_NUM_SAMPLES and limits["hand"]["type"] == "string"


def test_request_options_reach_the_detector_parameters() -> None:
    cloud = {"points": [[0.0, 0.0, 0.5], [0.01, 0.0, 0.5], [0.0, 0.01, 0.5]], "viewpoints": [[0.0, 0.0, 0.0]]}
    default = detection_inputs(DetectRequest.model_validate({"cloud": cloud})).params
    asked = detection_inputs(DetectRequest.model_validate({"cloud": cloud, "early_stop": True, "max_grasps": 5,
                                                           "approach_distance": 0.08, "clustering": True})).params
    assert (default.early_stop, default.use_clustering, default.approach_distance) == (False, False, 0.05)
    assert (asked.early_stop, asked.use_clustering, asked.approach_distance, asked.max_grasps) == (True, True, 0.08, 5)


def test_the_wire_defaults_are_the_detectors() -> None:
    """range_window, max_per_object and robust_copies default on the wire to what the detector defaults to, and
    the wire's unknown_space text names the detector's fallback share (the wire package does not import the detector:
    graspd.server.wire)."""
    from graspd.gpd.occlusion import UNKNOWN_FALLBACK_SHARE  # noqa: PLC0415
    from graspd.gpd.preprocess import DEFAULT_RANGE_WINDOW  # noqa: PLC0415
    from graspd.gpd.robustness import ROBUST_COPIES, ROBUST_TOP  # noqa: PLC0415
    from graspd.gpd.selection import DEFAULT_MAX_PER_OBJECT  # noqa: PLC0415

    fields = DetectRequest.model_fields
    assert fields["robust_copies"].default == ROBUST_COPIES and f"first {ROBUST_TOP}" in str(
        fields["robust_copies"].description)
    assert fields["range_window"].default == DEFAULT_RANGE_WINDOW
    assert fields["max_per_object"].default == DEFAULT_MAX_PER_OBJECT
    assert f"{UNKNOWN_FALLBACK_SHARE:.0%}" in str(fields["unknown_space"].description)
