"""The grasp-template endpoints over HTTP: teach a grasp on a rendered box, find it again with method
"templates" on the same and on the moved box, report a failure and see F_l grow in GET /library and the
failed grasp drop; GPD grasps' outcomes stored with their 15-channel image; bad input named in 4xx."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from typing import Any

import numpy as np
import pytest
from fastapi.testclient import TestClient

from fixtures import box_side_grasp, box_top_grasp, grasp_angle_deg
from graspd.core.cloud import ViewpointCloud
from graspd.server.app import create_app
from graspd.server.settings import Settings
from graspd.templates import TemplateLibrary
from graspd_client import build_demonstration_request, build_detect_request
from graspd_lab.world.meshes import pose_from, rot_z

BOX = (0.05, 0.10, 0.08)
MOVE = pose_from(rot_z(1.1), (-0.03, 0.05, 0.0))


@pytest.fixture
def app(make_settings: Callable[..., Settings]) -> Iterator[TestClient]:
    with TestClient(create_app(make_settings())) as c:
        yield c


def _demonstrate(c: TestClient, cloud: ViewpointCloud, pose: np.ndarray, **options: Any) -> Any:
    return c.post("/demonstrations", json=build_demonstration_request(cloud.points, pose, cloud.viewpoints,
                                                                       **options))


def _templates(c: TestClient, cloud: ViewpointCloud, **options: Any) -> dict[str, Any]:
    r = c.post("/detect", json=build_detect_request(cloud.points, cloud.viewpoints, method="templates", **options))
    assert r.status_code == 200, r.text
    body: dict[str, Any] = r.json()
    return body


def _key(grasp: dict[str, Any]) -> tuple[float, ...]:
    """A grasp's pose rounded to 0.1 mm / 1e-4, to find the same candidate in another answer."""
    return tuple(np.round(np.array(grasp["pose"]).ravel(), 4).tolist())


def _problem(r: Any, status: int, field: str) -> str:
    assert r.status_code == status, r.text
    body = r.json()
    assert body["field"] == field, body
    return str(body["error"])


def test_teach_detect_fail_and_see_the_failure_set_grow(app: TestClient, render_box, box_pose,
                                                         check_convention) -> None:
    pose = box_pose()
    cloud = render_box(pose)
    top = box_top_grasp(pose, BOX)
    r = _demonstrate(app, cloud, top, label="box top")
    assert r.status_code == 200, r.text
    entry = r.json()["entry_id"]
    assert r.json()["library"]["num_entries"] == 1 and r.json()["library"]["num_failures"] == 0

    same = _templates(app, cloud, max_grasps=5)
    assert same["method"] == "templates" and same["scored"] is True and same["model"] is None
    assert same["num_entries"] == 1 and 0 < len(same["grasps"]) <= 5
    check_convention(same["grasps"])
    g = same["grasps"][0]
    assert g["template_entry"] == entry and g["id"].endswith(".0") and 0 < g["score"] <= 1
    assert np.isclose(g["score"], 1 / (1 + g["mismatch"]))
    assert np.linalg.norm(np.array(g["position"]) - top[:3, 3]) < 0.01

    moved_pose = MOVE @ pose
    moved = render_box(moved_pose)
    first = _templates(app, moved, max_grasps=50)
    want = box_top_grasp(moved_pose, BOX)
    best = first["grasps"][0]
    assert np.linalg.norm(np.array(best["position"]) - want[:3, 3]) < 0.01
    assert grasp_angle_deg(np.array(best["pose"])[:3, :3], want[:3, :3]) < 12.0

    r = app.post("/feedback", json={"grasp_id": best["id"], "success": False})
    assert r.status_code == 200, r.text
    fb = r.json()
    assert fb["method"] == "templates" and fb["entry_id"] == entry
    assert fb["failure_added"] is True and fb["image_stored"] is True
    lib = app.get("/library").json()
    assert lib["num_failures"] == 1 and lib["num_outcomes"] == 1 and lib["num_images"] == 1
    assert [(e["id"], e["label"], e["failures"]) for e in lib["entries"]] == [(entry, "box top", 1)]

    # the same view again: the failed candidate itself is gone (an identical failure makes m infinite, eq. 2)
    # and every other candidate matches its entry no better than before, the ones like the failed one worse
    again = _templates(app, moved, max_grasps=50)
    assert again["num_candidates"] == first["num_candidates"] and again["grasps"]
    before = {_key(x): x["mismatch"] for x in first["grasps"]}
    after = {_key(x): x["mismatch"] for x in again["grasps"]}
    assert _key(best) not in after
    common = sorted(set(before) & set(after))
    assert len(common) >= 10
    assert all(after[k] >= before[k] - 1e-9 for k in common)
    assert any(after[k] > 1.5 * before[k] for k in common)

    # a success is stored but leaves F_l alone
    ok = app.post("/feedback", json={"grasp_id": again["grasps"][0]["id"], "success": True}).json()
    assert ok["failure_added"] is False
    lib = app.get("/library").json()
    assert lib["num_failures"] == 1 and lib["num_outcomes"] == 2 and lib["num_successes"] == 1


