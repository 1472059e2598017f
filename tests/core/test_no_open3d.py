"""Detection and cloud files without open3d: preprocessing is numpy and scipy, and graspd.io reads PCD and PLY
with numpy; open3d belongs to the lab (graspd_lab.open3d_import, tests/lab/test_open3d_import.py)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

SERVICE = Path(__file__).resolve().parents[2] / "service"


def _run(code: str) -> str:
    env = {**os.environ, "PYTHONPATH": f"{SERVICE}{os.pathsep}{os.environ.get('PYTHONPATH', '')}"}
    return subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True,
                          timeout=300).stdout.strip()


def test_the_detector_runs_without_open3d() -> None:
    """Preprocessing (normals, outliers, the support plane) is numpy and scipy: a detection loads no open3d."""
    out = _run(
        "import sys, numpy as np\n"
        "from graspd.core.cloud import ViewpointCloud\n"
        "from graspd.gpd.detector import DetectionParams, GraspDetector\n"
        "rng = np.random.default_rng(0)\n"
        "pts = np.c_[rng.uniform(-0.1, 0.1, (3000, 2)), np.zeros(3000)].astype(np.float32)\n"
        "det = GraspDetector().detect(ViewpointCloud(points=pts, viewpoints=np.array([[0, 0, 0.5]], np.float32)),\n"
        "                             DetectionParams(num_samples=20, exclude_support_plane=True))\n"
        "print(det.num_points > 0, 'open3d' in sys.modules)\n"
    )
    assert out.splitlines() == ["True False"]
