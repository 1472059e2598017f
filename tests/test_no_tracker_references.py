"""Code and records explain themselves: no module of the service, the client or the lab, no benchmark, example,
script or test, no model plan or model page and no committed benchmark record names a tracker item ("issue 23") or
a design document the repository does not hold (DESIGN.md lives beside the project, not in it).  A reader of the
code, of bench/ or of the documentation site (which shows bench/results/ and models/ as committed) has no tracker:
such a reference tells them nothing, so each says what the thing is instead."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PATTERN = re.compile(r"\b[Ii]ssues? \d+|\bDESIGN\.md\b")
#: (folder, file patterns): every file under the folder whose name matches one of the patterns (rglob).
CHECKED = (
    ("service/graspd", ("*.py",)),
    ("client/graspd_client", ("*.py",)),
    ("lab/graspd_lab", ("*.py",)),
    ("examples", ("*",)),
    ("scripts", ("*",)),
    ("models", ("*.json", "*.md")),
    ("tests", ("*.py", "*.md", "*.json", "*.yaml", "*.txt")),
)
#: (folder, file patterns) checked in that folder only, not below it.
CHECKED_FLAT = (
    ("bench", ("*.py",)),
    ("bench/results", ("*.md",)),
)
#: Pictures and data are not read.
NOT_TEXT = {".png", ".jpg", ".jpeg", ".svg", ".pcd", ".ply", ".npy", ".npz", ".onnx", ".pt", ".pyc", ".mcap"}
#: This file must hold the pattern.
EXCLUDED = (Path(__file__).resolve(),)


def checked_files() -> list[Path]:
    found = {path for folder, patterns in CHECKED for pattern in patterns for path in (ROOT / folder).rglob(pattern)}
    found |= {path for folder, patterns in CHECKED_FLAT for pattern in patterns
              for path in (ROOT / folder).glob(pattern)}
    return sorted(path for path in found if path.is_file() and path.suffix not in NOT_TEXT
                  and "__pycache__" not in path.parts
                  and not any(path == excluded or excluded in path.parents for excluded in EXCLUDED))


def test_the_check_sees_the_files_it_names() -> None:
    files = {path.relative_to(ROOT).as_posix() for path in checked_files()}
    for expected in ("service/graspd/server/app.py", "bench/clutter.py", "bench/results/hostile.md",
                     "models/README.md", "models/plan-scenes.json", "examples/fleet/haproxy.cfg", "scripts/setup.sh",
                     "tests/fleet/test_fleet.py"):
        assert expected in files
    assert "tests/test_no_tracker_references.py" not in files
    assert "tests/server/test_detect_http.py" in files


def test_nothing_names_a_tracker_item_or_a_document_outside_the_repo() -> None:
    found = [f"{path.relative_to(ROOT)}:{n}: {line.strip()}" for path in checked_files()
             for n, line in enumerate(path.read_text(encoding="utf-8", errors="replace").splitlines(), 1)
             if PATTERN.search(line)]
    assert not found, "\n".join(found)
