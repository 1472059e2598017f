"""The client's target= and max_per_object= over HTTP and Zenoh: the same answer on both, objects parsed, and
targets beyond the limits refused before anything is sent."""

from __future__ import annotations

import numpy as np
import pytest

from graspd.server.settings import Settings
from graspd_client import GraspClient
from graspd_client.codec import WireError
from graspd_client.wire import MAX_TARGET_POINTS, build_detect_request, build_target
from graspd_client.zenoh_client import ZenohGraspClient
from target_scene import render_table

Server = tuple[str, str, Settings]


def test_http_and_zenoh_clients_send_the_same_target(server: Server) -> None:
    url, endpoint, _ = server
    scene = render_table()
    options = {"num_samples": 150, "max_per_object": 1}
    with GraspClient(url, timeout=60) as hc, ZenohGraspClient(connect=[endpoint], timeout=60) as zc:
        plain = hc.detect(scene.cloud.points, scene.cloud.viewpoints, **options)
        assert len(plain.scene_objects) == 6 and len(plain.object_ids) == len(plain)
        assert len(set(plain.object_ids[:6].tolist())) == 6  # max_per_object=1: one grasp each before any second
        oid = int(plain.object_ids[0])
        by_http = hc.detect(scene.cloud.points, scene.cloud.viewpoints, target={"object": oid}, **options)
        by_zenoh = zc.detect(scene.cloud.points, scene.cloud.viewpoints, target={"object": oid}, **options)
        by_mask = hc.detect(scene.cloud.points, scene.cloud.viewpoints,
                            target={"mask": scene.mask(int(np.bincount(scene.ids[scene.ids > 0]).argmax()))},
                            **options)
    assert len(by_http) and set(by_http.object_ids.tolist()) == {oid}
    assert np.allclose(by_http.positions, by_zenoh.positions) and by_http.raw["objects"] == by_zenoh.raw["objects"]
    assert len(by_mask) and len(set(by_mask.object_ids.tolist())) == 1


def test_targets_beyond_the_limits_are_refused_before_sending() -> None:
    with pytest.raises(WireError) as err:
        build_target({"points": np.zeros((MAX_TARGET_POINTS + 1, 3))})
    assert err.value.field == "target.points"
    with pytest.raises(WireError) as err:
        build_target({"indices": [1], "object": 2})
    assert err.value.field == "target"
    with pytest.raises(WireError) as err:
        build_target({"indices": np.array([0.5])})
    assert err.value.field == "target.indices"
    body = build_detect_request(np.zeros((4, 3)), target={"box": {"centre": [0, 0, 0], "quat_xyzw": [0, 0, 0, 1],
                                                                  "half_extents": [1, 1, 1]}}, max_per_object=3)
    assert body["target"]["box"]["quat_xyzw"] == [0.0, 0.0, 0.0, 1.0] and body["max_per_object"] == 3
