"""Uploaded meshes are checked with bounded memory: declared counts are compared with the bytes that can back
them before anything allocates (the 189-byte PLY declaring 1e9 vertices is a 422 in milliseconds, with no
parser and no process started), the check process runs under an address-space limit, and at most
GRASPD_INSTANCE_CHECK_WORKERS checks run at once with a bounded queue behind them (503 + Retry-After)."""

from __future__ import annotations

import resource
import shutil
import struct
import threading
import time
from collections.abc import Callable
from pathlib import Path

import pytest
from fastapi.testclient import TestClient

from fixtures import write_mesh
from graspd.io.mesh_file import MeshError, MeshLimits, check_declared_counts
from graspd.server.app import create_app
from graspd.server.problems import Problem
from graspd.server.services.instance_jobs import MeshCheckGate, check_mesh
from graspd.server.settings import Settings
from graspd_lab.world.meshes import box_mesh

#: The audit's mesh: an ASCII PLY whose header declares 1e9 vertices over three lines of data.
LYING_PLY = (b"ply\nformat ascii 1.0\nelement vertex 1000000000\nproperty float x\nproperty float y\n"
             b"property float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n"
             b"0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n")


def binary_ply(vertices: int, faces: int, body: bytes) -> bytes:
    head = (f"ply\nformat binary_little_endian 1.0\nelement vertex {vertices}\nproperty float x\nproperty float y\n"
            f"property float z\nelement face {faces}\nproperty list uchar int vertex_indices\nend_header\n")
    return head.encode() + body


@pytest.mark.parametrize(("data", "suffix", "words"), [
    (LYING_PLY, ".ply", "1000000000 vertices"),
    (LYING_PLY.replace(b"1000000000", b"900000"), ".ply", "need at least 5400"),   # under the cap, over the bytes
    (binary_ply(100_000, 1, bytes(40)), ".ply", "need at least 1200001"),           # 12-byte stride
    (binary_ply(3, 2_000_000, bytes(100)), ".ply", "2000000 faces"),
    (LYING_PLY.replace(b"1000000000", b"1e9"), ".ply", "invalid count"),
    (b"ply\nformat ascii 1.0\nelement vertex 3\n" + b"comment " * 10_000, ".ply", "does not end"),
    (bytes(80) + struct.pack("<I", 50_000_000) + bytes(100), ".stl", "needs 2500000084 bytes"),
    (b"v 0 0 0\n" * 10 + b"f 1 2 3\n" * 400_000, ".obj", "400000 faces"),
])
def test_declared_counts_that_bytes_cannot_back_are_refused(data: bytes, suffix: str, words: str) -> None:
    before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    t0 = time.perf_counter()
    with pytest.raises(MeshError) as err:
        check_declared_counts(data, suffix, MeshLimits(max_bytes=16 << 20))
    assert time.perf_counter() - t0 < 0.5
    assert err.value.field == "mesh" and words in err.value.message, err.value.message
    assert resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - before < 100_000  # kB: nothing grew with the claim


def test_honest_meshes_pass_the_count_check(tmp_path: Path) -> None:
    for suffix in (".ply", ".obj", ".stl"):
        path = write_mesh(tmp_path / f"box{suffix}", box_mesh(0.05, 0.08, 0.15))
        check_declared_counts(path.read_bytes(), suffix)


def test_the_check_process_runs_under_its_memory_limit(tmp_path: Path) -> None:
    """A limit below what reading a mesh needs makes the check fail cleanly (422 naming mesh), not the server."""
    path = write_mesh(tmp_path / "box.ply", box_mesh(0.05, 0.08, 0.15))
    hand: dict[str, float] = {}
    check_mesh(path, None, hand, 1 << 20, timeout_s=60, memory_mb=2048)  # the default limit: a good mesh passes
    with pytest.raises(Problem) as err:
        check_mesh(path, None, hand, 1 << 20, timeout_s=60, memory_mb=200)
    assert (err.value.status, err.value.field) == (422, "mesh") and "200 MiB" in err.value.message


def test_busy_checks_queue_then_answer_503_with_retry_after() -> None:
    gate = MeshCheckGate(workers=1, queue=1, retry_after_s=3)
    inside, release = threading.Event(), threading.Event()
    waited: list[str] = []

    def hold() -> None:
        with gate.slot(5):
            inside.set()
            release.wait(5)

    def wait_then_run() -> None:
        with gate.slot(5):
            waited.append("ran")

    first = threading.Thread(target=hold)
    first.start()
    assert inside.wait(5)
    second = threading.Thread(target=wait_then_run)
    second.start()
    deadline = time.monotonic() + 5
    while gate.waiting < 1 and time.monotonic() < deadline:
        time.sleep(0.01)
    with pytest.raises(Problem) as err:  # one running, one waiting: the third is turned away at once
        with gate.slot(5):
            pass
    assert err.value.status == 503 and err.value.retry_after == 3
    other = MeshCheckGate(workers=1, queue=4, retry_after_s=1)
    with other.slot(1), pytest.raises(Problem) as late, other.slot(0.05):  # a queue place, but no worker in time
        pass
    assert late.value.status == 503 and "within 0.05 s" in late.value.message
    release.set()
    first.join(5)
    second.join(5)
    assert waited == ["ran"] and gate.running == 0 and gate.waiting == 0


def test_the_lying_ply_upload_is_refused_fast_without_a_check_process(
        make_settings: Callable[..., Settings], tmp_path: Path, models_and_default: tuple[Path, str]) -> None:
    src, name = models_and_default
    folder = tmp_path / "models"
    folder.mkdir()
    for suffix in (".onnx", ".json"):
        shutil.copy(src / f"{name}{suffix}", folder / f"{name}{suffix}")
    settings = make_settings(models_dir=folder, instance_check_workers=1, instance_check_queue=0)
    with TestClient(create_app(settings)) as client:
        gate = client.app.state.service.jobs.checks  # type: ignore[attr-defined]
        t0 = time.perf_counter()
        reply = client.post("/models", files={"mesh": ("lie.ply", LYING_PLY)}, data={"name": "lie"})
        elapsed = time.perf_counter() - t0
        assert reply.status_code == 422 and reply.json()["field"] == "mesh", reply.text
        assert "1000000000 vertices" in reply.json()["error"]
        assert elapsed < 5.0
        assert gate.running == 0 and gate.waiting == 0
        with gate.slot(1):  # every worker busy and no queue: the next honest upload is told to come back
            box = write_mesh(tmp_path / "box.ply", box_mesh(0.05, 0.08, 0.15))
            busy = client.post("/models", files={"mesh": ("box.ply", box.read_bytes())}, data={"name": "box"})
        assert busy.status_code == 503 and int(busy.headers["Retry-After"]) >= 1, busy.text
    assert not list((folder / ".work").glob("*/mesh-*")), "refused meshes are not kept"
