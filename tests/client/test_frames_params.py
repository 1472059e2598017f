"""The client's wire forms of frames and uploads: camera poses in every form a robot has them, and file query
parameters written from Python values (what the server reads back: tests/server/test_frames_entrances.py)."""

from __future__ import annotations

import numpy as np
import pytest

from graspd_client import WireError, build_detect_request
from graspd_client.wire import camera_poses_json, upload_params

POSE = np.array([[0.0, -1.0, 0.0, 0.3], [1.0, 0.0, 0.0, -0.1], [0.0, 0.0, 1.0, 0.5], [0.0, 0.0, 0.0, 1.0]])
QUAT = [0.0, 0.0, 0.7071067811865476, 0.7071067811865476]


def test_camera_poses_json_takes_every_form() -> None:
    as_json = camera_poses_json([POSE, [0.3, -0.1, 0.5, *QUAT], {"position": (0.3, -0.1, 0.5), "quat_xyzw": QUAT}])
    assert as_json[0] == POSE.tolist()
    assert as_json[1] == as_json[2] == {"position": [0.3, -0.1, 0.5], "quat_xyzw": QUAT}
    assert camera_poses_json(POSE) == [POSE.tolist()]  # one 4x4 is one pose
    with pytest.raises(WireError) as err:
        camera_poses_json([np.eye(3)])
    assert err.value.field == "cloud.camera_poses[0]"


def test_a_request_with_camera_poses_leaves_the_default_viewpoint_out() -> None:
    body = build_detect_request(np.zeros((2, 3)), camera_poses=[POSE], points_frame="camera")
    assert "viewpoints" not in body["cloud"] and body["cloud"]["points_frame"] == "camera"
    assert build_detect_request(np.zeros((2, 3)))["cloud"]["viewpoints"] == [[0.0, 0.0, 0.0]]
    both = build_detect_request(np.zeros((2, 3)), [[1.0, 0.0, 0.0]], camera_poses=[POSE], points_frame="robot")
    assert both["cloud"]["viewpoints"] == [[1.0, 0.0, 0.0]]  # sent as given: the server says which to drop


def test_upload_params_write_query_text() -> None:
    params = upload_params({"camera_pose": [POSE, [0.3, -0.1, 0.5, *QUAT]], "intrinsics": (525, 525, 319.5, 239.5),
                            "viewpoint": [[0, 0, 0], [1, 2, 3]], "early_stop": True, "num_samples": 80,
                            "points_frame": "camera", "model": None})
    assert [len(p.split(",")) for p in params["camera_pose"]] == [16, 7]
    assert params["intrinsics"] == "525.0,525.0,319.5,239.5" and params["viewpoint"] == ["0.0,0.0,0.0", "1.0,2.0,3.0"]
    assert params["early_stop"] == "true" and params["num_samples"] == 80 and "model" not in params
    assert upload_params({"camera_pose": {"position": [1, 2, 3], "quat_xyzw": QUAT}})["camera_pose"] == [
        "1.0,2.0,3.0," + ",".join(repr(q) for q in QUAT)]
