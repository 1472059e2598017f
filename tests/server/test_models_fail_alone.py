"""Each model loads on its own: a broken .onnx or card is reported by name in /readyz and the
log while the others serve; a missing or broken default model means not ready, and /detect never silently
answers unscored."""

from __future__ import annotations

import logging
import shutil
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
from fastapi.testclient import TestClient

from graspd.gpd import classifier
from graspd.server.app import create_app
from graspd.server.settings import Settings

SHIPPED = classifier.default_models_dir()
DEFAULT = classifier.default_model_name()
needs_models = pytest.mark.skipif(not {DEFAULT, "box15"} <= set(classifier.available_models(SHIPPED)),
                                  reason="the shipped default model and box15 are not in models/")


@pytest.fixture
def models(tmp_path: Path) -> Path:
    """A copy of the shipped models (networks and cards) to break."""
    out = tmp_path / "models"
    out.mkdir()
    for name in (DEFAULT, "box15", "cylinder15"):
        for suffix in (".onnx", ".json"):
            if (SHIPPED / f"{name}{suffix}").is_file():
                shutil.copy(SHIPPED / f"{name}{suffix}", out / f"{name}{suffix}")
    (out / "plan.json").write_text('{"epochs": 3}')  # a JSON file that is not a card: ignored
    return out


def truncate(path: Path) -> None:
    path.write_bytes(path.read_bytes()[: path.stat().st_size // 2])


def corrupt(path: Path) -> None:
    data = bytearray(path.read_bytes())
    data[: 64] = bytes(range(64))  # the protobuf's first fields become nonsense
    path.write_bytes(bytes(data))


BREAKS: list[tuple[str, Callable[[Path], None]]] = [
    ("truncated onnx", lambda m: truncate(m / "box15.onnx")),
    ("empty onnx", lambda m: (m / "box15.onnx").write_bytes(b"")),
    ("corrupt onnx", lambda m: corrupt(m / "box15.onnx")),
    ("card not JSON", lambda m: (m / "box15.json").write_text("{not json")),
    ("card lacks keys", lambda m: (m / "box15.json").write_text('{"name": "box15", "representation": "x"}')),
]


@needs_models
@pytest.mark.parametrize(("name", "brk"), BREAKS, ids=[b[0] for b in BREAKS])
def test_one_broken_model_fails_alone(make_settings: Callable[..., Settings], models: Path, body: dict[str, Any],
                                      caplog: pytest.LogCaptureFixture, name: str,
                                      brk: Callable[[Path], None]) -> None:
    brk(models)
    with caplog.at_level(logging.ERROR, logger="graspd.server"), \
            TestClient(create_app(make_settings(models_dir=models, allow_unscored=False))) as c:
        ready = c.get("/readyz")
        assert ready.status_code == 200, ready.text
        out = ready.json()
        assert out["default_model"] == DEFAULT and "box15" not in out["models"]
        assert "box15" in out["model_errors"] and out["model_errors"]["box15"]
        assert any(getattr(r, "model", None) == "box15" for r in caplog.records if r.levelno == logging.ERROR)
        scored = c.post("/detect", json=body).json()
        assert scored["scored"] is True and scored["model"] == DEFAULT
        r = c.post("/detect", json={**body, "model": "box15"})
        assert r.status_code == 503 and r.json()["field"] == "model" and "failed to load" in r.json()["error"]
        assert c.post("/detect", json={**body, "model": "nope"}).status_code == 422


@needs_models
@pytest.mark.parametrize("how", ["onnx deleted, card kept", "onnx truncated"])
def test_default_model_missing_means_not_ready(make_settings: Callable[..., Settings], models: Path,
                                               body: dict[str, Any], how: str) -> None:
    if how.startswith("onnx deleted"):
        (models / f"{DEFAULT}.onnx").unlink()
    else:
        truncate(models / f"{DEFAULT}.onnx")
    with TestClient(create_app(make_settings(models_dir=models, allow_unscored=True))) as c:  # broken: never allowed
        ready = c.get("/readyz")
        assert ready.status_code == 503
        assert DEFAULT in " ".join(ready.json()["problems"]) and DEFAULT in ready.json()["model_errors"]
        r = c.post("/detect", json=body)
        assert r.status_code == 503 and r.json()["field"] == "model" and DEFAULT in r.json()["error"]
        assert "box15" in ready.json()["models"]  # the others serve when named
        assert c.post("/detect", json={**body, "model": "box15"}).json()["scored"] is True
        plain = c.post("/detect", json={**body, "use_classifier": False})  # unscored only when asked
        assert plain.status_code == 200 and plain.json()["scored"] is False


def test_no_models_folder_is_not_ready_unless_allowed(make_settings: Callable[..., Settings], tmp_path: Path,
                                                      body: dict[str, Any]) -> None:
    with TestClient(create_app(make_settings(models_dir=tmp_path / "none", allow_unscored=False))) as c:
        assert c.get("/readyz").status_code == 503
        r = c.post("/detect", json=body)
        assert r.status_code == 503 and r.json()["field"] == "model"
        assert c.post("/detect", json={**body, "use_classifier": False}).json()["scored"] is False
    with TestClient(create_app(make_settings(models_dir=tmp_path / "none", allow_unscored=True))) as c:
        assert c.get("/readyz").status_code == 200
        assert c.post("/detect", json=body).json()["scored"] is False  # configured: unscored


@needs_models
def test_configured_default_missing_is_named(make_settings: Callable[..., Settings], models: Path) -> None:
    with TestClient(create_app(make_settings(models_dir=models, default_model="lenet15"))) as c:
        ready = c.get("/readyz")
        assert ready.status_code == 503 and "lenet15" in " ".join(ready.json()["problems"])
