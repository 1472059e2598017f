"""The detection options the core supports, over the wire: use_classifier, gravity (utility ranking),
exclude_support_plane, min/max_aperture, in the JSON body and as upload query parameters; bad values get a
422 naming the field."""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from fastapi.testclient import TestClient

from graspd.core.cloud import ViewpointCloud
from graspd_lab.world.scenes import GRAVITY, cluttered_tabletop

DOWN = np.asarray(GRAVITY, np.float64)  # the rendered tabletop: table top at z = 0, gravity -z
TABLE_BAND = 0.01  # m: samples closer to z = 0 lie on the table


@pytest.fixture(scope="module")
def tabletop() -> ViewpointCloud:
    """Three procedural objects on a table, seen by two cameras (~33k points)."""
    return cluttered_tabletop(num_objects=3, seed=3, resolution_scale=0.5, table_size=(0.4, 0.4))


def grasps(client: TestClient, body: dict[str, Any]) -> dict[str, Any]:
    r = client.post("/detect", json=body)
    assert r.status_code == 200, r.text
    return dict(r.json())


def column(out: dict[str, Any], key: str) -> np.ndarray:
    return np.array([g[key] for g in out["grasps"]], np.float64).reshape(len(out["grasps"]), -1)


def test_use_classifier_false_is_the_unscored_ablation(scored_client: TestClient, krylon: ViewpointCloud,
                                                       small_body: Callable[..., dict[str, Any]]) -> None:
    scored = grasps(scored_client, small_body(krylon))
    assert scored["scored"] is True and scored["model"] is not None and scored["timings"]["score"] > 0
    assert all(g["score"] is not None for g in scored["grasps"])
    plain = grasps(scored_client, small_body(krylon, use_classifier=False))
    assert plain["scored"] is False and plain["model"] is None and plain["timings"]["score"] == 0.0
    assert plain["grasps"] and all(g["score"] is None for g in plain["grasps"])


def test_gravity_ranks_top_down_grasps_first(client: TestClient, tabletop: ViewpointCloud,
                                             small_body: Callable[..., dict[str, Any]]) -> None:
    # without an environment model nothing says which way is up, so only gravity turns J(h) on
    plain = grasps(client, small_body(tabletop, num_samples=150, environment="none"))
    ranked = grasps(client, small_body(tabletop, num_samples=150, gravity=(2 * DOWN).tolist(), environment="none"))
    # the same candidates either way (same seed); gravity only reorders by the utility J(h)
    assert ranked["num_candidates"] == plain["num_candidates"]
    top_plain = (column(plain, "approach")[:10] @ DOWN).mean()
    top_ranked = (column(ranked, "approach")[:10] @ DOWN).mean()
    assert top_ranked > top_plain + 0.2, (top_plain, top_ranked)
    assert top_ranked > 0.5, "the best grasps approach from above"


def test_exclude_support_plane_samples_nothing_on_the_table(client: TestClient, tabletop: ViewpointCloud,
                                                            small_body: Callable[..., dict[str, Any]]) -> None:
    body = small_body(tabletop, num_samples=150, selection=False, max_grasps=1000, environment="none")
    on_table = np.abs(column(grasps(client, body), "sample")[:, 2]) < TABLE_BAND
    assert on_table.sum() > 10, "without the option or an environment some candidates are sampled on the table"
    out = grasps(client, {**body, "exclude_support_plane": True})
    samples = column(out, "sample")
    assert len(samples) > 10 and (np.abs(samples[:, 2]) >= TABLE_BAND).all()
    # the default (environment "auto") samples on object points only, without the flag
    default = column(grasps(client, {**body, "environment": "auto"}), "sample")
    assert len(default) > 10 and (np.abs(default[:, 2]) >= TABLE_BAND).all()


