"""POST /models: an uploaded mesh becomes an instance model in a background job (GET /models shows its
progress), which POST /detect then selects by name; bad uploads are refused naming their field, a name in use
is a 409, a full queue a 503."""

from __future__ import annotations

import json
import re
import shutil
import time
from collections.abc import Callable
from pathlib import Path

import pytest
from fastapi.testclient import TestClient

from fixtures import write_mesh
from graspd.core.cloud import ViewpointCloud
from graspd.gpd.classifier import read_card
from graspd.server.app import create_app
from graspd.server.runner import serve_in_thread
from graspd.server.settings import Settings
from graspd_client import GraspClient
from graspd_client.errors import RequestRejected, ServerBusy
from graspd_lab.world.meshes import box_mesh


@pytest.fixture
def models_folder(tmp_path: Path, models_and_default: tuple[Path, str]) -> Path:
    """A writable models folder holding the default model (the base of instance models when it is generic15)."""
    src, name = models_and_default
    folder = tmp_path / "models"
    folder.mkdir()
    for suffix in (".onnx", ".json"):
        shutil.copy(src / f"{name}{suffix}", folder / f"{name}{suffix}")
    return folder


@pytest.fixture
def box_ply(tmp_path: Path) -> Path:
    return write_mesh(tmp_path / "box.ply", box_mesh(0.05, 0.08, 0.15))


def upload(client: TestClient, mesh: Path | None, filename: str | None = None, **fields: str) -> dict[str, object]:
    files = {"mesh": (filename or mesh.name, mesh.read_bytes())} if mesh is not None else None
    response = client.post("/models", files=files, data=fields or None)  # type: ignore[arg-type]
    body = response.json()
    body["status"] = response.status_code
    return body


def test_bad_uploads_are_refused_naming_the_field(make_settings: Callable[..., Settings], models_folder: Path,
                                                  models_and_default: tuple[Path, str], box_ply: Path,
                                                  tmp_path: Path) -> None:
    mm = write_mesh(tmp_path / "mm.ply", box_mesh(50.0, 80.0, 150.0))
    big = tmp_path / "big.obj"
    big.write_bytes(b"v 0 0 0\n" * 1000)
    settings = make_settings(models_dir=models_folder, instance_max_mesh_bytes=4096)
    with TestClient(create_app(settings)) as c:
        cases = [
            (upload(c, box_ply, name="../up"), 422, "name"),
            (upload(c, box_ply, name="mug\n"), 422, "name"),
            (upload(c, box_ply, name="ok", category="sphere"), 422, "category"),
            (upload(c, box_ply, name="ok", hand="claw"), 422, "hand"),
            (upload(c, box_ply, name="ok", colour="red"), 422, "colour"),
            (upload(c, None, name="ok"), 422, "mesh"),
            (upload(c, box_ply, "box.step", name="ok"), 422, "mesh"),
            (upload(c, mm, name="ok"), 422, "mesh"),
            (upload(c, big, name="ok"), 413, "mesh"),
            (upload(c, box_ply, name=models_and_default[1]), 409, "name"),
        ]
        for body, status, field in cases:
            assert (body["status"], body["field"]) == (status, field), body
        assert "metres" in str(cases[7][0]["error"])
        not_form = c.post("/models", json={"name": "ok"})
        assert not_form.status_code == 415 and not_form.json()["field"] == "body"
        listing = c.get("/models").json()
        assert listing["jobs"] == [] and [m["name"] for m in listing["models"]] == [models_and_default[1]]
    assert not (models_folder / "ok.onnx").exists()
    assert not list((models_folder / ".work").glob("*/mesh-*")), "refused meshes are not kept"
    assert not [p for p in (models_folder / ".work").glob("*") if "\n" in p.name], "no job folder for a bad name"


def test_the_model_listing_names_no_directory_of_any_machine(make_settings: Callable[..., Settings],
                                                             models_folder: Path,
                                                             models_and_default: tuple[Path, str]) -> None:
    """A card written on a build machine (init_from.path, the command's --models-dir) is listed by file name."""
    name = models_and_default[1]
    card_path = models_folder / f"{name}.json"
    card = json.loads(card_path.read_text())
    card["init_from"] = {"init_from": "scene15", "path": "/home/builder/runs/models-out/scene15.pt"}
    card["command"] = "graspd train --models-dir /srv/build/models-out --resume"
    card_path.write_text(json.dumps(card))
    with TestClient(create_app(make_settings(models_dir=models_folder))) as c:
        listing = c.get("/models").text
    assert "/home/" not in listing and "/srv/" not in listing and str(models_folder) not in listing
    listed = json.loads(listing)["models"][0]["card"]
    assert listed["init_from"]["path"] == "scene15.pt" and "--models-dir models-out" in listed["command"]


