"""After the warm-up, a robot's first requests compile nothing: with an empty numba cache (a fresh install or
image), the warm-up compiles every kernel that a capture upload (unorganised and organised PCD, as PCL wrote
them) and a JSON request take, so none of them pays seconds of compilation (about 30 s on 2 cores: every kernel
compiled from nothing, in a child process)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]

SCRIPT = r"""
import json, sys
from pathlib import Path
from numba.core import event

compiled = []


class Listener(event.Listener):
    def on_start(self, ev):
        pass

    def on_end(self, ev):
        compiled.append(ev.data["dispatcher"].py_func.__name__)


event.register("numba:compile", Listener())
from fastapi.testclient import TestClient  # noqa: E402
from graspd.server.app import create_app  # noqa: E402
from graspd.server.settings import Settings  # noqa: E402

out = {}
with TestClient(create_app(Settings(zenoh_enabled=False))) as client:
    out["warm-up"] = len(compiled)
    for path in sys.argv[1:]:
        compiled.clear()
        r = client.post("/detect", content=Path(path).read_bytes(), params={"num_samples": "60"},
                        headers={"content-type": "application/octet-stream"})
        out[Path(path).name] = [r.status_code, sorted(set(compiled))]
print(json.dumps(out))
"""


def test_first_uploads_after_the_warm_up_compile_no_kernel(real_data: Path, tmp_path: Path) -> None:
    files = [real_data / name for name in ("table_mug.pcd", "milk_cartoon_all_small_clorox.pcd",
                                           "table_scene_mug_stereo_textured.pcd")]
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path / "numba"),
           "PYTHONPATH": os.pathsep.join(str(ROOT / p) for p in ("service", "client"))}
    run = subprocess.run([sys.executable, "-c", SCRIPT, *map(str, files)], env=env, capture_output=True, text=True,
                         timeout=900, check=False)
    assert run.returncode == 0, run.stderr[-3000:]
    out = json.loads(run.stdout.strip().splitlines()[-1])
    assert out["warm-up"] > 50, out  # an empty cache: the warm-up compiled the kernels
    for path in files:
        status, kernels = out[path.name]
        assert status == 200 and kernels == [], (path.name, kernels)
