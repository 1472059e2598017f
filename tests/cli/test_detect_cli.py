"""The real Kinect clouds go through `graspd detect` and come out as grasps in the documented convention
(docs/robot/answer.md)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np

from graspd.cli.main import main


def _check_grasps(grasps: list[dict]) -> None:
    assert grasps
    for g in grasps[:20]:
        r = np.array(g["pose"])[:3, :3]
        assert np.allclose(r[:, 0], g["approach"]) and np.allclose(r[:, 1], g["binormal"])
        assert np.allclose(np.cross(g["approach"], g["binormal"]), g["axis"], atol=1e-6)
        assert np.allclose(np.array(g["pose"])[:3, 3], g["position"])
        assert 0.0 < g["width"] <= 0.1


def test_table_mug_through_graspd_detect(real_data: Path, tmp_path: Path) -> None:
    out, png = tmp_path / "g.json", tmp_path / "g.png"
    rc = main(["detect", str(real_data / "table_mug.pcd"), "--samples", "150", "--exclude-table",
               "--no-classifier", "--out", str(out), "--plot", str(png)])
    assert rc == 0
    result = json.loads(out.read_text())
    _check_grasps(result["grasps"])
    assert result["scored"] is False and "no classification" in result["note"]
    assert png.stat().st_size > 20_000
    # the mug stands on the table around x = 0.02, z = 0.77 m in the camera frame
    pos = np.array([g["position"] for g in result["grasps"][:10]])
    assert np.median(np.abs(pos[:, 0] - 0.0)) < 0.15


def test_krylon_through_the_installed_entry_point(real_data: Path, tmp_path: Path) -> None:
    out = tmp_path / "k.json"
    proc = subprocess.run(
        [sys.executable, "-m", "graspd.cli", "detect", str(real_data / "krylon.pcd"), "--viewpoint", "0.5", "0", "0.3",
         "--samples", "100", "--hand", "panda", "--no-classifier", "--out", str(out)],
        capture_output=True, text=True, timeout=120,
    )
    assert proc.returncode == 0, proc.stderr
    result = json.loads(out.read_text())
    _check_grasps(result["grasps"])
    assert result["hand"]["hand_outer_diameter"] == 0.10
    widths = np.array([g["width"] for g in result["grasps"]])
    assert np.median(widths) < 0.08  # the can is ~5.6 cm across


def test_bad_arguments_exit_with_a_message(tmp_path: Path, capsys) -> None:
    assert main(["detect", str(tmp_path / "missing.pcd"), "--no-classifier"]) == 2
    assert "missing.pcd" in capsys.readouterr().err
    (tmp_path / "c.npz").write_bytes(b"")
    assert main(["detect", str(tmp_path / "x.pcd"), "--hand", "nonesuch", "--no-classifier"]) == 2