def test_aperture_bounds_the_widths(client: TestClient, krylon: ViewpointCloud,
                                    small_body: Callable[..., dict[str, Any]]) -> None:
    body = small_body(krylon, selection=False, max_grasps=1000)
    widths = column(grasps(client, body), "width")[:, 0]
    lo, hi = np.quantile(widths, [0.25, 0.75])
    assert ((widths < lo) | (widths > hi)).any()
    kept = column(grasps(client, {**body, "min_aperture": lo, "max_aperture": hi}), "width")[:, 0]
    assert len(kept) > 0 and (kept >= lo).all() and (kept <= hi).all()


def test_upload_query_parameters_match_the_json_body(client: TestClient, krylon_path: Path, krylon: ViewpointCloud,
                                                     small_body: Callable[..., dict[str, Any]]) -> None:
    options = {"gravity": [0.0, -1.0, 0.0], "exclude_support_plane": True, "use_classifier": False,
               "min_aperture": 0.01, "max_aperture": 0.06}
    js = grasps(client, small_body(krylon, **options))
    query = "num_samples=60&viewpoint=0.5,0,0.3&gravity=0,-1,0&exclude_support_plane=true&use_classifier=false" \
            "&min_aperture=0.01&max_aperture=0.06"
    raw = client.post(f"/detect?{query}", content=krylon_path.read_bytes(),
                      headers={"Content-Type": "application/octet-stream"})
    assert raw.status_code == 200, raw.text
    assert len(js["grasps"]) > 0
    assert [g["position"] for g in raw.json()["grasps"]] == [g["position"] for g in js["grasps"]]
    plain = grasps(client, small_body(krylon))
    assert [g["position"] for g in plain["grasps"]] != [g["position"] for g in js["grasps"]]


P = [[0.0, 0.0, 0.5], [0.01, 0.0, 0.5], [0.0, 0.01, 0.5]]
BAD: list[tuple[str, dict[str, Any], str]] = [
    ("gravity zero", {"gravity": [0, 0, 0]}, "gravity"),
    ("gravity length", {"gravity": [0, -1]}, "gravity"),
    ("gravity text", {"gravity": "down"}, "gravity"),
    ("gravity nan", {"gravity": [0, float("nan"), -1]}, "gravity[1]"),
    ("use_classifier text", {"use_classifier": "maybe"}, "use_classifier"),
    ("exclude_support_plane list", {"exclude_support_plane": [1]}, "exclude_support_plane"),
    ("min_aperture negative", {"min_aperture": -0.01}, "min_aperture"),
    ("max_aperture zero", {"max_aperture": 0}, "max_aperture"),
    ("max_aperture absurd", {"max_aperture": 1e6}, "max_aperture"),
    ("max below min", {"min_aperture": 0.05, "max_aperture": 0.02}, "max_aperture"),
]


@pytest.mark.parametrize(("name", "extra", "field"), BAD, ids=[b[0] for b in BAD])
def test_bad_values_name_the_field(client: TestClient, name: str, extra: dict[str, Any], field: str) -> None:
    r = client.post("/detect", content=json.dumps({"cloud": {"points": P}, **extra}),
                    headers={"Content-Type": "application/json"})
    assert r.status_code == 422, r.text
    assert r.json()["field"] == field and r.json()["error"].startswith(field), r.json()


PCD = (b"# .PCD v0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH 3\nHEIGHT 1\nPOINTS 3\n"
       b"DATA ascii\n0 0 0.5\n0.01 0 0.5\n0 0.01 0.5\n")


@pytest.mark.parametrize(("query", "field"), [
    ("gravity=0,-1", "gravity"), ("gravity=0,0,0", "gravity"), ("use_classifier=maybe", "use_classifier"),
    ("exclude_support_plane=2", "exclude_support_plane"), ("min_aperture=wide", "min_aperture"),
    ("min_aperture=0.05&max_aperture=0.02", "max_aperture"),
])
def test_bad_upload_parameters_name_the_field(client: TestClient, query: str, field: str) -> None:
    r = client.post(f"/detect?{query}", content=PCD, headers={"Content-Type": "application/octet-stream"})
    assert r.status_code == 422, r.text
    assert r.json()["field"] == field, r.json()
