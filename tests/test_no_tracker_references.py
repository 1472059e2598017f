"""Code explains itself: no module of the service, the client or the lab names a tracker item ("issue 23") or a
design document the repository does not hold (DESIGN.md lives beside the project, not in it)."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("service/graspd", "client/graspd_client", "lab/graspd_lab")
PATTERN = re.compile(r"\b[Ii]ssues? \d+|\bDESIGN\.md\b")


def test_no_module_names_a_tracker_item_or_a_document_outside_the_repo() -> None:
    found = [f"{path.relative_to(ROOT)}:{n}: {line.strip()}"
             for package in PACKAGES for path in sorted((ROOT / package).rglob("*.py"))
             for n, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1) if PATTERN.search(line)]
    assert not found, "\n".join(found)
