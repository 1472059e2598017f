"""bench/containers.py: the precision check tells a wall pinch, a grasp in the air and a hand inside a wall
apart, and a tiny run writes the tables, the JSON, the picture and a resumable round log."""

from __future__ import annotations

import json
from pathlib import Path
from types import ModuleType

import numpy as np
import pytest

from graspd.core.grasp import GraspSet
from graspd.core.hand import HandGeometry
from graspd_lab.sim.containers import ContainerSpec
from graspd_lab.sim.world import SimWorld
from repo_module import load_bench


def _bench() -> ModuleType:
    return load_bench("containers")


def _down(x: float, y: float, z: float, yaw: float) -> tuple[np.ndarray, np.ndarray]:
    """A top-down hand (approach -z) with its base at (x, y, z), closing along yaw."""
    a = np.array([0.0, 0.0, -1.0])
    b = np.array([np.cos(yaw), np.sin(yaw), 0.0])
    return np.array([x, y, z]), np.column_stack([a, b, np.cross(a, b)])


def test_check_grasps_tells_walls_air_and_hands_in_walls_apart() -> None:
    bench = _bench()
    hand = HandGeometry()
    spec = ContainerSpec("thin_box", 0.30, 0.24, 0.10, 0.003, 0.01, 0.0)
    with SimWorld.create(has_tray=False, container=spec) as world:
        wall_x = 0.15 + 0.0015  # the +x wall's mid-plane; its top is at 0.11 m
        base = 0.11 + hand.hand_depth - 0.02  # fingertips 2 cm below the rim
        poses = [
            _down(wall_x, 0.0, base, 0.0),  # closes across the wall: pinches the rim
            _down(0.0, 0.0, 0.25, 0.0),  # closes on air above the floor
            _down(wall_x, 0.0, base, np.pi / 2),  # closes along the wall: the fingers stand in it
        ]
        grasps = GraspSet(positions=np.array([p for p, _ in poses]), rotations=np.array([r for _, r in poses]),
                          widths=np.full(3, 0.01), scores=np.array([3.0, 2.0, 1.0]),
                          samples=np.array([p for p, _ in poses]))
        assert bench.check_grasps(world, grasps, hand) == ["environment", "no pinch", "environment"]


def test_tiny_run_writes_tables_json_picture_and_resumes(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    bench = _bench()
    argv = ["--rounds", "1", "--objects", "2", "--styles", "corner", "tray", "--detectors", "baseline",
            "--out", str(tmp_path), "--tag", "t"]
    assert bench.main(argv) == 0
    md = (tmp_path / "containers-t.md").read_text()
    assert "## Headline: held-out styles only (corner)" in md
    assert "## tray (tuned on (training style), held_out ranges)" in md and "| baseline | 1 |" in md
    data = json.loads((tmp_path / "containers-t.json").read_text())
    assert set(data["headline"]) == {"baseline"} and data["headline"]["baseline"]["summary"]["rounds"] == 1
    row = data["settings"]["baseline@corner-held_out"]["rounds"][0]
    assert row["precision"]["container"]["style"] == "corner" and len(row["precision"]["verdicts"]) <= 5
    assert (tmp_path / "containers-t.png").read_bytes()[:4] == b"\x89PNG"
    log = tmp_path / "containers-t.rounds.jsonl"
    assert len(log.read_text().splitlines()) == 2
    capsys.readouterr()
    assert bench.main([*argv, "--no-pictures"]) == 0  # resumes: nothing new is run or recorded
    assert "resuming, 1 of 1 rounds recorded" in capsys.readouterr().out
    assert len(log.read_text().splitlines()) == 2


def test_held_out_styles_have_no_training_ranges() -> None:
    bench = _bench()
    with pytest.raises(SystemExit):
        bench.main(["--split", "training", "--styles", "corner", "--detectors", "baseline"])


def test_a_looked_bench_replays_a_container_style_or_a_clutter_scene() -> None:
    bench = _bench()
    tray = bench.looked_setting("household", "pile-side", "tray", "held_out")
    assert (tray.scene, tray.container, tray.container_split, tray.num_objects, tray.sensing, tray.objects) == (
        "container", "tray", "held_out", 8, "passive", "household")
    assert tray.hand.max_aperture == pytest.approx(0.075)
    pile = bench.looked_setting("household", "pile-side", None, "held_out")
    assert (pile.scene, pile.num_objects, pile.sensing, pile.container) == ("pile", 5, "side", None)