def test_gpd_grasp_outcomes_are_stored_with_their_image(make_settings: Callable[..., Settings], render_box,
                                                        box_pose) -> None:
    settings = make_settings(feedback_detections=1)
    cloud = render_box(box_pose())
    with TestClient(create_app(settings)) as c:
        def gpd() -> dict[str, Any]:
            r = c.post("/detect", json=build_detect_request(cloud.points, cloud.viewpoints, num_samples=40,
                                                           max_grasps=3))
            assert r.status_code == 200, r.text
            assert r.json()["method"] == "gpd" and r.json()["grasps"]
            return dict(r.json())

        old, new = gpd(), gpd()
        r = c.post("/feedback", json={"grasp_id": new["grasps"][1]["id"], "success": False})
        assert r.status_code == 200, r.text
        fb = r.json()
        assert fb["method"] == "gpd" and fb["entry_id"] is None and fb["image_stored"] is True
        assert fb["failure_added"] is False  # a GPD grasp has no library entry
        # only the last detection is remembered (feedback_detections=1)
        _problem(c.post("/feedback", json={"grasp_id": old["grasps"][0]["id"], "success": True}), 404, "grasp_id")
        _problem(c.post("/feedback", json={"grasp_id": new["request_id"] + "-99", "success": True}), 404,
                 "grasp_id")
        lib = c.get("/library").json()
        assert lib["num_outcomes"] == 1 and lib["num_images"] == 1 and lib["num_failures"] == 0
    stored = list(TemplateLibrary(settings.resolved_template_library()).iter_outcomes(with_images_only=True))
    assert len(stored) == 1 and stored[0]["grasp_id"] == new["grasps"][1]["id"] and stored[0]["success"] is False
    assert stored[0]["image"].shape == (15, 60, 60) and stored[0]["image"].any() and stored[0]["heights"] is None
    assert np.allclose(stored[0]["pose"], new["grasps"][1]["pose"])


def test_gpd_memory_cap_holds(make_settings: Callable[..., Settings], body: dict[str, Any]) -> None:
    with TestClient(create_app(make_settings(feedback_memory_mb=0.01))) as c:  # 10 KiB: no krylon cloud fits
        gid = c.post("/detect", json=body).json()["grasps"][0]["id"]
        _problem(c.post("/feedback", json={"grasp_id": gid, "success": True}), 404, "grasp_id")
    with TestClient(create_app(make_settings(feedback_memory_mb=1.0))) as c:  # one fits
        gid = c.post("/detect", json=body).json()["grasps"][0]["id"]
        assert c.post("/feedback", json={"grasp_id": gid, "success": True}).status_code == 200


def test_empty_library_answers_no_grasps(app: TestClient, render_box, box_pose) -> None:
    body = _templates(app, render_box(box_pose()))
    assert body["grasps"] == [] and body["num_entries"] == 0 and body["num_candidates"] > 0
    assert app.get("/library").json()["entries"] == []


