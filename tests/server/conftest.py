"""Server test fixtures: the real krylon can cloud (4,467 points), apps with and without Zenoh."""

from __future__ import annotations

import socket
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from fastapi.testclient import TestClient
from scipy.spatial.transform import Rotation

from fixtures import KRYLON_VIEWPOINT
from graspd.core.cloud import ViewpointCloud
from graspd.gpd import classifier
from graspd.io.cloud_files import read_cloud
from graspd.server.app import create_app
from graspd.server.settings import Settings
from graspd_client import build_detect_request


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@pytest.fixture(scope="session")
def krylon_path(real_data: Path) -> Path:
    return real_data / "krylon.pcd"


@pytest.fixture(scope="session")
def krylon(krylon_path: Path) -> ViewpointCloud:
    return read_cloud(krylon_path, viewpoints=np.array([KRYLON_VIEWPOINT], np.float32))


@pytest.fixture
def make_settings(tmp_path: Path) -> Callable[..., Settings]:
    """Settings for a test app: no Zenoh unless asked, an empty models folder (unscored) unless given, the
    template library in the test's temporary folder."""

    def make(**overrides: Any) -> Settings:
        base: dict[str, Any] = {"zenoh_enabled": False, "models_dir": tmp_path / "no-models", "detect_workers": 2,
                                "data_dir": tmp_path / "data",
                                "deadline_s": 300.0,
                                "queue_size": 8, "log_json": True,
                                "allow_unscored": True,  # no models: requests naming none are unscored, not 503
                                "warmup": False}  # test_warm_start.py turns it on where it is the subject
        base.update(overrides)
        return Settings(**base)

    return make


@pytest.fixture(scope="session")
def models_and_default(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, str]:
    """A folder of real models the project trained and the default name: the shipped models/ when they are
    there, else the tiny test model (~1-2 min to make)."""

    shipped = classifier.default_models_dir()
    if classifier.default_model_name() in classifier.available_models(shipped):
        return shipped, classifier.default_model_name()
    from graspd_lab.training.plans import train_tiny_model  # noqa: PLC0415

    return train_tiny_model(tmp_path_factory.mktemp("tiny-model"), seed=0).parent, "tiny15"


@pytest.fixture
def scored_client(make_settings: Callable[..., Settings], models_and_default: tuple[Path, str]
                  ) -> Iterator[TestClient]:
    """A test app with real trained models (scores grasps)."""
    with TestClient(create_app(make_settings(models_dir=models_and_default[0]))) as c:
        yield c


@pytest.fixture
def client(make_settings: Callable[..., Settings]) -> Iterator[TestClient]:
    with TestClient(create_app(make_settings())) as c:
        yield c


def _small_body(cloud: ViewpointCloud, **extra: Any) -> dict[str, Any]:
    options = {"num_samples": 60, **extra}
    return build_detect_request(cloud.points, cloud.viewpoints, **options)


@pytest.fixture
def small_body() -> Callable[..., dict[str, Any]]:
    """A detect request for a cloud with 60 samples (fast), options as build_detect_request takes them."""
    return _small_body


@pytest.fixture
def body(krylon: ViewpointCloud) -> dict[str, Any]:
    return _small_body(krylon)


@pytest.fixture
def check_convention() -> Callable[[list[dict[str, Any]]], None]:
    return _assert_grasp_convention


def _assert_grasp_convention(grasps: list[dict[str, Any]]) -> None:
    """Every grasp: orthonormal right-handed [approach, binormal, axis] matching pose and quaternion."""

    for g in grasps:
        r = np.array([g["approach"], g["binormal"], g["axis"]]).T
        assert np.allclose(r.T @ r, np.eye(3), atol=1e-6)
        assert np.allclose(np.cross(g["approach"], g["binormal"]), g["axis"], atol=1e-6)
        pose = np.array(g["pose"])
        assert np.allclose(pose[:3, :3], r) and np.allclose(pose[:3, 3], g["position"])
        assert np.allclose(pose[3], [0, 0, 0, 1])
        assert np.allclose(Rotation.from_quat(g["quat_xyzw"]).as_matrix(), r, atol=1e-6)
