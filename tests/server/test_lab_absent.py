"""A server installed without the lab (pip install graspd: no graspd_lab, torch or onnx) says what to install
when asked to train, and keeps serving: POST /models answers 503 naming graspd-lab, and `graspd train` exits 2
with the same advice.  Run in a child interpreter that does not see the lab, as on such an install."""

from __future__ import annotations

import json
import subprocess
import sys
import sysconfig
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]

#: The child runs with -S: site-packages is on its path (numpy, FastAPI, ...) but its .pth files are not read, so
#: the editable lab (graspd-lab, installed beside the server for the tests) is not there, as on a server-only install.
SITE = Path(sysconfig.get_paths()["purelib"])
LAB_GONE = "import importlib.util, sys\nassert importlib.util.find_spec('graspd_lab') is None\n"

SERVER = LAB_GONE + """
import json, sys
from fastapi.testclient import TestClient
from graspd.server.app import create_app
from graspd.server.settings import Settings
settings = Settings(zenoh_enabled=False, models_dir=sys.argv[1], data_dir=sys.argv[2], allow_unscored=True,
                    warmup=False)
with TestClient(create_app(settings)) as c:
    r = c.post('/models', data={'name': 'mug1'}, files={'mesh': ('mug.obj', b'v 0 0 0\\n', 'text/plain')})
    d = c.post('/detect', json={'cloud': {'points': [[0.0, 0.0, 0.5], [0.01, 0.0, 0.5], [0.0, 0.01, 0.5]]},
                                'num_samples': 3})
    print(json.dumps({'models': [r.status_code, r.json()], 'detect': d.status_code,
                      'lab_loaded': any(m.split('.')[0] == 'graspd_lab' for m in sys.modules)}))
"""


def _child(code: str, *args: str) -> subprocess.CompletedProcess[str]:
    path = f"{ROOT / 'service'}:{ROOT / 'client'}:{SITE}"
    return subprocess.run([sys.executable, "-S", "-c", code, *args], capture_output=True, text=True, timeout=120,
                          cwd=ROOT, env={"PYTHONPATH": path, "PATH": "/usr/bin:/bin"})


def test_post_models_without_the_lab_names_graspd_lab_and_the_server_keeps_serving(tmp_path: Path) -> None:
    run = _child(SERVER, str(tmp_path / "models"), str(tmp_path / "data"))
    assert run.returncode == 0, run.stderr[-2000:]
    out = json.loads(run.stdout.strip().splitlines()[-1])
    status, body = out["models"]
    assert status == 503 and "graspd-lab" in json.dumps(body), body
    assert out["detect"] == 200 and out["lab_loaded"] is False


def test_graspd_train_without_the_lab_exits_2_naming_graspd_lab(tmp_path: Path) -> None:
    code = LAB_GONE + "from graspd.cli.main import main\nraise SystemExit(main(['train', '--help']))\n"
    run = _child(code)
    assert run.returncode == 2, (run.returncode, run.stdout[-500:], run.stderr[-500:])
    assert "graspd-lab" in run.stdout + run.stderr
