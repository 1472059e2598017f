"""Targets over HTTP, uploads and the Zenoh parser: one object of a rendered organised table named as indices, a PNG
mask, COCO RLE (counts list and pycocotools' string), a box and an object id gets the same grasps; targets that
select nothing or do not fit the cloud are 422s naming the field."""

from __future__ import annotations

import base64
import io
from collections.abc import Callable
from typing import Any

import numpy as np
import pytest
from fastapi.testclient import TestClient
from PIL import Image

from graspd.core.masks import rle_decode, rle_string_counts
from graspd.gpd.selection import DEFAULT_MAX_PER_OBJECT
from graspd.server.requests import parse_request
from graspd.server.services.mapping import detection_inputs
from graspd_client.wire import build_detect_request, rle_counts
from target_scene import HEIGHT, WIDTH, OrganisedScene, render_table

SAMPLES = 200


def coco_string(counts: list[int]) -> str:
    """pycocotools' rleToString (maskApi.c), line for line: the compressed form a segmentation model writes."""
    out = []
    for i, x in enumerate(counts):
        if i > 2:
            x -= counts[i - 2]
        more = True
        while more:
            c = x & 0x1F
            x >>= 5
            more = (x != -1) if (c & 0x10) else (x != 0)
            if more:
                c |= 0x20
            out.append(chr(c + 48))
    return "".join(out)


def png_b64(mask: np.ndarray) -> str:
    buf = io.BytesIO()
    Image.fromarray((mask * 255).astype(np.uint8), "L").save(buf, format="PNG")
    return base64.b64encode(buf.getvalue()).decode("ascii")


@pytest.fixture(scope="module")
def six() -> OrganisedScene:
    return render_table()


def _body(scene: OrganisedScene, **options: Any) -> dict[str, Any]:
    return build_detect_request(scene.cloud.points, scene.cloud.viewpoints, num_samples=SAMPLES, **options)


def _positions(answer: dict[str, Any]) -> np.ndarray:
    return np.array([g["position"] for g in answer["grasps"]])


def test_one_object_named_six_ways_gets_the_same_grasps(scored_client: TestClient, six: OrganisedScene) -> None:
    plain = scored_client.post("/detect", json=_body(six)).json()
    assert len(plain["objects"]) == 6 and plain["max_per_object"] == DEFAULT_MAX_PER_OBJECT
    for g in plain["grasps"]:
        assert g["object"] is None or g["id"] and plain["grasps"].index(g) in plain["objects"][g["object"]]["grasps"]
    k = 5
    centre, rotation, half = six.boxes[k - 1]
    oid = int(np.argmin([np.linalg.norm(np.array(o["centre"][:2]) - centre[:2]) for o in plain["objects"]]))
    counts = rle_counts(six.mask(k))
    targets: list[dict[str, Any]] = [
        {"indices": six.rows(k)},
        {"mask": base64.b64decode(png_b64(six.mask(k)))},
        {"mask": six.mask(k)},  # the client sends a boolean image as COCO RLE counts
        {"mask": {"size": [HEIGHT, WIDTH], "counts": coco_string(counts)}},
        {"box": {"centre": centre, "rotation": rotation, "half_extents": half + 0.01}},
        {"object": oid},
    ]
    answers = []
    for target in targets:
        r = scored_client.post("/detect", json=_body(six, target=target))
        assert r.status_code == 200, r.text
        answers.append(r.json())
    assert len(answers[0]["grasps"]) >= 5
    for answer in answers[1:]:
        assert np.allclose(_positions(answer), _positions(answers[0]))
    assert {g["object"] for g in answers[0]["grasps"]} == {oid}
    assert answers[0]["objects"] == [{**o, "grasps": o["grasps"] if o["id"] != oid else list(range(len(
        answers[0]["grasps"])))} if o["id"] == oid else {**o, "grasps": []} for o in plain["objects"]]


