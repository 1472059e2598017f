"""A whole organised Kinect frame (a table 0.6-0.9 m away, the room behind it out to 2.3 m), uploaded as PCL wrote
it from its own camera at the origin: with a workspace around the table it gets no warning but the count of NaN
pixels; with none, the range window keeps the table and its objects, every grasp is on them, the answer counts
what was left out, and nothing warns (the camera is on no wrong side, and the default did its job)."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from fastapi.testclient import TestClient

from graspd.server.app import create_app
from graspd.server.settings import Settings

KINECT = "milk_cartoon_all_small_clorox.pcd"
TABLE = "-0.45,0.45,-0.4,0.25,0.5,1.2"  # a box around the table in the camera's frame (m)


@pytest.fixture(scope="module")
def scored(tmp_path_factory: pytest.TempPathFactory, models_and_default: tuple[Path, str]) -> Iterator[TestClient]:
    settings = Settings(zenoh_enabled=False, models_dir=models_and_default[0], data_dir=tmp_path_factory.mktemp("d"),
                        warmup=False, detect_workers=1, deadline_s=300.0)
    with TestClient(create_app(settings)) as c:
        yield c


def _upload(client: TestClient, data: bytes, **params: Any) -> dict[str, Any]:
    r = client.post("/detect", params={"num_samples": 150, **params}, content=data,
                    headers={"Content-Type": "application/octet-stream"})
    assert r.status_code == 200, r.text
    return dict(r.json())


def _codes(body: dict[str, Any]) -> list[str]:
    return [w["code"] for w in body["warnings"]]


def test_the_frame_with_a_workspace_warns_of_nothing_and_counts_its_nan_pixels(scored: TestClient,
                                                                              real_data: Path) -> None:
    body = _upload(scored, (real_data / KINECT).read_bytes(), workspace=TABLE)
    assert _codes(body) == [] and body["grasps"]
    assert body["num_points_received"] == 640 * 480 and 0 < body["num_points_dropped"] < 0.5 * 640 * 480
    assert body["num_points_out_of_range"] == 0  # the workspace chose the region: the range window does not apply


def test_the_whole_frame_keeps_the_table_and_counts_what_it_left_out(scored: TestClient, real_data: Path) -> None:
    body = _upload(scored, (real_data / KINECT).read_bytes())
    assert _codes(body) == [], body["warnings"]  # the default doing its job is no fault: counted, not warned of
    finite = body["num_points_received"] - body["num_points_dropped"]
    assert 0.05 * finite < body["num_points_out_of_range"] < finite  # the room 1.6-2.3 m away
    ranges = np.linalg.norm([g["position"] for g in body["grasps"]], axis=1)
    assert len(ranges) >= 5 and ranges.max() < 1.2, ranges  # the table's objects, not the room 1.6-2.3 m away


def test_range_window_zero_keeps_every_point(scored: TestClient, real_data: Path) -> None:
    body = _upload(scored, (real_data / KINECT).read_bytes(), range_window=0)
    assert body["num_points_out_of_range"] == 0


def test_a_tabletop_with_nothing_far_leaves_nothing_out(scored: TestClient, real_data: Path) -> None:
    body = _upload(scored, (real_data / "table_mug.pcd").read_bytes())
    assert _codes(body) == [] and body["num_points_out_of_range"] == 0, body["warnings"]
