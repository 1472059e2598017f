"""open3d without its dash/plotly drawing module until it is used (graspd_lab.open3d_import, installed when the
lab package is imported: the lab's modules import open3d, the server never does)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def _run(code: str) -> str:
    path = os.pathsep.join([str(ROOT / "service"), str(ROOT / "lab"), os.environ.get("PYTHONPATH", "")])
    return subprocess.run([sys.executable, "-c", code], env={**os.environ, "PYTHONPATH": path}, capture_output=True,
                          text=True, check=True, timeout=300).stdout.strip()


def test_the_lab_imports_open3d_without_dash_and_drawing_still_works() -> None:
    out = _run(
        "import sys\n"
        "import graspd_lab\n"
        "import open3d as o3d\n"
        "print('dash' in sys.modules, 'plotly' in sys.modules)\n"
        "pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector([[0, 0, 0], [1, 0, 0], [0, 1, 0.0]]))\n"
        "fig = o3d.visualization.get_plotly_fig([pc])\n"
        "print(type(fig).__name__, 'dash' in sys.modules)\n"
    )
    assert out.splitlines() == ["False False", "Figure True"]


def test_no_stand_in_once_open3d_is_loaded() -> None:
    out = _run("import open3d\nfrom graspd_lab.open3d_import import defer_plotly_drawing\n"
               "print(defer_plotly_drawing())")
    assert out == "False"