def test_coco_rle_decodes_column_major_in_both_forms() -> None:
    mask = np.zeros((5, 7), bool)
    mask[1:4, 2] = mask[0, 6] = mask[4, 0] = True
    counts = rle_counts(mask)
    assert counts[0] == 4  # column 0 holds rows 0-3 unset, then row 4 set: column-major
    assert (rle_decode(np.array(counts), 5, 7) == mask.reshape(-1)).all()
    big = np.random.default_rng(0).random((40, 60)) < 0.3
    c = rle_counts(big)
    assert rle_string_counts(coco_string(c)).tolist() == c
    assert (rle_decode(rle_string_counts(coco_string(c)), 40, 60) == big.reshape(-1)).all()


@pytest.mark.parametrize(("target", "field"), [
    (lambda s: {"mask": np.zeros((HEIGHT, WIDTH - 1), bool) | True}, "target.mask"),
    (lambda s: {"mask": base64.b64decode(png_b64(np.ones((HEIGHT + 1, WIDTH), bool)))}, "target.mask"),
    (lambda s: {"mask": {"size": [HEIGHT, WIDTH], "counts": [HEIGHT * WIDTH - 3, 2]}}, "target.mask.counts"),
    (lambda s: {"indices": [0, len(s.cloud)]}, "target.indices"),
    (lambda s: {"indices": [-1]}, "target.indices"),
    (lambda s: {"indices": np.flatnonzero(~np.isfinite(s.cloud.points).all(axis=1))[:3]}, "target.indices"),
    (lambda s: {"box": {"centre": [1.0, 1.0, 1.0], "half_extents": [0.05, 0.05, 0.05]}}, "target.box"),
    (lambda s: {"box": {"centre": [0.0, 0.0, 0.0], "quat_xyzw": [0, 0, 0, 2], "half_extents": [1, 1, 1]}},
     "target.box.quat_xyzw"),
    (lambda s: {"object": 6}, "target.object"),
    (lambda s: {"points": [[2.0, 2.0, 2.0]]}, "target.points"),
])
def test_a_target_that_does_not_fit_the_cloud_is_a_422_naming_the_field(
        client: TestClient, six: OrganisedScene, target: Callable[[OrganisedScene], dict[str, Any]],
        field: str) -> None:
    r = client.post("/detect", json=_body(six, target=target(six)))
    assert r.status_code == 422, r.text
    assert r.json()["field"] == field, r.json()


def test_two_targets_at_once_are_refused(client: TestClient, six: OrganisedScene) -> None:
    body = _body(six, target={"object": 0})
    body["target"]["indices"] = [1, 2]
    r = client.post("/detect", json=body)
    assert r.status_code == 422 and r.json()["field"] == "target"


def test_upload_query_parameters_and_zenoh_json_carry_the_target(scored_client: TestClient,
                                                                 six: OrganisedScene) -> None:
    k = 2
    finite = np.isfinite(six.cloud.points).all(axis=1)
    buf = io.BytesIO()
    np.save(buf, six.cloud.points[finite])  # an .npy upload: rows as the file has them
    rows = np.flatnonzero(six.ids[finite] == k)
    query = {"viewpoint": ",".join(map(str, six.cloud.viewpoints[0])), "num_samples": str(SAMPLES),
             "target_indices": ",".join(map(str, rows))}
    uploaded = scored_client.post("/detect", content=buf.getvalue(), params=query,
                                  headers={"content-type": "application/x-npy"})
    assert uploaded.status_code == 200, uploaded.text
    as_json = scored_client.post("/detect", json=_body(six, target={"indices": six.rows(k)})).json()
    assert np.allclose(_positions(uploaded.json()), _positions(as_json))
    centre, _, half = six.boxes[k - 1]
    box = ",".join(map(str, [*centre, 0, 0, 0, 1, *(half + 0.05)]))
    r = scored_client.post("/detect", content=buf.getvalue(), params={**query, "target_box": box},
                           headers={"content-type": "application/x-npy"})
    assert r.status_code == 422 and r.json()["field"] == "target_box"  # one target at a time
    parsed = parse_request(_body(six, target={"indices": six.rows(k)}, max_per_object=0))  # what Zenoh runs
    params = detection_inputs(parsed).params
    assert params.target is not None and params.target.kind == "indices" and params.max_per_object == 0
    assert params.target.rows is not None and params.target.rows.sum() == len(six.rows(k))
