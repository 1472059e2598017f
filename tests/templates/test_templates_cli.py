"""`graspd templates ...` end to end on a saved cloud: demonstrate, detect, feedback, library."""

from __future__ import annotations

import argparse
import json

import numpy as np

from fixtures import box_top_grasp
from graspd.cli.templates import register
from graspd.server.settings import Settings

BOX = (0.05, 0.10, 0.08)


def _run(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="graspd")
    register(parser.add_subparsers(dest="command", required=True))
    args = parser.parse_args(argv)
    return int(args.func(args))


def test_cli_round_trip(tmp_path, render_box, box_pose, capsys) -> None:
    pose = box_pose()
    cloud = render_box(pose)
    path = tmp_path / "box.npz"
    np.savez(path, points=cloud.points, viewpoints=cloud.viewpoints, camera_source=cloud.camera_source)
    lib = ["--library", f"sqlite:///{tmp_path}/lib.db"]
    demo = box_top_grasp(pose, BOX)
    assert _run(["templates", "demonstrate", str(path), "--pose", *map(str, demo.ravel()), "--label", "top", *lib]) == 0
    assert json.loads(capsys.readouterr().out) == {"entry_id": 1}
    out = tmp_path / "grasps.json"
    assert _run(["templates", "detect", str(path), "--max-grasps", "3", "--out", str(out), *lib]) == 0
    result = json.loads(out.read_text())
    assert result["method"] == "templates" and result["grasps"][0]["template_entry"] == 1
    assert np.linalg.norm(np.array(result["grasps"][0]["position"]) - demo[:3, 3]) < 0.01
    capsys.readouterr()
    assert _run(["templates", "feedback", result["grasps"][0]["id"], "--failure", *lib]) == 0
    assert json.loads(capsys.readouterr().out)["failure_added"] is True
    assert _run(["templates", "library", *lib]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["num_entries"] == 1 and summary["num_failures"] == 1 and summary["entries"][0]["label"] == "top"
    # bad input: the error names the field, exit status 2
    assert _run(["templates", "demonstrate", str(path), "--pose", *["0"] * 16, *lib]) == 2
    assert "hand_pose" in capsys.readouterr().err
    assert _run(["templates", "feedback", "nope", "--success", *lib]) == 2
    assert "grasp_id" in capsys.readouterr().err


def test_cli_opens_the_servers_library_by_default(tmp_path, monkeypatch, capsys) -> None:
    """No --library: the library the server opens (Settings: <data dir>/templates.db, or the URL setting)."""
    monkeypatch.delenv("GRASPD_TEMPLATE_LIBRARY", raising=False)
    monkeypatch.delenv("GRASPD_TEMPLATE_HAND", raising=False)
    monkeypatch.setenv("GRASPD_DATA_DIR", str(tmp_path / "data"))
    assert Settings().resolved_template_library() == f"sqlite:///{tmp_path / 'data' / 'templates.db'}"
    assert _run(["templates", "library"]) == 0
    assert json.loads(capsys.readouterr().out)["num_entries"] == 0
    assert (tmp_path / "data" / "templates.db").exists()
    monkeypatch.setenv("GRASPD_TEMPLATE_LIBRARY", f"sqlite:///{tmp_path}/other.db")
    assert _run(["templates", "library"]) == 0
    assert (tmp_path / "other.db").exists()
