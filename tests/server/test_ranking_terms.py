"""Explainable answers: every GPD grasp carries the terms that ranked it, the response says
how they combine, and the order of the grasps is the order of their keys."""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

from fastapi.testclient import TestClient

from graspd.core.grasp import RANKING_RULE

TERMS = ("classifier", "utility", "width", "unknown")


def _check_terms(out: dict[str, Any]) -> list[dict[str, float]]:
    assert out["ranking_rule"] == RANKING_RULE
    terms = [g["ranking"] for g in out["grasps"]]
    assert terms and all(set(t) == {*TERMS, "key"} for t in terms)
    for t in terms:
        assert math.isclose(t["key"], math.prod(t[k] for k in TERMS), rel_tol=1e-9, abs_tol=1e-12)
        assert 0.0 <= t["utility"] <= 1.0 and 0.2 - 1e-9 <= t["width"] <= 1.0 and 0.0 <= t["unknown"] <= 1.0
    keys = [t["key"] for t in terms]
    assert keys == sorted(keys, reverse=True)  # best first, by key
    return terms


def test_scored_grasps_carry_their_ranking_terms(scored_client: TestClient,
                                                 small_body: Callable[..., dict[str, Any]],
                                                 krylon: Any) -> None:
    r = scored_client.post("/detect", json=small_body(krylon, gravity=[0, 0, -1], max_grasps=10))
    assert r.status_code == 200, r.text
    out = r.json()
    terms = _check_terms(out)
    # without clustering the classifier term is the grasp's own score
    for g, t in zip(out["grasps"], terms, strict=True):
        assert math.isclose(t["classifier"], g["score"], rel_tol=1e-6)
    # gravity given: the utility term varies between grasps (it is not a constant 1)
    assert len({round(t["utility"], 6) for t in terms}) > 1


def test_unscored_grasps_rank_by_the_other_terms(client: TestClient, body: dict[str, Any]) -> None:
    out = client.post("/detect", json=body).json()
    terms = _check_terms(out)
    assert all(t["classifier"] == 1.0 for t in terms) and all(g["score"] is None for g in out["grasps"])


def test_no_ranking_when_selection_is_off(client: TestClient, small_body: Callable[..., dict[str, Any]],
                                          krylon: Any) -> None:
    r = client.post("/detect", json=small_body(krylon, selection=False))
    assert r.status_code == 200, r.text
    out = r.json()
    assert out["grasps"] and "ranking_rule" not in out and all("ranking" not in g for g in out["grasps"])
