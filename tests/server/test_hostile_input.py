"""Small requests that declare huge or lying content get a 4xx naming the field,
decided from the declared sizes before anything large is allocated; never a 500."""

from __future__ import annotations

import base64
import io
import struct
import zlib
from collections.abc import Callable
from typing import Any

import numpy as np
import open3d as o3d
import pytest
from fastapi.testclient import TestClient
from PIL import Image

from graspd.core.cloud import ViewpointCloud
from graspd.io.ros import RosDecodeError, decode_pointcloud2, encode_pointcloud2

EYE = np.eye(4).tolist()
INTR = {"fx": 500.0, "fy": 500.0, "cx": 320.0, "cy": 240.0}
OCTET = {"Content-Type": "application/octet-stream"}


def png_bytes(width: int, height: int) -> bytes:
    """A valid black RGB PNG of any size, compressed row by row (a 7000 x 7000 one is ~150 kB)."""
    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    comp = zlib.compressobj(9)
    row = bytes(1 + 3 * width)
    idat = b"".join(comp.compress(row) for _ in range(height)) + comp.flush()
    ihdr = struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)
    return b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", idat) + chunk(b"IEND", b"")


def pcd(points: np.ndarray, declared: int | str, width: int | str | None = None) -> bytes:
    head = (f"# .PCD v0.7\nVERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH "
            f"{declared if width is None else width}\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS {declared}\n"
            f"DATA binary\n")
    return head.encode() + points.astype("<f4").tobytes()


P500 = np.random.default_rng(0).uniform(-0.05, 0.05, (500, 3)).astype(np.float32) + [0, 0, 0.5]
ASCII = ("# .PCD v0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH 1000\nHEIGHT 1\nPOINTS 1000\n"
         "DATA ascii\n" + "".join(f"{x:.4f} {y:.4f} {z:.4f}\n" for x, y, z in P500[:10])).encode()
PLY_BOMB = (b"ply\nformat binary_little_endian 1.0\nelement vertex 20000000\nproperty float x\nproperty float y\n"
            b"property float z\nproperty list uchar int idx\nend_header\n" + bytes(24))

UPLOADS = [
    ("POINTS beyond 64 bits", pcd(P500, 10**20)),
    ("POINTS -1", pcd(P500, -1)),
    ("POINTS 5 with 500 records", pcd(P500, 5)),
    ("WIDTH not POINTS", pcd(P500, 500, width=499)),
    ("ascii 1000 declared, 10 rows", ASCII),
    ("PLY list bomb", PLY_BOMB),
]


@pytest.mark.parametrize(("name", "data"), UPLOADS, ids=[u[0] for u in UPLOADS])
def test_lying_files_are_422_naming_the_points(client: TestClient, name: str, data: bytes) -> None:
    assert len(data) < 10_000
    r = client.post("/detect", content=data, headers=OCTET)
    assert r.status_code == 422, r.text
    assert r.json()["field"] == "cloud.points"


def test_binary_compressed_upload_is_accepted(client: TestClient, krylon: ViewpointCloud, tmp_path: Any) -> None:
    path = tmp_path / "k.pcd"
    o3d.io.write_point_cloud(str(path), o3d.geometry.PointCloud(o3d.utility.Vector3dVector(krylon.points)),
                             compressed=True)
    r = client.post("/detect?num_samples=60&viewpoint=0.5,0,0.3", content=path.read_bytes(), headers=OCTET)
    assert r.status_code == 200, r.text
    as_json = client.post("/detect", json={"cloud": {"points": krylon.points.tolist(), "viewpoints": [[0.5, 0, 0.3]]},
                                           "num_samples": 60}).json()
    assert r.json()["num_points"] == as_json["num_points"]  # LZF-decompressed to the very points written
    assert len(r.json()["grasps"]) > 0


@pytest.mark.parametrize("depth", [1000, 1025, 5000])
def test_deep_json_is_a_4xx_naming_the_body(client: TestClient, depth: int) -> None:
    deep = "[" * depth + "]" * depth
    for text in (deep, f'{{"cloud": {{"points": {deep}}}}}', f'{{"cloud": {{"points": [[0, 0, NaN]]}}, "x": {deep}}}'):
        r = client.post("/detect", content=text, headers={"Content-Type": "application/json"})
        assert r.status_code == 422, r.text[:300]
        assert r.json()["field"] in ("body", "cloud.points", "cloud", "x")