def test_the_shipped_model_cards_name_no_directory_of_any_machine() -> None:
    for card in (Path(__file__).resolve().parents[2] / "models").glob("*.json"):
        text = card.read_text()
        assert not re.search(r"(?<![\w.~/:])/(?:tmp|work|home|root|srv|data)/", text), card.name


def test_uploads_need_the_token(make_settings: Callable[..., Settings], models_folder: Path,
                                box_ply: Path) -> None:
    with TestClient(create_app(make_settings(models_dir=models_folder, token="s3cret"))) as c:
        body = upload(c, box_ply, name="box_i")
        assert body["status"] == 401
        assert c.get("/models").status_code == 401


def test_an_uploaded_mesh_becomes_a_model_detect_selects_by_name(
        make_settings: Callable[..., Settings], models_folder: Path, models_and_default: tuple[Path, str],
        box_ply: Path, krylon: ViewpointCloud) -> None:
    """Upload -> job (queued/running, progress in GET /models) -> done -> loaded -> /detect model=name, through
    the HTTP client; a second job while one runs finds the queue (0) full, the same name is a 409.  A tiny
    budget: 3 views, 16 exemplars each, 1 epoch."""
    settings = make_settings(models_dir=models_folder, instance_views=3, instance_per_view=16, instance_epochs=1,
                             instance_max_minutes=0.2, instance_queue=0)
    t0 = time.perf_counter()
    with serve_in_thread(settings) as url, GraspClient(url, timeout=120, retries=0) as client:
        job = client.train_instance(box_ply, "box_i")
        assert job["state"] in ("queued", "running") and job["name"] == "box_i"
        assert job["base_model"] == ("generic15" if models_and_default[1] == "generic15" else None)
        with pytest.raises(RequestRejected) as taken:
            client.train_instance(box_ply, "box_i")
        assert (taken.value.status, taken.value.field) == (409, "name")
        with pytest.raises(ServerBusy):
            client.train_instance(box_ply, "box_j")
        done = client.wait_instance(job["id"], timeout=180, poll=0.5)
        assert done["state"] == "done" and done["error"] is None, done
        assert done["views"] == 3 and done["epoch"] == 1 and done["elapsed_s"] > 0
        listing = client.models()
        model = {m["name"]: m for m in listing["models"]}["box_i"]
        compared = model["card"]["instance_comparison"]["models"]
        assert compared["box_i"]["role"] == "instance" and compared["box_i"]["n"] > 0
        assert [j["state"] for j in listing["jobs"]] == ["done"]
        grasps = client.detect(krylon.points, krylon.viewpoints, model="box_i", num_samples=60, max_grasps=5)
        assert grasps.model == "box_i" and len(grasps) > 0
    elapsed = time.perf_counter() - t0
    assert read_card(models_folder / "box_i.json")["instance"]["mesh"].startswith("mesh-")
    print(f"upload -> trained -> detect with the new model: {elapsed:.1f} s")


def test_a_missing_category_model_is_refused_and_a_stopped_job_says_why(
        make_settings: Callable[..., Settings], models_folder: Path, box_ply: Path) -> None:
    """No cylinder15 in the folder: 422 naming category at once.  A job past GRASPD_INSTANCE_TIMEOUT_S is
    stopped and fails saying so; its name is free again."""
    settings = make_settings(models_dir=models_folder, instance_timeout_s=1.0)
    with TestClient(create_app(settings)) as c:
        body = upload(c, box_ply, name="can_i", category="cylinder")
        assert (body["status"], body["field"]) == (422, "category") and "cylinder15" in str(body["error"])
        job = upload(c, box_ply, name="box_i")
        assert job["status"] == 202, job
        end = time.monotonic() + 60
        while (state := c.get("/models").json()["jobs"][0])["state"] not in ("done", "failed"):
            assert time.monotonic() < end, state
            time.sleep(0.2)
        assert state["state"] == "failed" and "time limit" in str(state["error"]), state
        assert not (models_folder / "box_i.onnx").exists()
        again = upload(c, box_ply, name="box_i")
        assert again["status"] == 202, again