def test_bad_input_is_named(app: TestClient, render_box, box_pose) -> None:
    pose = box_pose()
    cloud = render_box(pose)
    top = box_top_grasp(pose, BOX)
    good = build_demonstration_request(cloud.points, top, cloud.viewpoints)

    def demo(**change: Any) -> Any:
        body = {k: v for k, v in {**good, **change}.items() if v is not None}
        return app.post("/demonstrations", json=body)

    sheared = top.copy()
    sheared[:3, :3] = sheared[:3, :3] @ np.array([[1.0, 0.3, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
    assert "orthonormal" in _problem(demo(hand_pose=sheared.tolist()), 422, "hand_pose")
    mirrored = top.copy()
    mirrored[:3, 2] *= -1
    assert "right-handed" in _problem(demo(hand_pose=mirrored.tolist()), 422, "hand_pose")
    _problem(demo(hand_pose=top[:3].tolist()), 422, "hand_pose")
    _problem(app.post("/demonstrations", json={"cloud": good["cloud"]}), 422, "hand_pose")
    _problem(app.post("/demonstrations", json={"hand_pose": top.tolist()}), 422, "cloud")
    far = top.copy()
    far[:3, 3] += [0.3, 0.0, 0.0]  # 30 cm beside the box: no side of it is approached
    assert "approaches no camera-facing side" in _problem(demo(hand_pose=far.tolist()), 422, "hand_pose")
    above = top.copy()
    above[:3, 3] += [0.0, 0.0, 0.5]  # on the top's axis but half a metre above it: the fingers hold nothing
    assert "approaches no camera-facing side" in _problem(demo(hand_pose=above.tolist()), 422, "hand_pose")
    assert "made for" in _problem(demo(hand="panda"), 422, "hand")
    _problem(demo(label="x" * 201), 422, "label")
    _problem(demo(workspace=[1, 0, 0, 1, 0, 1]), 422, "workspace")
    _problem(app.post("/demonstrations", content=b"{not json", headers={"Content-Type": "application/json"}),
             400, "body")

    detect = build_detect_request(cloud.points, cloud.viewpoints, method="templates", num_samples=50)
    assert "not used by method 'templates'" in _problem(app.post("/detect", json=detect), 422, "num_samples")
    del detect["num_samples"]
    _problem(app.post("/detect", json={**detect, "method": "nope"}), 422, "method")

    _problem(app.post("/feedback", json={"grasp_id": "0123456789abcdef.0", "success": False}), 404, "grasp_id")
    _problem(app.post("/feedback", json={"grasp_id": "0123456789abcdef-0", "success": False}), 404, "grasp_id")
    _problem(app.post("/feedback", json={"grasp_id": "no such thing", "success": False}), 422, "grasp_id")
    _problem(app.post("/feedback", json={"grasp_id": "0123456789abcdef.0"}), 422, "success")
    _problem(app.post("/feedback", json={"grasp_id": "0123456789abcdef.0", "success": "yes"}), 422, "success")
    _problem(app.post("/feedback", json={"success": True}), 422, "grasp_id")
    # nothing was added, and the service keeps serving
    assert _demonstrate(app, cloud, top).status_code == 200
    assert app.get("/library").json()["num_entries"] == 1


def test_a_library_that_cannot_open_answers_503_and_gpd_still_works(make_settings: Callable[..., Settings],
                                                                    body: dict[str, Any]) -> None:
    settings = make_settings(template_library="sqlite:////proc/graspd-no-such-dir/templates.db")
    with TestClient(create_app(settings)) as c:
        assert "cannot be opened" in _problem(c.get("/library"), 503, "template_library")
        templates = {k: v for k, v in body.items() if k != "num_samples"}
        _problem(c.post("/detect", json={**templates, "method": "templates"}), 503, "template_library")
        assert c.post("/detect", json=body).status_code == 200


def test_template_ids_survive_a_restart_gpd_ids_do_not(make_settings: Callable[..., Settings], render_box,
                                                      box_pose) -> None:
    pose = box_pose()
    cloud = render_box(pose)
    with TestClient(create_app(make_settings())) as c:
        assert _demonstrate(c, cloud, box_top_grasp(pose, BOX), label="top").status_code == 200
        template_id = _templates(c, cloud, max_grasps=2)["grasps"][0]["id"]
        gpd = c.post("/detect", json=build_detect_request(cloud.points, cloud.viewpoints, num_samples=30)).json()
    with TestClient(create_app(make_settings())) as c:  # the same library file, a new process state
        assert c.get("/library").json()["entries"][0]["label"] == "top"
        r = c.post("/feedback", json={"grasp_id": template_id, "success": False})
        assert r.status_code == 200 and r.json()["failure_added"] is True, r.text
        assert "forgotten" in _problem(c.post("/feedback", json={"grasp_id": gpd["grasps"][0]["id"], "success": True}),
                                       404, "grasp_id")


def test_only_the_newest_template_detections_are_kept(make_settings: Callable[..., Settings], render_box,
                                                     box_pose) -> None:
    pose = box_pose()
    cloud = render_box(pose)
    with TestClient(create_app(make_settings(template_detections=2))) as c:
        _demonstrate(c, cloud, box_top_grasp(pose, BOX))
        ids = [_templates(c, cloud, max_grasps=1)["grasps"][0]["id"] for _ in range(3)]
        assert c.get("/library").json()["num_detections"] == 2
        assert "pruned" in _problem(c.post("/feedback", json={"grasp_id": ids[0], "success": True}), 404, "grasp_id")
        for gid in ids[1:]:
            assert c.post("/feedback", json={"grasp_id": gid, "success": True}).status_code == 200


def test_template_endpoints_need_the_token_when_set(make_settings: Callable[..., Settings]) -> None:
    with TestClient(create_app(make_settings(token="s3cret"))) as c:
        _problem(c.get("/library"), 401, "Authorization")
        _problem(c.post("/feedback", json={"grasp_id": "0123456789abcdef.0", "success": True}), 401, "Authorization")
        _problem(c.post("/demonstrations", json={}), 401, "Authorization")
        assert c.get("/library", headers={"Authorization": "Bearer s3cret"}).status_code == 200


def test_second_demonstration_and_upload_with_method(app: TestClient, render_box, box_pose) -> None:
    pose = box_pose()
    cloud = render_box(pose)
    assert _demonstrate(app, cloud, box_top_grasp(pose, BOX), label="top").json()["entry_id"] == 1
    r = _demonstrate(app, cloud, box_side_grasp(pose, BOX), label="side")
    assert r.json()["entry_id"] == 2 and r.json()["library"]["num_entries"] == 2
    n = len(cloud)
    data = (f"VERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH {n}\nHEIGHT 1\n"
            f"POINTS {n}\nDATA binary\n").encode() + cloud.points.astype("<f4").tobytes()
    r = app.post("/detect", content=data, headers={"Content-Type": "application/octet-stream"},
                 params={"method": "templates", "max_grasps": 20, "viewpoint": "0.5,0.1,0.5"})
    assert r.status_code == 200, r.text
    assert r.json()["method"] == "templates" and {g["template_entry"] for g in r.json()["grasps"]} == {1, 2}