def test_too_large_numbers_are_4xx(client: TestClient) -> None:
    for text in ('{"cloud": {"points": [[1e999, 0, 0]]}}', '{"cloud": {"points": [[0, 0, 1]]}, "num_samples": '
                 + "9" * 5000 + "}"):
        r = client.post("/detect", content=text, headers={"Content-Type": "application/json"})
        assert 400 <= r.status_code < 500, r.text[:300]


def crops(image: dict[str, Any], intrinsics: dict[str, float] = INTR) -> dict[str, Any]:
    return {"intrinsics": intrinsics, "camera_pose": EYE, **image}


def test_huge_png_is_refused_from_its_header(client: TestClient, small_body: Callable[..., dict[str, Any]],
                                             krylon: ViewpointCloud) -> None:
    big = png_bytes(7000, 7000)
    assert len(big) < 1_000_000
    body = {**small_body(krylon), "crops": crops({"image_png": base64.b64encode(big).decode()})}
    r = client.post("/detect", json=body)
    assert r.status_code == 422 and r.json()["field"] == "crops.image_png", r.text
    assert "7000x7000" in r.json()["error"]


@pytest.mark.parametrize(("name", "image", "intrinsics", "field"), [
    ("1x1 png", {"image_png": base64.b64encode(png_bytes(1, 1)).decode()}, INTR, "crops.image_png"),
    ("1x1 array", {"image": [[[0, 0, 0]]]}, INTR, "crops.image"),
    ("principal point outside", {"image_png": base64.b64encode(png_bytes(64, 48)).decode()}, INTR,
     "crops.intrinsics"),
])
def test_images_that_cannot_give_crops_are_422(client: TestClient, small_body: Callable[..., dict[str, Any]],
                                               krylon: ViewpointCloud, name: str, image: dict[str, Any],
                                               intrinsics: dict[str, float], field: str) -> None:
    r = client.post("/detect", json={**small_body(krylon), "crops": crops(image, intrinsics)})
    assert r.status_code == 422 and r.json()["field"] == field, r.text


def test_matching_image_still_gives_crops(client: TestClient, small_body: Callable[..., dict[str, Any]],
                                          krylon: ViewpointCloud) -> None:
    buf = io.BytesIO()
    Image.new("RGB", (64, 48)).save(buf, format="PNG")
    image = {"image_png": base64.b64encode(buf.getvalue()).decode()}
    r = client.post("/detect", json={**small_body(krylon), "crops": crops(image, {"fx": 50, "fy": 50, "cx": 32,
                                                                                   "cy": 24})})
    assert r.status_code == 200, r.text
    grasps = r.json()["grasps"]
    assert grasps and all("crop" in g for g in grasps)
    for g in grasps:  # a square RGB PNG cut from the image sent where the grasp projects into it, else none
        crop = g["crop"]
        assert (crop["png"] is not None) == crop["in_image"]
        if crop["in_image"]:
            with Image.open(io.BytesIO(base64.b64decode(crop["png"]))) as png:
                assert png.mode == "RGB" and png.size[0] == png.size[1] > 0
    assert any(g["crop"]["in_image"] for g in grasps)


def test_405_carries_allow(client: TestClient) -> None:
    r = client.get("/detect")
    assert r.status_code == 405 and r.headers["Allow"] == "POST" and r.json()["error"]


def test_request_id_header_matches_the_body(client: TestClient, body: dict[str, Any]) -> None:
    r = client.post("/detect", json=body)
    assert r.headers["X-Request-ID"] == r.json()["request_id"]
    assert r.json()["grasps"][0]["id"].startswith(r.json()["request_id"])
    bad = client.post("/detect", json={"cloud": {"points": []}})
    assert len(bad.headers["X-Request-ID"]) == 16 and bad.headers["X-Request-ID"] != r.headers["X-Request-ID"]


def test_pointcloud2_declaring_more_than_its_data_is_refused() -> None:
    """CDR PointCloud2 (the Zenoh stream): width x height x point_step checked against the data and the cap."""

    good = encode_pointcloud2(P500)
    assert len(decode_pointcloud2(good).cloud.points) == 500
    width_at = good.find(struct.pack("<I", 500))  # height 1 then width 500 (little-endian CDR)
    for width in (501, 10_000_000, 2**32 - 1):
        lying = good[:width_at] + struct.pack("<I", width) + good[width_at + 4:]
        with pytest.raises(RosDecodeError):
            decode_pointcloud2(lying)
