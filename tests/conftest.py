"""Shared test setup: paths to the real clouds beside the repository; small rendered scenes of a 5 x 10 x 8 cm
box on a table seen by one camera from above and aside (grasp templates, the service's template endpoints),
ray cast in numpy (box_scene), so the service's tests need no lab."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import pytest

from box_scene import pose_from, render_boxes, rot_z, table_box
from error_text import leaks
from graspd.core.cloud import ViewpointCloud

REPO = Path(__file__).resolve().parents[1]
REAL_DATA = REPO.parent / "shared" / "data" / "real"


@pytest.fixture(scope="session")
def real_data() -> Path:
    if not (REAL_DATA / "table_mug.pcd").exists():
        pytest.fail(f"the real clouds are expected in {REAL_DATA} (../shared beside the repository)")
    return REAL_DATA


@pytest.fixture(autouse=True)
def error_bodies_give_nothing_away(monkeypatch: pytest.MonkeyPatch) -> Iterator[None]:
    """Every 4xx/5xx body an httpx client (the FastAPI test client included) receives in a test is checked for
    object reprs, tracebacks and machine paths (error_text.LEAKS); the test that provoked one fails."""
    found: list[str] = []
    send = httpx.Client.send

    def checked_send(self: httpx.Client, request: httpx.Request, *args: Any, **kwargs: Any) -> httpx.Response:
        response = send(self, request, *args, **kwargs)
        if response.status_code >= 400 and not kwargs.get("stream"):
            found.extend(f"{request.method} {request.url.path} -> {response.status_code}: {leak}"
                         for leak in leaks(response.text))
        return response

    monkeypatch.setattr(httpx.Client, "send", checked_send)
    yield
    assert not found, f"error bodies give the server's inside away: {found}"


CAMERA = np.array([[0.5, 0.1, 0.5]])
BOX = (0.05, 0.10, 0.08)


def _render(pose: np.ndarray, extents: tuple[float, float, float] = BOX, cameras: np.ndarray = CAMERA,
            noise: float = 0.0, seed: int = 0) -> ViewpointCloud:
    return render_boxes([table_box(), (extents, pose)], cameras, (0.0, 0.0, 0.04), width=320, height=240,
                        noise=noise, seed=seed)


@pytest.fixture(scope="session")
def render_box() -> Callable[..., ViewpointCloud]:
    """render_box(pose 4x4, extents=BOX, cameras=CAMERA, noise=0, seed=0) -> the cloud of a box on a table."""
    return _render


@pytest.fixture(scope="session")
def box_pose() -> Callable[..., np.ndarray]:
    """box_pose(yaw=0.3, xy=(0.02, 0.01), extents=BOX): a box standing on the table."""

    def make(yaw: float = 0.3, xy: tuple[float, float] = (0.02, 0.01),
             extents: tuple[float, float, float] = BOX) -> np.ndarray:
        return pose_from(rot_z(yaw), (xy[0], xy[1], extents[2] / 2))

    return make
