"""Importing the server loads none of the heavy optional stacks: torch (training) and pybullet (the sim
benchmark) are extras the service image does without; nor does reading cloud files load open3d, which
the server distribution no longer depends on."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]

HEAVY = ("torch", "pybullet", "graspd_lab")  # graspd_lab: any module of the lab loads its package

PROBE = (
    "import sys, graspd.server.app, graspd.server.zenoh.node, graspd.server.cli; "
    f"print(','.join(m for m in {HEAVY!r} if m in sys.modules))"
)


def test_server_import_loads_no_torch_pybullet_or_lab_module() -> None:
    """A fresh interpreter (nothing imported by other tests) imports the app, the Zenoh node and the serve CLI;
    none of HEAVY is in sys.modules afterwards."""
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(REPO / "service"), str(REPO / "client"), env.get("PYTHONPATH", "")])
    out = subprocess.run([sys.executable, "-c", PROBE], capture_output=True, text=True, env=env, timeout=120,
                         cwd=REPO, check=True)
    loaded = [m for m in out.stdout.strip().split(",") if m]
    assert loaded == [], f"importing graspd.server loaded {loaded}"


# ---- no open3d in the server: cloud files are read with numpy ---------------------------------------
WITHOUT = (*HEAVY, "open3d")

READ_PROBE = """
import sys
import numpy as np
import graspd.server.app
from graspd.io.cloud_files import read_input
from graspd.server.uploads import upload_request
folder, real = sys.argv[1], sys.argv[2]
pts = np.random.default_rng(0).normal(size=(50, 3)).astype("<f4")
head = ("# .PCD v0.7\\nVERSION 0.7\\nFIELDS x y z\\nSIZE 4 4 4\\nTYPE F F F\\nCOUNT 1 1 1\\nWIDTH 50\\nHEIGHT 1\\n"
        "POINTS 50\\n")
ply = "ply\\nformat {} 1.0\\nelement vertex 50\\nproperty float x\\nproperty float y\\nproperty float z\\nend_header\\n"
text = "".join(f"{x!r} {y!r} {z!r}\\n" for x, y, z in pts.astype(float).tolist())
files = {"b.pcd": (head + "DATA binary\\n").encode() + pts.tobytes(),
         "a.pcd": (head + "DATA ascii\\n" + text).encode(),
         "b.ply": ply.format("binary_little_endian").encode() + pts.tobytes(),
         "a.ply": (ply.format("ascii") + text).encode()}
for name, data in files.items():
    open(f"{folder}/{name}", "wb").write(data)
    assert np.array_equal(read_input(f"{folder}/{name}").cloud.points, pts), name
    upload_request(data, name[2:], {}, [])
assert len(read_input(real).cloud) > 0
try:
    upload_request(b"ply\\nformat ascii 1.0\\nelement vertex 2\\nproperty float x\\nend_header\\n", "ply", {}, [])
except Exception as exc:  # refused: a 422 naming the points
    assert getattr(exc, "status", None) == 422, exc
else:
    raise AssertionError("a PLY without y, z was read")
print(",".join(m for m in sys.argv[3].split(",") if m in sys.modules))
"""


def test_reading_cloud_files_loads_no_open3d_torch_or_pybullet(tmp_path: Path, real_data: Path) -> None:
    """A fresh interpreter imports the app, then reads PCD (ascii, binary) and PLY (ascii, binary) files as the CLI
    does (read_input) and as POST /detect does (upload_request), the real Kinect cloud and a refused file among
    them: none of WITHOUT (open3d, torch, pybullet, the lab) is in sys.modules afterwards."""
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(REPO / "service"), str(REPO / "client"), env.get("PYTHONPATH", "")])
    out = subprocess.run([sys.executable, "-c", READ_PROBE, str(tmp_path), str(real_data / "table_mug.pcd"),
                          ",".join(WITHOUT)],
                         capture_output=True, text=True, env=env, timeout=120, cwd=REPO)
    assert out.returncode == 0, out.stderr
    loaded = [m for m in out.stdout.strip().split(",") if m]
    assert loaded == [], f"reading cloud files loaded {loaded}"


def test_the_server_distribution_depends_on_no_heavy_stack() -> None:
    """pyproject.toml's own dependencies (what `pip install graspd` and the Docker image get) list no open3d,
    torch, pybullet or Ray: the lab brings those."""
    import tomllib  # noqa: PLC0415

    project = tomllib.loads((REPO / "pyproject.toml").read_text())["project"]
    names = [re.split(r"[\s<>=!~\[;]", d, maxsplit=1)[0].lower() for d in project["dependencies"]]
    assert not {"open3d", "torch", "pybullet", "ray", "graspd-lab"} & set(names), names
