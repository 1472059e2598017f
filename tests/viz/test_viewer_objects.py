"""The view shows the scene's objects and lets a person pick one: on the rendered table of six objects, POST
/viewer lists the answer's objects (a colour and a "grasp this" button each, boxes in the scene), each grasp row
names its object as the answer does, and target_object=K (what the drop page sends when K is picked in its frame)
draws K's grasps only and marks K; the drop page re-asks only for an integer from its own frame."""

from __future__ import annotations

import io
import re
from collections.abc import Iterator

import numpy as np
import pytest
from fastapi.testclient import TestClient

from graspd.server.app import create_app
from graspd.server.settings import Settings
from graspd.viz.viewer import DROP_CSP, DROP_SCRIPT, OBJECT_COLOURS, drop_page_html, script_hash
from graspd_client.wire import build_detect_request
from target_scene import CAMERA, OrganisedScene, render_table

SAMPLES = 120


@pytest.fixture(scope="module")
def client(tmp_path_factory: pytest.TempPathFactory) -> Iterator[TestClient]:
    settings = Settings(port=0, zenoh_enabled=False, models_dir=tmp_path_factory.mktemp("no-models"),
                        data_dir=tmp_path_factory.mktemp("data"), allow_unscored=True, detect_workers=1,
                        warmup=False)
    with TestClient(create_app(settings)) as c:
        yield c


@pytest.fixture(scope="module")
def six() -> OrganisedScene:
    return render_table()


@pytest.fixture(scope="module")
def npy(six: OrganisedScene) -> bytes:
    buf = io.BytesIO()
    np.save(buf, six.cloud.points[np.isfinite(six.cloud.points).all(axis=1)])
    return buf.getvalue()


def view(client: TestClient, npy: bytes, **params: object) -> str:
    r = client.post("/viewer", files={"file": ("six.npy", npy, "application/octet-stream")},
                    params={"num_samples": SAMPLES, "viewpoint": ",".join(map(str, CAMERA)), **params})
    assert r.status_code == 200, r.text[:300]
    return r.text


def rows_objects(page: str) -> list[str]:
    """The object column of the page's grasp rows, in rank order ("-" for none)."""
    return re.findall(r'<tr data-rank="\d+" title="[^"]*, object (\w+)">', page)


def test_the_view_lists_the_answers_objects_and_each_grasps_object(client: TestClient, six: OrganisedScene,
                                                                   npy: bytes) -> None:
    answer = client.post("/detect", json=build_detect_request(six.cloud.points, six.cloud.viewpoints,
                                                              num_samples=SAMPLES)).json()
    page = view(client, npy)
    listed = re.findall(r'<li data-object="(\d+)"><span class="dot" style="background:(#\w+)"></span>object \d+: '
                        r'(\d+) grasps', page)
    assert [int(k) for k, _, _ in listed] == [o["id"] for o in answer["objects"]] and len(listed) == 6
    assert len({c for _, c, _ in listed}) == 6 and all(c in OBJECT_COLOURS for _, c, _ in listed)
    assert all(f'data-pick="{o["id"]}"' in page for o in answer["objects"])
    shown = answer["grasps"][:50]
    assert rows_objects(page) == ["none" if g["object"] is None else str(g["object"]) for g in shown]
    assert [int(n) for _, _, n in listed] == [sum(g["object"] == o["id"] for g in shown) for o in answer["objects"]]
    assert 'class="picked"' not in page and '"sceneObjects":[0,1,2,3,4,5]' in page


def test_target_object_draws_that_objects_grasps_and_marks_it(client: TestClient, npy: bytes) -> None:
    page = view(client, npy, target_object=4)
    assert '<li data-object="4" class="picked">' in page and 'data-pick="-1">all objects</button>' in page
    assert rows_objects(page) and set(rows_objects(page)) == {"4"}
    r = client.post("/viewer", files={"file": ("six.npy", npy, "application/octet-stream")},
                    params={"num_samples": SAMPLES, "viewpoint": ",".join(map(str, CAMERA)), "target_object": 9})
    assert r.status_code == 422 and r.json()["field"] == "target.object"


def test_the_drop_page_re_asks_only_for_an_id_from_its_own_frame() -> None:
    page = drop_page_html("/viewer")
    assert "e.source !== view.contentWindow" in page and "Number.isInteger(k)" in page
    assert 'url.searchParams.set("target_object", String(target))' in page
    assert script_hash(DROP_SCRIPT) in DROP_CSP and "connect-src 'self'" in DROP_CSP
