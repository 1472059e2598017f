"""bench/walls.py matches each wall box found to the container side it stands on (in the container's frame, turned
by its yaw) and counts the sides missed and the walls that are no side."""

from __future__ import annotations

import numpy as np

from graspd_lab.sim.containers import ContainerSpec
from repo_module import load_bench

TRAY = ContainerSpec(style="tray", inner_x=0.30, inner_y=0.24, wall_height=0.05, wall_thickness=0.01,
                     floor_height=0.0, yaw=np.pi / 2, walls=("-x", "+x", "-y", "+y"), ceiling_height=0.0)


def test_a_wall_box_on_a_side_is_that_side_and_one_inside_is_none() -> None:
    bench = load_bench("walls")
    # turned a quarter: the container's +x side (x = 0.155 in its frame) lies at world y = 0.155
    assert bench.side_of(TRAY, TRAY.to_world(np.array([[0.155, 0.02, 0.03]]))[0]) == "+x"
    assert bench.side_of(TRAY, TRAY.to_world(np.array([[-0.01, -0.125, 0.03]]))[0]) == "-y"
    assert bench.side_of(TRAY, TRAY.to_world(np.array([[0.09, 0.0, 0.03]]))[0]) is None  # objects' faces inside
    assert bench.side_of(TRAY, TRAY.to_world(np.array([[0.155, 0.30, 0.03]]))[0]) is None  # beyond the side's end


def test_the_report_counts_missed_sides_and_walls_that_are_no_side() -> None:
    bench = load_bench("walls")
    rows = [{"seed": 0, "style": "tray", "sides": ["-x", "+x", "-y", "+y"], "found": ["-x", "+x", "-y"],
             "not_sides": [[0.09, 0.0, 0.03]]},
            {"seed": 1, "style": "tray", "sides": ["-x", "+x", "-y", "+y"], "found": ["-x", "+x", "-y", "+y"],
             "not_sides": []}]
    md = bench.report(rows, {"command": "c", "commit": "x", "styles": ["tray"], "split": "training",
                             "object_set": "household-training", "seeds": "0-1"})
    assert "| tray | 2 | 8 | 7 | 1 | 1 | 1 | 1 |" in md
    assert "| tray | 0 | +y | [[0.09, 0.0, 0.03]] |" in md and "| tray | 1 |" not in md


def test_a_shelf_open_front_is_no_wall_and_its_three_sides_are() -> None:
    """The training shelf of seed 16 (a floor slab, a ceiling 35 cm up), as its benchmark round first sees it: the
    sides' front edges and the floor's lie in one plane across the open front, which the cameras see the shelf's
    inside through; the front is no wall, and the back and both sides are found."""
    bench = load_bench("walls")
    scene = bench.scene_walls("shelf", "training", "household-training", 16)
    assert scene["found"] == ["+x", "+y", "-y"]
    assert scene["not_sides"] == []


def test_a_tray_side_that_objects_rise_above_is_not_seen_through() -> None:
    """The training tray of seed 102, as its benchmark round first sees it: objects standing against its +x side rise
    above it, and the cameras see the table beyond over the side's own top; lines of sight there pass over the side,
    not through it, so all four sides are walls and no object's face is."""
    bench = load_bench("walls")
    scene = bench.scene_walls("tray", "training", "household-training", 102)
    assert scene["found"] == ["+x", "+y", "-x", "-y"]
    assert scene["not_sides"] == []


def test_a_shelf_whose_back_wall_holds_more_points_than_the_table_stands_on_the_table() -> None:
    """The training shelf of seed 3 with no gravity in the request: its back wall, seen head-on, holds more points
    than the table around the shelf, but the table, the shelf's floor and the objects' tops face up; up is the
    table's normal, and the back and both sides are the walls found."""
    bench = load_bench("walls")
    scene = bench.scene_walls("shelf", "training", "household-training", 3)
    assert scene["found"] == ["+x", "+y", "-y"]
    assert scene["not_sides"] == []


def test_a_deep_bin_whose_walls_face_the_cameras_more_than_its_floor_stands_on_the_table() -> None:
    """The training deep bin of seed 118 with no gravity in the request: the near wall's outside and the far wall's
    inside both face the cameras, more points than the floor and the table around the bin, but they span far less;
    up stays the table's normal and all four sides are found."""
    bench = load_bench("walls")
    scene = bench.scene_walls("deep_bin", "training", "household-training", 118)
    assert scene["found"] == ["+x", "+y", "-x", "-y"]
    assert scene["not_sides"] == []
