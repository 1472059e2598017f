"""The container image built from the Dockerfile and run, with podman (scripts/image.sh: it installs podman, runc
and debootstrap when missing and makes debian:bookworm-slim with debootstrap when no registry can be reached).
The container, on the host's network with a free port for HTTP and for Zenoh, becomes ready with numba's machine
code from the image (nothing compiled at start), passes its HEALTHCHECK, answers table_mug with grasps on the
cloud, serves the viewer page from its package data, runs as uid 10001, holds no lab, pip or compiler, and stops
gracefully on `podman stop`.

Needs root (podman here runs rootful, apt installs it); minutes: a build from scratch takes about 2.5 min on two
cores, a cached one under a minute.  tests/server/test_container_install.py replays the same pip steps without a
container engine."""

from __future__ import annotations

import json
import os
import shutil
import socket
import subprocess
import time
from collections.abc import Iterator
from pathlib import Path

import httpx
import numpy as np
import pytest

from graspd.io.cloud_files import read_input

ROOT = Path(__file__).resolve().parents[2]
NUMBA_CACHE = "/home/graspd/.cache/graspd/numba"  # the graspd user's, filled at build time

pytestmark = pytest.mark.slow


def podman(*args: str, check: bool = True, timeout: float = 120) -> subprocess.CompletedProcess[str]:
    """Run podman with runc (crun refuses these machines' cgroup v1 layout) where runc is installed."""
    runtime = ["--runtime", "runc"] if shutil.which("runc") else []
    return subprocess.run(["podman", *runtime, *args], capture_output=True, text=True, check=check, timeout=timeout)


def free_port() -> int:
    """A TCP port nothing on the host listens on now (the container shares the host's network)."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@pytest.fixture(scope="module")
def image() -> Iterator[str]:
    """The image of this checkout, built by scripts/image.sh (as `make image` does) and removed afterwards."""
    if os.geteuid() != 0:
        pytest.skip("needs root: podman runs rootful here, and apt-get installs it when missing")
    if shutil.which("podman") is None and shutil.which("apt-get") is None:
        pytest.skip("podman is not installed and there is no apt-get to install it")
    tag = f"localhost/graspd-test:{os.getpid()}"
    before = dangling()  # untagged images another build left: not this test's to remove
    started = time.monotonic()
    build = subprocess.run(["bash", str(ROOT / "scripts" / "image.sh"), tag], capture_output=True, text=True,
                           timeout=1800)
    assert build.returncode == 0, build.stdout[-4000:] + build.stderr[-4000:]
    print(f"image built in {time.monotonic() - started:.0f} s, "
          f"{int(podman('image', 'inspect', tag, '--format', '{{.Size}}').stdout)} bytes")
    try:
        yield tag
    finally:  # the image, and the build's first stage (dangling images made since this build began: no other's)
        podman("rmi", "-f", tag, check=False)
        ours = sorted(dangling() - before)
        if ours:
            podman("rmi", "-f", *ours, check=False, timeout=600)


def dangling() -> set[str]:
    """The ids of podman's untagged images (a build's intermediate stages); none before podman is installed."""
    if shutil.which("podman") is None:
        return set()
    listed = podman("images", "--filter", "dangling=true", "--format", "{{.ID}}", check=False)
    return {line.strip() for line in listed.stdout.splitlines() if line.strip()}


def wait_ready(name: str, port: int, timeout: float = 240) -> None:
    """Until GET /readyz answers 200, failing with the container's log if it exits or the time runs out."""
    deadline = time.monotonic() + timeout
    while True:
        try:
            if httpx.get(f"http://127.0.0.1:{port}/readyz", timeout=2).status_code == 200:
                return
        except httpx.TransportError:
            pass
        running = podman("inspect", name, "--format", "{{.State.Running}}").stdout.strip()
        log = podman("logs", name, check=False)
        assert running == "true", log.stdout[-4000:] + log.stderr[-4000:]
        assert time.monotonic() < deadline, "never ready: " + log.stdout[-4000:] + log.stderr[-4000:]
        time.sleep(0.5)


def test_image_serves_table_mug_as_non_root_with_no_lab_and_stops_gracefully(image: str, real_data: Path) -> None:
    name = f"graspd-test-{os.getpid()}"
    port, zenoh = free_port(), free_port()
    index = ["find", NUMBA_CACHE, "-name", "*.nbi", "-printf", "%p %T@\\n"]  # numba's index files, modified when
    baked = podman("run", "--rm", "--entrypoint", index[0], image, *index[1:]).stdout  # a kernel is compiled
    podman("run", "-d", "--name", name, "--network=host", "-e", f"GRASPD_PORT={port}",
           "-e", "GRASPD_HOST=127.0.0.1", "-e", f'GRASPD_ZENOH_LISTEN=["tcp/127.0.0.1:{zenoh}"]', image)
    try:
        wait_ready(name, port)
        # numba's kernels came from the image: the warm-up compiled none (no index file is new or rewritten)
        assert baked.count(".nbi") >= 5, baked
        assert sorted(podman("exec", name, *index).stdout.splitlines()) == sorted(baked.splitlines())
        assert podman("healthcheck", "run", name, check=False).returncode == 0  # the Dockerfile's HEALTHCHECK

        mug = real_data / "table_mug.pcd"
        r = httpx.post(f"http://127.0.0.1:{port}/detect", params={"num_samples": 150}, content=mug.read_bytes(),
                       headers={"Content-Type": "application/octet-stream"}, timeout=120)
        assert r.status_code == 200, r.text
        grasps = r.json()["grasps"]
        assert len(grasps) >= 10, r.json()
        points = read_input(mug).cloud.points
        positions = np.array([g["position"] for g in grasps])
        lo, hi = points.min(axis=0) - 0.05, points.max(axis=0) + 0.05  # on the cloud, not somewhere else
        assert ((positions >= lo) & (positions <= hi)).all(), positions

        viewer = httpx.get(f"http://127.0.0.1:{port}/viewer", timeout=30)  # package data: graspd/viz/static
        assert viewer.status_code == 200 and "<script" in viewer.text and "@@SCRIPT@@" not in viewer.text

        assert podman("exec", name, "id", "-u").stdout.strip() == "10001"
        lab = podman("exec", name, "python", "-c", "import graspd_lab", check=False)
        assert lab.returncode != 0 and "No module named 'graspd_lab'" in lab.stderr
        heavy = podman("exec", name, "python", "-c", "import importlib.util as u; print([m for m in "
                       "('torch', 'pybullet', 'open3d', 'pip', 'setuptools') if u.find_spec(m)])")
        assert heavy.stdout.strip() == "[]"
        tools = podman("exec", name, "sh", "-c", "command -v pip pip3 gcc cc c++ || true")
        assert tools.stdout.strip() == ""
    finally:
        started = time.monotonic()
        podman("stop", "-t", "60", name, check=False, timeout=90)
        stopped_in = time.monotonic() - started
        state = json.loads(podman("inspect", name, "--format", "{{json .State}}", check=False).stdout or "{}")
        log = podman("logs", name, check=False)
        podman("rm", "-f", "-v", name, check=False)
    out = log.stdout + log.stderr
    assert state.get("ExitCode") in (0, 143) and stopped_in < 30, (state, out[-4000:])  # SIGTERM, not SIGKILL
    assert '"msg": "graspd shutting down' in out and "Application shutdown complete" in out
