"""Over HTTP: a kilobyte .npz that would inflate to a gigabyte, a deflate member inflating past its declared
size, and an upload with 1,000 cameras (viewpoint parameters, or a viewpoints member) get a 422 naming the field,
decided before anything large is inflated or built; the next good request is served."""

from __future__ import annotations

import bz2
import io
import struct
import time
import tracemalloc
import zipfile
import zlib
from collections.abc import Callable
from typing import Any

import numpy as np
from fastapi.testclient import TestClient
from httpx import Response

from graspd.core.cloud import ViewpointCloud

OCTET = {"Content-Type": "application/octet-stream"}
MB = 1 << 20


def npy(array: np.ndarray) -> bytes:
    buf = io.BytesIO()
    np.save(buf, array)
    return buf.getvalue()


def one_member_zip(name: str, stream: bytes, method: int, declared: int) -> bytes:
    """A zip of one already compressed member claiming declared bytes uncompressed."""
    fname = f"{name}.npy".encode()
    local = struct.pack("<4sHHHHHIIIHH", b"PK\x03\x04", 20, 0, method, 0, 0, 0, len(stream), declared,
                        len(fname), 0) + fname
    central = struct.pack("<4sHHHHHHIIIHHHHHII", b"PK\x01\x02", 20, 20, 0, method, 0, 0, 0, len(stream),
                          declared, len(fname), 0, 0, 0, 0, 0, 0) + fname
    end = struct.pack("<4sHHHHIIH", b"PK\x05\x06", 0, 0, 1, 1, len(central), len(local) + len(stream), 0)
    return local + stream + central + end


def zeros_after(head: bytes, compressor: Any, mib: int) -> bytes:
    zero = bytes(MB)
    return compressor.compress(head) + b"".join(compressor.compress(zero) for _ in range(mib)) + compressor.flush()


HEAD = npy(np.zeros((1, 3), np.float32))


def measured(call: Callable[[], Response]) -> tuple[Response, float, int]:
    """The response, the seconds it took and the peak of Python/numpy memory (bytes, every thread) meanwhile."""
    tracemalloc.start()
    t0 = time.perf_counter()
    try:
        r = call()
        return r, time.perf_counter() - t0, tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()


def good_upload_is_served(client: TestClient, krylon: ViewpointCloud) -> None:
    vp = ",".join(str(v) for v in krylon.viewpoints[0])
    r = client.post(f"/detect?num_samples=30&viewpoint={vp}", content=npy(krylon.points), headers=OCTET)
    assert r.status_code == 200, r.text[:300]


def test_compression_bombs_in_an_npz_are_422_naming_the_member(client: TestClient, krylon: ViewpointCloud) -> None:
    bzip2 = one_member_zip("points", zeros_after(HEAD, bz2.BZ2Compressor(9), 64), zipfile.ZIP_BZIP2, 4096)
    deflate = one_member_zip("points", zeros_after(HEAD, zlib.compressobj(9, zlib.DEFLATED, -15), 256),
                             zipfile.ZIP_DEFLATED, 4096)
    assert len(bzip2) < 2_000 and len(deflate) < 400_000
    for bomb, words in ((bzip2, "bzip2"), (deflate, "npz: points")):
        r, seconds, peak = measured(lambda b=bomb: client.post("/detect", content=b, headers=OCTET))
        assert r.status_code == 422, r.text
        assert r.json()["field"] == "cloud.points" and words in r.json()["error"], r.text
        assert peak < 20 * MB, peak
        assert seconds < 2.0, seconds
    good_upload_is_served(client, krylon)


def test_a_thousand_cameras_are_422_before_any_array_is_built(client: TestClient, krylon: ViewpointCloud) -> None:
    """20k points with 1,000 viewpoint parameters: refused naming viewpoint, counted before the file is read
    (the nearest-camera table would be 20k x 1000 x 3 float64: 480 MB).  The same cameras as an .npz member:
    refused naming cloud.viewpoints from its header.  1,000 camera_pose parameters: named too."""
    points = np.random.default_rng(0).uniform(-0.1, 0.1, (20_000, 3)).astype(np.float32)
    cams = np.random.default_rng(1).uniform(-1, 1, (1000, 3))
    query = "&".join(f"viewpoint={x:.3f},{y:.3f},{z:.3f}" for x, y, z in cams)
    r, seconds, peak = measured(lambda: client.post(f"/detect?{query}", content=npy(points), headers=OCTET))
    assert r.status_code == 422 and r.json()["field"] == "viewpoint", r.text
    assert "at most 64" in r.json()["error"]
    assert peak < 20 * MB and seconds < 2.0, (peak, seconds)
    poses = "&".join(["camera_pose=0,0,0,0,0,0,1"] * 1000)
    r = client.post(f"/detect?points_frame=robot&{poses}", content=npy(points), headers=OCTET)
    assert r.status_code == 422 and r.json()["field"] == "camera_pose", r.text
    buf = io.BytesIO()
    np.savez_compressed(buf, points=points, viewpoints=cams)
    r, seconds, peak = measured(lambda: client.post("/detect", content=buf.getvalue(), headers=OCTET))
    assert r.status_code == 422 and r.json()["field"] == "cloud.viewpoints", r.text
    assert "at most 64 camera positions" in r.json()["error"]
    assert peak < 20 * MB and seconds < 2.0, (peak, seconds)
    good_upload_is_served(client, krylon)


def test_sixty_four_cameras_still_pick_each_points_nearest(client: TestClient) -> None:
    """At the cap, the nearest-camera stand-in still runs (bounded): points around each of two far cameras
    are served."""
    rng = np.random.default_rng(2)
    points = np.concatenate([rng.normal(0, 0.02, (300, 3)) + [0, 0, 0.5], rng.normal(0, 0.02, (300, 3))])
    cams = np.concatenate([[[0, 0, 1.0], [0, 0, -0.5]], rng.uniform(5, 6, (62, 3))])
    query = "&".join(f"viewpoint={x},{y},{z}" for x, y, z in cams)
    r = client.post(f"/detect?num_samples=20&{query}", content=npy(points.astype(np.float32)), headers=OCTET)
    assert r.status_code == 200, r.text[:300]
