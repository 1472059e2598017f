"""Template test fixtures: library URLs in the test's temporary folder (the box scenes, render_box and
box_pose, are in tests/conftest.py for the service tests too)."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import pytest


@pytest.fixture()
def library_url(tmp_path: Path) -> Callable[[str], str]:
    """library_url(name) -> an SQLite URL in the test's temporary folder."""

    def make(name: str = "lib") -> str:
        return f"sqlite:///{tmp_path}/{name}.db"

    return make
