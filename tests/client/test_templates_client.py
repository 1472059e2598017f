"""The clients' grasp-template methods against a real server (HTTP and Zenoh): teach a grasp, detect with
method="templates", report outcomes by grasp id, read the library; errors name the field."""

from __future__ import annotations

import asyncio
from typing import Any

import numpy as np
import pytest

from fixtures import box_top_grasp
from graspd.server.settings import Settings
from graspd_client import AsyncGraspClient, GraspClient, RequestRejected
from graspd_client.zenoh_client import ZenohGraspClient
from graspd_lab.world.meshes import pose_from, rot_z

Server = tuple[str, str, Settings]
BOX = (0.05, 0.10, 0.08)


def _failures(library: dict[str, Any]) -> dict[int, int]:
    return {int(e["id"]): int(e["failures"]) for e in library["entries"]}


def test_http_client_teach_detect_and_fail(server: Server, render_box, box_pose) -> None:
    url, _, _ = server
    pose = box_pose()
    cloud = render_box(pose)
    moved_pose = pose_from(rot_z(-0.8), (0.04, -0.03, 0.0)) @ pose
    moved = render_box(moved_pose)
    with GraspClient(url, timeout=60) as client:
        taught = client.add_demonstration(cloud.points, box_top_grasp(pose, BOX), cloud.viewpoints, label="top")
        entry = taught["entry_id"]
        assert taught["library"]["num_entries"] >= 1
        g = client.detect(moved.points, moved.viewpoints, method="templates", max_grasps=10)
        assert g.method == "templates" and g.scored and g.model is None and 0 < len(g) <= 10
        assert all(i.count(".") == 1 for i in g.ids) and ((g.scores > 0) & (g.scores <= 1)).all()
        want = box_top_grasp(moved_pose, BOX)
        assert np.linalg.norm(g.positions[0] - want[:3, 3]) < 0.01
        before = _failures(client.library())
        fb = client.feedback(g.ids[0], False)
        assert fb["failure_added"] and fb["image_stored"] and fb["method"] == "templates"
        after = _failures(client.library())
        assert after[fb["entry_id"]] == before[fb["entry_id"]] + 1 and entry in after
        gpd = client.detect(cloud.points, cloud.viewpoints, num_samples=40, max_grasps=2)
        assert gpd.method == "gpd" and client.feedback(gpd.ids[0], True)["method"] == "gpd"
        with pytest.raises(RequestRejected) as info:
            client.feedback("0123456789abcdef.3", True)
        assert info.value.status == 404 and info.value.field == "grasp_id"
        with pytest.raises(RequestRejected) as info:
            client.add_demonstration(cloud.points, 2 * np.eye(4), cloud.viewpoints)
        assert info.value.status == 422 and info.value.field == "hand_pose"


def test_async_client_templates(server: Server, render_box, box_pose) -> None:
    url, _, _ = server
    pose = box_pose(yaw=-0.4)
    cloud = render_box(pose)

    async def run() -> tuple[Any, Any, Any]:
        async with AsyncGraspClient(url, timeout=60) as client:
            taught = await client.add_demonstration(cloud.points, box_top_grasp(pose, BOX), cloud.viewpoints)
            g = await client.detect(cloud.points, cloud.viewpoints, method="templates", max_grasps=3)
            fb = await client.feedback(g.ids[0], True)
            return taught, fb, await client.library()

    taught, fb, library = asyncio.run(run())
    assert fb["success"] is True and fb["failure_added"] is False
    assert taught["entry_id"] in {e["id"] for e in library["entries"]}


def test_zenoh_client_templates(server: Server, render_box, box_pose) -> None:
    url, endpoint, _ = server
    pose = box_pose(yaw=0.9)
    cloud = render_box(pose)
    with ZenohGraspClient(connect=[endpoint], timeout=60) as zc, GraspClient(url, timeout=60) as hc:
        taught = zc.add_demonstration(cloud.points, box_top_grasp(pose, BOX), cloud.viewpoints, label="zenoh")
        gz = zc.detect(cloud.points, cloud.viewpoints, method="templates", max_grasps=5)
        gh = hc.detect(cloud.points, cloud.viewpoints, method="templates", max_grasps=5)
        assert gz.method == "templates" and len(gz) > 0 and np.allclose(gz.poses, gh.poses)
        before = _failures(zc.library())
        fb = zc.feedback(gz.ids[0], False)
        assert fb["failure_added"] and _failures(zc.library())[fb["entry_id"]] == before[fb["entry_id"]] + 1
        assert hc.library() == zc.library() and taught["entry_id"] in before
        with pytest.raises(RequestRejected) as info:
            zc.feedback("0123456789abcdef-0", False)
        assert info.value.status == 404 and info.value.field == "grasp_id"
        with pytest.raises(RequestRejected) as info:
            zc.detect(cloud.points, cloud.viewpoints, method="templates", num_samples=10)
        assert info.value.field == "num_samples"
