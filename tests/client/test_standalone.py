"""graspd-client works with only numpy and httpx: no graspd server package on the path."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]

SCRIPT = r"""
import sys
import numpy as np
import graspd_client
from graspd_client import GraspClient, Grasps, build_detect_request, decode_array
from graspd_client import build_demonstration_request, build_feedback_request
body = build_detect_request(np.zeros((5, 3), np.float32), [[0, 0, 1]], num_samples=10, hand="panda")
assert build_detect_request(np.zeros((5, 3)), method="templates")["method"] == "templates"
assert build_demonstration_request(np.zeros((5, 3)), np.eye(4), label="a")["hand_pose"][3] == [0, 0, 0, 1]
assert build_feedback_request("a.0", False) == {"grasp_id": "a.0", "success": False}
pts = decode_array(body["cloud"]["points"], "cloud.points", shape=(None, 3))
assert pts.shape == (5, 3)
response = {"grasps": [{"id": "a", "position": [0, 0, 0], "approach": [1, 0, 0], "binormal": [0, 1, 0],
            "axis": [0, 0, 1], "width": 0.03, "score": None, "sample": [0, 0, 0],
            "pose": [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]], "quat_xyzw": [0, 0, 0, 1]}],
            "model": None, "scored": False, "timings": {"total": 0.1}}
g = Grasps.from_response(response)
assert g.poses.shape == (1, 4, 4) and np.isnan(g.scores[0]) and g.ids == ["a"]
c = GraspClient("http://127.0.0.1:9")
assert callable(c.add_demonstration) and callable(c.feedback) and callable(c.library)
c.close()
heavy = [m for m in ("graspd", "open3d", "torch", "onnxruntime", "scipy", "fastapi", "pydantic")
         if m in sys.modules]
assert not heavy, heavy
print("ok")
"""


def test_client_imports_without_server_package() -> None:
    env = {"PYTHONPATH": str(ROOT / "client"), "PATH": "/usr/bin:/bin"}
    code = f"import sys; sys.path.insert(0, {str(ROOT / 'client')!r})\n" + SCRIPT
    out = subprocess.run([sys.executable, "-I", "-c", code], capture_output=True, text=True, env=env, cwd="/",
                         timeout=60)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "ok"
    assert "graspd_client" in out.stdout or out.stdout.strip() == "ok"


BLOCK_SERVER = r"""
import importlib.abc, sys
class NoServer(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path=None, target=None):
        if name == "graspd" or name.startswith("graspd."):
            raise ImportError("the graspd server package is absent in this environment")
        return None
sys.meta_path.insert(0, NoServer())
"""


def test_client_works_when_the_server_package_cannot_be_imported() -> None:
    # CI installs both distributions in one venv; refusing every graspd import proves the client needs none.
    code = BLOCK_SERVER + f"sys.path.insert(0, {str(ROOT / 'client')!r})\n" + SCRIPT
    out = subprocess.run([sys.executable, "-I", "-c", code], capture_output=True, text=True, cwd="/", timeout=60)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "ok"
