"""GET /viewer serves the drop page; POST /viewer answers a dropped PCD/PLY with the 3D view, guarded like
/detect upload (token, size cap, query options, 4xx naming the field).  FastAPI test client, real engine."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest
from fastapi.testclient import TestClient

from fixtures import KRYLON_VIEWPOINT
from graspd.server.app import create_app
from graspd.server.settings import Settings
from graspd.viz.viewer import PLOT_ID

TOKEN = "viewer-token-0123456789"
AUTH = {"Authorization": f"Bearer {TOKEN}"}
CAP = 400_000


@pytest.fixture(scope="module")
def client(tmp_path_factory: pytest.TempPathFactory) -> Iterator[TestClient]:
    settings = Settings(port=0, zenoh_enabled=False, models_dir=tmp_path_factory.mktemp("no-models"),
                        data_dir=tmp_path_factory.mktemp("data"), allow_unscored=True, detect_workers=1,
                        token=TOKEN, max_body_bytes=CAP, warmup=False)
    with TestClient(create_app(settings)) as c:
        yield c


@pytest.fixture(scope="module")
def krylon_pcd(real_data: Path) -> bytes:
    return (real_data / "krylon.pcd").read_bytes()


def test_get_viewer_is_the_drop_page(client: TestClient) -> None:
    r = client.get("/viewer")
    assert r.status_code == 200 and r.headers["content-type"].startswith("text/html")
    assert 'data-post="/viewer"' in r.text and 'form.append("file"' in r.text


def test_post_viewer_draws_the_detection(client: TestClient, krylon_pcd: bytes) -> None:
    r = client.post("/viewer", files={"file": ("krylon.pcd", krylon_pcd, "application/octet-stream")},
                    params={"num_samples": 60, "max_grasps": 7, "viewpoint": ",".join(map(str, KRYLON_VIEWPOINT))},
                    headers=AUTH)
    assert r.status_code == 200, r.text[:300]
    assert r.headers["content-type"].startswith("text/html")
    page = r.text
    assert f'id="{PLOT_ID}"' in page and "krylon.pcd: 7 grasps" in page
    assert "<script src=\"http" not in page  # self-contained


@pytest.mark.parametrize(
    ("kwargs", "status", "field"),
    [
        ({"headers": {}}, 401, "Authorization"),
        ({"params": {"num_samples": 0}}, 422, "num_samples"),
        ({"params": {"bogus": 1}}, 422, "bogus"),
        ({"params": {"method": "templates"}}, 422, "method"),
        ({"files": {"other": ("k.pcd", b"x")}}, 422, "file"),
        ({"files": {"file": ("k.txt", b"hello world")}}, 415, "body"),
        ({"files": {"file": ("big.pcd", b"0" * (CAP + 1))}}, 413, "body"),
        ({"content": b"VERSION .7\n", "files": None}, 415, "body"),
    ],
)
def test_bad_viewer_posts_name_the_field(client: TestClient, krylon_pcd: bytes, kwargs: dict[str, object],
                                         status: int, field: str) -> None:
    args: dict[str, object] = {"files": {"file": ("krylon.pcd", krylon_pcd)}, "params": {"num_samples": 20},
                               "headers": AUTH}
    args.update(kwargs)
    if args.get("files") is None:
        args.pop("files")
    r = client.post("/viewer", **args)  # type: ignore[arg-type]
    assert r.status_code == status, r.text[:300]
    assert r.json()["field"] == field
