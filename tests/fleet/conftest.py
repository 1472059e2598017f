"""Fleet test set-up: bench/fleet.py's machinery (graspd servers behind HAProxy on loopback, the load driver, the
kill), skipped with its reason where the haproxy binary is missing; the real table_mug request; and the
throwaway PostgreSQL server of tests/templates/test_library_postgres.py for the shared template library."""

from __future__ import annotations

from pathlib import Path
from types import ModuleType

import pytest

from repo_module import load_module

REPO = Path(__file__).resolve().parents[2]


def _load(path: Path, name: str) -> ModuleType:
    """A module of this repository by file, registered (dataclasses look their module up in sys.modules)."""
    return load_module(path, name, register=True)


_fleet = _load(REPO / "bench" / "fleet.py", "bench_fleet")
# the `postgres` fixture (module scope): initdb/pg_ctl on a free port, password auth, a database "graspd"
_pg = _load(REPO / "tests" / "templates" / "test_library_postgres.py", "library_postgres")
postgres = _pg.postgres


@pytest.fixture(scope="session")
def fleet() -> ModuleType:
    """bench/fleet.py as a module; skips when haproxy is not installed."""
    if _fleet.haproxy_binary() is None:
        pytest.skip("haproxy is not installed: apt-get install haproxy (scripts/setup.sh installs it)")
    return _fleet


@pytest.fixture(scope="module")
def library_url(postgres: tuple[str, int]) -> str:
    """The SQLAlchemy URL of the throwaway server's database "graspd" (a fleet's shared template library)."""
    return str(_pg._url(*postgres))


@pytest.fixture(scope="session")
def mug_1mb(fleet: ModuleType, real_data: Path) -> bytes:
    """POST /detect of table_mug thinned to 66,000 points (1.06 MB JSON: a typical 66k-point cloud), 30 samples
    (~0.1 s of detection: many requests in a few seconds)."""
    payload, _ = fleet.mug_request(66_000, num_samples=30)
    assert 1_000_000 < len(payload) < 1_100_000
    return bytes(payload)
