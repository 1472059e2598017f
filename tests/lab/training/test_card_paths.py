"""Model cards name no directory of the machine that trained them: the shipped cards, plans and evaluations in
models/ hold no absolute path, a card the training writes records paths under the working directory (the
checkout) relative to it and cuts any other to its last part, and the tiny model's card holds none."""

from __future__ import annotations

import json
import re
import subprocess
from pathlib import Path
from typing import Any

from graspd_lab.training.export import write_card

REPO = Path(__file__).resolve().parents[3]
#: An absolute POSIX path: a slash that starts a token, then at least one directory.
ABSOLUTE = re.compile(r"(?<![\w.~/:])/(?:[\w.+\-@%]+/)+[\w.+\-@%]*")
#: A directory of a machine in prose (routes such as /models/{name} are not paths).
MACHINE = re.compile(r"(?<![\w.~/:])/(?:tmp|work|home|root|usr|opt|var|etc|srv|mnt|Users)/[\w.+\-@%/]+")


def strings(value: Any) -> list[str]:
    """Every string in a JSON value, keys included."""
    if isinstance(value, str):
        return [value]
    if isinstance(value, dict):
        return [s for k, v in value.items() for s in [k, *strings(v)]]
    if isinstance(value, list):
        return [s for v in value for s in strings(v)]
    return []


def absolute_paths(card: Any) -> list[str]:
    return [m[0] for s in strings(card) for m in ABSOLUTE.finditer(s)]


def tracked(pattern: str) -> list[Path]:
    out = subprocess.run(["git", "ls-files", pattern], cwd=REPO, capture_output=True, text=True, check=True).stdout
    return [REPO / line for line in out.splitlines()]


def test_no_shipped_card_plan_or_evaluation_names_a_machine_directory() -> None:
    cards = tracked("models/*.json")
    assert len(cards) >= 20 and any(p.parent.name == "comparison" for p in cards)
    for path in cards:
        assert absolute_paths(json.loads(path.read_text())) == [], path.relative_to(REPO)
    texts = tracked("models/*.md")
    assert any(p.parent.name == "evaluation" for p in texts)
    for path in texts:
        assert MACHINE.findall(path.read_text()) == [], path.relative_to(REPO)
    # the checks see a path
    assert absolute_paths({"training": {"config": {"dataset": "/work/data/scenes500"}}}) == ["/work/data/scenes500"]
    assert MACHINE.findall("Dataset: `/home/me/scenes`") == ["/home/me/scenes"]


def test_a_written_card_records_paths_relative_to_the_checkout(tmp_path: Path) -> None:
    root = tmp_path / "checkout"
    card = {"name": "m", "training": {"config": {"dataset": f"{root}/data/generated/gpd15", "seed": 0}},
            "command": f"graspd train --dataset {root}/data/generated/gpd15 --models-dir {root}/models  # model m",
            "source": "/elsewhere/datasets/scenes500", "here": str(root)}
    written = json.loads(write_card(tmp_path / "m.json", card, root=root).read_text())
    assert written["training"]["config"] == {"dataset": "data/generated/gpd15", "seed": 0}
    assert written["command"] == "graspd train --dataset data/generated/gpd15 --models-dir models  # model m"
    assert written["source"] == "scenes500" and written["here"] == "."
    assert absolute_paths(written) == []


def test_the_tiny_model_card_holds_no_absolute_path(tiny_model: Path) -> None:
    card = json.loads(tiny_model.with_suffix(".json").read_text())
    assert card["training"]["config"]["dataset"] and absolute_paths(card) == []
