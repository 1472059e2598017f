"""A real graspd server on a loopback port for the client tests, and the krylon can cloud."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from fixtures import KRYLON_VIEWPOINT
from graspd.core.cloud import ViewpointCloud
from graspd.io.cloud_files import read_cloud
from graspd.server.runner import free_port, serve_in_thread
from graspd.server.settings import Settings


@pytest.fixture(scope="module")
def krylon(real_data: Path) -> ViewpointCloud:
    return read_cloud(real_data / "krylon.pcd", viewpoints=np.array([KRYLON_VIEWPOINT], np.float32))


@pytest.fixture(scope="module")
def server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[str, str, Settings]]:
    """(http base URL, zenoh endpoint, settings) of a server with one worker and no queue (easy to fill)."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    settings = Settings(port=0, zenoh_enabled=True, zenoh_listen=[endpoint], zenoh_stream=False, deadline_s=300,
                        models_dir=tmp_path_factory.mktemp("no-models"), detect_workers=1, queue_size=0,
                        data_dir=tmp_path_factory.mktemp("data"), allow_unscored=True)
    with serve_in_thread(settings) as url:
        yield url, endpoint, settings
