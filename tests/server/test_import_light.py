"""Importing the server loads none of the heavy optional stacks: torch (training) and pybullet (the sim
benchmark) are extras the service image does without (issue 12)."""

from __future__ import annotations

import os
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
