"""graspd detect's target flags on the rendered table of six objects, saved as an organised .npy (one row per
pixel, NaN where nothing was hit): --target-mask (a PNG of the image's size), --target-box, --target-object and
--target-indices give the grasps POST /detect gives for the same target (same seed, unscored); --max-per-object
reaches the ranking; --plot and --view mark the target's object; a mask of another size names the flag."""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from fastapi.testclient import TestClient
from PIL import Image

from graspd.cli.main import main
from graspd.core.grasp import rotation_to_quat_xyzw
from graspd.server.app import create_app
from graspd.server.settings import Settings
from graspd_client.wire import build_detect_request
from target_scene import CAMERA, HEIGHT, WIDTH, OrganisedScene, render_table

SAMPLES, MAX_GRASPS = 150, 12
#: The object the targets name (1-based, as in OrganisedScene.ids).
K = 2


@pytest.fixture(scope="module")
def six() -> OrganisedScene:
    return render_table()


@pytest.fixture(scope="module")
def client(tmp_path_factory: pytest.TempPathFactory) -> Iterator[TestClient]:
    settings = Settings(port=0, zenoh_enabled=False, models_dir=tmp_path_factory.mktemp("no-models"),
                        data_dir=tmp_path_factory.mktemp("data"), allow_unscored=True, detect_workers=1,
                        warmup=False)
    with TestClient(create_app(settings)) as c:
        yield c


@pytest.fixture(scope="module")
def files(six: OrganisedScene, tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    d = tmp_path_factory.mktemp("six")
    out = {"cloud": d / "six.npy", "mask": d / "mask.png", "small": d / "small.png", "rows": d / "rows.txt"}
    np.save(out["cloud"], six.cloud.points.reshape(HEIGHT, WIDTH, 3))
    Image.fromarray((six.mask(K) * 255).astype(np.uint8), "L").save(out["mask"])
    Image.fromarray((six.mask(K)[:-1] * 255).astype(np.uint8), "L").save(out["small"])
    out["rows"].write_text(",\n".join(map(str, six.rows(K))))
    return out


def cli(files: dict[str, Path], tmp: Path, *flags: str) -> dict[str, Any]:
    out = tmp / "answer.json"
    rc = main(["detect", str(files["cloud"]), "--viewpoint", *map(str, CAMERA), "--samples", str(SAMPLES),
               "--max-grasps", str(MAX_GRASPS), "--no-classifier", "--out", str(out), *flags])
    assert rc == 0
    answer: dict[str, Any] = json.loads(out.read_text())
    return answer


def http(client: TestClient, six: OrganisedScene, **options: Any) -> dict[str, Any]:
    organised = six.cloud.points.reshape(HEIGHT, WIDTH, 3)  # as the CLI reads the (H, W, 3) .npy: with its grid
    body = build_detect_request(organised, six.cloud.viewpoints, num_samples=SAMPLES, max_grasps=MAX_GRASPS,
                                use_classifier=False, **options)
    r = client.post("/detect", json=body)
    assert r.status_code == 200, r.text
    answer: dict[str, Any] = r.json()
    return answer


def positions(answer: dict[str, Any]) -> np.ndarray:
    return np.array([g["position"] for g in answer["grasps"]])


def test_each_target_flag_gives_the_grasps_of_the_same_http_target(client: TestClient, six: OrganisedScene,
                                                                   files: dict[str, Path], tmp_path: Path) -> None:
    plain = http(client, six)
    centre, rotation, half = six.boxes[K - 1]
    oid = int(np.argmin([np.linalg.norm(np.array(o["centre"][:2]) - centre[:2]) for o in plain["objects"]]))
    expected = http(client, six, target={"indices": six.rows(K)})
    assert len(expected["grasps"]) >= 3 and {g["object"] for g in expected["grasps"]} == {oid}
    quat = rotation_to_quat_xyzw(rotation[None])[0]
    box = [*centre, *quat, *(half + 0.01)]
    for flags in (["--target-mask", str(files["mask"])], ["--target-indices", str(files["rows"])],
                  ["--target-box", *map(str, box)], ["--target-object", str(oid)]):
        got = cli(files, tmp_path, *flags)
        assert np.allclose(positions(got), positions(expected), atol=1e-6), flags
    assert np.allclose(positions(http(client, six, target={"box": {"centre": centre, "quat_xyzw": quat,
                                                                   "half_extents": half + 0.01}})),
                       positions(expected), atol=1e-6)


def test_max_per_object_reaches_the_ranking(client: TestClient, six: OrganisedScene, files: dict[str, Path],
                                            tmp_path: Path) -> None:
    got = cli(files, tmp_path, "--max-per-object", "0")
    assert np.allclose(positions(got), positions(http(client, six, max_per_object=0)), atol=1e-6)
    assert not np.allclose(positions(got), positions(http(client, six)), atol=1e-6)  # the default covers more


def test_the_plot_and_the_view_mark_the_target_object(files: dict[str, Path], tmp_path: Path) -> None:
    plot, view = tmp_path / "six.png", tmp_path / "six.html"
    answer = cli(files, tmp_path, "--target-object", "3", "--plot", str(plot), "--view", str(view))
    assert {g["object"] for g in answer["grasps"]} == {3}
    page = view.read_text()
    assert '<li data-object="3" class="picked">' in page and "target: object 3" in page
    assert plot.stat().st_size > 10_000


def test_a_target_that_does_not_fit_names_the_flag(files: dict[str, Path], tmp_path: Path,
                                                   capsys: pytest.CaptureFixture[str]) -> None:
    base = ["detect", str(files["cloud"]), "--samples", "20", "--no-classifier", "--out", str(tmp_path / "x.json")]
    assert main([*base, "--target-mask", str(files["small"])]) == 2
    assert "--target-mask: target.mask" in capsys.readouterr().err
    assert main([*base, "--target-object", "6"]) == 2
    assert "target.object" in capsys.readouterr().err
    with pytest.raises(SystemExit):  # one target at a time
        main([*base, "--target-object", "1", "--target-mask", str(files["mask"])])
