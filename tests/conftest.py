"""Shared test setup: paths to the real clouds beside the repository."""

from __future__ import annotations

from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
REAL_DATA = REPO.parent / "shared" / "data" / "real"


@pytest.fixture(scope="session")
def real_data() -> Path:
    if not (REAL_DATA / "table_mug.pcd").exists():
        pytest.fail(f"the real clouds are expected in {REAL_DATA} (../shared beside the repository)")
    return REAL_DATA
