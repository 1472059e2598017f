"""Load a module of this repository by its file: bench/, docs/hooks/ and the test folders are not packages.

Importable as `repo_module` (pyproject.toml: [tool.pytest.ini_options] pythonpath = ["tests"])."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path
from types import ModuleType

REPO = Path(__file__).resolve().parents[1]
BENCH = REPO / "bench"


def load_module(path: Path, name: str, register: bool = False) -> ModuleType:
    """The module at path, executed afresh under name; register: also put it in sys.modules (dataclasses look
    their module up there)."""
    spec = importlib.util.spec_from_file_location(name, path)
    assert spec is not None and spec.loader is not None, path
    module = importlib.util.module_from_spec(spec)
    if register:
        sys.modules[name] = module
    spec.loader.exec_module(module)
    return module


def load_bench(script: str, name: str | None = None) -> ModuleType:
    """bench/<script>.py as a module (name: bench_<script> unless given)."""
    return load_module(BENCH / f"{script}.py", name or f"bench_{script}")
